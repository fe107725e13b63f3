"""Z-cull (units/zcull.py) in the full pipeline.

Culling must be invisible: images with z-cull on and off are bit-identical.
Culled (triangle, tile) records are brute-forced: every sample of the tile is
run through the sample tester's exact ``inside_test`` and, if covered, must
fail the depth test against the depth buffer as it was when z-cull culled the
record (captured at that moment). Records flagged "no depth read" must pass it.
The ROP's refresh of the boxes is compared with a brute-force scan of the
depth buffer after every batch.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import pipeline_sim.render as render
import units.rop as rop_mod
import units.zcull as zc
from pipeline_sim.config import RopConfig, load_arch, pass_settings
from pipeline_sim.definitions import N_OPS, OP_CMP
from pipeline_sim.pass_state import PassState
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.regions import RegionPlan, RegionSamples
from pipeline_sim.render import RenderPass, run_pass
from pipeline_sim.sampling import make_samples
from units.rop import Rop
from units.sample_tester import inside_test
from units.triangle_setup import TriangleSetup

W, H, SPP = 64, 48, 4
# small batches and FIFOs (one default batch of records each) keep z-cull close
# behind the ROP, so the occluder's depths are known before the hidden tiles come
BASE = ["simulation.triangles_per_batch=2", "simulation.tiles_per_batch=64", "pipeline.queue_depth=1"]


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
    return run_pass(RenderPass(draw=draw, **pass_settings(BASE + overrides), spp=SPP, **kw))


@pytest.mark.parametrize("overrides", [["zcull.enabled=false"], ["pass.depth_test=always"]])
def test_bypassed_zcull_runs(overrides):
    """Regression: with z-cull bypassed the tile records used to reach the
    sample tester without the 'noread' field (KeyError)."""
    draw = occluded_scene(6, n_behind=20)
    res = run_pass(RenderPass(draw=draw, **pass_settings(overrides), spp=SPP))
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


@pytest.mark.parametrize("refresh", ["timed", "ordered"])
@pytest.mark.parametrize("func", ["less", "lequal"])
def test_zcull_on_off_bit_identical_and_culls(scene, func, refresh):
    off = render_with(scene, ["zcull.enabled=false", f"pass.depth_test={func}"])
    on = render_with(scene, [f"pass.depth_test={func}"], zcull_refresh=refresh)
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


@pytest.mark.parametrize("refresh", ["timed", "ordered"])
@pytest.mark.parametrize("func", ["less", "lequal"])
def test_culled_records_cannot_pass_depth_test(monkeypatch, scene, func, refresh):
    calls = _capture(monkeypatch)
    settings = pass_settings(BASE + [f"pass.depth_test={func}"])
    arch = settings["arch"]
    res = run_pass(RenderPass(draw=scene, **settings, spp=SPP, zcull_refresh=refresh))
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
    on = render_with(scene, [f"pass.depth_test={func}"], clear_depth=clear)
    off = render_with(scene, [f"pass.depth_test={func}", "zcull.enabled=false"], clear_depth=clear)
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


def brute_box(samples, k, nt, nl):
    """The (t, u, v) box of sample ``k``."""
    it = min(nt - 1, int(np.floor(float(samples.t[k]) * nt)))
    iu = min(nl - 1, max(0, int(np.floor((float(samples.u[k]) + 1.0) * 0.5 * nl))))
    iv = min(nl - 1, max(0, int(np.floor((float(samples.v[k]) + 1.0) * 0.5 * nl))))
    return (it * nl + iu) * nl + iv


def brute_zmax(samples, depth, tile_size, nt, nl):
    """Per tile of ``samples``' rows (tile-row-major) and box: the first largest
    depth in the tile's row-major sample order (-inf for a box without samples)."""
    w, spp = samples.width, samples.spp
    tiles_x = -(-w // tile_size)
    tiles_y = -(-samples.height // tile_size)
    out = np.full((tiles_x * tiles_y, nt * nl * nl), -np.inf, np.float32)
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            for y in range(ty * tile_size, min((ty + 1) * tile_size, samples.height)):
                for x in range(tx * tile_size, min((tx + 1) * tile_size, w)):
                    for k in range((y * w + x) * spp, (y * w + x + 1) * spp):
                        box = brute_box(samples, k, nt, nl)
                        if depth[k] > out[ty * tiles_x + tx, box]:
                            out[ty * tiles_x + tx, box] = depth[k]
    return out


def zcull_and_rop(cfg, state, w, h, spp, ts, rows, seed, ahead=False):
    """A z-cull unit and a ROP refreshing it over regions of ``rows`` rows, region 0 open: (plan, the regions'
    samples, z-cull, ROP). ``ahead``: each next region's samples are made, and grouped by z-cull box, on a
    background thread while the one before is refreshed (as a pass does); else the groups are made by
    each region's first refresh."""
    plan = RegionPlan(w, h, rows)
    zcull = zc.ZCull(cfg, state.depth_test, ts, w, h, 1.0)
    regions = RegionSamples(plan, lambda r: make_samples(w, h, spp, seed, lens=True, motion=True, rows=r),
                            prepare=zcull.groups.prepare if ahead else None)
    if ahead:
        regions.will_visit(range(plan.count))
    rop = Rop(RopConfig(), state, w, h, spp, (0, 0, 0, 1), 1.0, zcull, regions.region(0), rows=plan.bounds(0))
    return plan, regions, zcull, rop


def each_region(plan, regions, rop):
    """The regions in order, each opened on the ROP (region 0 is open already): (first row, end row, samples)."""
    for region in range(plan.count):
        r0, r1 = plan.bounds(region)
        samples = regions.region(region)
        if region:
            rop.open_region((r0, r1), samples)
        yield r0, r1, samples


@pytest.mark.parametrize("func,depth_write,slices,boxes,rows", [
    ("less", True, 4, 2, 4), ("lequal", True, 4, 2, 8), ("lequal", True, 2, 3, 12),
    ("less", False, 4, 2, 8), ("lequal", True, 1, 1, 4)])
def test_refresh_matches_brute_force_after_every_batch(func, depth_write, slices, boxes, rows):
    """Many small batches over few tiles and depth levels (ties, +0 and -0): after
    each batch, the touched tiles' boxes are those of a full scan of the depth
    buffer, bit for bit, and every other tile's are unchanged. The depth read
    is that of scanning a tile when first refreshed, and after that the boxes
    where a depth not below their zmax was replaced: their samples, four
    bytes each."""
    rng = np.random.default_rng(slices * 10 + boxes + rows + depth_write)
    w, h, spp, ts = 10, 12, 4, 4
    arch = load_arch()
    cfg = dataclasses.replace(arch.zcull, time_slices=slices, lens_boxes=boxes)
    plan, regions, zcull, rop = zcull_and_rop(cfg, PassState(depth_test=func, depth_write=depth_write), w, h, spp, ts,
                                              rows, seed=5)
    levels = np.array([0.0, -0.0, 0.25, 0.5, 0.5, 0.75, 1.0], np.float32)
    for r0, r1, samples in each_region(plan, regions, rop):
        t0 = r0 // ts * zcull.tiles_x
        box = [brute_box(samples, k, slices, boxes) for k in range(len(samples.t))]
        scanned = set()  # tiles refreshed from this region's depth buffer
        for _ in range(12):
            n = int(rng.integers(1, 40))
            pix = rng.integers(r0 * w, r1 * w, n).astype(np.int32)
            batch = dict(pix=pix, sidx=rng.integers(0, spp, n).astype(np.int32),
                         z=levels[rng.integers(0, len(levels), n)], color=np.ones((n, 4), np.float32),
                         noread=np.zeros(n, np.bool_))
            before = zcull.zmax.copy()
            request, *_ = rop.run(batch)
            _, events, nbytes = rop.refresh_zcull([request])
            py, px = pix // w, pix % w
            touched = np.unique((py // ts) * zcull.tiles_x + px // ts)
            assert events[rop_mod.EV_REFRESH_TILES] == len(touched)
            read = scans = 0
            for tile in touched:
                mine = [k for k in range((r1 - r0) * w * spp)
                        if ((k // spp) // w // ts) * zcull.tiles_x + (k // spp) % w // ts == tile - t0]
                if tile in scanned:  # the boxes where a depth not below their zmax was replaced
                    stale = {box[(p - r0 * w) * spp + si] for p, si, old in zip(pix, batch["sidx"], request[2])
                             if (p // w // ts) * zcull.tiles_x + p % w // ts == tile
                             and old >= before[tile, box[(p - r0 * w) * spp + si]]}
                else:  # a tile's first refresh reads all of it
                    stale = set(box[k] for k in mine)
                    scanned.add(tile)
                scans += bool(stale)
                read += sum(box[k] in stale for k in mine)
            assert events[rop_mod.EV_REFRESH_SCANS] == scans
            assert nbytes == 4 * read
            expect = before.copy()
            expect[touched] = brute_zmax(samples, rop.depth, ts, slices, boxes)[touched - t0]
            np.testing.assert_array_equal(zcull.zmax.view(np.uint32), expect.view(np.uint32))


@pytest.mark.parametrize("lag", [1, 3])
def test_unpublished_refreshes_reach_the_test_in_order(lag):
    """Refreshes made with ``publish`` off (the ROP working ahead) leave the boxes the z-cull test reads
    alone until ``publish_refresh``, which hands them over one by one, in order: the test then reads,
    bit for bit, what a z-cull refreshed and published at once read after the same refresh (the boxes
    themselves compared with a full scan of the depth buffer in
    ``test_refresh_matches_brute_force_after_every_batch``), over a region change too."""
    rng = np.random.default_rng(40 + lag)
    w, h, spp, ts = 10, 12, 4, 4
    cfg = load_arch().zcull
    state = PassState(depth_test="less")
    at_once = zcull_and_rop(cfg, state, w, h, spp, ts, 8, seed=5)
    later = zcull_and_rop(cfg, state, w, h, spp, ts, 8, seed=5)
    levels = np.array([0.0, 0.25, 0.5, 0.75, 1.0], np.float32)
    published = []  # the boxes the z-cull refreshed at once shows after each refresh
    waiting = 0
    for (r0, r1, _), _ in zip(each_region(*at_once[:2], at_once[3]), each_region(*later[:2], later[3])):
        for _ in range(10):
            n = int(rng.integers(1, 40))
            batch = dict(pix=rng.integers(r0 * w, r1 * w, n).astype(np.int32),
                         sidx=rng.integers(0, spp, n).astype(np.int32), z=levels[rng.integers(0, len(levels), n)],
                         color=np.ones((n, 4), np.float32), noread=np.zeros(n, np.bool_))
            request, *_ = at_once[3].run(batch)
            at_once[3].refresh_zcull([request])
            published.append(at_once[2].zmax.copy())
            shown = later[2].zmax.copy()
            request, *_ = later[3].run(batch)
            later[3].refresh_zcull([request], publish=False)
            np.testing.assert_array_equal(later[2].zmax, shown)  # not seen before it is published
            waiting += 1
            if waiting == lag:
                for k in range(len(published) - lag, len(published)):
                    later[2].publish_refresh()
                    np.testing.assert_array_equal(later[2].zmax.view(np.uint32), published[k].view(np.uint32))
                waiting = 0
    assert len({p.tobytes() for p in published}) > 6
    for k in range(len(published) - waiting, len(published)):  # those still waiting
        later[2].publish_refresh()
        np.testing.assert_array_equal(later[2].zmax.view(np.uint32), published[k].view(np.uint32))
    with pytest.raises(RuntimeError, match="no z-cull refresh waits"):
        later[2].publish_refresh()
    request, *_ = later[3].run(batch)
    later[3].refresh_zcull([request], publish=False)
    with pytest.raises(RuntimeError, match="would overtake"):
        later[3].refresh_zcull([request])


def test_refresh_rescans_a_new_depth_buffer():
    """A tile refreshed from one depth buffer and then from another (a region
    drawn again with fresh buffers) gets the boxes of the new buffer."""
    w, h, spp, ts = 8, 4, 4, 4
    samples = make_samples(w, h, spp, 3, lens=True, motion=True)
    zcull = zc.ZCull(load_arch().zcull, "less", ts, w, h, 1.0)
    pix = np.arange(w * h, dtype=np.int32).repeat(spp)
    sidx = np.tile(np.arange(spp, dtype=np.int32), w * h)
    first = np.random.default_rng(1).random(w * h * spp).astype(np.float32) * 0.5
    prior = np.ones(len(pix), np.float32)  # every sample written from the clear depth
    work = zcull.refresh(pix, sidx, prior, samples, first)
    np.testing.assert_array_equal(zcull.zmax, brute_zmax(samples, first, ts, zcull.nt, zcull.nl))
    cleared = np.ones_like(first)
    cleared[:spp] = 0.25
    prior = np.full(len(pix), np.nan, np.float32)
    prior[:spp] = 1.0
    work += zcull.refresh(pix[:spp], sidx[:spp], prior[:spp], samples, cleared)
    expect = brute_zmax(samples, cleared, ts, zcull.nt, zcull.nl)
    np.testing.assert_array_equal(zcull.zmax[0], expect[0])
    np.testing.assert_array_equal(zcull.zmax[1], brute_zmax(samples, first, ts, zcull.nt, zcull.nl)[1])
    assert work[zc.RF_TILES] == 2 + 1


def numpy_zmax(samples, depth, tile_size, nt, nl):
    """``brute_zmax`` computed another way, with numpy over all samples at once: per (tile, box) the
    largest depth, and of the samples holding it the first in the tile's row-major order (its bits: +0
    or -0), -inf for an empty box."""
    w, spp, h = samples.width, samples.spp, samples.height
    tiles_x = -(-w // tile_size)
    nbox = nt * nl * nl
    it = np.minimum(nt - 1, np.floor(samples.t.astype(np.float64) * nt)).astype(np.int64)
    iu, iv = (np.clip(np.floor((a.astype(np.float64) + 1.0) * 0.5 * nl), 0, nl - 1).astype(np.int64)
              for a in (samples.u, samples.v))
    k = np.arange(w * h * spp)
    px, py, s = k // spp % w, k // spp // w, k % spp
    group = ((py // tile_size) * tiles_x + px // tile_size) * nbox + (it * nl + iu) * nl + iv
    ngroups = tiles_x * -(-h // tile_size) * nbox
    top = np.full(ngroups, -np.inf, np.float32)
    np.maximum.at(top, group, depth)
    order = ((py % tile_size) * tile_size + px % tile_size) * spp + s  # the scan's order within a tile
    first = np.full(ngroups, len(k), np.int64)
    at_top = depth == top[group]
    np.minimum.at(first, group[at_top], order[at_top])
    sample_at = np.full(ngroups, -1, np.int64)
    sample_at[group[at_top & (order == first[group])]] = k[at_top & (order == first[group])]
    out = np.where(sample_at >= 0, depth[np.maximum(sample_at, 0)], top).astype(np.float32)
    return out.reshape(-1, nbox)


@pytest.mark.parametrize("func,slices,boxes,spp,rows,group,ahead", [
    ("less", 4, 2, 64, 8, 1, False), ("lequal", 4, 2, 64, 8, 3, True), ("less", 2, 3, 32, 12, 2, False),
    ("lequal", 1, 1, 16, 4, 1, True), ("less", 4, 2, 64, 4, 2, True)])
def test_refresh_of_many_samples_per_box_matches_numpy(func, slices, boxes, spp, rows, group, ahead):
    """Many samples per pixel and box, as at high spp: random batches of random pixels (each pixel's
    samples together, or scattered), a random subset of each pixel's samples at random depths (a few
    levels with ties, +0 and -0, and continuous ones), over several tiles and regions, refreshed after each
    ``group`` of batches (the ordered refresh takes several requests), with the samples' box groups made
    ahead or by each region's first refresh. After each refresh every tile's boxes equal a numpy
    recomputation from the whole depth buffer, bit for bit, and the work counted is what a rescan of the
    stale boxes reads (those a depth not below their zmax was replaced in, all of a tile's first
    refresh)."""
    rng = np.random.default_rng(spp + slices + boxes + rows + group + ahead)
    w, h, ts = 14, 12, 4
    cfg = dataclasses.replace(load_arch().zcull, time_slices=slices, lens_boxes=boxes)
    plan, regions, zcull, rop = zcull_and_rop(cfg, PassState(depth_test=func), w, h, spp, ts, rows, seed=9,
                                              ahead=ahead)
    levels = np.array([0.0, -0.0, 0.5, 0.5, 0.75, 0.9], np.float32)
    for r0, r1, samples in each_region(plan, regions, rop):
        t0 = r0 // ts * zcull.tiles_x
        box = np.array([brute_box(samples, k, slices, boxes) for k in range(len(samples.t))])
        tile_of = ((np.arange(len(box)) // spp // w // ts) * zcull.tiles_x + np.arange(len(box)) // spp % w // ts)
        scanned = set()
        for step in range(40 // group):
            before = zcull.zmax.copy()
            requests = []
            for _ in range(group):
                # the first batch covers the region, so that a box's largest depth is not the clear depth; one
                # halfway through writes +0 and -0 all over: the largest depths are zeros, which of them is first
                # shows in their bits
                cover = step in (0, 20 // group)
                pix = rng.choice(np.arange(r0 * w, r1 * w), int(rng.integers(1, 12)), replace=False)
                pix = np.repeat(np.arange(r0 * w, r1 * w) if cover else pix, spp)
                sidx = np.tile(np.arange(spp), len(pix) // spp)
                keep = rng.random(len(pix)) < (1.0 if cover else rng.uniform(0.2, 1.0))
                pix, sidx = pix[keep].astype(np.int32), sidx[keep].astype(np.int32)
                if rng.random() < 0.3:  # scattered: a pixel's samples apart
                    perm = rng.permutation(len(pix))
                    pix, sidx = pix[perm], sidx[perm]
                n = len(pix)
                z = np.where(rng.random(n) < 0.3, levels[rng.integers(0, len(levels), n)],
                             rng.uniform(-0.2, 0.9, n)).astype(np.float32)
                if step == 20 // group:
                    z = levels[rng.integers(0, 2, n)]
                batch = dict(pix=pix, sidx=sidx, z=z, color=np.ones((n, 4), np.float32),
                             noread=np.zeros(n, np.bool_))
                requests.append(rop.run(batch)[0])
            ops, events, nbytes = rop.refresh_zcull(requests)
            pix = np.concatenate([q[0] for q in requests])
            k = (pix - r0 * w) * spp + np.concatenate([q[1] for q in requests])
            prior = np.concatenate([q[2] for q in requests])
            touched = np.unique(tile_of[k])
            read = scans = checks = 0
            for tile in touched:
                mine = tile_of == tile
                if tile in scanned:
                    writes = tile_of[k] == tile
                    checks += np.count_nonzero(writes)
                    stale = np.unique(box[k][writes & (prior >= before[t0 + tile, box[k]])])
                else:
                    stale = np.unique(box[mine])
                    scanned.add(tile)
                scans += len(stale) > 0
                read += np.count_nonzero(mine & np.isin(box, stale))
            assert events[rop_mod.EV_REFRESH_TILES] == len(touched)
            assert events[rop_mod.EV_REFRESH_SCANS] == scans
            assert (nbytes, ops[OP_CMP]) == (4 * read, checks + read)
            expect = before.copy()
            expect[t0 + touched] = numpy_zmax(samples, rop.depth, ts, slices, boxes)[touched]
            np.testing.assert_array_equal(zcull.zmax.view(np.uint32), expect.view(np.uint32))
        # the numpy recomputation agrees with the loop over samples
        np.testing.assert_array_equal(numpy_zmax(samples, rop.depth, ts, slices, boxes).view(np.uint32),
                                      brute_zmax(samples, rop.depth, ts, slices, boxes).view(np.uint32))


@pytest.mark.parametrize("nt,nl,spp,pattern", [(4, 2, 64, "net5"), (2, 3, 16, "random"), (1, 1, 8, "net"),
                                               (16, 3, 32, "table"), (3, 2, 1, "stratified")])
def test_box_groups_match_a_stable_sort_by_box(nt, nl, spp, pattern):
    """``box_groups_kernel`` against numpy: each sample's box as ``brute_box`` finds it, and each pixel's
    samples in a stable sort by box (``np.argsort`` of the boxes, stable) with each box's run where the
    counts of the boxes before it end. A table puts samples on the boxes' edges: t = 0 and just below 1,
    u and v at -1, 0 and 1."""
    w, h = 5, 3
    rng = np.random.default_rng(nt * 100 + nl * 10 + spp)
    table = None
    if pattern == "table":
        table = rng.random((spp, 5))
        table[::4, 4] = 0.0
        table[1::4, 4] = np.nextafter(1.0, 0.0)
        table[:, 2:4] = rng.choice([-1.0, 0.0, 1.0, 0.3, -0.7], (spp, 2))
    samples = make_samples(w, h, spp, 11, lens=True, motion=True, pattern=pattern, table=table,
                           lens_shape="square" if pattern == "table" else "disk")
    n, npix, nbox = w * h * spp, w * h, nt * nl * nl
    box_of, order = np.empty(n, np.uint8), np.empty(n, np.uint16)
    start = np.empty((npix, nbox + 1), np.int32)
    zc.box_groups_kernel(spp, nt, nl, samples.t, samples.u, samples.v, box_of, order, start)
    for got, want in zip((box_of, order, start), numpy_box_groups(samples, nt, nl)):
        np.testing.assert_array_equal(got, want)


def numpy_box_groups(samples, nt, nl):
    """(box_of, order, start) as ``box_groups_kernel`` lays them out, from ``brute_box`` and numpy's stable
    sort."""
    spp = samples.spp
    n, nbox = len(samples.t), nt * nl * nl
    box_of = np.array([brute_box(samples, k, nt, nl) for k in range(n)])
    per_pixel = box_of.reshape(-1, spp)
    order = np.argsort(per_pixel, axis=1, kind="stable").reshape(-1)
    counts = np.stack([np.bincount(b, minlength=nbox) for b in per_pixel])
    start = np.concatenate([np.zeros((len(per_pixel), 1), int), counts.cumsum(axis=1)], axis=1)
    return box_of, order, start


def test_box_groups_prepared_taken_and_their_buffers_reused(monkeypatch):
    """``BoxGroups``: groups prepared ahead are taken as prepared (grouped, not made again), a set not
    prepared gets buffers for the refresh to fill (not grouped), in those of the groups taken before (no
    longer read once a later region's are taken)."""
    w, h, spp = 6, 8, 16
    sets = [make_samples(w, h, spp, 5, lens=True, motion=True, rows=(r, r + 2)) for r in range(0, 8, 2)]
    groups = zc.BoxGroups(4, 2)

    def check(got, s):
        for a, b in zip(got, numpy_box_groups(s, 4, 2)):
            np.testing.assert_array_equal(a, b)

    groups.prepare(sets[0])
    groups.prepare(sets[1])
    calls = []
    with monkeypatch.context() as m:
        m.setattr(zc, "box_groups_kernel", lambda *a: calls.append(a))
        first = groups.take(sets[1])  # region 1 first, as prepared (region 0's, passed, are dropped)
        again = groups.take(sets[2])  # not prepared
    assert not calls and first[3] and not again[3]
    check(first[:3], sets[1])
    assert all(np.shares_memory(a, b) for a, b in zip(again[:3], first[:3]))
    groups.prepare(sets[3])
    last = groups.take(sets[3])
    assert last[3] and not any(np.shares_memory(a, b) for a, b in zip(last[:3], again[:3]))
    check(last[:3], sets[3])


@pytest.mark.parametrize("func", [zc.CULL_LESS, zc.CULL_LEQUAL])
@pytest.mark.parametrize("seed", range(4))
def test_interval_query_answer_and_work_against_a_loop_over_boxes(func, seed):
    """The interval query over random records and boxes against a plain loop: the answer is visible iff some
    record's z^lo is in front of (LESS) or on (LEQUAL) the zmax of a box its (t^, u^, v^) touch (the boxes
    found by each one's index range, t in [0, 1], u and v in [-1, 1]); the records and comparisons counted are
    those up to and including the first such box, in record order and box order (t, then u, then v), all of
    them when there is none; a second batch after the answer is not looked at."""
    rng = np.random.default_rng(seed)
    nt, nl, tiles_x, n = 4, 2, 3, 40
    zmax = rng.choice([0.3, 0.5, 0.7], (6, nt * nl * nl)).astype(np.float32)
    tx, ty = rng.integers(0, 3, n), rng.integers(0, 2, n)
    t = np.sort(rng.uniform(0, 1, (n, 2)), axis=1)
    u, v = (np.sort(rng.uniform(-1, 1, (n, 2)), axis=1) for _ in range(2))
    # behind every box (seed 0), on the farthest boxes (1: visible only for LEQUAL), one record in front (2, 3)
    z_lo = np.full(n, 0.7 if seed == 1 else 0.75, np.float32)
    if seed >= 2:
        z_lo[10 + 5 * seed] = 0.2
    want, tiles, boxes = False, 0, 0
    for i in range(n):
        tiles += 1
        for it in range(nt):
            for iu in range(nl):
                for iv in range(nl):
                    if not (it / nt <= t[i, 1] and t[i, 0] < (it + 1) / nt and -1 + 2 * iu / nl <= u[i, 1]
                            and u[i, 0] < -1 + 2 * (iu + 1) / nl and -1 + 2 * iv / nl <= v[i, 1]
                            and v[i, 0] < -1 + 2 * (iv + 1) / nl):
                        continue
                    boxes += 1
                    zm = zmax[ty[i] * tiles_x + tx[i], (it * nl + iu) * nl + iv]
                    if z_lo[i] < zm or (func == zc.CULL_LEQUAL and z_lo[i] == zm):
                        want = True
                        break
                if want:
                    break
            if want:
                break
        if want:
            break
    answer = np.zeros(len(zc.QUERY_FIELDS), np.int64)
    ops = np.zeros(N_OPS, np.int64)
    args = (tx, ty, t[:, 0], t[:, 1], u[:, 0], u[:, 1], v[:, 0], v[:, 1], z_lo, tiles_x, nt, nl, zmax, func, answer,
            ops)
    zc.interval_query_kernel(*args)
    zc.interval_query_kernel(*args)  # a second batch of the same draw: nothing more once visible
    assert answer.tolist() == [int(want), tiles * (1 if want else 2), boxes * (1 if want else 2)]
    assert ops[OP_CMP] == answer[zc.Q_BOXES]
    assert want == (seed >= 2 or (seed == 1 and func == zc.CULL_LEQUAL))


_DEPTHS = st.sampled_from([0.0, 0.25, 0.5, 0.75, 1.0])
_UNIT = st.one_of(st.sampled_from([0.0, 0.25, 0.5, 0.75, 1.0]), st.floats(0.0, 1.0))
_SIGNED = st.one_of(st.sampled_from([-1.0, -0.5, 0.0, 0.5, 1.0]), st.floats(-1.0, 1.0))


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([(1, 1), (2, 1), (4, 2), (3, 3)]), st.sampled_from(["less", "lequal"]),
       st.lists(st.tuples(_UNIT, _SIGNED, _SIGNED, _DEPTHS), min_size=0, max_size=40),
       st.lists(st.tuples(_UNIT, _UNIT, _SIGNED, _SIGNED, _SIGNED, _SIGNED, _DEPTHS, _DEPTHS),
                min_size=1, max_size=12))
def test_zcull_never_culls_what_the_depth_test_could_pass(boxes, func, drawn, records):
    """The z-cull test against the exact depth test, on random and tied inputs: boxes whose zmax and zmin
    are the largest and smallest depth of the samples drawn in them (-inf and +inf with none), and
    records of random (t, u, v) intervals and depth ranges. A culled record has no drawn sample in its
    intervals that a depth in its range could pass; a record let through without depth reads passes at
    every such sample; the counts are those of the records so found."""
    nt, nl = boxes
    nbox = nt * nl * nl
    zmax = np.full((1, nbox), -np.inf, np.float32)
    zmin = np.full((1, nbox), np.inf, np.float32)
    pts = [(np.float32(t if t < 1.0 else 0.999), np.float32(u), np.float32(v), np.float32(d)) for t, u, v, d in drawn]
    for t, u, v, d in pts:
        b = zc._sample_box(t, u, v, nt, nl)
        zmax[0, b] = max(zmax[0, b], d)
        zmin[0, b] = min(zmin[0, b], d)
    n = len(records)
    cols = {k: np.empty(n, np.float32) for k in ("t_lo", "t_hi", "u_lo", "u_hi", "v_lo", "v_hi", "z_lo", "z_hi")}
    for i, (ta, tb, ua, ub, va, vb, za, zb) in enumerate(records):
        for key, (a, b) in zip(("t", "u", "v", "z"), ((ta, tb), (ua, ub), (va, vb), (za, zb))):
            cols[f"{key}_lo"][i], cols[f"{key}_hi"][i] = min(a, b), max(a, b)
    keep = np.empty(n, np.bool_)
    noread = np.empty(n, np.bool_)
    ops, events = np.zeros(N_OPS, np.int64), np.zeros(len(zc.EVENTS), np.int64)
    zeros = np.zeros(n, np.int32)
    zc.zcull_kernel(zeros, zeros, zeros, cols["t_lo"], cols["t_hi"], cols["u_lo"], cols["u_hi"], cols["v_lo"],
                    cols["v_hi"], cols["z_lo"], cols["z_hi"], 1, nt, nl, zmax, zmin.copy(),
                    zc.CULL_LESS if func == "less" else zc.CULL_LEQUAL, keep, noread, ops, events)
    passes = (lambda z, d: z < d) if func == "less" else (lambda z, d: z <= d)  # noqa: E731
    for i in range(n):
        inside = [d for t, u, v, d in pts
                  if cols["t_lo"][i] <= t <= cols["t_hi"][i] and cols["u_lo"][i] <= u <= cols["u_hi"][i]
                  and cols["v_lo"][i] <= v <= cols["v_hi"][i]]
        if not keep[i]:  # the nearest depth of the record fails against every drawn sample it could meet
            assert not any(passes(cols["z_lo"][i], d) for d in inside), (i, inside)
        if noread[i]:  # the farthest depth of the record is in front of every drawn sample it could meet
            assert keep[i] and all(cols["z_hi"][i] < d for d in inside), (i, inside)
    assert events[zc.EV_CULLED] == np.count_nonzero(~keep)
    assert events[zc.EV_NOREAD] == np.count_nonzero(noread)
