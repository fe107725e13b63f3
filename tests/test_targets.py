"""The parts of a pass (docs/pipeline.md §2.6-2.7): render targets with per-channel blends, depth rules and
draw filters, resolves (box, lens regions, none), the append buffer, queries, textures and several draws,
each against a reference computed another way (numpy over the fragment list, brute-force coverage, numpy
weighted means, direct indexing, scipy's interpolation, each draw rendered alone)."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from hard_cases.harness import exact_coverage, make_draw, tri
from pipeline_sim.config import RopConfig, load_arch
from pipeline_sim.errors import UserError
from pipeline_sim.pass_state import ClipPlanes, PassState
from pipeline_sim.simulation import SimOptions
from pipeline_sim.render import RenderPass, run_pass, run_passes
from pipeline_sim.shaders import (IN_DEPTH, IN_SAMPLE, IN_T, IN_TRIANGLE, IN_TUPLE, IN_U, IN_V, IN_X, IN_Y,
                                  append_record, fetch, sample_layer)
from pipeline_sim.targets import AppendBuffer, LensRegion, ShaderOutput, Target
from units.rop import Rop

W, H = 24, 16


# --------------------------------------------------------------------------- ROP: targets over a fragment list
def _fragments(rng, n, npix, spp, ntri):
    return dict(pix=rng.integers(0, npix, n).astype(np.int32), sidx=rng.integers(0, spp, n).astype(np.int32),
                z=rng.random(n).astype(np.float32), tri=rng.integers(0, ntri, n).astype(np.int32),
                noread=np.zeros(n, np.bool_), color=(rng.integers(-8, 9, (n, 6)) / 4.0).astype(np.float32))


def test_per_channel_blends_depth_rules_and_draw_filters_match_numpy():
    """Per-channel MIN/MAX (a tz-box, Nilsson12 §3), ADD on one draw's fragments only, and depth rules,
    against numpy's unbuffered ufunc.at over the fragment list (applied in list order)."""
    rng = np.random.default_rng(3)
    width, height, spp, ntri = 4, 3, 4, 10
    npix = width * height
    tri_draw = (np.arange(ntri) >= 6).astype(np.int32)  # triangles 0-5: draw 0, 6-9: draw 1
    outputs = (ShaderOutput("box", 4), ShaderOutput("light", 2))
    big = 3.0e38
    targets = (Target("tz", "box", ("min", "max", "min", "max"), (big, -big, big, -big), depth="always"),
               Target("light", "light", "add", (0.5, 0.0), depth="always", draws=(1,)),
               Target("tested", "light", "replace", (7.0, 7.0)))
    # depth test "never": only targets written regardless of it change
    rop = Rop(RopConfig(), PassState(depth_test="never"), width, height, spp, (0, 0, 0, 0), 1.0, targets=targets,
              outputs=outputs, tri_draw=tri_draw, n_draws=2)
    want = [np.tile(np.float32(t.clear), (npix * spp, 1)) for t in targets]
    for batch in range(3):
        f = _fragments(rng, 200, npix, spp, ntri)
        _, ops, ev, traffic = rop.run(f)
        slot = f["pix"] * spp + f["sidx"]
        for c, op in enumerate((np.minimum, np.maximum, np.minimum, np.maximum)):
            op.at(want[0][:, c], slot, f["color"][:, c])
        mine = tri_draw[f["tri"]] == 1
        for c in range(2):
            np.add.at(want[1][:, c], slot[mine], f["color"][mine, 4 + c])
        assert ev[3] == 0  # samples_written: those passing the depth test
    for buf, w in zip(rop.buffers, want):
        np.testing.assert_array_equal(buf, w)
    rop.resolve()
    np.testing.assert_allclose(rop.images["tz"][0], want[0].reshape(height, width, spp, 4).mean(axis=2), rtol=1e-6)
    assert rop.queries.tolist() == [0, 0]


