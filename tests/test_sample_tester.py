"""The sample tester's exact 5D test against an independent reference.

The reference (tests/reference.py) clips the triangle at the sample's
(t, u, v) against the near and far planes, divides by w and solves for
barycentrics with Cramer's rule in float64 — no 2DH edge functions.
"""

import numpy as np
from hypothesis import given
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
