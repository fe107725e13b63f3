"""Sweeps: the sweep file, resuming after a real kill, failing points, the dask executor."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline_sim.errors import UserError
from pipeline_sim.sweep import HOST_TIMING_FIELDS, load_sweep, point_id, run_sweep, toml_literal
from scenes import moving_sphere, scene_toml

ROOT = Path(__file__).resolve().parent.parent


TINY = """
[sweep]
scene = "scene.toml"
[reference]
kind = "pipeline"
spp = 16
[grid]
"image.spp" = [1, 4]
"tile_traverser.tile_size" = [8, 16]
"""

# 8 points of about half a second each, so a kill lands in the middle
KILL = """
[sweep]
scene = "scene.toml"
[reference]
spp = 16
[grid]
"image.width" = [96]
"image.height" = [54]
"image.spp" = [8, 16, 32, 64]
"tile_traverser.tile_size" = [8, 16]
"""


def _folder(path: Path, sweep: str, subdivisions: int = 1) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    (path / "scene.toml").write_text(scene_toml(moving_sphere(subdivisions), width=32, height=18, seed=2, lens_radius=0.05))
    (path / "sweep.toml").write_text(sweep)
    return path / "sweep.toml"


def _comparable(frame: pd.DataFrame) -> pd.DataFrame:
    """The points table without the host-timing columns, rows by point id."""
    return frame.drop(columns=list(HOST_TIMING_FIELDS)).sort_values("point_id").reset_index(drop=True)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny sweep run once with the default (local process pool) executor."""
    base = tmp_path_factory.mktemp("tiny")
    sweep = _folder(base, TINY)
    out = base / "out"
    frame = run_sweep(load_sweep(sweep), out, executor="local", workers=2, progress=False)
    return sweep, out, frame


def test_tiny_sweep_rows_files_and_tables(tiny):
    sweep, out, frame = tiny
    spec = load_sweep(sweep)
    ids = [point_id(p) for p in spec.points]
    assert len(ids) == 4 and len(set(ids)) == 4
    points = pd.read_csv(out / "points.csv")
    assert list(points.point_id) == ids  # sweep order, each point once
    assert (points.status == "ok").all()
    assert sorted(zip(points["image.spp"], points["tile_traverser.tile_size"])) == [(1, 8), (1, 16), (4, 8), (4, 16)]
    for col in ("frame_cycles", "ops_total", "samples_tested", "samples_covered", "ste", "shader_executions",
                "shader_executions_per_pixel", "depth_bytes_per_pixel", "bottleneck_unit",
                "rmse", "psnr", "ssim", "flip"):
        assert points[col].notna().all(), col
    # more samples, less error; the tile size changes work, not the image
    by = points.set_index(["image.spp", "tile_traverser.tile_size"])
    assert by.loc[(4, 8), "rmse"] < by.loc[(1, 8), "rmse"]
    assert by.loc[(1, 8), "rmse"] == by.loc[(1, 16), "rmse"]
    assert by.loc[(1, 16), "samples_tested"] > by.loc[(1, 8), "samples_tested"]

    results = pd.read_csv(out / "results.csv", keep_default_na=False)
    assert list(results.columns) == ["point_id", "kind", "unit", "name", "value"]
    assert not results.duplicated(["point_id", "kind", "unit", "name"]).any()
    assert set(results.kind) == {"counter", "summary"}
    assert (results[results.kind == "summary"].unit == "").all()
    for pid in ids:
        counters = pd.read_csv(out / "points" / pid / "counters.csv")
        mine = results[(results.point_id == pid) & (results.kind == "counter")]
        assert len(mine) == len(counters)
        summ = results[(results.point_id == pid) & (results.kind == "summary")].set_index("name").value
        assert float(summ["flip"]) == pytest.approx(float(points.set_index("point_id").loc[pid, "flip"]))
        folder = out / "points" / pid
        for name in ("image.npy", "error_map.npy", "image.png", "counters.csv", "timing.csv", "queues.csv",
                     "trace.json", "run.json"):
            assert (folder / name).is_file(), name
        assert np.load(folder / "image.npy").shape == (18, 32, 4)
        assert np.load(folder / "error_map.npy").shape == (18, 32)
        trace = json.loads((folder / "trace.json").read_text())
        assert set(trace) == {"units", "queues", "frame_cycles"}
        run = json.loads((folder / "run.json").read_text())
        assert run["params"] == spec.points[ids.index(pid)]
        assert run["arch"]["tile_traverser"]["tile_size"] == run["params"]["tile_traverser.tile_size"]
        assert run["image"]["spp"] == run["params"]["image.spp"] and run["scene_digest"] == spec.scene_digest
        assert "numpy" in run["versions"]
    meta = json.loads((out / "sweep.json").read_text())
    assert [p["point_id"] for p in meta["points"]] == ids
    assert len(list((out / "records").glob("*.json"))) == 4
    assert len(list((out / "reference").glob("*.npy"))) == 1  # one image size, one reference