def test_queries_count_depth_passing_samples_per_draw():
    """Queries against a brute-force count over the fragment list, with a sequential depth test."""
    rng = np.random.default_rng(5)
    width, height, spp, ntri = 3, 2, 2, 9
    tri_draw = np.repeat(np.arange(3, dtype=np.int32), 3)
    rop = Rop(RopConfig(), PassState(depth_test="less"), width, height, spp, (0, 0, 0, 0), 1.0, tri_draw=tri_draw,
              n_draws=3)
    depth = np.full(width * height * spp, np.float32(1.0))
    want = np.zeros(3, np.int64)
    for batch in range(4):
        f = _fragments(rng, 50, width * height, spp, ntri)
        f["color"] = f["color"][:, :4].copy()
        rop.run(f)
        for p, s, z, t in zip(f["pix"], f["sidx"], f["z"], f["tri"]):
            if z < depth[p * spp + s]:
                depth[p * spp + s] = z
                want[tri_draw[t]] += 1
    assert rop.queries.tolist() == want.tolist() and want.min() > 0


# --------------------------------------------------------------------------- pipeline: append buffer and inputs
@nb.njit(cache=True)
def _append_sample_shader(inputs, params, textures, out, append):
    """Appends (pixel x, pixel y, sample index, triangle, tuple index) of each shaded sample."""
    rec = np.empty(5, np.float32)
    for i in range(inputs.shape[1]):
        rec[0] = np.floor(inputs[IN_X, i])
        rec[1] = np.floor(inputs[IN_Y, i])
        rec[2] = inputs[IN_SAMPLE, i]
        rec[3] = inputs[IN_TRIANGLE, i]
        rec[4] = inputs[IN_TUPLE, i]
        append_record(append, rec)
        for c in range(out.shape[1]):
            out[i, c] = 1.0


def _two_triangles(height: int = H):
    """Two non-overlapping moving, defocused triangles: each sample is covered at most once."""
    q = np.concatenate([tri((-0.9, -0.8, 0.3, 1.0), (0.1, -0.9, 0.3, 1.0), (-0.5, 0.7, 0.3, 1.0)),
                        tri((0.2, 0.1, 0.6, 1.0), (0.95, -0.2, 0.6, 1.0), (0.7, 0.9, 0.6, 1.0))])
    r = q + np.array([0.15, 0.05, 0.0, 0.0])
    lx = np.full(q.shape[:2] + (2,), 0.05)
    return make_draw(q, r, lx, -lx, width=W, height=height)


def _count_pass(draw, *, append=None, pattern="net", spp=4, **kw) -> RenderPass:
    arch = load_arch()
    state = PassState(depth_test="always", shading_mode="per_sample", sample_pattern=pattern, blend="add")
    return RenderPass(draw=draw, arch=arch, spp=spp, seed=2, state=state, shader=_append_sample_shader,
                      append=append, clear_color=(0, 0, 0, 0), **kw)


def _covered(draw, samples) -> np.ndarray:
    """Brute force: (x, y, sample, triangle) of every covered sample, sorted."""
    count, _, tlast = exact_coverage(draw, samples)
    assert count.max() == 1
    y, x, s = np.nonzero(count)
    return np.stack([x, y, s, tlast[y, x, s]], axis=1).astype(np.float64)


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize("pattern", ["net", "interleave"])
def test_append_buffer_holds_every_covered_sample_with_its_indices(pattern):
    draw = _two_triangles()
    res = run_pass(_count_pass(draw, append=AppendBuffer(("x", "y", "sample", "triangle", "tuple"), 10_000),
                               pattern=pattern))
    rec = res.append.records.astype(np.float64)
    want = _covered(draw, res.samples)
    assert res.append.overflow == 0 and len(want) > 50
    np.testing.assert_array_equal(_sorted_rows(rec[:, :4]), _sorted_rows(want))
    # the tuple index: the sample's (u, v, t) among the interleave pattern's tuples; -1 without them
    x, y, s = (rec[:, k].astype(np.int64) for k in range(3))
    if res.samples.tup is None:
        assert np.all(rec[:, 4] == -1)
    else:
        np.testing.assert_array_equal(rec[:, 4], res.samples.tup[(y * W + x) * res.samples.spp + s])


