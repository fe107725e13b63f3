"""The command line: outputs of `run`, help texts, and one-line errors for bad input."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from pipeline_sim.cli import main
from pipeline_sim.output import linear_to_srgb8, read_exr

SMALL = """
[image]
width = 48
height = 32
spp = 4
seed = 2
[camera]
eye = [0.0, 0.5, 4.0]
look_at = [0.0, 0.5, 0.0]
fov_y = 45.0
near = 0.1
far = 20.0
[camera.lens]
radius = 0.05
focus_distance = 4.0
[[objects]]
primitive = "sphere"
radius = 0.7
subdivisions = 1
[objects.open]
translate = [-0.3, 0.5, 0.0]
[objects.close]
translate = [0.3, 0.5, 0.0]
"""


@pytest.fixture
def small_scene(tmp_path):
    p = tmp_path / "small.toml"
    p.write_text(SMALL)
    return p


def test_run_writes_every_output(small_scene, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(small_scene), "--out", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"image.npy", "image.exr", "image.png", "counters.csv", "timing.csv", "queues.csv", "run.json",
            "report.md", "report.html"} <= names
    img = np.load(out / "image.npy")
    assert img.shape == (32, 48, 4) and img.dtype == np.float32
    np.testing.assert_array_equal(read_exr(out / "image.exr"), img)
    png = np.asarray(Image.open(out / "image.png"))
    np.testing.assert_array_equal(png, linear_to_srgb8(img))
    counters = pd.read_csv(out / "counters.csv")
    assert list(counters.columns) == ["unit", "counter", "value"]
    assert set(counters.unit) == {"triangle_setup", "tile_traverser", "tile_test", "zcull", "sample_tester",
                                  "shading", "rop"}
    info = json.loads((out / "run.json").read_text())
    for key in ("arch", "scene_digest", "versions", "seed", "wall_time_s", "frame_cycles", "dimensions"):
        assert key in info
    assert info["dimensions"] == {"motion": True, "lens": True}
    assert info["arch"]["tile_traverser"]["tile_size"] == 4
    text = capsys.readouterr().out
    assert "STE" in text and "frame cycles" in text and "numba kernels ready" in text
    # the html report is self-contained
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "http" not in html.split("<body>")[1]


def test_options_override_scene_and_arch(small_scene, tmp_path):
    out = tmp_path / "o"
    assert main(["run", str(small_scene), "--out", str(out), "--spp", "8", "--tile", "8", "--seed", "9",
                 "--set", "shading.cache_entries=64", "--quiet"]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["image"]["spp"] == 8 and info["seed"] == 9
    assert info["arch"]["tile_traverser"]["tile_size"] == 8
    assert info["arch"]["shading"]["cache_entries"] == 64


def test_entry_point_and_help():
    for args in (["--help"], ["run", "--help"], ["check", "--help"], ["arch", "--help"], ["warmup", "--help"]):
        res = subprocess.run([sys.executable, "-m", "pipeline_sim", *args], capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        assert "usage: pipeline-sim" in res.stdout


BAD_CASES = [
    ("malformed TOML", "[image\nwidth = 3", [], "TOML"),
    ("unknown key", SMALL.replace("fov_y", "fovy"), [], "fovy"),
    ("missing mesh", SMALL.replace('primitive = "sphere"\nradius = 0.7\nsubdivisions = 1', 'mesh = "nope.obj"'),
     [], "nope.obj"),
    ("nan coordinate", SMALL.replace("eye = [0.0, 0.5, 4.0]", "eye = [nan, 0.5, 4.0]"), [], "eye"),
    ("zero width", SMALL.replace("width = 48", "width = 0"), [], "width"),
    ("bad spp option", SMALL, ["--spp", "0"], "spp"),
    ("unknown --set section", SMALL, ["--set", "tile_tst.tile_size=8"], "tile_test"),
    ("unknown --set key", SMALL, ["--set", "zcull.slices=8"], "slices"),
    ("bad --set value", SMALL, ["--set", "tile_traverser.tile_size=3"], "tile_size"),
]


@pytest.mark.parametrize("name,text,extra,needle", BAD_CASES, ids=[c[0] for c in BAD_CASES])
def test_bad_input_one_line_exit_2_nothing_written(name, text, extra, needle, tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(text)
    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "pipeline_sim", "run", str(scene), "--out", str(out), *extra],
                         capture_output=True, text=True)
    assert res.returncode == 2
    err = res.stderr.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err and needle in err
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["scene.toml"]


def test_missing_scene_file(tmp_path):
    res = subprocess.run([sys.executable, "-m", "pipeline_sim", "check", str(tmp_path / "none.toml")],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "none.toml" in res.stderr and "Traceback" not in res.stderr


def test_failed_run_keeps_previous_output(small_scene, tmp_path):
    out = tmp_path / "out"
    assert main(["run", str(small_scene), "--out", str(out), "--quiet"]) == 0
    before = (out / "run.json").read_text()
    assert main(["run", str(small_scene), "--out", str(out), "--set", "rop.blend=mix"]) == 2
    assert (out / "run.json").read_text() == before


def test_sweep_and_report_commands(root, tmp_path):
    """The quick shipped sweep runs through the CLI, resumes, and its report is written."""
    out = tmp_path / "quick"
    sweep = root / "workloads/sweeps/quick.toml"
    assert main(["sweep", str(sweep), "--out", str(out), "--workers", "2", "--quiet"]) == 0
    points = pd.read_csv(out / "points.csv")
    assert len(points) == 6 and (points.status == "ok").all()
    # what accuracy costs: along spp, error falls and cost rises, at every tile size
    for _, group in points.sort_values("image.spp").groupby("tile_traverser.tile_size"):
        assert group.rmse.is_monotonic_decreasing and group.flip.is_monotonic_decreasing
        assert group.frame_cycles.is_monotonic_increasing and group.samples_tested.is_monotonic_increasing
    mtimes = {p.name: p.stat().st_mtime_ns for p in (out / "records").iterdir()}
    assert main(["sweep", str(sweep), "--out", str(out), "--quiet"]) == 0  # resume: nothing recomputed
    assert {p.name: p.stat().st_mtime_ns for p in (out / "records").iterdir()} == mtimes
    assert main(["report", str(out), "-o", str(out / "r.html")]) == 0
    html = (out / "r.html").read_text()
    assert html.count("data:image/png;base64,") >= 5
    assert (out / "r.md").exists()


def test_report_of_a_non_sweep_folder_is_a_user_error(tmp_path):
    res = subprocess.run([sys.executable, "-m", "pipeline_sim", "report", str(tmp_path)], capture_output=True,
                         text=True)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