def test_rerun_computes_nothing_and_extension_reuses_points(tiny, tmp_path, capsys):
    sweep, shared, frame = tiny
    out = tmp_path / "out"
    shutil.copytree(shared, out)  # the fixture's folder stays as it is for the other tests
    before = {p: p.stat().st_mtime_ns for p in (out / "records").glob("*.json")}
    again = run_sweep(load_sweep(sweep), out, executor="local", workers=2, progress=True)
    assert "already done" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in (out / "records").glob("*.json")} == before
    pd.testing.assert_frame_equal(_comparable(again), _comparable(frame))

    # the same points written in another key order, plus one more spp value: only the new ones run
    extended = tmp_path / "extended.toml"
    shutil.copy(sweep.parent / "scene.toml", tmp_path / "scene.toml")
    extended.write_text(TINY.replace('"image.spp" = [1, 4]\n"tile_traverser.tile_size" = [8, 16]',
                                     '"tile_traverser.tile_size" = [16, 8]\n"image.spp" = [4, 1, 2]'))
    spec = load_sweep(extended)
    assert {point_id(p) for p in spec.points} >= set(frame.point_id)
    result = run_sweep(spec, out, executor="serial", progress=True)
    err = capsys.readouterr().err
    assert "6 points, 4 done, 2 to run" in err
    assert err.count(" ok wall=") == 2  # one plain line per finished point (stderr is not a terminal)
    assert len(result) == 6 and result.point_id.is_unique
    assert {p: p.stat().st_mtime_ns for p in (out / "records").glob("*.json") if p in before} == before


def test_point_id_is_order_independent():
    a = {"image.spp": 4, "tile_traverser.tile_size": 8}
    b = {"tile_traverser.tile_size": 8, "image.spp": 4}
    assert point_id(a) == point_id(b)
    assert point_id(a) != point_id({**a, "image.spp": 2})
    assert len(point_id(a)) == 12 and int(point_id(a), 16) >= 0


