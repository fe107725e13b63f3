"""ROP (units/rop.py): depth test, blending, counters and resolve.

Every check compares the numba kernel / ``Rop`` class against a plain Python
sequential reference written here (operator-module comparisons, float32
arithmetic done with numpy scalars), or against closed forms.
"""

from __future__ import annotations

import operator

import numpy as np
import pytest

from pipeline_sim.config import RopConfig
from pipeline_sim.definitions import BLEND_MODES, DEPTH_FUNCS
from pipeline_sim.definitions import N_OPS, OP_ADD, OP_CMP
from pipeline_sim.pass_state import PassState
from units.rop import EVENTS, Rop

DEPTH_CMP = {
    "less": operator.lt,
    "lequal": operator.le,
    "greater": operator.gt,
    "gequal": operator.ge,
    "equal": operator.eq,
    "always": lambda a, b: True,
    "never": lambda a, b: False,
}
DEPTH_LEVELS = np.array([0.0, 0.25, 0.5, 0.75, 1.0], np.float32)  # few levels: many ties


def reference_rop(frags, spp, func, depth_write, blend, depth, color):
    """Sequential per-fragment reference. Mutates ``depth`` (list of float32) and
    ``color`` (list of 4-lists of float32). Returns a dict of counts, with
    "prior": per fragment, the depth it replaced (NaN: it wrote none)."""
    cmp = DEPTH_CMP[func]
    cnt = dict(depth_tests=0, depth_passed=0, depth_reads_skipped=0, samples_written=0,
               depth_reads=0, depth_writes=0, color_reads=0, color_writes=0)
    prior = []
    for pix, sidx, z, col, noread in frags:
        slot = pix * spp + sidx
        cnt["depth_tests"] += 1
        if noread:
            cnt["depth_reads_skipped"] += 1
        else:
            cnt["depth_reads"] += 1
        prior.append(np.float32(np.nan))
        if not cmp(np.float32(z), depth[slot]):
            continue
        cnt["depth_passed"] += 1
        if depth_write:
            prior[-1] = depth[slot]
            depth[slot] = np.float32(z)
            cnt["depth_writes"] += 1
        old = color[slot]
        if blend == "replace":
            new = [np.float32(c) for c in col]
        else:
            cnt["color_reads"] += 1
            if blend == "add":
                new = [np.float32(np.float32(o) + np.float32(c)) for o, c in zip(old, col)]
            elif blend == "min":
                new = [min(np.float32(o), np.float32(c)) for o, c in zip(old, col)]
            else:
                new = [max(np.float32(o), np.float32(c)) for o, c in zip(old, col)]
        color[slot] = new
        cnt["color_writes"] += 1
        cnt["samples_written"] += 1
    cnt["bytes_read"] = 4 * cnt["depth_reads"] + 16 * cnt["color_reads"]
    cnt["bytes_written"] = 4 * cnt["depth_writes"] + 16 * cnt["color_writes"]
    return cnt, np.array(prior, np.float32)


def random_frags(rng, n, npix, spp):
    pix = rng.integers(0, npix, n).astype(np.int32)
    sidx = rng.integers(0, spp, n).astype(np.int32)
    z = DEPTH_LEVELS[rng.integers(0, len(DEPTH_LEVELS), n)]
    # colors on a coarse grid so that min/max ties happen, and with negatives
    color = (rng.integers(-4, 9, (n, 4)) / 4.0).astype(np.float32)
    noread = rng.random(n) < 0.3
    return pix, sidx, z, color, noread


def as_frag_list(pix, sidx, z, color, noread):
    return [(int(p), int(s), np.float32(zz), [np.float32(c) for c in col], bool(nr))
            for p, s, zz, col, nr in zip(pix, sidx, z, color, noread)]