@nb.njit(cache=True)
def _append_tuple_shader(inputs, params, textures, out, append):
    """Appends (sample index, tuple index, u, v, t) of each shaded sample."""
    rec = np.empty(5, np.float32)
    for i in range(inputs.shape[1]):
        rec[0], rec[1] = inputs[IN_SAMPLE, i], inputs[IN_TUPLE, i]
        rec[2], rec[3], rec[4] = inputs[IN_U, i], inputs[IN_V, i], inputs[IN_T, i]
        append_record(append, rec)
        for c in range(out.shape[1]):
            out[i, c] = 1.0


def test_a_sample_table_row_is_the_tuple_index():
    """With a sample table (its rows not in t order here), the tuple index of a sample is its row in the
    table sorted by t, and its (u, v, t) that row's: the tuple k of every pixel (Nilsson12 §7)."""
    rng = np.random.default_rng(4)
    table = np.column_stack([rng.random((6, 2)), rng.uniform(-1, 1, (6, 2)), rng.permutation(6) / 6 + 0.05])
    p = _count_pass(_two_triangles(), append=AppendBuffer(("sample", "tuple", "u", "v", "t"), 10_000), spp=6,
                    sample_table=table)
    p.shader = _append_tuple_shader
    rec = run_pass(p).append.records
    ordered = table[np.argsort(table[:, 4])].astype(np.float32)
    assert len(rec) > 50 and np.array_equal(rec[:, 0], rec[:, 1])
    np.testing.assert_array_equal(rec[:, 2:], ordered[rec[:, 1].astype(int)][:, 2:])


def test_append_buffer_keeps_the_first_records_and_counts_the_overflow():
    draw = _two_triangles()
    fields = ("x", "y", "sample", "triangle", "tuple")
    full = run_pass(_count_pass(draw, append=AppendBuffer(fields, 10_000))).append
    small = run_pass(_count_pass(draw, append=AppendBuffer(fields, 37))).append
    assert len(small.records) == 37 and small.overflow == len(full.records) - 37
    np.testing.assert_array_equal(small.records, full.records[:37])  # in the order appended
    none = run_pass(_count_pass(draw))
    assert none.append is None


def test_cached_shading_has_no_sample_or_tuple_index():
    draw = _two_triangles()
    p = _count_pass(draw, append=AppendBuffer(("x", "y", "sample", "triangle", "tuple"), 10_000))
    p.state = p.state.replace(shading_mode="cache")
    rec = run_pass(p).append.records
    assert len(rec) and np.all(rec[:, 2] == -1) and np.all(rec[:, 4] == -1)


# --------------------------------------------------------------------------- resolves
@nb.njit(cache=True)
def _lens_shader(inputs, params, textures, out, append):
    """(u, v, t, depth): a different value at every sample."""
    for i in range(inputs.shape[1]):
        out[i, 0] = inputs[IN_U, i]
        out[i, 1] = inputs[IN_V, i]
        out[i, 2] = inputs[IN_T, i]
        out[i, 3] = inputs[IN_DEPTH, i]


def test_lens_region_resolve_is_the_weighted_mean_of_the_kept_samples():
    """Per-view resolve (Nilsson12 §8) against numpy weighted means of the per-sample data ("none")."""
    draw = _two_triangles()
    views = (LensRegion(-1.0, 0.2), LensRegion(-0.2, 1.0), LensRegion(-0.5, 0.5, -1.0, 0.0))  # overlapping
    targets = (Target("color", clear=(0.0, 0.0, 0.0, 0.0)), Target("views", resolve="lens", views=views),
               Target("raw", resolve="none"))
    p = RenderPass(draw=draw, arch=load_arch(), spp=16, seed=4, shader=_lens_shader, targets=targets,
                   state=PassState(depth_test="less", shading_mode="per_sample", sample_pattern="net"))
    res = run_pass(p)
    raw = res.sample_data["raw"].astype(np.float64)  # (H, W, spp, 4)
    s = res.samples
    u, v = s.u.reshape(H, W, -1), s.v.reshape(H, W, -1)
    assert len(res.images["views"]) == 3 and res.images["raw"] == []
    for view, img in zip(views, res.images["views"]):
        w = ((u >= view.u_lo) & (u <= view.u_hi) & (v >= view.v_lo) & (v <= view.v_hi)).astype(np.float64)
        tot = w.sum(axis=2)[..., None]
        with np.errstate(invalid="ignore"):
            want = np.where(tot > 0, (raw * w[..., None]).sum(axis=2) / tot, 0.0)  # no sample: the clear value
        np.testing.assert_allclose(img, want, rtol=1e-6, atol=1e-6)
    # the first target's box resolve is the image: the plain mean of the same samples
    np.testing.assert_allclose(res.image, raw.mean(axis=2), rtol=1e-6, atol=1e-7)
    assert res.images["color"][0] is res.image
    assert not np.array_equal(res.images["views"][0], res.images["views"][1])