def test_real_kill_then_resume(tmp_path):
    sweep = _folder(tmp_path / "killed", KILL, subdivisions=3)
    out = tmp_path / "killed" / "out"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen(
        [sys.executable, "-c",
         "import sys; from pipeline_sim.sweep import load_sweep, run_sweep; "
         "run_sweep(load_sweep(sys.argv[1]), sys.argv[2], executor='local', workers=1, progress=False)",
         str(sweep), str(out)],
        cwd=ROOT, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    records = out / "records"
    deadline = time.monotonic() + 120
    try:
        while len(list(records.glob("*.json"))) < 2:
            assert proc.poll() is None, f"the sweep ended before it was killed: {proc.stderr.read().decode()}"
            assert time.monotonic() < deadline, "no records after 120 s"
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the parent and its worker: one process group
        proc.wait()
        proc.stderr.close()
    done = sorted(records.glob("*.json"))
    assert 2 <= len(done) < 8, "the kill came too late to test anything"
    # a point folder without its record (as if killed between the two): must be computed again
    victim = done[0].stem
    assert (out / "points" / victim).is_dir()
    done[0].unlink()
    stamp = (out / "points" / victim / "run.json").stat().st_mtime_ns
    kept = {p.name: p.stat().st_mtime_ns for p in done[1:]}

    resumed = run_sweep(load_sweep(sweep), out, executor="local", workers=1, progress=False)

    assert {p.name: p.stat().st_mtime_ns for p in records.glob("*.json") if p.name in kept} == kept  # not redone
    assert (out / "points" / victim / "run.json").stat().st_mtime_ns != stamp  # redone
    points = pd.read_csv(out / "points.csv")
    assert len(points) == 8 and points.point_id.is_unique and (points.status == "ok").all()
    assert sorted(p.name for p in (out / "points").iterdir()) == sorted(points.point_id)  # no leftovers
    assert len(list(records.iterdir())) == 8
    results = pd.read_csv(out / "results.csv", keep_default_na=False)
    assert not results.duplicated(["point_id", "kind", "unit", "name"]).any()

    clean = tmp_path / "clean"
    whole = run_sweep(load_sweep(sweep), clean, executor="serial", progress=False)
    pd.testing.assert_frame_equal(_comparable(points), _comparable(pd.read_csv(clean / "points.csv")))
    pd.testing.assert_frame_equal(_comparable(resumed), _comparable(whole))
    host = results.name.isin(HOST_TIMING_FIELDS)
    other = pd.read_csv(clean / "results.csv", keep_default_na=False)
    key = ["point_id", "kind", "unit", "name"]
    pd.testing.assert_frame_equal(results[~host].sort_values(key).reset_index(drop=True),
                                  other[~other.name.isin(HOST_TIMING_FIELDS)].sort_values(key).reset_index(drop=True))


def test_failing_point_is_recorded_and_the_others_finish(tmp_path):
    # A shading cache of 2^62 entries is outside the setting's range. Loading the sweep refuses
    # it, so it is put into the points after loading, as a stale or hand-made spec would have it:
    # those points fail only when they run.
    huge = 4611686018427387904
    sweep = _folder(tmp_path, TINY.replace('"tile_traverser.tile_size" = [8, 16]', "")
                    + '[[zip]]\n"shading.cache_entries" = [1024, 2048]\n"shading.cache_ways" = [8, 1]\n')
    with pytest.raises(UserError, match="cache_entries: must be from 1 to"):
        load_sweep(_folder(tmp_path / "refused", sweep.read_text().replace("2048", str(huge))))
    spec = load_sweep(sweep)
    spec.points = [{**p, "shading.cache_entries": huge} if p["shading.cache_entries"] == 2048 else p
                   for p in spec.points]
    assert len(spec.points) == 4
    frame = run_sweep(spec, tmp_path / "out", executor="local", workers=2, progress=False)
    points = pd.read_csv(tmp_path / "out" / "points.csv", keep_default_na=False)
    assert len(points) == 4 and len(frame) == 4
    bad = points[points["shading.cache_entries"] == 4611686018427387904]
    good = points[points["shading.cache_entries"] == 1024]
    assert (bad.status == "error").all() and (good.status == "ok").all()
    assert all(msg and "\n" not in msg for msg in bad.error)
    assert all("cache_entries: must be from 1 to" in msg for msg in bad.error)
    for pid in bad.point_id:
        rec = json.loads((tmp_path / "out" / "records" / f"{pid}.json").read_text())
        assert "Traceback" in rec["traceback"]
        assert not (tmp_path / "out" / "points" / pid).exists()
    # a failed point is done too: running again computes nothing
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "out" / "records").glob("*.json")}
    run_sweep(spec, tmp_path / "out", executor="serial", progress=False)
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "out" / "records").glob("*.json")} == before


def test_dask_local_cluster_matches_local_pool(tiny, tmp_path):
    pytest.importorskip("distributed")
    sweep, _, local = tiny
    frame = run_sweep(load_sweep(sweep), tmp_path / "dask", executor="dask", workers=2, progress=False)
    assert (frame.status == "ok").all()
    pd.testing.assert_frame_equal(_comparable(frame), _comparable(local))
    pd.testing.assert_frame_equal(_comparable(pd.read_csv(tmp_path / "dask" / "points.csv")),
                                  _comparable(pd.read_csv(tiny[1] / "points.csv")))


