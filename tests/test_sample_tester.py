"""The sample tester's exact 5D test against an independent reference.

The reference (tests/reference.py) clips the triangle at the sample's
(t, u, v) against the near and far planes, divides by w and solves for
barycentrics with Cramer's rule in float64 — no 2DH edge functions.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reference import point_coverage, positions_at, render_static
from triangles import moving_triangle, setup_and_tiles
from units.sample_tester import inside_test

W, H = 48, 32


def edge_distance_px(tri_clip, x, y):
    """Distance in pixels from (x, y) to the triangle's projected edges (inf if any w <= 0)."""
    w = tri_clip[:, 3]
    if np.any(w <= 1e-6):
        return 0.0
    sx = (tri_clip[:, 0] / w + 1) * W / 2
    sy = (1 - tri_clip[:, 1] / w) * H / 2
    best = np.inf
    for k in range(3):
        a = np.array([sx[k], sy[k]])
        b = np.array([sx[(k + 1) % 3], sy[(k + 1) % 3]])
        ab = b - a
        tt = np.clip(np.dot([x, y] - a, ab) / max(np.dot(ab, ab), 1e-300), 0, 1)
        best = min(best, float(np.linalg.norm(a + tt * ab - [x, y])))
    return best


@given(moving_triangle(allow_w_cross=False), st.integers(0, 2**31), st.booleans())
def test_inside_test_matches_reference(tri, seed, cull):
    q, r, lx, ly = tri
    setup, alive, _ = setup_and_tiles(q, r, lx, ly, W, H)
    tb = setup.table
    rng = np.random.default_rng(seed)
    for _ in range(40):
        x, y = rng.uniform(0, W), rng.uniform(0, H)
        t = np.float32(rng.uniform())
        u, v = np.float32(rng.uniform(-0.7, 0.7)), np.float32(rng.uniform(-0.7, 0.7))
        x32, y32 = np.float32(x), np.float32(y)
        clip = positions_at(q, r, lx, ly, float(t), float(u), float(v))[0]
        # points within rounding distance of an edge may go either way
        if edge_distance_px(clip, float(x32), float(y32)) < 1e-3:
            continue
        want = point_coverage(clip, float(x32), float(y32), W, H, cull_backfaces=cull)
        got = inside_test(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, 0, x32, y32, t, u, v, cull,
                          tb.edge_eps)[0]
        assert got == want, (x32, y32, t, u, v)


def test_depth_and_barycentrics_match_reference():
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = np.zeros((1, 3, 4))
        q[0, :, 3] = rng.uniform(1, 3, 3)
        q[0, :, :2] = rng.uniform(-0.8, 0.8, (3, 2)) * q[0, :, 3:4]
        q[0, :, 2] = rng.uniform(-0.9, 0.9, 3) * q[0, :, 3]
        setup, _, _ = setup_and_tiles(q, q, np.zeros((1, 3, 2)), np.zeros((1, 3, 2)), W, H)
        tb = setup.table
        attr = np.eye(3)[None]  # barycentric coordinates as the interpolated attribute
        img, tid, depth = render_static(q, attr, W, H)
        for py, px in zip(*np.nonzero(tid == 0)):
            x, y = np.float32(px + 0.5), np.float32(py + 0.5)
            if edge_distance_px(q[0], float(x), float(y)) < 1e-2:
                continue
            ok, b0, b1, b2, z = inside_test(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, 0, x, y, np.float32(0.5),
                                            np.float32(0), np.float32(0), False, tb.edge_eps)
            assert ok
            np.testing.assert_allclose([b0, b1, b2], img[py, px], atol=2e-4)
            assert abs(z - depth[py, px]) < 1e-4


def test_specialized_2d_path_equals_generic_test():
    """Static pinhole triangles take the per-tile 2D path; every covered sample
    must be exactly what the generic per-sample 5D test says, and vice versa."""
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    rng = np.random.default_rng(11)
    n = 30
    q = np.zeros((n, 3, 4))
    q[:, :, 3] = rng.uniform(0.5, 3, (n, 3))
    q[:, :, :2] = rng.uniform(-1.2, 1.2, (n, 3, 2)) * q[:, :, 3:4]
    q[:, :, 2] = rng.uniform(-0.9, 0.9, (n, 3)) * q[:, :, 3]
    setup, alive, tiles = setup_and_tiles(q, q, np.zeros((n, 3, 2)), np.zeros((n, 3, 2)), W, H)
    samples = make_samples(W, H, 8, 3, lens=False, motion=False)
    tester = SampleTester(None, setup.table, samples, 8, False)
    out, _, _ = tester.run(tiles)
    got = set(zip(out["tri"].tolist(), out["pix"].tolist(), out["sidx"].tolist()))
    tb = setup.table
    want = set()
    for i in range(len(tiles["tri"])):
        tri, tx, ty = int(tiles["tri"][i]), int(tiles["tx"][i]), int(tiles["ty"][i])
        for py in range(ty * 8, min(ty * 8 + 8, H)):
            for px in range(tx * 8, min(tx * 8 + 8, W)):
                for s in range(8):
                    k = (py * W + px) * 8 + s
                    ok = inside_test(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, tri, np.float32(px + samples.x[k]),
                                     np.float32(py + samples.y[k]), samples.t[k], samples.u[k], samples.v[k],
                                     False, tb.edge_eps)[0]
                    if ok:
                        want.add((tri, py * W + px, s))
    assert len(want) > 200
    assert got == want


# ---------------------------------------------------------------------------
# The tester's fast paths (tile-major sample orders, slot ranges, fused and
# packed passes, per-edge tolerances, batched pass 2) against a plain loop:
# every sample of every record, in pixel order, through ``inside_test``.