@pytest.mark.parametrize("blend", BLEND_MODES)
@pytest.mark.parametrize("func", DEPTH_FUNCS)
@pytest.mark.parametrize("depth_write", [True, False])
def test_rop_kernel_matches_sequential_reference(func, blend, depth_write):
    rng = np.random.default_rng(100 * DEPTH_FUNCS.index(func) + 10 * BLEND_MODES.index(blend) + depth_write)
    width, height, spp = 3, 2, 4
    npix = width * height
    for trial in range(3):
        clear_depth = float(DEPTH_LEVELS[rng.integers(1, len(DEPTH_LEVELS))])
        rop = Rop(RopConfig(), PassState(depth_test=func, blend=blend, depth_write=depth_write), width, height, spp,
                  (0, 0, 0, 0), clear_depth, zcull=object())  # a z-cull: run returns the priors in its request
        depth_buf, color_buf = rop.depth, rop.color
        color_buf[:] = (rng.integers(-4, 9, (npix * spp, 4)) / 4.0).astype(np.float32)
        ref_depth = [np.float32(d) for d in depth_buf]
        ref_color = [[np.float32(c) for c in row] for row in color_buf]
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        traffic = np.zeros(2, np.int64)
        total = None
        # several batches carry buffer state
        for batch in range(3):
            frags = random_frags(rng, 80, npix, spp)
            request, o, e, t = rop.run(dict(zip(("pix", "sidx", "z", "color", "noread"), frags),
                                            tri=np.zeros(80, np.int32)))
            ops += o
            events += e
            traffic += t
            prior = request[2]
            cnt, ref_prior = reference_rop(as_frag_list(*frags), spp, func, depth_write, blend, ref_depth, ref_color)
            np.testing.assert_array_equal(prior, ref_prior)
            total = cnt if total is None else {k: total[k] + cnt[k] for k in total}
        np.testing.assert_array_equal(depth_buf, np.array(ref_depth, np.float32))
        np.testing.assert_array_equal(color_buf, np.array(ref_color, np.float32))
        got = dict(zip(EVENTS, events.tolist()))
        for name in EVENTS:  # z-cull refreshes are counted by ``Rop.refresh_zcull``, not the kernel
            assert got[name] == total.get(name, 0), name
        assert traffic[0] == total["bytes_read"]
        assert traffic[1] == total["bytes_written"]
        assert ops[OP_CMP] == total["depth_tests"]
        assert ops[OP_ADD] == (0 if blend == "replace" else 4 * total["depth_passed"])
        if not depth_write:
            assert np.all(depth_buf == np.float32(clear_depth))


@pytest.mark.parametrize("func,pick", [("less", np.minimum), ("lequal", np.minimum),
                                       ("greater", np.maximum), ("gequal", np.maximum)])
def test_final_depth_is_running_extremum(func, pick):
    """Closed form: with writes on, less/lequal leave min(clear, z...) per slot,
    greater/gequal max(clear, z...); slots never hit keep the clear depth."""
    rng = np.random.default_rng(7)
    npix, spp, clear = 5, 4, 0.5
    pix = rng.integers(0, npix, 300).astype(np.int32)
    sidx = rng.integers(0, spp, 300).astype(np.int32)
    sidx[pix == 4] = 0  # pixel 4 only ever touches sample 0
    z = rng.random(300).astype(np.float32)
    rop = Rop(RopConfig(), PassState(depth_test=func, blend="replace", depth_write=True), npix, 1, spp, (0, 0, 0, 1),
              clear)
    batch = dict(pix=pix, sidx=sidx, z=z, color=rng.random((300, 4)).astype(np.float32),
                 noread=np.zeros(300, np.bool_))
    rop.run(batch)
    expect = np.full(npix * spp, clear, np.float32)
    pick.at(expect, pix.astype(np.int64) * spp + sidx, z)
    np.testing.assert_array_equal(rop.depth, expect)
    assert np.all(rop.depth.reshape(npix, spp)[4, 1:] == np.float32(clear))


def test_replace_less_color_is_first_strict_minimum():
    """Closed form for less + replace: each slot's color is that of the first
    fragment reaching the slot's minimum depth (ties lose under less)."""
    rng = np.random.default_rng(11)
    n, nslot = 400, 12
    slot = rng.integers(0, nslot, n)
    z = DEPTH_LEVELS[rng.integers(0, 4, n)]  # all below the clear depth 1.0
    color = rng.random((n, 4)).astype(np.float32)
    rop = Rop(RopConfig(), PassState(depth_test="less"), nslot, 1, 1, (9, 9, 9, 9), 1.0)
    rop.run(dict(pix=slot.astype(np.int32), sidx=np.zeros(n, np.int32), z=z, color=color,
                 noread=np.zeros(n, np.bool_)))
    for s in range(nslot):
        idx = np.nonzero(slot == s)[0]
        if len(idx) == 0:
            np.testing.assert_array_equal(rop.color[s], np.full(4, 9, np.float32))
            continue
        zmin = z[idx].min()
        first = idx[np.argmax(z[idx] == zmin)]
        np.testing.assert_array_equal(rop.color[s], color[first])


