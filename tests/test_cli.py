"""The command line: outputs of `run`, help texts, and one-line errors for bad input."""

import json
import os
import shlex
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from pipeline_sim.cli import main
from pipeline_sim.output import linear_to_srgb8, read_exr
from scenes import moving_sphere, scene_toml

SMALL = scene_toml(moving_sphere(), seed=2, lens_radius=0.05)


@pytest.fixture
def small_scene(tmp_path):
    p = tmp_path / "small.toml"
    p.write_text(SMALL)
    return p


def test_run_writes_every_output(small_scene, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(small_scene), "--out", str(out)]) == 0
    # a scene is the workload kind "scene": its one pass, "main", under passes/
    assert {p.name for p in out.iterdir()} == {"passes", "results.json", "run.json", "report.md", "report.html",
                                               "report_files", ".pipeline-sim.json"}
    main_pass = out / "passes" / "main"
    assert [p.name for p in (out / "passes").iterdir()] == ["main"]
    assert {p.name for p in main_pass.iterdir()} == {"image.npy", "image.exr", "image.png", "counters.csv",
                                                     "timing.csv", "queues.csv", "trace.json"}
    assert json.loads((out / "results.json").read_text()) == {}
    img = np.load(main_pass / "image.npy")
    assert img.shape == (32, 48, 4) and img.dtype == np.float32
    np.testing.assert_array_equal(read_exr(main_pass / "image.exr"), img)
    png = np.asarray(Image.open(main_pass / "image.png"))
    np.testing.assert_array_equal(png, linear_to_srgb8(img))
    counters = pd.read_csv(main_pass / "counters.csv")
    assert list(counters.columns) == ["unit", "counter", "value", "timing_dependent"]
    dependent = counters.set_index(["unit", "counter"]).timing_dependent
    assert dependent.dtype == bool and not dependent["triangle_setup"].any()
    assert dependent["zcull", "tiles_culled"] and dependent["sample_tester", "samples_tested"]
    assert set(counters.unit) == {"triangle_setup", "tile_traverser", "tile_test", "zcull", "sample_tester",
                                  "shading", "rop"}
    info = json.loads((out / "run.json").read_text())
    for key in ("kind", "workload", "arch", "passes", "versions", "wall_time_s", "frame_cycles", "headline"):
        assert key in info
    assert info["kind"] == "scene" and [p["name"] for p in info["passes"]] == ["main"]
    (state,) = info["passes"]
    assert state["dimensions"] == {"motion": True, "lens": True}
    assert (state["seed"], state["spp"], state["zcull_refresh"], state["textures"]) == (2, 4, "timed", [])
    assert info["arch"]["tile_traverser"]["tile_size"] == 4 and state["arch_changes"] == {}
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
    assert info["workload"]["image"]["spp"] == 8 and info["workload"]["scene"]["image"]["seed"] == 9
    assert (info["passes"][0]["spp"], info["passes"][0]["seed"]) == (8, 9)
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
    assert main(["run", str(small_scene), "--out", str(out), "--set", "pass.blend=mix"]) == 2
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
    assert stat.S_IMODE((out / "points.csv").stat().st_mode) == 0o666 & ~_current_umask()
    assert main(["report", str(out), "-o", str(out / "r.html")]) == 0
    html = (out / "r.html").read_text()
    assert html.count("data:image/png;base64,") >= 5
    assert (out / "r.md").exists()


def _current_umask():
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_report_of_a_non_sweep_folder_is_a_user_error(tmp_path):
    res = subprocess.run([sys.executable, "-m", "pipeline_sim", "report", str(tmp_path)], capture_output=True,
                         text=True)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


# ---------------------------------------------------------------------------
# output locations: never destroy what the tool did not write (pipeline_sim/output_folder.py)