def reference_run(tester, tiles):
    """What the sample tester must output for ``tiles``: (covered records as a
    dict of arrays, events, t-range lookups, samples given the two-stage or
    tuple-mask test), by testing sample after sample."""
    from units.sample_tester import EVENTS, _f32_at_least, _f32_at_most

    s, tb, ts = tester.samples, tester.table, tester.tile_size
    ev = dict.fromkeys(EVENTS, 0)
    out = {k: [] for k in ("tri", "pix", "sidx", "z", "b0", "b1", "b2", "noread")}
    lines = tiles.get("lines")
    masks = tiles.get("mask")
    searches = extra = 0
    for i in range(len(tiles["tri"])):
        tri = int(tiles["tri"][i])
        moving = bool(np.any(tb.dp_32[tri] != 0) or np.any(tb.dl_32[tri] != 0))
        lens = bool(np.any(tb.l0_32[tri] != 0))
        dims = int(moving) + 2 * int(lens)
        general = dims != 0 or not tester.specialize
        ta, tb_ = _f32_at_least(tiles["t_lo"][i]), _f32_at_most(tiles["t_hi"][i])
        ua, ub = _f32_at_least(tiles["u_lo"][i]), _f32_at_most(tiles["u_hi"][i])
        va, vb = _f32_at_least(tiles["v_lo"][i]), _f32_at_most(tiles["v_hi"][i])
        za, zb = np.float32(tiles["z_lo"][i]), np.float32(tiles["z_hi"][i])
        x0, y0 = int(tiles["tx"][i]) * ts, int(tiles["ty"][i]) * ts
        full_t = tiles["t_lo"][i] <= 0.0 and tiles["t_hi"][i] >= 1.0
        for py in range(y0, min(y0 + ts, s.height)):
            for px in range(x0, min(x0 + ts, s.width)):
                ev["pixels_visited"] += 1
                searches += not full_t
                for si in range(s.spp):
                    k = (py * s.width + px) * s.spp + si
                    t, u, v = s.t[k], s.u[k], s.v[k]
                    if not ta <= t <= tb_:
                        continue
                    ev["samples_in_range"] += 1
                    extra += general and (lines is not None or masks is not None)
                    ok = ua <= u <= ub and va <= v <= vb
                    if ok and general and lines is not None:
                        lc, ls, hc, hs, mc, ms, kc, ks = lines[i]
                        ok = t >= lc + ls * u and t <= hc + hs * u and t >= mc + ms * v and t <= kc + ks * v
                    if ok and general and masks is not None:
                        ok = bool((int(masks[i]) >> int(s.tup[k])) & 1)
                    if not ok:
                        continue
                    ev["samples_tested"] += 1
                    ev[("tests_2d", "tests_3d_xyt", "tests_4d_xyuv", "tests_5d")[dims if tester.specialize else 3]] += 1
                    hit, b0, b1, b2, z = inside_test(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, tri,
                                                     np.float32(np.float32(px) + s.x[k]),
                                                     np.float32(np.float32(py) + s.y[k]), t, u, v,
                                                     tester.backface_culling, tb.edge_eps)
                    if hit:
                        for key, val in (("tri", tri), ("pix", py * s.width + px), ("sidx", si),
                                         ("z", min(max(z, za), zb)), ("b0", b0), ("b1", b1), ("b2", b2),
                                         ("noread", tiles["noread"][i])):
                            out[key].append(val)
    ev["samples_covered"] = len(out["tri"])
    dt = {"tri": np.int32, "pix": np.int32, "sidx": np.int32, "noread": np.bool_}
    return ({k: np.array(v, dt.get(k, np.float32)) for k, v in out.items()}, np.array([ev[e] for e in EVENTS]),
            searches, extra)


def assert_tester_matches_reference(tester, tiles):
    """The tester's covered samples (bit for bit, in order), events and
    arithmetic counters equal the plain loop's."""
    from pipeline_sim.definitions import N_OPS, OP_CMP, OP_MADD, OP_MUL, OP_RCP
    from units.sample_tester import COVER_OPS_MADD, COVER_OPS_MUL, COVER_OPS_RCP, EVENTS, TEST_OPS_MADD, TEST_OPS_MUL

    got, ops, events = tester.run(tiles)
    want, want_events, searches, extra = reference_run(tester, tiles)
    assert [int(e) for e in events] == [int(e) for e in want_events], list(zip(EVENTS, events, want_events))
    for key in want:
        assert got[key].dtype == want[key].dtype
        assert got[key].tobytes() == want[key].tobytes(), key
    ev = dict(zip(EVENTS, (int(e) for e in want_events)))
    spp = tester.samples.spp
    log_spp = 1
    while (1 << log_spp) <= spp:
        log_spp += 1
    n_tests = [ev["tests_2d"], ev["tests_3d_xyt"], ev["tests_4d_xyuv"], ev["tests_5d"]]
    cov = ev["samples_covered"]
    has_lines = "lines" in tiles
    want_ops = np.zeros(N_OPS, np.int64)
    want_ops[OP_MADD] = (sum(n * m for n, m in zip(n_tests, TEST_OPS_MADD)) + cov * COVER_OPS_MADD
                         + extra * (4 if has_lines else 0))
    want_ops[OP_MUL] = sum(n * m for n, m in zip(n_tests, TEST_OPS_MUL)) + cov * COVER_OPS_MUL
    want_ops[OP_RCP] = cov * COVER_OPS_RCP
    want_ops[OP_CMP] = 2 * searches * log_spp + extra * (4 if has_lines else 1) + 4 * ev["samples_tested"]
    assert ops.tolist() == want_ops.tolist()
    return got, ev