BAD = [
    ('[sweep]\nscene = "scene.toml"\n[grdi]\n"image.spp" = [1]\n', "unknown key 'grdi' (did you mean 'grid'?)"),
    ('[sweep]\nscene = "missing.toml"\n', "sweep.scene: scene file 'missing.toml' not found"),
    ('[grid]\n"image.spp" = [1]\n', "[sweep] table"),
    ('[sweep]\nscene = "scene.toml"\nmetric = ["rmse"]\n', "did you mean 'metrics'"),
    ('[sweep]\nscene = "scene.toml"\nmetrics = ["rmes"]\n', "did you mean 'rmse'"),
    ('[sweep]\nscene = "scene.toml"\nset = ["zcull.time_slice=4"]\n', "sweep.set"),
    ('[sweep]\nscene = "scene.toml"\narch = "nope.toml"\n', "sweep.arch: architecture file 'nope.toml' not found"),
    ('[sweep]\nscene = "scene.toml"\n[reference]\nkind = "acumulation"\n', "did you mean 'accumulation'"),
    ('[sweep]\nscene = "scene.toml"\n[reference]\nsp = 16\n', "did you mean 'spp'"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"tile_traverser.tilesize" = [8]\n', "did you mean 'tile_size'"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"tile_travrser.tile_size" = [8]\n', "did you mean 'tile_traverser'"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"image.sp" = [8]\n', "did you mean 'spp'"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"tile_traverser.tile_size" = []\n', "[grid] tile_traverser.tile_size: "
                                                                                 "the list of values is empty"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"tile_traverser.tile_size" = [8, 12]\n',
     "[grid] tile_traverser.tile_size = 12"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"pass.blend" = ["replace", "bogus"]\n', 'pass.blend = "bogus"'),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"rop.blend" = ["add"]\n',
     '[grid] rop.blend: rop.blend is pass state now: name it "pass.blend" instead'),
    ('[sweep]\nscene = "scene.toml"\nset = ["pipeline.region_samples=0"]\n',
     'pipeline.region_samples is a simulation option now: name it "simulation.region_samples" instead'),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"pass.clip.t_hi" = [0.5, 2.0]\n', "pass.clip.t_hi = 2.0"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"pass.clip.t_high" = [0.5]\n', "did you mean 't_hi'"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"simulation.region_samples" = [-1]\n',
     "simulation.region_samples: must be from 0 to"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"image.spp" = [1, 3]\n',
     "point image.spp=3: spp = 3 must be a power of two"),
    ('[sweep]\nscene = "scene.toml"\n[[zip]]\n"shading.cache_entries" = [256, 1024]\n"shading.cache_ways" = [4]\n',
     "[[zip]] #1: lists must have equal lengths"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"shading.cache_entries" = [1024]\n"shading.cache_ways" = [8, 5]\n',
     "shading.cache_ways = 5"),
    ('[sweep]\nscene = "scene.toml"\n[grid]\n"image.spp" = [1]\n[[zip]]\n"image.spp" = [2]\n', "already varied"),
    ('[sweep\n', "invalid TOML"),
]


@pytest.mark.parametrize("text, expected", BAD)
def test_validation_errors_are_one_line(tmp_path, text, expected):
    sweep = _folder(tmp_path, text)
    with pytest.raises(UserError) as err:
        load_sweep(sweep)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(str(sweep)) and expected in msg, msg


def test_cross_key_rules_are_judged_per_point(tmp_path):
    # 100 entries is not a multiple of the default 8 ways, but every point pairs it with 4 ways
    sweep = _folder(tmp_path, '[sweep]\nscene = "scene.toml"\n[[zip]]\n"shading.cache_entries" = [100, 1024]\n'
                              '"shading.cache_ways" = [4, 8]\n')
    assert len(load_sweep(sweep).points) == 2