def _cli(*args, cwd=None, umask=None):
    preexec = (lambda: os.umask(umask)) if umask is not None else None
    return subprocess.run([sys.executable, "-m", "pipeline_sim", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, preexec_fn=preexec)


def _one_line_error(res, needle):
    assert res.returncode == 2, res.stderr
    err = res.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and needle in err, err
    assert "numba kernels ready" not in res.stdout   # refused before any simulation


def _tree(root):
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def test_out_an_existing_file_is_refused(small_scene, tmp_path):
    f = tmp_path / "some_file"
    f.write_text("precious")
    before = _tree(tmp_path)
    _one_line_error(_cli("run", small_scene, "--out", f), "not a folder")
    _one_line_error(_cli("run", small_scene, "--out", f, "--force"), "not a folder")
    assert _tree(tmp_path) == before


def test_out_a_folder_with_other_files_is_refused_unless_forced(small_scene, tmp_path):
    d = tmp_path / "mydir"
    d.mkdir()
    (d / "thesis.txt").write_text("years of work")
    before = _tree(tmp_path)
    _one_line_error(_cli("run", small_scene, "--out", d, "-q"), "thesis.txt")
    assert _tree(tmp_path) == before
    res = _cli("run", small_scene, "--out", d, "-q", "--force")
    assert res.returncode == 0, res.stderr
    assert (d / "thesis.txt").read_text() == "years of work" and (d / "passes/main/image.npy").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mydir", "small.toml"]


def test_out_dot(small_scene, tmp_path):
    """`--out .`: refused in a folder of the user's files; rewritten in place in a folder the tool wrote."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "notes.txt").write_text("mine")
    _one_line_error(_cli("run", small_scene, "--out", ".", "-q", cwd=work), "notes.txt")
    (work / "notes.txt").unlink()
    res = _cli("run", small_scene, "--out", ".", "-q", cwd=work)      # empty: fine
    assert res.returncode == 0, res.stderr
    res = _cli("run", small_scene, "--out", ".", "-q", "--seed", "5", cwd=work)   # the tool's own: again
    assert res.returncode == 0, res.stderr
    assert json.loads((work / "run.json").read_text())["passes"][0]["seed"] == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.toml", "work"]   # nothing hidden beside it
    assert not [p for p in work.iterdir() if p.name.startswith(".") and p.name != ".pipeline-sim.json"]


def _read_only_mount_available():
    import shutil

    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o ro tmpfs /mnt"], capture_output=True)
    return probe.returncode == 0


@pytest.mark.skipif(not _read_only_mount_available(), reason="needs unshare -m and mount (a read-only tmpfs)")
def test_read_only_file_system_is_refused_before_the_work(small_scene, tmp_path, root, sweep_results):
    """Every command that writes checks its destination first: one line, exit 2, no simulation run."""
    ro = tmp_path / "ro"
    ro.mkdir()
    commands = {
        "run": ["run", small_scene, "--out", ro / "run"],
        "compare": ["compare", small_scene, "--algorithms", "bbox", "hierarchical", "--out", ro / "cmp"],
        "sweep": ["sweep", root / "workloads/sweeps/quick.toml", "--out", ro / "sweep"],
        "report": ["report", sweep_results, "-o", ro / "report.html"],
    }
    for name, args in commands.items():
        cli = " ".join(shlex.quote(str(a)) for a in [sys.executable, "-m", "pipeline_sim", *args])
        res = subprocess.run(["unshare", "-m", "sh", "-c", f"mount -t tmpfs -o ro tmpfs {shlex.quote(str(ro))} "
                              f"&& {cli}"], capture_output=True, text=True)
        _one_line_error(res, "Read-only file system")
        assert "STE" not in res.stdout + res.stderr, name


def test_unwritable_path_is_refused_before_the_work(small_scene, tmp_path, sweep_results):
    """A destination under a regular file cannot be created, whoever runs the tool (root included)."""
    (tmp_path / "f").write_text("x")
    _one_line_error(_cli("run", small_scene, "--out", tmp_path / "f" / "out"), "cannot write")
    _one_line_error(_cli("compare", small_scene, "--algorithms", "bbox", "--out", tmp_path / "f" / "c"),
                    "cannot write")
    _one_line_error(_cli("report", sweep_results, "-o", tmp_path / "f" / "r.html"), "is not a folder")
    assert (tmp_path / "f").read_text() == "x"


def test_sigkill_while_writing_leaves_the_previous_outputs_and_the_next_run_cleans_up(small_scene, tmp_path):
    out = tmp_path / "out"
    assert _cli("run", small_scene, "--out", out, "-q").returncode == 0
    before = _tree(out)
    killed = False
    for _ in range(5):   # the write phase lasts about a second; kill inside it
        proc = subprocess.Popen([sys.executable, "-m", "pipeline_sim", "run", str(small_scene), "--out", str(out),
                                 "--seed", "7", "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            staging = [p for p in tmp_path.glob(".out.pipeline-sim-*.tmp") if (p / "run.json").exists()]
            if staging:
                proc.send_signal(signal.SIGKILL)
                proc.wait()
                killed = True
                break
            time.sleep(0.002)
        if killed:
            break
        proc.wait()
        if proc.returncode == 0:   # finished before it was caught: restore the first outputs and try again
            assert _cli("run", small_scene, "--out", out, "-q").returncode == 0
            before = _tree(out)
    assert killed, "never caught the run while it wrote its outputs"
    assert _tree(out) == before                                     # the previous outputs, untouched
    assert list(tmp_path.glob(".out.pipeline-sim-*.tmp"))           # what the killed write left
    res = _cli("run", small_scene, "--out", out, "--seed", "7", "-q")
    assert res.returncode == 0, res.stderr
    assert not list(tmp_path.glob(".out.*"))                        # recognised and removed
    assert json.loads((out / "run.json").read_text())["passes"][0]["seed"] == 7


def test_written_files_have_the_umask_modes(small_scene, tmp_path):
    out = tmp_path / "runs" / "default"
    assert _cli("run", small_scene, "--out", out, "-q", umask=0o022).returncode == 0
    mode = lambda p: stat.S_IMODE(p.stat().st_mode)  # noqa: E731
    assert mode(out) == 0o755 and mode(out / "report_files") == 0o755
    figures = list((out / "report_files").glob("*.png"))
    assert figures
    assert mode(out / "passes") == 0o755 and mode(out / "passes/main") == 0o755
    for f in [*figures, out / "passes/main/image.npy", out / "run.json", out / "report.html"]:
        assert mode(f) == 0o644, f


@pytest.fixture
def sweep_results(tmp_path):
    """The smallest valid sweep results folder `report` accepts."""
    d = tmp_path / "results"
    d.mkdir()
    (d / "sweep.json").write_text(json.dumps({"scene": "s.toml", "points": []}))
    pd.DataFrame({"point_id": ["p1"], "status": ["error"], "error": ["x"]}).to_csv(d / "points.csv", index=False)
    pd.DataFrame(columns=["point_id", "kind", "unit", "name", "value"]).to_csv(d / "results.csv", index=False)
    return d


def test_help_of_each_command_shows_its_own_examples():
    from pipeline_sim.cli import EXAMPLES, build_parser

    parser = build_parser()
    for command, examples in EXAMPLES.items():
        res = subprocess.run([sys.executable, "-m", "pipeline_sim", command, "--help"], capture_output=True,
                             text=True)
        assert res.returncode == 0
        for other, lines in EXAMPLES.items():
            for line in lines:
                assert (line in res.stdout) == (other == command or line in examples), (command, line)
        for line in examples:   # every example parses, and the files it names are shipped
            args = parser.parse_args(shlex.split(line)[1:])
            for key in ("scene", "sweep"):
                name = getattr(args, key, None)
                if name and name.startswith("workloads/"):
                    assert (Path(__file__).resolve().parent.parent / name).is_file(), line


def test_commands_in_shipped_files_are_real_commands(root):
    """Every command a shipped workload file shows in its comments parses and names files that exist."""
    from pipeline_sim.cli import build_parser

    parser = build_parser()
    shown = []
    for path in sorted((root / "workloads").rglob("*.toml")):
        for line in path.read_text().splitlines():
            text = line.lstrip("# ").strip()
            if line.startswith("#") and ("pipeline-sim " in text or "python -m" in text):
                shown.append((path.name, text))
    assert shown
    for name, text in shown:
        words = shlex.split(text)
        assert words[0] == "pipeline-sim", f"{name}: {text}"
        args = parser.parse_args(words[1:])
        for key in ("scene", "sweep"):
            if getattr(args, key, None):
                assert (root / getattr(args, key)).is_file(), f"{name}: {text}"


@pytest.mark.parametrize("content", ["not json", "[1, 2]", '{"a": 1}'])
def test_sweep_into_a_folder_with_a_foreign_sweep_json_is_refused(root, tmp_path, content):
    out = tmp_path / "s"
    out.mkdir()
    (out / "sweep.json").write_text(content)
    _one_line_error(_cli("sweep", root / "workloads/sweeps/quick.toml", "--out", out, "-q"), "sweep.json")
    assert (out / "sweep.json").read_text() == content and [p.name for p in out.iterdir()] == ["sweep.json"]


@pytest.mark.skipif(not _read_only_mount_available(), reason="needs unshare -m and mount (a small tmpfs)")
def test_a_full_disk_is_one_line_and_leaves_nothing(small_scene, tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    cli = " ".join(shlex.quote(str(a)) for a in [sys.executable, "-m", "pipeline_sim", "run", small_scene, "--out",
                                                 disk / "out", "-q"])
    res = subprocess.run(["unshare", "-m", "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs {shlex.quote(str(disk))} "
                          f"&& {cli}; echo rc=$?; ls -A {shlex.quote(str(disk))}"], capture_output=True, text=True)
    assert "rc=1" in res.stdout, res.stdout + res.stderr
    err = res.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and "No space left on device" in err, err
    assert res.stdout.strip().endswith("rc=1")       # and the disk holds nothing afterwards


@pytest.mark.parametrize("command", [["check", "{f}"], ["arch", "--arch", "{f}"], ["sweep", "{f}", "--out", "{o}"]])
def test_an_input_that_is_a_fifo_is_one_line_not_a_hang(tmp_path, command):
    """Every input file (scene, architecture, sweep) is read through one reader that refuses what is not a
    regular file: reading a FIFO with no writer blocked forever."""
    fifo = tmp_path / "input.toml"
    os.mkfifo(fifo)
    args = [a.format(f=fifo, o=tmp_path / "out") for a in command]
    res = subprocess.run([sys.executable, "-m", "pipeline_sim", *args], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "not a regular file" in res.stderr, res.stderr
    assert not (tmp_path / "out").exists()