def random_draw(rng, n, width, height, motion=True, lens=True):
    """``n`` random clip-space triangles, a mix of static, moving, defocused and both."""
    q = np.zeros((n, 3, 4))
    w = rng.uniform(0.6, 3.0, (n, 1))
    centre = rng.uniform(-1.1, 1.1, (n, 1, 2))
    size = rng.uniform(0.05, 0.6, (n, 1, 1))
    q[:, :, 3] = w * rng.uniform(0.9, 1.1, (n, 3))
    q[:, :, :2] = (centre + size * rng.uniform(-1, 1, (n, 3, 2))) * q[:, :, 3:4]
    q[:, :, 2] = rng.uniform(-0.9, 0.9, (n, 3)) * q[:, :, 3]
    r = q.copy()
    kind = rng.integers(0, 4, n)  # 0 static, 1 moving, 2 defocused, 3 both
    mov = (kind & 1).astype(bool) & motion
    r[mov, :, :2] += rng.uniform(-0.3, 0.3, (int(mov.sum()), 1, 2)) * q[mov, :, 3:4]
    r[mov, :, 3] *= rng.uniform(0.9, 1.1, (int(mov.sum()), 1))
    lx = np.zeros((n, 3, 2))
    ly = np.zeros((n, 3, 2))
    dof = (kind & 2).astype(bool) & lens
    coc = rng.uniform(0.0, 0.15, (int(dof.sum()), 3, 1))
    lx[dof] = coc * np.array([1.0, 1.3])
    ly[dof] = coc * np.array([1.0, 0.8])
    return q, r, lx, ly


@pytest.mark.parametrize("tile_size, spp, pattern, width, height, cull, specialize", [
    (4, 16, "net", 48, 32, False, True),
    (8, 16, "net", 50, 30, False, True),  # partial tiles at the right and bottom
    (4, 8, "random", 37, 21, True, True),  # slots not t-ordered across pixels, back faces culled
    (2, 4, "stratified", 24, 18, False, False),  # every test as 5D
    (16, 4, "net", 40, 40, False, True),
])
def test_fast_paths_match_plain_loop(tile_size, spp, pattern, width, height, cull, specialize):
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    rng = np.random.default_rng(tile_size * 1000 + spp)
    q, r, lx, ly = random_draw(rng, 12, width, height)
    setup, _, tiles = setup_and_tiles(q, r, lx, ly, width, height, tile_size=tile_size, backface_culling=cull)
    samples = make_samples(width, height, spp, 3, lens=True, motion=True, pattern=pattern)
    tester = SampleTester(None, setup.table, samples, tile_size, cull, specialize)
    _, ev = assert_tester_matches_reference(tester, tiles)
    assert ev["samples_covered"] > 100
    assert ev["samples_tested"] < ev["pixels_visited"] * spp  # the intervals cut samples
    # records one at a time (no batching of pass 2) give the same
    per_record = [tester.run({k: v[i:i + 1] for k, v in tiles.items()})[0] for i in range(len(tiles["tri"]))]
    whole = tester.run(tiles)[0]
    for key in whole:
        assert np.concatenate([o[key] for o in per_record]).tobytes() == whole[key].tobytes()


def test_outputs_grown_between_records_equal_the_plain_loop(monkeypatch):
    """The kernel stops before a record whose covered samples might not fit, the tester grows its outputs
    and the kernel goes on from that record: the samples, events and counters equal the plain loop's, and
    equal those of one call with room for all."""
    import units.sample_tester as st_mod
    from pipeline_sim.sampling import make_samples

    rng = np.random.default_rng(5)
    q, r, lx, ly = random_draw(rng, 12, 48, 32)
    # and two large triangles, one static, one moving: many records of one triangle pending at once
    big = np.array([[[-0.9, -0.9, 0.1, 1.0], [0.9, -0.8, 0.1, 1.0], [0.1, 0.9, 0.1, 1.0]]] * 2)
    moved = big.copy()
    moved[1, :, 0] += 0.4
    q, r = np.concatenate([q, big]), np.concatenate([r, moved])
    lx, ly = np.concatenate([lx, np.zeros((2, 3, 2))]), np.concatenate([ly, np.zeros((2, 3, 2))])
    setup, _, tiles = setup_and_tiles(q, r, lx, ly, 48, 32, tile_size=4, backface_culling=False)
    samples = make_samples(48, 32, 16, 3, lens=True, motion=True, pattern="net")
    calls = []

    def counted(*args):
        calls.append(args[-12])  # the record the call starts at
        return kernel(*args)

    guards = []
    records = st_mod.SAMPLE

    class Guarded:  # outputs followed by a guard band that no write may reach
        @staticmethod
        def allocate(n, fill=True):
            out = {}
            for k, v in records.allocate(n + 20000, fill).items():
                v[n:] = 7
                guards.append((v[n:], v[n:].copy()))
                out[k] = v[:n]
            return out

    kernel = st_mod.sample_test_kernel
    monkeypatch.setattr(st_mod, "sample_test_kernel", counted)
    monkeypatch.setattr(st_mod, "SAMPLE", Guarded)
    tester = st_mod.SampleTester(None, setup.table, samples, 4, False, True)
    grown, ev = assert_tester_matches_reference(tester, tiles)  # a new tester sizes its outputs for 2 tiles
    assert all(np.array_equal(g, kept) for g, kept in guards)
    assert len(calls) >= 3 and calls[0] == 0 and calls == sorted(set(calls)) and ev["samples_covered"] > 10000
    calls.clear()
    tester._per_record = float(len(tiles["tri"]) * 4 * 4 * 16)  # room for every record at once
    whole = tester.run(tiles)[0]
    assert calls == [0]
    for key in whole:
        assert whole[key].tobytes() == grown[key].tobytes()