@pytest.mark.parametrize("blend", BLEND_MODES)
@pytest.mark.parametrize("func", DEPTH_FUNCS)
def test_rop_class_batches_and_counters(func, blend):
    """``Rop.run`` over several batches equals the reference, and its return values
    carry the counts the pipeline turns into counters."""
    rng = np.random.default_rng(DEPTH_FUNCS.index(func) * 10 + BLEND_MODES.index(blend))
    width, height, spp = 4, 3, 2
    clear_color = (0.25, -0.5, 1.0, 1.0)
    rop = Rop(RopConfig(), PassState(depth_test=func, blend=blend, depth_write=True), width, height, spp, clear_color, 0.75)
    ref_depth = [np.float32(0.75)] * (width * height * spp)
    ref_color = [[np.float32(c) for c in clear_color] for _ in range(width * height * spp)]
    sums = np.zeros(len(EVENTS), np.int64)
    bytes_rw = np.zeros(2, np.int64)
    ref_tot = None
    for _ in range(4):
        frags = random_frags(rng, int(rng.integers(0, 60)), width * height, spp)
        batch = dict(zip(("pix", "sidx", "z", "color", "noread"), frags))
        request, ops, ev, traffic = rop.run(batch)
        assert request is None  # no z-cull to refresh
        sums += ev
        bytes_rw += traffic
        cnt, _ = reference_rop(as_frag_list(*frags), spp, func, True, blend, ref_depth, ref_color)
        ref_tot = cnt if ref_tot is None else {k: ref_tot[k] + cnt[k] for k in ref_tot}
    assert dict(zip(EVENTS, sums.tolist())) == {k: ref_tot.get(k, 0) for k in EVENTS}  # no z-cull: no refresh
    assert bytes_rw.tolist() == [ref_tot["bytes_read"], ref_tot["bytes_written"]]
    np.testing.assert_array_equal(rop.depth, np.array(ref_depth, np.float32))
    np.testing.assert_array_equal(rop.color, np.array(ref_color, np.float32))


def test_depth_write_false_leaves_depth_untouched():
    rng = np.random.default_rng(3)
    for func in DEPTH_FUNCS:
        rop = Rop(RopConfig(), PassState(depth_test=func, depth_write=False, blend="add"), 4, 4, 4, (0, 0, 0, 0), 0.5)
        before = rop.depth.copy()
        frags = random_frags(rng, 500, 16, 4)
        _, _, ev, traffic = rop.run(dict(zip(("pix", "sidx", "z", "color", "noread"), frags)))
        np.testing.assert_array_equal(rop.depth, before)
        written = ev[EVENTS.index("samples_written")]
        assert traffic[1] == 16 * written  # color only, no depth bytes
        if func == "always":
            assert written == 500
            # add blending of every fragment: per-slot sums (order-free for these exact quarters)
            slot = frags[0].astype(np.int64) * 4 + frags[1]
            expect = np.zeros((64, 4), np.float64)
            np.add.at(expect, slot, frags[3].astype(np.float64))
            np.testing.assert_array_equal(rop.color, expect.astype(np.float32))
        if func == "never":
            assert written == 0 and np.all(rop.color == 0)


def test_resolve_is_per_pixel_mean_over_samples():
    rng = np.random.default_rng(5)
    width, height, spp = 7, 5, 8
    rop = Rop(RopConfig(), PassState(), width, height, spp, (0, 0, 0, 1), 1.0)
    rop.color[:] = rng.normal(size=rop.color.shape).astype(np.float32)
    got = rop.resolve()
    assert got.shape == (height, width, 4) and got.dtype == np.float32
    expect = np.zeros((height, width, 4))
    for y in range(height):
        for x in range(width):
            base = (y * width + x) * spp
            expect[y, x] = rop.color[base:base + spp].astype(np.float64).sum(axis=0) / spp
    np.testing.assert_allclose(got, expect, rtol=1e-6, atol=1e-7)


