"""Z-cull (units/zcull.py) in the full pipeline.

Culling must be invisible: images with z-cull on and off are bit-identical.
Culled (triangle, tile) records are brute-forced: every sample of the tile is
run through the sample tester's exact ``inside_test`` and, if covered, must
fail the depth test against the depth buffer as it was when z-cull culled the
record (captured at that moment). Records flagged "no depth read" must pass it.
"""

from __future__ import annotations

import numpy as np
import pytest

import pipeline_sim.render as render
import units.zcull as zc
from pipeline_sim.config import load_arch
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.render import RenderPass, run_pass
from units.rop import Rop
from units.sample_tester import inside_test
from units.triangle_setup import TriangleSetup

W, H, SPP = 64, 48, 4
# small batches and FIFOs (one default batch of records each) keep z-cull close
# behind the ROP, so the occluder's depths are known before the hidden tiles come
BASE = ["pipeline.triangles_per_batch=2", "pipeline.tiles_per_batch=64", "pipeline.queue_depth=1"]


def occluded_scene(seed, n_behind=400, lens=True, motion=True):
    """Two triangles covering the screen, drawn first, with a tilted depth
    z = 0.3 x + 0.2 y - 0.2 (NDC, -0.7..0.3), then many small triangles at
    z in [-0.3, 0.95]: mostly hidden, some in front where the plane is deep."""
    rng = np.random.default_rng(seed)
    corners = np.array([[-1.1, -1.1], [1.1, -1.1], [1.1, 1.1], [-1.1, 1.1]])
    occ = np.zeros((2, 3, 4))
    for t, idx in enumerate(([0, 1, 2], [0, 2, 3])):
        occ[t, :, :2] = corners[idx]
        occ[t, :, 2] = 0.3 * corners[idx, 0] + 0.2 * corners[idx, 1] - 0.2
        occ[t, :, 3] = 1.0
    q = np.zeros((n_behind, 3, 4))
    q[:, :, :2] = rng.uniform(-1, 1, (n_behind, 1, 2)) + rng.normal(0, 0.12, (n_behind, 3, 2))
    q[:, :, 2] = rng.uniform(-0.3, 0.95, (n_behind, 1)) + rng.normal(0, 0.03, (n_behind, 3))
    q[:, :, 3] = 1.0
    r = q.copy()
    if motion:
        r[:, :, :2] += rng.normal(0, 0.1, (n_behind, 1, 2))
        r[:, :, 2] += rng.normal(0, 0.05, (n_behind, 1))
    q = np.concatenate([occ, q])
    r = np.concatenate([occ, r])
    n = len(q)
    lx = np.zeros((n, 3, 2))
    if lens:
        lx[2:] = rng.uniform(0.0, 0.04, (n_behind, 1, 1))
    color = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    return draw_from_clip(q, r, lx, lx.copy(), color, W, H)


def render_with(draw, overrides, **kw):
    return run_pass(RenderPass(draw=draw, arch=load_arch(overrides=BASE + overrides), spp=SPP, **kw))


@pytest.mark.parametrize("overrides", [["zcull.enabled=false"], ["rop.depth_test=always"]])
def test_bypassed_zcull_runs(overrides):
    """Regression: with z-cull bypassed the tile records used to reach the
    sample tester without the 'noread' field (KeyError)."""
    draw = occluded_scene(6, n_behind=20)
    res = run_pass(RenderPass(draw=draw, arch=load_arch(overrides=overrides), spp=SPP))
    assert "zcull" not in res.units_used
    assert res.counter("rop", "depth_reads_skipped") == 0  # nobody claimed a skippable read


def culled(res):
    return res.counter("zcull", "tiles_culled")


@pytest.fixture(scope="module")
def scene():
    return occluded_scene(1)


@pytest.fixture(scope="module")
def reference_image(scene):
    res = render_with(scene, ["zcull.enabled=false"])
    assert "zcull" not in res.units_used
    return res


@pytest.mark.parametrize("func", ["less", "lequal"])
def test_zcull_on_off_bit_identical_and_culls(scene, func):
    off = render_with(scene, ["zcull.enabled=false", f"rop.depth_test={func}"])
    on = render_with(scene, [f"rop.depth_test={func}"])
    assert "zcull" in on.units_used
    np.testing.assert_array_equal(on.image, off.image)
    np.testing.assert_array_equal(on.depth, off.depth)
    # a large share of the hidden triangles' tiles never reach the sample tester
    assert culled(on) > 0.3 * on.counter("zcull", "records_in")
    assert on.counter("zcull", "records_out") == on.counter("zcull", "records_in") - culled(on)
    assert on.counter("sample_tester", "samples_tested") < off.counter("sample_tester", "samples_tested")
    # culled records cannot have written anything: the ROP wrote the same or fewer samples
    assert on.counter("rop", "samples_written") <= off.counter("rop", "samples_written")


@pytest.mark.parametrize("seed,lens,motion", [(2, True, True), (3, False, True), (4, True, False),
                                               (5, False, False)])