def test_resolve_none_over_several_regions_matches_one_region():
    draw = _two_triangles(height=96)
    targets = (Target("color", clear=(0.0, 0.0, 0.0, 0.0)), Target("raw", resolve="none"))

    def go(region_samples):
        return run_pass(RenderPass(draw=draw, arch=load_arch(), spp=4, seed=4, shader=_lens_shader, targets=targets,
                                   state=PassState(shading_mode="per_sample"),
                                   simulation=SimOptions(region_samples=region_samples)))
    one, many = go(1 << 20), go(W * 4 * 4)
    assert many.regions.count > 1
    np.testing.assert_array_equal(many.sample_data["raw"], one.sample_data["raw"])


# --------------------------------------------------------------------------- textures
def test_sample_layer_is_bilinear_interpolation_and_fetch_indexes():
    rng = np.random.default_rng(9)
    tex = rng.random((5, 7, 3)).astype(np.float32)
    for s, t in rng.uniform(-0.2, 1.2, (200, 2)):
        layer = int(rng.integers(0, 3))
        # texel centres at half-integers, clamped at the border: scipy's order-1 interpolation, mode "nearest"
        want = map_coordinates(tex[:, :, layer].astype(np.float64), [[t * 5 - 0.5], [s * 7 - 0.5]], order=1,
                               mode="nearest")[0]
        assert abs(sample_layer(tex, layer, s, t) - want) < 1e-5
    for x, y, layer in ((0, 0, 0), (6, 4, 2), (3, 2, 1), (-3, 9, 1)):
        assert fetch(tex, x, y, layer) == tex[min(max(y, 0), 4), min(max(x, 0), 6), layer]


@nb.njit(cache=True)
def _shadow_shader(inputs, params, textures, out, append):
    """Shadow-map-like lookup in a per-sample depth array: channel 0 the light pass's depth of this
    sample index at this pixel, channel 1 whether it lies in front of this receiver (in shadow)."""
    for i in range(inputs.shape[1]):
        d = fetch(textures[0], inputs[IN_X, i], inputs[IN_Y, i], int(inputs[IN_SAMPLE, i]))
        out[i, 0] = d
        out[i, 1] = 1.0 if d < inputs[IN_DEPTH, i] - 1e-4 else 0.0
        out[i, 2] = 0.0
        out[i, 3] = 1.0


def test_a_pass_reads_an_earlier_pass_per_sample_depth_as_a_texture_array():
    """Two passes: an occluder's per-sample depth (one layer per sample index), then a receiver that looks
    it up per sample; against the first pass's depth indexed directly."""
    occluder = make_draw(tri((-0.8, -0.9, 0.1, 1.0), (0.7, -0.6, 0.1, 1.0), (-0.2, 0.8, 0.1, 1.0)), width=W, height=H)
    quad = np.concatenate([tri((-1, -1, 0.5, 1), (1, -1, 0.5, 1), (1, 1, 0.5, 1)),
                           tri((-1, -1, 0.5, 1), (1, 1, 0.5, 1), (-1, 1, 0.5, 1))])
    receiver = make_draw(quad, width=W, height=H)
    state = PassState(shading_mode="per_sample", sample_pattern="net")
    light = RenderPass(draw=occluder, arch=load_arch(), spp=8, seed=1, name="light", state=state)
    camera = RenderPass(draw=receiver, arch=load_arch(), spp=8, seed=3, name="camera", state=state,
                        shader=_shadow_shader, textures=("light.depth",),
                        targets=(Target("color"), Target("raw", resolve="none")))
    out = run_passes([light, camera])
    raw = out["camera"].sample_data["raw"]
    depth = out["light"].depth  # (H, W, spp)
    np.testing.assert_array_equal(raw[..., 0], depth)
    shadowed = raw[..., 1] == 1
    np.testing.assert_array_equal(shadowed, depth < 0.5 - 1e-4)
    assert 0 < shadowed.mean() < 1