def test_other_sweep_in_folder_is_refused(tiny, tmp_path):
    sweep, out, _ = tiny
    other = sweep.parent / "other_reference.toml"
    other.write_text(TINY.replace("spp = 16", "spp = 32"))
    with pytest.raises(UserError, match="different sweep"):
        run_sweep(load_sweep(other), out, executor="serial", progress=False)


def test_shipped_sweeps_validate():
    study = load_sweep(ROOT / "workloads/sweeps/accuracy_cost.toml")
    assert len(study.points) == 7 * 2 * 2 * 2
    assert study.reference.kind == "pipeline" and study.reference.spp == 256
    assert {p["image.spp"] for p in study.points} == {1, 2, 4, 8, 16, 32, 64}
    quick = load_sweep(ROOT / "workloads/sweeps/quick.toml")
    assert 2 <= len(quick.points) <= 8


def test_arch_file_fixed_set_and_zip_reach_the_run(tmp_path):
    (tmp_path / "arch.toml").write_text("[zcull]\ntime_slices = 8\n[shading]\nreplacement = \"fifo\"\n")
    sweep = _folder(tmp_path, '[sweep]\nscene = "scene.toml"\narch = "arch.toml"\nset = ["zcull.lens_boxes=1"]\n'
                              'metrics = ["rmse", "flip"]\n[reference]\nspp = 4\n'
                              '[[zip]]\nshading.cache_entries = [64]\nshading.cache_ways = [2]\n')
    spec = load_sweep(sweep)
    assert spec.points == [{"shading.cache_entries": 64, "shading.cache_ways": 2}]
    frame = run_sweep(spec, tmp_path / "out", executor="serial", progress=False)
    assert list(frame.columns[-3:]) == ["rmse", "flip", "error"] and "ssim" not in frame
    run = json.loads((tmp_path / "out" / "points" / frame.point_id[0] / "run.json").read_text())
    assert run["arch"]["zcull"] == {**run["arch"]["zcull"], "time_slices": 8, "lens_boxes": 1}
    assert run["arch"]["shading"]["replacement"] == "fifo"
    assert (run["arch"]["shading"]["cache_entries"], run["arch"]["shading"]["cache_ways"]) == (64, 2)
    assert run["set"] == ["zcull.lens_boxes=1", "shading.cache_entries=64", "shading.cache_ways=2"]


@given(st.one_of(st.booleans(), st.integers(-2**63, 2**63 - 1), st.floats(allow_nan=True), st.text()))
def test_toml_literal_reads_back_as_the_same_value(value):
    """The --set right-hand side a sweep writes for a point parses back (tomllib) to the value it holds."""
    import tomllib

    back = tomllib.loads(f"v = {toml_literal(value)}")["v"]
    assert back == value or (value != value and back != back)
    assert type(back) is type(value)


# ---------------------------------------------------------------------------
# A workload kind's own keys and results

OCCLUSION = """kind = "occlusion"
width = 16
height = 16
spp = 1
proxies = 2
tile_sizes = [8]
time_slices = [1]
lens_boxes = [1]
"""

def _doc_example(section: str) -> str:
    """The first TOML block under the heading ``section`` of docs/sweep-format.md."""
    text = (ROOT / "docs" / "sweep-format.md").read_text()
    after = text[text.index(f"## {section}\n"):]
    return after[after.index("```toml\n") + 8:after.index("\n```", after.index("```toml\n"))]


# the documentation's example, on a small copy of the occlusion file
WORKLOAD_SWEEP = _doc_example("A workload kind's results").replace(
    'scene = "workloads/apps/occlusion/occlusion.toml"', 'scene = "occlusion.toml"')


def _workload_folder(path: Path, sweep: str) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    (path / "occlusion.toml").write_text(OCCLUSION)
    (path / "sweep.toml").write_text(sweep)
    return path / "sweep.toml"