def test_a_region_tester_equals_the_whole_frame_tester_on_the_region_records():
    """A tester holding a screen region's samples (rows from a tile row below the top, grown outputs
    included) gives, for the records in that region, exactly the covered samples of the plain loop over
    the whole frame's samples (``reference_run``): pixels numbered in the frame, the same sample indices,
    depths and barycentrics."""
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    width, height, spp, ts = 40, 32, 8, 4
    rng = np.random.default_rng(17)
    q, r, lx, ly = random_draw(rng, 14, width, height)
    setup, _, tiles = setup_and_tiles(q, r, lx, ly, width, height, tile_size=ts, backface_culling=False)
    frame = SampleTester(None, setup.table, make_samples(width, height, spp, 9, lens=True, motion=True), ts, False)
    for rows in ((8, 20), (12, 32)):
        in_region = (tiles["ty"] >= rows[0] // ts) & (tiles["ty"] < rows[1] // ts)
        records = {k: v[in_region] for k, v in tiles.items()}
        region = SampleTester(None, setup.table,
                              make_samples(width, height, spp, 9, lens=True, motion=True, rows=rows), ts, False)
        got = region.run(records)[0]
        want, _ = assert_tester_matches_reference(frame, records)  # the plain loop over the frame's samples
        assert len(want["tri"]) > 200
        assert got["pix"].min() >= rows[0] * width and got["pix"].max() < rows[1] * width
        for key in want:
            assert got[key].tobytes() == want[key].tobytes(), key


def test_a_failing_half_of_a_two_thread_layout_raises_and_leaves_no_thread(monkeypatch):
    """When the helper thread's half of a two-thread layout fails, ``prepare`` raises its error on the
    calling thread (no half-written layout is kept) and the helper has been joined."""
    import threading

    import units.sample_tester as st_mod
    from pipeline_sim.sampling import make_samples

    plain = st_mod._tile_major

    def second_half_fails(width, height, row0, spp, tile_size, ty0, ty1, *rest):
        if ty0 > 0:
            raise MemoryError("second half")
        return plain(width, height, row0, spp, tile_size, ty0, ty1, *rest)

    monkeypatch.setattr(st_mod, "_tile_major", second_half_fails)
    layouts = st_mod.TileMajorLayouts(4)
    s = make_samples(16, 16, 4, 1, lens=True, motion=True)
    with pytest.raises(MemoryError, match="second half"):
        layouts.prepare(s, True)
    assert not any(t.name.startswith("tile-major-layout") for t in threading.enumerate())
    assert len(layouts.ahead) == 0


@pytest.mark.parametrize("scale", [1e18, 1e25])
def test_tester_keeps_every_sample_in_the_intervals_without_a_finite_bound(scale):
    """Vertices scaled until pass 1's vertex form could overflow (1e18: most records' products may pass
    float32's largest value while ``_decide``'s stay finite; 1e25: no finite tolerance): those records take
    every sample in the intervals as a candidate, on the fused path and (with narrow lens intervals on every
    other record) the packed one, and the tester still covers exactly what the plain loop covers."""
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import K_5D, SampleTester, _f32_at_least, _f32_at_most, _tolerances, triangle_constants

    width, height, spp, ts = 24, 16, 8, 4
    rng = np.random.default_rng(11)
    q, r, lx, ly = random_draw(rng, 12, width, height)
    setup, _, tiles = setup_and_tiles(q, r, lx, ly, width, height, tile_size=ts)
    table = setup.table
    for name in ("p0_32", "dp_32", "l0_32", "dl_32"):
        getattr(table, name)[:] *= np.float32(scale)
    table.edge_eps[:] = np.minimum(table.edge_eps.astype(np.float64) * scale * scale, 3e38).astype(np.float32)
    narrow = np.arange(len(tiles["tri"])) % 2 == 1
    for lo, hi in (("u_lo", "u_hi"), ("v_lo", "v_hi")):
        mid = 0.5 * (tiles[lo] + tiles[hi])
        tiles[lo] = np.where(narrow, mid - 0.1, tiles[lo])
        tiles[hi] = np.where(narrow, mid + 0.1, tiles[hi])
    every = 0
    for i, tri in enumerate(tiles["tri"]):
        c = triangle_constants(table.p0_32, table.dp_32, table.l0_32, table.dl_32, tri)
        bounds = [f(tiles[k][i]) for k in ("t_lo", "t_hi", "u_lo", "u_hi", "v_lo", "v_hi")
                  for f in ((_f32_at_least,) if k.endswith("lo") else (_f32_at_most,))]
        x_max, y_max = (tiles["tx"][i] + 1) * ts + 1.0, (tiles["ty"][i] + 1) * ts + 1.0
        every += _tolerances(c, *bounds, x_max, y_max, table.edge_eps[tri], K_5D)[3]
    assert every > len(tiles["tri"]) // 2
    samples = make_samples(width, height, spp, 3, lens=True, motion=True)
    tester = SampleTester(None, table, samples, ts, False)
    _, ev = assert_tester_matches_reference(tester, tiles)
    if scale == 1e18:
        assert ev["samples_covered"] > 10


@pytest.mark.parametrize("algorithm", ["two_stage", "interleave_uvt"])
def test_fast_paths_match_plain_loop_with_lines_and_masks(algorithm):
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    width, height, spp = 40, 24, 8
    rng = np.random.default_rng(7)
    q, r, lx, ly = random_draw(rng, 10, width, height)
    pattern = "interleave" if algorithm == "interleave_uvt" else "net"
    samples = make_samples(width, height, spp, 5, lens=True, motion=True, pattern=pattern, interleave_tuples=32)
    tuples = samples.tuples if algorithm == "interleave_uvt" else None
    setup, _, tiles = setup_and_tiles(q, r, lx, ly, width, height, tile_size=4, algorithm=algorithm, tuples=tuples)
    assert ("lines" if algorithm == "two_stage" else "mask") in tiles
    tester = SampleTester(None, setup.table, samples, 4, False)
    _, ev = assert_tester_matches_reference(tester, tiles)
    assert ev["samples_covered"] > 50


@given(st.one_of(moving_triangle(allow_w_cross=False), moving_triangle(allow_w_cross=False, motion=False)),
       st.integers(0, 2**31), st.sampled_from([2, 4, 8]))
def test_fast_paths_match_plain_loop_on_adversarial_triangles(tri, seed, tile_size):
    """Moving triangles, and static defocused ones (pass 1's xyuv formula, without the time terms)."""
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    q, r, lx, ly = tri
    width, height = 24, 16
    setup, alive, tiles = setup_and_tiles(q, r, lx, ly, width, height, tile_size=tile_size)
    samples = make_samples(width, height, 4, seed % 1000, lens=True, motion=True)
    tester = SampleTester(None, setup.table, samples, tile_size, False)
    assert_tester_matches_reference(tester, tiles)


def _random_tile(rng):
    """Float32 constants of a random moving, defocused triangle (layout of ``_keep``), the tile's
    intervals and bounds on |x| and |y|."""
    f32 = np.float32
    scale = 10.0 ** rng.uniform(-2, 3)
    c = np.zeros(40, np.float32)
    c[0:9] = rng.uniform(-1, 1, 9) * scale  # X, Y, W at t = 0
    c[6:9] = rng.uniform(0.05, 2, 3) * scale
    c[9:18] = rng.uniform(-0.3, 0.3, 9) * scale  # motion
    c[18:24] = rng.uniform(-0.2, 0.2, 6) * scale  # lens
    c[24:30] = rng.uniform(-0.05, 0.05, 6) * scale
    ta, tb = sorted(rng.uniform(0, 1, 2).astype(f32))
    return c, (ta, tb, f32(-1), f32(1), f32(-1), f32(1)), 64.0, 48.0


def _samples_in(rng, intervals, x_max, y_max, n=2000):
    f32 = np.float32
    ta, tb = intervals[:2]
    return (rng.uniform(ta, tb, n).astype(f32), rng.uniform(-1, 1, n).astype(f32),
            rng.uniform(-1, 1, n).astype(f32), rng.uniform(0, x_max, n).astype(f32),
            rng.uniform(0, y_max, n).astype(f32))


def _vertices(c, t, u, v):
    """Float32 vertices at each sample, as ``_keep`` and ``_decide`` compute them."""
    X = [c[k] + t * c[9 + k] + u * (c[18 + k] + t * c[24 + k]) for k in range(3)]
    Y = [c[3 + k] + t * c[12 + k] + v * (c[21 + k] + t * c[27 + k]) for k in range(3)]
    W = [c[6 + k] + t * c[15 + k] for k in range(3)]
    return X, Y, W


def _exact_edges(X, Y, W, x, y):
    """The edge values of the float32 vertices and samples in float64 (products of two float32 are exact)."""
    as64 = [[a.astype(np.float64) for a in P] for P in (X, Y, W)]
    return _edges_np(*as64, x.astype(np.float64), y.astype(np.float64))


def test_tolerance_bounds_float32_edge_error():
    """``_tolerances`` (static, pinhole: ``_decide``'s own float32 values): for samples in the tile's
    intervals, the float32 edge value never differs from ``_decide``'s float64 re-test by more than the
    per-edge tolerance (which is what lets pass 1 drop samples for good)."""
    from units.sample_tester import K_2D, _tolerances

    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(60):
        c, intervals, x_max, y_max = _random_tile(rng)
        tol = -np.array(_tolerances(tuple(c), *intervals, x_max, y_max, np.float32(np.inf), K_2D)[:3], np.float64)
        t, u, v, x, y = _samples_in(rng, intervals, x_max, y_max)
        X, Y, W = _vertices(c, t, u, v)
        e32 = _edges_np(X, Y, W, x, y)
        e64 = _exact_edges(X, Y, W, x, y)
        for k in range(3):
            err = np.abs(e32[k].astype(np.float64) - e64[k])
            assert np.all(err <= tol[k]), (k, err.max(), tol[k])
            worst = max(worst, float((err / tol[k]).max()))
    assert worst > 0.01  # the tolerance is a bound, not orders of magnitude off


def test_vertex_form_tolerance_bounds_its_own_rounding():
    """Pass 1's vertex form (e_k = B_i A_j - A_i B_j, A_i = X_i - x W_i, B_i = Y_i - y W_i, in float32)
    stays within its share of the tolerance of the float64 edge value: the vertex form's tolerance less
    the one bounding ``_decide``'s own values (``K_2D``'s with no eps cap), which a sample ``_decide``
    accepts may be below zero by. So pass 1 never drops an accepted sample."""
    from units.sample_tester import K_2D, K_5D, _tolerances

    rng = np.random.default_rng(4)
    worst = 0.0
    for _ in range(60):
        c, intervals, x_max, y_max = _random_tile(rng)
        inf = np.float32(np.inf)
        *own, every = _tolerances(tuple(c), *intervals, x_max, y_max, inf, K_5D)
        decide = np.array(_tolerances(tuple(c), *intervals, x_max, y_max, inf, K_2D)[:3], np.float64)
        assert not every
        share = decide - np.array(own, np.float64)
        t, u, v, x, y = _samples_in(rng, intervals, x_max, y_max)
        X, Y, W = _vertices(c, t, u, v)
        A = [X[k] - x * W[k] for k in range(3)]
        B = [Y[k] - y * W[k] for k in range(3)]
        e64 = _exact_edges(X, Y, W, x, y)
        for k in range(3):
            i, j = (k + 1) % 3, (k + 2) % 3
            e32 = B[i] * A[j] - A[i] * B[j]
            assert e32.dtype == np.float32
            err = np.abs(e32.astype(np.float64) - e64[k])
            assert np.all(err <= share[k]), (k, err.max(), share[k])
            worst = max(worst, float((err / share[k]).max()))
    assert worst > 0.01


@pytest.mark.parametrize("scale", [1e25, 1e19])
def test_vertex_form_keeps_every_sample_beyond_float32_range(scale):
    """A triangle whose vertex-form products may leave float32's range keeps every sample in the
    intervals (``every``): at 1e25 its tolerance is infinite; at 1e19 the tolerance is finite but the
    products (x y W_i W_j about 1e42) are not. A moderate triangle's tolerance is finite."""
    from units.sample_tester import K_5D, _tolerances

    rng = np.random.default_rng(5)
    c, intervals, x_max, y_max = _random_tile(rng)
    inf = np.float32(np.inf)
    assert not _tolerances(tuple(c), *intervals, x_max, y_max, inf, K_5D)[3]
    huge = (c / np.abs(c).max() * np.float32(scale)).astype(np.float32)
    *tol, every = _tolerances(tuple(huge), *intervals, x_max, y_max, inf, K_5D)
    assert every
    if scale == 1e19:
        assert np.all(np.isfinite(tol))


def _pass1_trial(rng, scale, kind, n=4096):
    """One random moving (``K_5D``) or defocused (``K_XYUV``) triangle of either orientation, its vertices
    behind the eye (W < 0) now and then, scaled by ``scale``, and ``n`` samples in a 40 x 30 tile, half of
    them put on an edge (a point between two projected vertices, rounded to float32), where only the
    tolerance keeps them. Asserts that ``_keep`` in vertex form (through ``_pass1_fused`` with
    ``_tolerances``' bounds) keeps every sample ``inside_test`` accepts; returns how many it accepted, or
    None when no finite pass-1 bound holds (the kernel then keeps every sample in the intervals)."""
    from units.sample_tester import K_XYUV, K_5D, _pass1_fused, _tolerances, triangle_constants

    f32 = np.float32
    x_max, y_max = 40.0, 30.0
    w = rng.uniform(0.5, 2.0, 3) * (np.where(rng.random(3) < 0.15, -1.0, 1.0))
    p0 = np.zeros((3, 4), np.float32)
    p0[:, 0] = rng.uniform(-5, x_max + 5, 3) * w
    p0[:, 1] = rng.uniform(-5, y_max + 5, 3) * w
    p0[:, 2] = rng.uniform(-0.5, 0.5, 3) * w
    p0[:, 3] = w
    dp = np.zeros((3, 4), np.float32)
    dl = np.zeros((3, 4), np.float32)
    if kind == K_5D:
        dp[:, :2] = rng.uniform(-8, 8, (3, 2)) * w[:, None]
        dp[:, 3] = rng.uniform(-0.1, 0.1, 3)
        dl[:, :2] = rng.uniform(-1, 1, (3, 2))
    l0 = np.zeros((3, 4), np.float32)
    l0[:, :2] = rng.uniform(-6, 6, (3, 2))
    P0, DP, L0, DL = (a[None] * f32(scale) for a in (p0, dp, l0, dl))
    c = triangle_constants(P0, DP, L0, DL, 0)
    ta, tb = (f32(0), f32(1)) if kind == K_XYUV else tuple(np.sort(rng.uniform(0, 1, 2)).astype(f32))
    t = rng.uniform(ta, tb, n).astype(f32)
    u = rng.uniform(-1, 1, n).astype(f32)
    v = rng.uniform(-1, 1, n).astype(f32)
    x = rng.uniform(0, x_max, n).astype(f32)
    y = rng.uniform(0, y_max, n).astype(f32)
    X, Y, W = _vertices(np.array(c, np.float32), t, u, v)
    half = n // 2
    i, j = rng.integers(0, 3, half), rng.integers(1, 3, half)
    j = (i + j) % 3
    a = rng.uniform(0, 1, half)
    rows = np.arange(half)
    Xs, Ys, Ws = np.array(X, np.float64), np.array(Y, np.float64), np.array(W, np.float64)
    px = (1 - a) * Xs[i, rows] / Ws[i, rows] + a * Xs[j, rows] / Ws[j, rows]
    py = (1 - a) * Ys[i, rows] / Ws[i, rows] + a * Ys[j, rows] / Ws[j, rows]
    ok = (px >= 0) & (px <= x_max) & (py >= 0) & (py <= y_max)
    x[:half][ok] = px[ok].astype(f32)
    y[:half][ok] = py[ok].astype(f32)
    eps = np.array([f32(1e-3) * f32(scale) ** 2], np.float32)
    accepted = np.array([inside_test(P0, DP, L0, DL, 0, x[q], y[q], t[q], u[q], v[q], False, eps)[0]
                         for q in range(n)])
    *tol, every = _tolerances(c, ta, tb, f32(-1), f32(1), f32(-1), f32(1), x_max, y_max, eps[0], kind)
    if every:
        return None
    cand = np.zeros(n + 64, np.uint8)
    _pass1_fused(kind, n, 0, t, u, v, x, y, cand, ta, tb, f32(-1), f32(1), f32(-1), f32(1), c, *tol)
    kept = cand[:n].astype(bool)
    assert np.all(kept[accepted]), np.flatnonzero(accepted & ~kept)[:5]
    return int(accepted.sum())


@pytest.mark.parametrize("scale", [1e-12, 1e-3, 1.0, 1e6, 1e15, 1e17])
def test_pass1_keeps_every_sample_the_exact_test_accepts(scale):
    """``_pass1_trial`` on 40 triangles a scale, from 1e-12 to 1e17 (a quarter of them defocused only)."""
    from units.sample_tester import K_XYUV, K_5D

    rng = np.random.default_rng(int(np.log10(scale)) + 40)
    counts = [_pass1_trial(rng, scale, K_XYUV if trial % 4 == 0 else K_5D) for trial in range(40)]
    tested = [k for k in counts if k is not None]
    assert sum(tested) > 1000  # the triangles cover something
    assert len(tested) >= 20  # and most take pass 1


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(-12, 17), st.booleans())
def test_pass1_never_drops_an_accepted_sample(seed, exponent, defocus_only):
    """The same property as a hypothesis search: any seed, any power of ten from 1e-12 to 1e17, moving
    and defocused or defocused only (1,024 samples a triangle)."""
    from units.sample_tester import K_XYUV, K_5D

    _pass1_trial(np.random.default_rng(seed), 10.0**exponent, K_XYUV if defocus_only else K_5D, n=1024)


