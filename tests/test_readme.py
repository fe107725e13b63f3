"""The examples of README.md and docs/*.md work: every TOML example loads and
means what its text says (scenes also render), and every command runs.

Each TOML block of the documentation starts with a marker line naming its
kind (``# scene``, ``# arch`` or ``# sweep``), so that none goes untested.
"""

import math
import re
import shlex
import tomllib
from pathlib import Path

import pytest

from pipeline_sim.cli import main
from pipeline_sim.config import load_arch
from pipeline_sim.scene import load_scene

ROOT = Path(__file__).resolve().parent.parent
KINDS = ("scene", "arch", "sweep")


def doc_files(root: Path) -> list[Path]:
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def blocks(root: Path, lang: str) -> list[tuple[str, str]]:
    """(file, text) of every fenced ``lang`` block of the documentation."""
    return [(path.relative_to(root).as_posix(), block) for path in doc_files(root)
            for block in re.findall(rf"```{lang}\n(.*?)```", path.read_text(), flags=re.S)]


def examples(kind: str) -> list[str]:
    return [b for _, b in blocks(ROOT, "toml") if b.startswith(f"# {kind}\n")]


def test_every_toml_example_is_marked(root):
    for where, block in blocks(root, "toml"):
        assert block.split("\n", 1)[0] in [f"# {k}" for k in KINDS], f"{where}: unmarked TOML example"
    for kind in KINDS:
        assert examples(kind), f"no '# {kind}' example in README.md or docs/"


@pytest.mark.parametrize("block", examples("scene"))
def test_scene_example_loads_and_renders(root, tmp_path, block):
    data = tomllib.loads(block)
    path = root / ".readme_example_scene.toml"  # mesh paths are relative to the repo root
    try:
        path.write_text(block)
        scene = load_scene(path)
        assert main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    finally:
        path.unlink()
    image, camera = data["image"], data["camera"]
    assert (scene.image.width, scene.image.height, scene.image.spp) == (image["width"], image["height"], image["spp"])
    assert [o.name for o in scene.objects] == [o["name"] for o in data.get("objects", [])]
    assert (scene.camera.lens is not None) == ("lens" in camera)
    moves = any(k in camera and camera[k] != camera[k.removesuffix("_close")] for k in ("eye_close", "look_at_close"))
    assert scene.camera.moving == moves
    for table, got in (("pass", scene.pass_state), ("simulation", scene.simulation)):
        for key, value in data.get(table, {}).items():
            if isinstance(value, dict):
                assert all(getattr(getattr(got, key), k) == v for k, v in value.items()), f"[{table}.{key}]"
            else:
                assert getattr(got, key) == value, f"[{table}] {key}"


@pytest.mark.parametrize("block", examples("arch"))
def test_arch_example_loads(tmp_path, block):
    p = tmp_path / "arch.toml"
    p.write_text(block)
    resolved = load_arch(p).to_dict()
    for section, keys in tomllib.loads(block).items():
        for key, value in keys.items():
            assert resolved[section][key] == value, f"[{section}] {key}"


@pytest.mark.parametrize("block", examples("sweep"))
def test_sweep_example_loads(root, block):
    from pipeline_sim.sweep import load_sweep

    data = tomllib.loads(block)
    path = root / ".readme_example_sweep.toml"  # paths are relative to the sweep file
    arch = root / data["sweep"]["arch"] if "arch" in data["sweep"] else None
    assert arch is None or not arch.exists()
    try:
        path.write_text(block)
        if arch is not None:
            arch.write_text("[zcull]\ntime_slices = 2\n")
        spec = load_sweep(path)
    finally:
        path.unlink()
        if arch is not None:
            arch.unlink()
    grid = [len(v) for v in data.get("grid", {}).values()]
    zips = [len(next(iter(group.values()))) for group in data.get("zip", [])]
    assert len(spec.points) == math.prod(grid + zips)


def commands(root: Path) -> list[str]:
    out = []
    for _, block in blocks(root, "sh"):
        for line in block.splitlines():
            line = line.split("#")[0].strip()
            if line.startswith("pipeline-sim "):
                out.append(line)
    return out


def test_readme_lists_commands(root):
    assert len(commands(root)) >= 5


@pytest.mark.parametrize("command", commands(ROOT))
def test_readme_command_runs(root, tmp_path, monkeypatch, command):
    args = shlex.split(command)[1:]
    if args[0] == "report":  # reports the sweep the README runs just before
        sweep = root / "workloads/sweeps/quick.toml"
        assert main(["sweep", str(sweep), "--out", str(tmp_path / "out"), "--quiet"]) == 0
        args[1] = str(tmp_path / "out")
    if "--out" in args:
        args[args.index("--out") + 1] = str(tmp_path / "out")
    if "-o" in args:
        args[args.index("-o") + 1] = str(tmp_path / "report.html")
    monkeypatch.chdir(root)
    assert main(args + (["--quiet"] if args[0] in ("run", "sweep") else [])) == 0