def test_workload_keys_vary_the_file_and_results_become_columns(tmp_path):
    from reports.sweep_report import build_report

    out = tmp_path / "out"
    assert 'scene = "occlusion.toml"' in WORKLOAD_SWEEP
    frame = run_sweep(load_sweep(_workload_folder(tmp_path, WORKLOAD_SWEEP)), out, executor="serial",
                      progress=False)
    assert (frame.status == "ok").all() and len(frame) == 4
    points = pd.read_csv(out / "points.csv")
    listed = [c for c in points.columns if c.startswith("result.")]
    assert listed[:2] == ["result.proxies", "result.truly_occluded"]  # the listed results first
    for _, row in points.iterrows():
        folder = out / "points" / row.point_id
        resolved = json.loads((folder / "run.json").read_text())["workload"]
        results = json.loads((folder / "results.json").read_text())
        # the point's file keys reached the workload, and its results reached the table
        assert json.loads(str(row["workload.time_slices"])) == resolved["settings"]["time_slices"]
        assert row["workload.proxies"] == resolved["settings"]["proxies"]
        assert row["result.proxies"] == results["proxies"] == row["workload.proxies"]
        assert row["result.truly_occluded"] == results["truly_occluded"]
        assert row["result.configuration.time_slices"] == results["configuration"]["time_slices"]
    html = build_report(out, out / "report.html")
    text = html.with_suffix(".md").read_text()
    assert "error metric: result.proxies (lower is better)" in text  # the first listed result, by default
    build_report(out, out / "report.html", metric="result.truly_occluded", force=True)
    assert "error metric: result.truly_occluded (higher is better)" in html.with_suffix(".md").read_text()


@pytest.mark.parametrize("grid, message", [
    ('"workload.proxie" = [2]', "unknown key 'proxie' (did you mean 'proxies'?)"),
    ('"workload.proxies" = [0]', "[grid] workload.proxies = 0: proxies:"),
    ('"workload.tile_sizes.x" = [1]', "workload.tile_sizes.x: 'tile_sizes' is not a table of the file"),
    ('"workload.proxies" = [[1, [2]]]', "values must be numbers, booleans, strings or lists of them"),
])
def test_bad_workload_keys_are_one_line(tmp_path, grid, message):
    sweep = _workload_folder(tmp_path, f"[sweep]\nscene = \"occlusion.toml\"\n[grid]\n{grid}\n")
    with pytest.raises(UserError) as exc:
        load_sweep(sweep)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_workload_keys_of_a_scene_and_unlisted_maximize_are_refused(tmp_path):
    sweep = _folder(tmp_path, '[sweep]\nscene = "scene.toml"\n[grid]\n"workload.spp" = [1]\n')
    with pytest.raises(UserError, match="has no file keys"):
        load_sweep(sweep)
    sweep = _workload_folder(tmp_path / "w", '[sweep]\nscene = "occlusion.toml"\nmaximize = ["x"]\n')
    with pytest.raises(UserError, match="maximize: 'x' is not one of the sweep's results"):
        load_sweep(sweep)


def test_a_listed_result_the_workload_lacks_fails_the_point(tmp_path):
    sweep = _workload_folder(tmp_path, '[sweep]\nscene = "occlusion.toml"\nresults = ["pcs_size"]\n')
    frame = run_sweep(load_sweep(sweep), tmp_path / "out", executor="serial", progress=False)
    assert list(frame.status) == ["error"]
    assert "results.json has no figure pcs_size (it has: proxies," in frame.error[0]


def test_a_point_keeps_the_workloads_derived_images(tmp_path):
    """A collision point writes its Fig. 6 overlap images as a run does (written by the same code)."""
    scene = ROOT / "workloads" / "apps" / "collision" / "collide.toml"
    (tmp_path / "sweep.toml").write_text(f'[sweep]\nscene = "{scene}"\n[grid]\n"workload.resolution" = [8]\n')
    frame = run_sweep(load_sweep(tmp_path / "sweep.toml"), tmp_path / "out", executor="serial", progress=False)
    assert list(frame.status) == ["ok"], frame.error.tolist()
    point = tmp_path / "out" / "points" / frame.point_id[0]
    images = sorted(p.name for p in (point / "images").iterdir())
    assert images and all(name.startswith("ball-box.") for name in images), images
    assert {"results.json", "passes"} <= {p.name for p in point.iterdir()}