def test_resolve_after_rendering_fragments():
    """End to end through run(): one pixel gets a full-coverage color, another half."""
    rop = Rop(RopConfig(), PassState(depth_test="less"), 2, 1, 4, (0, 0, 0, 0), 1.0)
    pix = np.array([0, 0, 0, 0, 1, 1], np.int32)
    sidx = np.array([0, 1, 2, 3, 0, 2], np.int32)
    color = np.tile(np.array([[1.0, 2.0, 4.0, 1.0]], np.float32), (6, 1))
    rop.run(dict(pix=pix, sidx=sidx, z=np.full(6, 0.5, np.float32), color=color, noread=np.zeros(6, bool)))
    img = rop.resolve()
    np.testing.assert_array_equal(img[0, 0], [1.0, 2.0, 4.0, 1.0])
    np.testing.assert_array_equal(img[0, 1], [0.5, 1.0, 2.0, 0.5])


@pytest.mark.parametrize("first_channels", [1, 2, 4, 5])
def test_replaced_first_target_of_any_width_with_further_targets(first_channels):
    """A first target replaced on every channel (the depth test's own loop writes it, of any channel count)
    before an added and an always-written target: each buffer and the counts against a sequential Python
    reference over the fragment list."""
    from pipeline_sim.targets import ShaderOutput, Target

    rng = np.random.default_rng(first_channels)
    width, height, spp = 3, 2, 2
    nslot = width * height * spp
    outputs = (ShaderOutput("a", first_channels), ShaderOutput("b", 3))
    targets = (Target("first", "a"), Target("sum", "b", "add"), Target("last", "b", depth="always"))
    rop = Rop(RopConfig(), PassState(depth_test="less"), width, height, spp, (0, 0, 0, 0), 1.0, targets=targets,
              outputs=outputs)
    want = [np.zeros((nslot, o.channels), np.float32) for o in (outputs[0], outputs[1], outputs[1])]
    depth = np.full(nslot, np.float32(1.0))
    for batch in range(3):
        n = 60
        pix, sidx, z, _, noread = random_frags(rng, n, width * height, spp)
        color = (rng.integers(-4, 9, (n, first_channels + 3)) / 4.0).astype(np.float32)
        _, ops, ev, traffic = rop.run(dict(pix=pix, sidx=sidx, z=z, color=color, noread=noread))
        passed = 0
        for i in range(n):
            k = pix[i] * spp + sidx[i]
            if z[i] < depth[k]:
                depth[k] = z[i]
                passed += 1
                want[0][k] = color[i, :first_channels]
                want[1][k] = want[1][k] + color[i, first_channels:]
            want[2][k] = color[i, first_channels:]
        assert ev[EVENTS.index("depth_tests")] == ops[OP_CMP] == n
        assert ev[EVENTS.index("samples_written")] == passed
        assert ops[OP_ADD] == 3 * passed  # the added target's channels, where the test passed
        # depth reads, and the added target's; depth writes and each target's (the last one's for every sample)
        assert traffic[0] == 4 * int((~noread).sum()) + 12 * passed
        assert traffic[1] == 4 * passed + 4 * first_channels * passed + 12 * passed + 12 * n
    for buf, w in zip(rop.buffers, want):
        np.testing.assert_array_equal(buf, w)
    np.testing.assert_array_equal(rop.depth, depth)


@pytest.mark.parametrize("channels", [1, 3, 4, 5, 8])
def test_resolve_kernel_sums_in_sample_order(channels):
    """The box filter against a plain Python loop summing each pixel's samples in float64 in sample order,
    bit for bit, at any channel count: small values among +-1e20, which swallow them, so another order of
    additions gives another sum."""
    from units.rop import resolve_kernel

    rng = np.random.default_rng(channels)
    npix, spp = 6, 16
    buf = np.where(rng.random((npix * spp, channels)) < 0.25, rng.choice([-1e20, 1e20], (npix * spp, channels)),
                   rng.normal(size=(npix * spp, channels))).astype(np.float32)
    out = np.empty((npix, channels), np.float32)
    resolve_kernel(buf, spp, out)
    for p in range(npix):
        for c in range(channels):
            acc = 0.0
            for s in range(spp):
                acc += float(buf[p * spp + s, c])
            assert out[p, c].view(np.uint32) == np.float32(acc / spp).view(np.uint32)