def _edges_np(X, Y, W, x, y):
    """The three edge values as ``_edges`` and ``_decide`` compute them, elementwise."""
    out = []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        a = Y[j] * W[i] - W[j] * Y[i]
        b = W[j] * X[i] - X[j] * W[i]
        c = X[j] * Y[i] - Y[j] * X[i]
        out.append(a * x + b * y + c)
    return out


@pytest.mark.parametrize("motion, lens", [(False, False), (True, False), (False, True), (True, True)])
def test_fast_paths_match_plain_loop_on_samples_on_shared_edges(motion, lens):
    """A fan of triangles over a grid of pixel centres, sampled at pixel
    centres and corners: many samples lie exactly on edges and vertices,
    where only ``_decide``'s float64 re-test can tell (so pass 1 must never
    drop them). With ``lens``, static triangles take pass 1's xyuv formula
    and moving ones the 5D one: the samples at u = v = 0 sit on the edges,
    those at u = v = +-0.5 a whole pixel off, and t runs to both ends of
    the shutter."""
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    width, height = 20, 14
    table = np.array([[0.5, 0.5, 0, 0, 0.5], [0.0, 0.0, 0, 0, 0.25], [0.5, 0.0, 0, 0, 0.5], [0.0, 0.5, 0, 0, 0.75]])
    if lens:
        table = np.array([[0.5, 0.5, 0, 0, 0.0], [0.0, 0.0, 0.5, 0.5, 0.0], [0.5, 0.0, -0.5, 0, 0.25],
                          [0.0, 0.5, 0, 0, 0.5], [0.5, 0.5, 0.5, -0.5, 0.5], [0.0, 0.0, 0, 0.5, 0.75],
                          [0.5, 0.0, 0, 0, 1.0], [0.0, 0.5, -0.5, -0.5, 1.0]])
    samples = make_samples(width, height, len(table), 0, lens=lens, motion=motion, pattern="table", table=table)
    pts = [(x + 0.5, y + 0.5) for y in range(1, height, 4) for x in range(1, width, 5)]
    cols = len(range(1, width, 5))
    tris = []
    for i in range(len(pts)):
        if (i + 1) % cols == 0 or i + cols + 1 >= len(pts):
            continue
        a, b, c, d = pts[i], pts[i + 1], pts[i + cols], pts[i + cols + 1]
        tris += [(a, b, d), (a, d, c)]
    n = len(tris)
    q = np.zeros((n, 3, 4))
    for i, tri in enumerate(tris):
        for k, (x, y) in enumerate(tri):
            w = 1.0 + 0.37 * ((i * 7 + k) % 5)  # rounded vertices: float32 edge values err
            q[i, k] = (2 * x / width - 1) * w, (1 - 2 * y / height) * w, 0.5 * w, w
    r = q.copy()
    if motion:  # a whole-pixel shift over the shutter: at t = 0.5 the edges sit on half pixels
        r[:, :, 0] += 2 * 2.0 / width * r[:, :, 3]
    lx = np.zeros((n, 3, 2))
    ly = np.zeros((n, 3, 2))
    if lens:  # at u = +-0.5 a whole pixel (lens offsets scale with w, as positions do)
        lx[:] = 2 * 2.0 / width * q[:, :, 3:4]
        ly[:] = -2 * 2.0 / height * q[:, :, 3:4]
    setup, _, tiles = setup_and_tiles(q, r, lx, ly, width, height, tile_size=4)
    tester = SampleTester(None, setup.table, samples, 4, False)
    _, ev = assert_tester_matches_reference(tester, tiles)
    assert ev["samples_covered"] > 300
    if lens:
        assert ev["tests_5d" if motion else "tests_4d_xyuv"] == ev["samples_tested"]