def test_a_texture_that_names_nothing_is_one_line():
    p = RenderPass(draw=_two_triangles(), arch=load_arch(), spp=1, textures=("nowhere",))
    with pytest.raises(UserError, match="texture 'nowhere'"):
        run_passes([p])


# --------------------------------------------------------------------------- several draws
def _counting_targets():
    return (Target("color", clear=(0.0, 0.0, 0.0, 0.0)), Target("raw", resolve="none"))


def _counting(draws, **kw):
    state = PassState(depth_test="always", shading_mode="per_sample", blend="add", clip=ClipPlanes(0.0, 1.0))
    return run_pass(RenderPass(draw=draws, arch=load_arch(), spp=8, seed=6, state=state,
                               simulation=SimOptions(triangles_per_batch=64), targets=_counting_targets(),
                               shader=_append_sample_shader, **kw))


def test_several_draws_with_their_own_clip_planes_equal_each_draw_alone():
    """Each draw keeps its own clip planes in t (Nilsson12 §5): the per-sample sum of one pass of both
    draws equals the sum of each draw rendered alone, and the clip planes do cut."""
    a, b = _two_triangles(), _two_triangles()
    a.clip = ClipPlanes(t_lo=0.0, t_hi=0.4)
    b.clip = ClipPlanes(t_lo=0.6, t_hi=1.0)
    both = _counting([a, b], append=AppendBuffer(("x", "y", "sample", "triangle", "tuple"), 10_000))
    alone = [_counting([d]).sample_data["raw"] for d in (a, b)]
    np.testing.assert_array_equal(both.sample_data["raw"], alone[0] + alone[1])
    unclipped = _two_triangles()
    assert alone[0].sum() < _counting([unclipped]).sample_data["raw"].sum()
    assert both.queries.tolist() == [int(alone[0][..., 0].sum()), int(alone[1][..., 0].sum())]
    # submission order: every record of draw 0 (triangles 0-1) before any of draw 1 (triangles 2-3)
    order = both.append.records[:, 3]
    assert np.all(np.diff((order >= 2).astype(int)) >= 0)


def test_query_counts_samples_of_each_draw_that_pass_the_depth_test():
    """Queries against brute force: draw 0 an occluder in front, draw 1 a triangle behind it; a sample of
    draw 1 passes where draw 0 does not cover it (depth test less)."""
    front = make_draw(tri((-0.9, -0.9, 0.2, 1.0), (0.6, -0.5, 0.2, 1.0), (-0.4, 0.9, 0.2, 1.0)), width=W, height=H)
    back = make_draw(tri((-0.3, -0.8, 0.7, 1.0), (0.95, -0.1, 0.7, 1.0), (0.2, 0.95, 0.7, 1.0)), width=W, height=H)
    res = run_pass(RenderPass(draw=[front, back], arch=load_arch(), spp=8, seed=7,
                              state=PassState(depth_test="less", depth_write=True)))
    c0, _, _ = exact_coverage(front, res.samples)
    c1, _, _ = exact_coverage(back, res.samples)
    want = [int((c0 > 0).sum()), int(((c1 > 0) & (c0 == 0)).sum())]
    assert res.queries.tolist() == want and min(want) > 0 and (c1 > 0).sum() > want[1]


# --------------------------------------------------------------------------- declarations
@pytest.mark.parametrize("targets,match", [
    ((Target("a", source="nope"),), "source 'nope'"),
    ((Target("a", blend=("min", "max")),), "blend"),
    ((Target("a", clear=(0.0, float("inf"), 0.0, 0.0)),), "finite"),
    ((Target("a", draws=(3,)),), "draws"),
    ((Target("a", resolve="lens"),), "views"),
    ((Target("a"), Target("a")), "distinct"),
])
def test_a_target_the_pass_cannot_run_is_refused_in_one_line(targets, match):
    p = RenderPass(draw=_two_triangles(), arch=load_arch(), spp=1, targets=targets)
    with pytest.raises(UserError, match=match):
        run_pass(p)