def test_each_region_starts_cleared():
    """Targets of 1, 3 and 5 channels with their own clear values (-0 among them), over three screen
    regions: each region's buffers hold the clear values, bit for bit, when it opens, though the last
    one's were written all over; its depth the clear depth."""
    from pipeline_sim.definitions import ShaderOutput, Target

    width, height, spp = 4, 6, 2
    outputs = (ShaderOutput("a", 1), ShaderOutput("b", 3), ShaderOutput("c", 5))
    clears = ((-0.0,), (0.25, -1.5, 3.0), (1.0, 2.0, -0.0, 4.0, 1e30))
    targets = tuple(Target(o.name, o.name, clear=c) for o, c in zip(outputs, clears))
    rop = Rop(RopConfig(), PassState(depth_test="always"), width, height, spp, (0, 0, 0, 0), 0.5, targets=targets,
              outputs=outputs, rows=(0, 2))
    for r0 in (2, 4):
        n = 2 * width * spp
        pix = np.repeat(np.arange((r0 - 2) * width, r0 * width, dtype=np.int32), spp)
        rop.run(dict(pix=pix, sidx=np.tile(np.arange(spp, dtype=np.int32), 2 * width),
                     z=np.zeros(n, np.float32), color=np.full((n, 9), 7.0, np.float32), noread=np.zeros(n, bool)))
        rop.open_region((r0, r0 + 2))
        for buf, clear in zip(rop.buffers, clears):
            want = np.tile(np.array(clear, np.float32), (n, 1))
            np.testing.assert_array_equal(buf.view(np.uint32), want.view(np.uint32))
        np.testing.assert_array_equal(rop.depth, np.full(n, 0.5, np.float32))


def test_the_open_regions_samples_come_with_its_first_batch_and_keep_what_was_written():
    """The pipeline hands a region's samples to the ROP with its first batch: the first region, opened
    when the ROP is made, may get them then, its buffers kept (not cleared again); a region without
    them resolves as a box, and refuses a lens resolve."""
    from pipeline_sim.definitions import LensRegion, ShaderOutput, Target
    from pipeline_sim.sampling import make_samples

    width, height, spp = 4, 4, 4
    outputs = (ShaderOutput("a", 2),)
    n = 2 * width * spp
    batch = dict(pix=np.repeat(np.arange(2 * width, dtype=np.int32), spp),
                 sidx=np.tile(np.arange(spp, dtype=np.int32), 2 * width), z=np.zeros(n, np.float32),
                 color=np.arange(2 * n, dtype=np.float32).reshape(n, 2), noread=np.zeros(n, bool))
    s = make_samples(width, height, spp, 2, lens=True, motion=False, rows=(0, 2))
    box = (Target("box", "a"),)
    lens = box + (Target("lens", "a", resolve="lens", views=(LensRegion(-1, 0),)),)
    for targets in (box, lens):
        rop = Rop(RopConfig(), PassState(depth_test="always"), width, height, spp, (0, 0, 0, 0), 1.0, rows=(0, 2),
                  targets=targets, outputs=outputs)
        rop.run(batch)
        if targets is lens:
            with pytest.raises(ValueError, match="rows 0-2: a lens resolve needs the region's samples"):
                rop.open_region((2, 4))
        rop.open_region((0, 2), s)
        assert rop.samples is s
        np.testing.assert_array_equal(rop.buffers[0][:, 0], np.arange(0, 2 * n, 2, dtype=np.float32))
        img = rop.resolve()
        want = np.arange(0, 2 * n, 2, dtype=np.float64).reshape(2, width, spp).mean(axis=2)
        np.testing.assert_array_equal(img[:2, :, 0], want)


def test_kept_samples_of_a_region_never_opened_are_the_clears():
    """A "none" target over three regions, the last one never opened (no batch reached it): its kept
    per-sample data are the target's clear values, not whatever memory held."""
    from pipeline_sim.definitions import ShaderOutput, Target

    width, height, spp = 3, 6, 2
    targets = (Target("box", "a"), Target("raw", "a", clear=(1.5, -2.0), resolve="none"))
    rop = Rop(RopConfig(), PassState(depth_test="always"), width, height, spp, (0, 0, 0, 0), 1.0, rows=(0, 2),
              targets=targets, outputs=(ShaderOutput("a", 2),))
    rop.open_region((2, 4))
    rop.resolve()
    raw = rop.sample_data()["raw"]
    assert raw.shape == (height, width, spp, 2)
    np.testing.assert_array_equal(raw.reshape(-1, 2), np.tile(np.float32([1.5, -2.0]), (height * width * spp, 1)))