def test_zcull_invisible_across_scenes(seed, lens, motion):
    draw = occluded_scene(seed, n_behind=250, lens=lens, motion=motion)
    on = render_with(draw, [])
    off = render_with(draw, ["zcull.enabled=false"])
    np.testing.assert_array_equal(on.image, off.image)
    assert culled(on) > 0


def _capture(monkeypatch):
    """Record every z-cull kernel call with the ROP depth buffer at that moment."""
    rops, calls = [], []

    class RecordingRop(Rop):
        def __init__(self, *args, **kw):
            super().__init__(*args, **kw)
            rops.append(self)

    original = zc.zcull_kernel

    def recording_kernel(*args):
        depth_before = rops[-1].depth.copy()
        original(*args)
        calls.append(dict(tri=args[0].copy(), tx=args[1].copy(), ty=args[2].copy(), keep=args[17].copy(),
                          noread=args[18].copy(), depth=depth_before))

    monkeypatch.setattr(render, "Rop", RecordingRop)
    monkeypatch.setattr(zc, "zcull_kernel", recording_kernel)
    return calls


def _tile_samples(table, samples, tri, tx, ty, ts):
    """Brute force: (slot, z) of every sample of the tile the triangle covers."""
    out = []
    for py in range(ty * ts, min((ty + 1) * ts, H)):
        for px in range(tx * ts, min((tx + 1) * ts, W)):
            for s in range(SPP):
                k = (py * W + px) * SPP + s
                ok, _, _, _, z = inside_test(table.p0_32, table.dp_32, table.l0_32, table.dl_32, tri,
                                             np.float32(px + samples.x[k]), np.float32(py + samples.y[k]),
                                             samples.t[k], samples.u[k], samples.v[k], False,
                                             table.edge_eps)
                if ok:
                    out.append((k, float(z)))
    return out


@pytest.mark.parametrize("func", ["less", "lequal"])
def test_culled_records_cannot_pass_depth_test(monkeypatch, scene, func):
    calls = _capture(monkeypatch)
    arch = load_arch(overrides=BASE + [f"rop.depth_test={func}"])
    res = run_pass(RenderPass(draw=scene, arch=arch, spp=SPP))
    ts = arch.tile_traverser.tile_size
    setup = TriangleSetup(arch.triangle_setup, scene, ts)
    setup.run(np.arange(scene.n, dtype=np.int64))
    table = setup.table
    rng = np.random.default_rng(0)
    cull_list = [(c, i) for c in calls for i in np.nonzero(~c["keep"])[0]]
    front_list = [(c, i) for c in calls for i in np.nonzero(c["noread"])[0]]
    assert len(cull_list) == culled(res) > 0
    assert len(front_list) == res.counter("zcull", "tiles_no_depth_read")
    fails = lambda z, d: (z >= d) if func == "less" else (z > d)  # noqa: E731
    covered_checked = 0
    for j in rng.choice(len(cull_list), size=min(60, len(cull_list)), replace=False):
        c, i = cull_list[j]
        for k, z in _tile_samples(table, res.samples, int(c["tri"][i]), int(c["tx"][i]), int(c["ty"][i]), ts):
            covered_checked += 1
            assert fails(np.float32(z), c["depth"][k]), (
                f"culled tri {c['tri'][i]} tile ({c['tx'][i]}, {c['ty'][i]}) covers slot {k} "
                f"at z={z} in front of depth {c['depth'][k]}")
            # the final depth buffer can only be nearer still
            assert fails(np.float32(z), res.depth.reshape(-1)[k])
    assert covered_checked > 100  # culled tiles were really covered, not just empty
    for j in rng.choice(len(front_list), size=min(30, len(front_list)), replace=False):
        c, i = front_list[j]
        for k, z in _tile_samples(table, res.samples, int(c["tri"][i]), int(c["tx"][i]), int(c["ty"][i]), ts):
            assert np.float32(z) < c["depth"][k]


@pytest.mark.parametrize("func", ["greater", "always", "gequal", "equal", "never"])
def test_zcull_inactive_for_other_depth_functions(scene, func):
    clear = -1.0 if func in ("greater", "gequal") else 1.0
    on = render_with(scene, [f"rop.depth_test={func}"], clear_depth=clear)
    off = render_with(scene, [f"rop.depth_test={func}", "zcull.enabled=false"], clear_depth=clear)
    assert "zcull" not in on.units_used
    assert culled(on) == 0 and on.counter("zcull", "records_in") == 0
    np.testing.assert_array_equal(on.image, off.image)
    if func in ("greater", "always"):
        # the hidden triangles really show: the image differs from the less image
        less = render_with(scene, [])
        assert not np.array_equal(on.image, less.image)


@pytest.mark.parametrize("slices,boxes", [(1, 1), (2, 1), (4, 2), (16, 3), (1, 4)])
def test_box_knobs_do_not_change_image(scene, reference_image, slices, boxes):
    res = render_with(scene, [f"zcull.time_slices={slices}", f"zcull.lens_boxes={boxes}"])
    np.testing.assert_array_equal(res.image, reference_image.image)
    np.testing.assert_array_equal(res.depth, reference_image.depth)
    assert culled(res) > 0