def _numpy_layout(s, ts):
    """The tester's layout of sample set ``s`` built with numpy: (x, y, u, v, t and, if the set has them,
    the tuple indices) each tile by tile, slot-major in each tile (x, y absolute), each slot's t range,
    the u and v range (0 included) and ``xy_max``."""
    width = s.width
    t = s.t.reshape(s.height, width, s.spp)
    px = np.arange(width, dtype=np.float32)[None, :, None]
    py = np.arange(s.row0, s.row0 + s.height, dtype=np.float32)[:, None, None]
    fields = (s.x.reshape(t.shape) + px, s.y.reshape(t.shape) + py, s.u.reshape(t.shape), s.v.reshape(t.shape), t)
    if s.tup is not None:
        fields += (s.tup.reshape(t.shape),)
    slot_major = [[] for _ in fields]
    for y0 in range(0, s.height, ts):
        for x0 in range(0, width, ts):
            for k, f in enumerate(fields):
                block = f[y0:y0 + ts, x0:x0 + ts]  # (h, w, spp)
                slot_major[k].append(block.transpose(2, 0, 1).ravel())
    arrays = [np.concatenate(a) for a in slot_major]
    tup = arrays.pop() if s.tup is not None else None
    uv = [min(s.u.min(), 0), max(s.u.max(), 0), min(s.v.min(), 0), max(s.v.max(), 0)]
    return (*arrays, tup, t.min(axis=(0, 1)), t.max(axis=(0, 1)), uv,
            float(max(np.abs(s.x).max(), np.abs(s.y).max())) * (1 + 1e-6))


