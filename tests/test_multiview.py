"""Stereo and multi-view in one 5D pass (Nilsson12 §8; docs/multiview.md).

* Each view converges to its own camera: a numpy ray-cast render from the view's lens sub-region alone
  (``reference_view_images``, independent of the 5D path), error falling with samples per view and far
  below the error against the neighbouring view's camera (stereo, seven overlapping views).
* The lens resolve's weights, read off by resolving one-hot samples: they sum to one per pixel and
  view, are equal (a box filter), and a sample weighs in exactly the views whose windows hold it (one
  for stereo; one or two for overlapping windows), each window holding samples_per_view samples.
* The increase of shader executions over one view: with no cache it is the closed form of the sample
  counts, (views - 1 + window) / window - 1; an unbounded cache never evicts and never executes more
  than a sized one; with 1,024 entries the increases stay far below the uncached ones (Nilsson12
  reports +10% for stereo, +15% for seven views); results.json's figures agree with its table.
* The reference's pre-cull (``_screen_bounds``) is conservative: every pixel a ray from the lens box can
  hit a moving triangle through lies in the triangle's bounds (hypothesis).
* The workload through ``pipeline-sim run`` (images written), its bad input, the docs example.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.render import run_pass
from units.rop import lens_resolve
from workloads.apps.multiview import Layout, Multiview, Settings, _screen_bounds, reference_view_images, rmse
from runs import ran_file, refused_file

ROOT = Path(__file__).resolve().parents[1]
STEREO = dict(views=2, window=1.0, spacing=0.3)
SEVEN = dict(views=7, window=2.0, spacing=0.15)


def workload(**changes) -> Multiview:
    w = Multiview(Path("multiview.toml"), load_arch())
    w.settings_file = Settings(**{"width": 24, "height": 16, **changes})
    return w


@pytest.mark.parametrize("line", [STEREO, SEVEN], ids=["stereo", "seven"])
def test_each_view_converges_to_a_render_from_its_own_camera(line):
    # a wide camera line at 48x36: pixels of parallax between the views
    w = workload(**{**line, "spacing": 3.3 * line["spacing"]}, width=48, height=36)
    reference = reference_view_images(w.settings_file, w.layout(), 128)
    errors = {}
    for spv in (4, 64):
        w.settings_file = dataclasses.replace(w.settings_file, samples_per_view=spv)
        views = run_pass(w.make_pass("views", line["views"], w.arch, True)).images["views"]
        errors[spv] = [rmse(v, r) for v, r in zip(views, reference)]
        if spv == 64:  # each view is its own camera's, not the farthest one's (the parallax between them)
            for k in range(len(views)):
                far = len(views) - 1 if k < len(views) / 2 else 0
                assert rmse(views[k], reference[far]) > 2 * errors[spv][k]
    # 16 times the samples: the error falls by about 4 where noise dominates; the references' own noise
    # (128 rays) floors it
    assert all(hi < 0.5 * lo for hi, lo in zip(errors[64], errors[4])), errors
    assert max(errors[64]) < 0.03, errors


UNIT = st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.0, 1.0))
POINT = st.tuples(st.floats(-10.0, 10.0), st.floats(-10.0, 10.0), st.floats(-40.0, -1e-3))


@settings(max_examples=500, deadline=None)
@given(st.lists(POINT, min_size=6, max_size=6), st.lists(st.floats(-2.0, 2.0), min_size=4, max_size=4),
       st.floats(1.0, 40.0), st.floats(0.2, 5.0), st.floats(0.2, 5.0), st.integers(8, 64), st.integers(8, 64),
       UNIT, UNIT, UNIT, UNIT, UNIT, UNIT)
def test_screen_bounds_hold_every_pixel_a_ray_hits_the_triangle_through(points, box, focus, fx, fy, w, h, t,
                                                                       a, b, lu, lv, flip):
    """The reference's pre-cull: a point of the triangle at time t (barycentrics a, b, folded into the
    triangle), seen from a point of the lens box (z = 0), is hit by the ray from that lens point through
    the point where the line meets the focus plane; that point's pixel must lie in the triangle's bounds.
    Vertices anywhere in front of the lens plane (z < 0, also between it and the near plane), moving
    independently; corners of the shutter, the lens box and the triangle included."""
    world = np.array(points).reshape(2, 1, 3, 3)
    x_lo, x_hi, y_lo, y_hi = sorted(box[:2]) + sorted(box[2:])
    proj = np.diag([fx, fy, 1.0, 1.0])
    x0, x1, y0, y1 = _screen_bounds(world[0], world[1], (x_lo, x_hi, y_lo, y_hi), focus, proj, w, h)[0]
    if a + b > 1.0:
        a, b = 1.0 - a, 1.0 - b
    tri = (1.0 - t) * world[0, 0] + t * world[1, 0]
    p = (1.0 - a - b) * tri[0] + a * tri[1] + b * tri[2]
    lens = np.array([x_lo + lu * (x_hi - x_lo), y_lo + lv * (y_hi - y_lo), 0.0])
    on_focus = lens + (p - lens) * focus / -p[2]
    px = np.floor((on_focus[0] * fx / focus + 1.0) / 2.0 * w)
    py = np.floor((1.0 - on_focus[1] * fy / focus) / 2.0 * h)
    assert x0 <= px <= x1 and y0 <= py <= y1, (px, py, (x0, x1, y0, y1))


@pytest.mark.parametrize("line", [STEREO, SEVEN], ids=["stereo", "seven"])
def test_window_weights_sum_to_one_and_a_sample_weighs_in_the_views_holding_it(line):
    w = workload(**line, samples_per_view=8)
    layout = w.layout()
    samples = run_pass(w.make_pass("views", line["views"], w.arch, True)).samples
    spp = layout.spp
    one_hot = np.tile(np.eye(spp, dtype=np.float32), (samples.npix, 1))  # sample s of each pixel: channel s
    u = samples.u.astype(np.float64)
    # the windows from the camera positions in world units, not from Layout.windows
    x = u * layout.half_width
    cams = (np.arange(layout.views) - (layout.views - 1) / 2) * layout.spacing
    half = layout.window * layout.spacing / 2
    holding = np.zeros((layout.views, len(u)), bool)
    for k, region in enumerate(w.make_pass("views", line["views"], w.arch, True).targets[0].views):
        weights = lens_resolve(one_hot, spp, samples.u, samples.v, region, np.zeros(spp, np.float32))
        np.testing.assert_allclose(weights.sum(axis=1), 1.0, rtol=1e-6)  # per pixel's sample set
        inside = weights.reshape(-1) > 0
        holding[k] = np.abs(x - cams[k]) <= half * (1 + 1e-6)
        near_edge = np.abs(np.abs(x - cams[k]) - half) < 1e-5 * layout.half_width
        assert np.array_equal(inside[~near_edge], holding[k][~near_edge])  # exactly the views holding it
        per_pixel = inside.reshape(-1, spp)
        assert (per_pixel.sum(axis=1) == layout.samples_per_view).mean() > 0.99  # the window's strata
        w_in = weights[per_pixel]
        np.testing.assert_allclose(w_in, np.repeat(1.0 / per_pixel.sum(axis=1), per_pixel.sum(axis=1)), rtol=1e-6)
    views_per_sample = holding.sum(axis=0)
    if layout.window == 1.0:
        assert (views_per_sample == 1).mean() > 0.999  # disjoint sub-lenses
    else:  # overlapping windows: the two end strata of the lens in one view, all others in two
        ends = np.abs(x) > layout.half_width - layout.spacing  # one spacing at each end
        assert (views_per_sample[ends] == 1).mean() > 0.99 and (views_per_sample[~ends] == 2).mean() > 0.99


def test_per_eye_u_tests_test_the_samples_one_u_interval_tests():
    """Why the tile test has no per-view u option: per-eye u tests, made here by drawing the geometry once
    per eye with user clip planes on u (folded into each record's u^, Nilsson12 §2), test exactly the
    samples one pass's single u^ tests (its windows tile the lens, so the union of u^ and each window is
    u^) and cover the same ones, at twice the tile tests."""
    from pipeline_sim.pass_state import ClipPlanes

    w = workload(**STEREO, width=32, height=24)
    one = w.make_pass("views", 2, w.arch, True)
    eyes = [dataclasses.replace(one.draw, clip=ClipPlanes(u_lo=lo, u_hi=hi)) for lo, hi in w.layout().windows()]
    single, split = run_pass(one), run_pass(dataclasses.replace(one, draw=eyes, targets=None))
    for counter in ("samples_tested", "samples_covered"):
        assert single.counter("sample_tester", counter) == split.counter("sample_tester", counter)
    assert split.counter("tile_test", "records_in") == 2 * single.counter("tile_test", "records_in")


@pytest.mark.parametrize("line", [STEREO, SEVEN], ids=["stereo", "seven"])
def test_shader_execution_increase_over_one_view(line):
    w = workload(**line, width=32, height=24, samples_per_view=8, view_counts=[1, 2, 7], cache_sizes=[0, 256, 1024],
                 reference_spp=4)
    run = w.run()
    results = run.results
    rows = {(int(r.views), str(r.cache)): r for r in run.tables["shader_executions"].itertuples()}
    for n in (1, 2, 7):
        layout = Layout(n, line["spacing"], line["window"], 8)
        uncached = rows[(n, "0")]
        assert uncached.shader_executions == uncached.samples_covered  # no cache: one per covered sample
        unbounded = rows[(n, "unbounded")]
        assert unbounded.cache_entries >= 4 * layout.spp * 32 * 24
        assert run.passes[f"views{n}_cacheunbounded"].counter("shading", "evictions") == 0
        assert all(unbounded.shader_executions <= rows[(n, c)].shader_executions for c in ("256", "1024"))
        for c in ("0", "256", "1024", "unbounded"):
            assert results[f"executions_views{n}_cache{c}"] == rows[(n, c)].shader_executions
            if n > 1:
                expect = rows[(n, c)].shader_executions / rows[(1, c)].shader_executions - 1
                assert results[f"increase_views{n}_cache{c}"] == pytest.approx(expect, rel=1e-12)
        if n > 1:  # no cache: the samples, (views - 1 + window) / window times one view's
            closed = (n - 1 + line["window"]) / line["window"] - 1
            assert results[f"increase_views{n}_cache0"] == pytest.approx(closed, rel=0.03)
            # shading reused across views, time and lens: a small part of the uncached increase
            assert results[f"increase_views{n}_cache1024"] < 0.1 * closed


def test_run_writes_every_view_side_by_side_and_anaglyph(tmp_path):
    out, _ = ran_file(tmp_path, 'kind = "multiview"\nwidth = 24\nheight = 16\nviews = 3\nwindow = 2.0\n'
                              'view_counts = []\ncache_sizes = []\nreference_spp = 4\n')
    images = {p.stem: np.load(p) for p in (out / "images").glob("*.npy")}
    assert sorted(images) == ["anaglyph", "side_by_side", "view_0", "view_1", "view_2"]
    assert all((out / "images" / f"{name}.png").is_file() for name in images)
    views = [images[f"view_{k}"] for k in range(3)]
    np.testing.assert_array_equal(images["side_by_side"], np.concatenate(views, axis=1))
    np.testing.assert_array_equal(images["anaglyph"][..., 0], views[0][..., 0])
    np.testing.assert_array_equal(images["anaglyph"][..., 1:], views[-1][..., 1:])
    assert np.abs(views[0] - views[-1]).max() > 0.1  # parallax
    results = json.loads((out / "results.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert len(results["rmse_per_view"]) == 3 and not (out / "shader_executions.csv").exists()
    assert "images/anaglyph.png" in json.loads((out / "run.json").read_text())["images"]


@pytest.mark.parametrize("text, message", [
    ("views = 7\nwindow = 2.0\nsamples_per_view = 3", "must be whole numbers"),
    ("views = 2\nspacing = 0.0", "need cameras apart"),
    ("views = 2\nreference_x = 5.0", "off the camera line"),
    ("view = 2", "did you mean 'views'"),
])
def test_multiview_bad_input_is_one_line(tmp_path, capsys, text, message):
    assert message in refused_file(tmp_path, capsys, "multiview", text)


def test_docs_example_runs_as_written():
    text = (ROOT / "docs/multiview.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    exec(compile(code, "docs/multiview.md", "exec"), {})


def test_cost_sweep_varies_samples_per_view_and_cache_size(tmp_path):
    from pipeline_sim.sweep import load_sweep, run_sweep

    shipped = load_sweep(ROOT / "workloads/sweeps/multiview_cost.toml")
    assert len(shipped.points) == 16
    seven = (ROOT / "workloads/apps/multiview/seven.toml").read_text()
    (tmp_path / "seven.toml").write_text(re.sub(r"(?m)^height = \d+", "height = 12",
                                                re.sub(r"(?m)^width = \d+", "width = 16", seven)))
    assert "width = 16" in (tmp_path / "seven.toml").read_text()
    text = (ROOT / "workloads/sweeps/multiview_cost.toml").read_text().replace("../apps/multiview/", "")
    text = re.sub(r'"workload.samples_per_view" = \[.*\]', '"workload.samples_per_view" = [2, 32]', text)
    text = re.sub(r'"shading.cache_entries" = \[.*\]', '"shading.cache_entries" = [64]', text)
    (tmp_path / "sweep.toml").write_text(text)
    frame = run_sweep(load_sweep(tmp_path / "sweep.toml"), tmp_path / "out", executor="serial", progress=False)
    assert (frame.status == "ok").all() and len(frame) == 2
    error = dict(zip(frame["workload.samples_per_view"], frame["result.rmse_mean"]))
    assert error[32] < 0.5 * error[2]
