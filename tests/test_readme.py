"""The README's examples work: its scene and architecture files load and its commands run."""

import re
import shlex
from pathlib import Path

import pytest

from pipeline_sim.cli import main
from pipeline_sim.config import load_arch
from pipeline_sim.scene import load_scene


def blocks(root, lang):
    text = (root / "README.md").read_text()
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


def test_scene_example_loads_and_renders(root, tmp_path):
    scene_blocks = [b for b in blocks(root, "toml") if b.startswith("# scene")]
    assert len(scene_blocks) == 1
    path = root / ".readme_example_scene.toml"  # mesh paths are relative to the repo root
    try:
        path.write_text(scene_blocks[0])
        scene = load_scene(path)
        assert scene.camera.lens is not None and scene.camera.moving
        assert main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    finally:
        path.unlink()


def test_arch_example_loads(root, tmp_path):
    arch_blocks = [b for b in blocks(root, "toml") if b.startswith("# arch")]
    assert len(arch_blocks) == 1
    p = tmp_path / "arch.toml"
    p.write_text(arch_blocks[0])
    arch = load_arch(p)
    assert arch.tile_traverser.tile_size == 16 and arch.shading.replacement == "fifo"


def test_sweep_example_loads(root):
    from pipeline_sim.sweep import load_sweep

    sweep_blocks = [b for b in blocks(root, "toml") if b.startswith("# sweep")]
    assert len(sweep_blocks) == 1
    path = root / ".readme_example_sweep.toml"  # paths are relative to the sweep file
    arch = root / "my_arch.toml"
    try:
        path.write_text(sweep_blocks[0])
        arch.write_text("[zcull]\ntime_slices = 2\n")
        spec = load_sweep(path)
        assert len(spec.points) == 3 * 2 * 2 * 2
    finally:
        path.unlink()
        arch.unlink()


def commands(root):
    out = []
    for block in blocks(root, "sh"):
        for line in block.splitlines():
            line = line.split("#")[0].strip()
            if line.startswith("pipeline-sim "):
                out.append(line)
    return out


def test_readme_lists_commands(root):
    assert len(commands(root)) >= 5


README_COMMANDS = commands(Path(__file__).resolve().parent.parent)


@pytest.mark.parametrize("command", README_COMMANDS)
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