def _assert_layout(got, s, ts):
    ax, ay, au, av, at, tup, lo, hi, uv, xy_max = got
    want = _numpy_layout(s, ts)
    for a, b in zip((ax, ay, au, av, at), want[:5]):
        assert a.tobytes() == b.tobytes()
    if want[5] is not None:
        assert tup.tobytes() == want[5].tobytes()
    np.testing.assert_array_equal(lo, want[6])
    np.testing.assert_array_equal(hi, want[7])
    np.testing.assert_array_equal(uv, want[8])
    assert xy_max == want[9]


def test_layout_orders_and_ranges_match_numpy():
    """``SampleTester.layout`` against numpy: the tile-major order, each
    slot's t range and the samples' x, y, u, v ranges, for a region whose
    tiles are cut at the right and bottom; then a smaller region laid out in
    the buffers the first one left."""
    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    width, spp, ts = 21, 8, 4
    tester = SampleTester(None, None, None, ts, False)
    for rows in ((4, 15), (8, 14)):
        s = make_samples(width, 18, spp, 2, lens=True, motion=True, rows=rows)
        tester.use_samples(s)
        assert len(tester.layout()[4]) == len(s.t)
        _assert_layout(tester.layout(), s, ts)
    # Interleave UVT's tuple indices move with their samples
    s = make_samples(width, 18, spp, 2, lens=True, motion=True, rows=(4, 15), pattern="interleave",
                     interleave_tuples=32)
    assert s.tup is not None and len(np.unique(s.tup)) > 8
    tester.use_samples(s)
    _assert_layout(tester.layout(), s, ts)


