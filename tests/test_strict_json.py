"""Every JSON file the tool writes parses with a strict (RFC 8259) parser.

Python's json module writes and reads NaN and Infinity, which are not JSON:
strict parsers (JavaScript's JSON.parse, jq, serde_json) reject the file.
The worst case for a ratio is a scene whose only triangle is degenerate: no
sample is tested, so STE is 0 / 0; and an image identical to the one it is
measured against has an infinite PSNR. Those figures are null. Every file
that `run`, `compare` and `sweep` write is read back here with a parser
that refuses NaN and Infinity.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline_sim.cli import main
from pipeline_sim.output import finite_or_none, write_json
from scenes import mesh_object, scene_toml

SCENE = scene_toml(mesh_object("flat.obj"), width=24, height=16, seed=7, eye_y=0.0)
# one triangle whose three vertices lie on a line: it covers nothing
DEGENERATE_OBJ = "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"


def strict_load(path: Path):
    def refuse(token):
        raise ValueError(f"{path.name}: {token} is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def all_json(folder: Path) -> list[Path]:
    files = sorted(folder.rglob("*.json"))
    assert files, f"no JSON written in {folder}"
    return files


@pytest.fixture
def degenerate_scene(tmp_path):
    (tmp_path / "flat.obj").write_text(DEGENERATE_OBJ)
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


def test_run_json_of_a_scene_with_nothing_tested(degenerate_scene, tmp_path):
    out = tmp_path / "run"
    assert main(["run", str(degenerate_scene), "--out", str(out), "--quiet"]) == 0
    for path in all_json(out):
        strict_load(path)
    info = strict_load(out / "run.json")
    assert info["headline"]["samples_tested"] == 0 and info["headline"]["ste"] is None


def test_comparison_json_with_identical_images_and_nothing_tested(degenerate_scene, tmp_path):
    out = tmp_path / "compare"
    assert main(["compare", str(degenerate_scene), "--algorithms", "bbox", "hierarchical", "--out", str(out),
                 "--quiet"]) == 0
    for path in all_json(out):
        strict_load(path)
    rows = strict_load(out / "comparison.json")["rows"]
    # every image is identical to BBOX's: infinite PSNR, written as null; STE 0 / 0 likewise
    assert [r["psnr_db"] for r in rows] == [None, None] and [r["ste"] for r in rows] == [None, None]


def test_sweep_files_with_a_point_identical_to_its_reference(degenerate_scene, tmp_path):
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'[sweep]\nscene = "{degenerate_scene.name}"\n[reference]\nspp = 4\n'
                     '[grid]\n"pass.shading_mode" = ["per_sample", "cache"]\n')
    out = tmp_path / "sweep_out"
    assert main(["sweep", str(sweep), "--out", str(out), "--executor", "serial", "--quiet"]) == 0
    files = all_json(out)
    assert {p.name for p in files} >= {"sweep.json", "run.json", "trace.json"}
    assert len(list((out / "records").glob("*.json"))) == 2
    for path in files:
        strict_load(path)
    for path in (out / "records").glob("*.json"):
        summary = strict_load(path)["summary"]
        assert summary["status"] == "ok" and summary["ste"] is None and summary["psnr"] is None


def test_writer_refuses_a_non_finite_number(tmp_path):
    """A NaN that reaches write_json without a source deciding what it means is an error, not a NaN token."""
    with pytest.raises(ValueError):
        write_json(tmp_path / "x.json", {"ratio": float("nan")})
    with pytest.raises(ValueError):
        write_json(tmp_path / "x.json", {"psnr": np.float64(np.inf)})
    assert not (tmp_path / "x.json").exists()


def test_finite_or_none():
    assert finite_or_none(float("nan")) is None and finite_or_none(np.inf) is None and finite_or_none(None) is None
    assert finite_or_none(np.float32(0.5)) == 0.5 and type(finite_or_none(np.float32(0.5))) is float