def test_layout_keeps_nan_rules():
    """NaN samples: the t and u, v ranges ignore them; a NaN x makes
    ``xy_max`` infinite (every tolerance then falls back to the edge's eps)."""
    import dataclasses

    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester

    s = make_samples(8, 8, 4, 1, lens=True, motion=True)
    clean = SampleTester(None, None, s, 4, False).layout()
    t, u, x = s.t.copy(), s.u.copy(), s.x.copy()
    t[5] = u[7] = np.nan
    lay = SampleTester(None, None, dataclasses.replace(s, t=t, u=u), 4, False).layout()
    for a, b in zip(clean[6:9], lay[6:9]):
        np.testing.assert_array_equal(a, b)
    x[3] = np.nan
    assert SampleTester(None, None, dataclasses.replace(s, x=x), 4, False).layout()[9] == np.inf


def test_layouts_built_on_two_threads_match_numpy():
    """A layout the pipeline waits for is built on two threads, half the tile rows each, and its ranges
    merged: the same as numpy's (odd numbers of tile rows, cut tiles, a set of one tile row), and the NaN
    rules hold whichever half holds the NaN."""
    import dataclasses

    from pipeline_sim.sampling import make_samples
    from units.sample_tester import TileMajorLayouts

    width, spp, ts = 21, 8, 4
    layouts = TileMajorLayouts(ts)
    for rows in ((4, 15), (0, 18), (8, 12)):
        s = make_samples(width, 18, spp, 5, lens=True, motion=True, rows=rows)
        layouts.prepare(s, True)
        lay = layouts.take(s)
        _assert_layout(lay[:-1], s, ts)
        layouts.release(lay)
    s = make_samples(width, 16, spp, 5, lens=True, motion=True)
    n = len(s.t)
    for k in (3, n - 3):  # first half, second half
        t, u, x = s.t.copy(), s.u.copy(), s.x.copy()
        t[k] = u[k] = np.nan
        with_nan = dataclasses.replace(s, t=t, u=u)
        layouts.prepare(with_nan, True)
        lay = layouts.take(with_nan)
        by_slot = t.reshape(-1, spp)
        np.testing.assert_array_equal(lay[6], np.nanmin(by_slot, axis=0))
        np.testing.assert_array_equal(lay[7], np.nanmax(by_slot, axis=0))
        np.testing.assert_array_equal(lay[8][:2], [min(np.nanmin(u), 0), max(np.nanmax(u), 0)])
        layouts.release(lay)
        x[k] = np.nan
        x_nan = dataclasses.replace(s, x=x)
        layouts.prepare(x_nan, True)
        lay = layouts.take(x_nan)
        assert lay[9] == np.inf
        layouts.release(lay)


def test_layouts_prepared_on_another_thread_equal_those_built_in_place_and_reuse_buffers():
    """``TileMajorLayouts``: a layout prepared on another thread (as a region's samples are made ahead)
    is the one the tester takes, equal to the numpy layout; a released
    layout's buffers serve the next region's; layouts prepared for regions the tester has passed are
    released when it takes a later one."""
    import threading

    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester, TileMajorLayouts

    width, spp, ts = 21, 8, 4
    sets = [make_samples(width, 24, spp, 3, lens=True, motion=True, rows=(r0, r0 + 8)) for r0 in (0, 8, 16)]
    layouts = TileMajorLayouts(ts)
    tester = SampleTester(None, None, None, ts, False, layouts=layouts)
    worker = threading.Thread(target=lambda: [layouts.prepare(s) for s in sets])
    worker.start()
    worker.join()
    tester.use_samples(sets[1])  # region 0 got no batch: its prepared layout is dropped on the next take
    _assert_layout(tester.layout(), sets[1], ts)
    assert len(layouts.ahead) == 1 and len(layouts._free) == 1  # region 2's waits; region 0's buffers free
    tester.use_samples(sets[2])
    tester.layout()
    tester.use_samples(make_samples(width, 24, spp, 4, lens=True, motion=True, rows=(0, 8)))
    free = [buffers[0][0] for buffers in layouts._free]
    assert len(free) == TileMajorLayouts.KEEP_FREE
    x = tester.layout()[0]  # built now, in buffers an earlier region left
    assert any(np.shares_memory(x, b) for b in free)
    with pytest.raises(ValueError, match="8-pixel tester"):
        SampleTester(None, None, None, 8, False, layouts=layouts)


def test_layouts_prepared_while_the_tester_takes_and_releases_others_are_right():
    """A thread prepares each next region's layout while the tester takes, reads and releases the
    current one, as a pass does, over several rounds: every layout the tester reads equals the numpy
    layout, though the buffers go round between regions."""
    import threading

    from pipeline_sim.sampling import make_samples
    from units.sample_tester import SampleTester, TileMajorLayouts

    width, spp, ts = 13, 4, 4
    sets = [make_samples(width, 40, spp, 7, lens=True, motion=True, rows=(r0, r0 + 8)) for r0 in range(0, 40, 8)]
    for _ in range(5):
        layouts = TileMajorLayouts(ts)
        tester = SampleTester(None, None, None, ts, False, layouts=layouts)
        for i, s in enumerate(sets):
            ahead = threading.Thread(target=layouts.prepare, args=(sets[i + 1],)) if i + 1 < len(sets) else None
            tester.use_samples(s)  # releases the layout of the region before
            if ahead is not None:
                ahead.start()
            _assert_layout(tester.layout(), s, ts)
            if ahead is not None:
                ahead.join()
