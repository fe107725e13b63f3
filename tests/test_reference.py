"""Closed-form checks of the independent reference renderer (tests/reference.py)."""

from __future__ import annotations

import numpy as np
import pytest

try:  # works whether or not tests/ is a package
    from tests.reference import (accumulation_render, exact_time_coverage,
                                 render_static, stratified_points)
except ImportError:  # pragma: no cover
    from reference import (accumulation_render, exact_time_coverage,
                           render_static, stratified_points)


# --------------------------------------------------------------------------- #
# helpers
# --------------------------------------------------------------------------- #
def pix_to_clip(xp, yp, width, height, z=0.0, w=1.0):
    """Clip-space vertex for pixel coordinates (from top), NDC depth z, w."""
    xn = 2.0 * xp / width - 1.0
    yn = 1.0 - 2.0 * yp / height
    return np.array([xn * w, yn * w, z * w, w])


def rect_tris(x0, x1, y0, y1, width, height, z=0.0, ws=(1.0, 1.0, 1.0, 1.0)):
    """Two CCW (in NDC) triangles covering pixel rect [x0,x1] x [y0,y1]."""
    # corners: bottom-left, bottom-right, top-right, top-left (in NDC, y up)
    A = pix_to_clip(x0, y1, width, height, z, ws[0])
    B = pix_to_clip(x1, y1, width, height, z, ws[1])
    C = pix_to_clip(x1, y0, width, height, z, ws[2])
    D = pix_to_clip(x0, y0, width, height, z, ws[3])
    return np.array([[A, B, C], [A, C, D]])


def perspective(fovy, aspect, near, far):
    f = 1.0 / np.tan(fovy / 2)
    return np.array([
        [f / aspect, 0, 0, 0],
        [0, f, 0, 0],
        [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
        [0, 0, -1, 0],
    ])


def sample_ndc(width, height, offsets=(0.5, 0.5)):
    jj, ii = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    jj = jj + offsets[0]
    ii = ii + offsets[1]
    return 2 * jj / width - 1, 1 - 2 * ii / height


def raycast(tri_eye, xn, yn, aspect, f):
    """Moller-Trumbore eye ray vs eye-space triangle for NDC sample arrays.

    Returns (s, b1, b2, det) with the ray point s * d, d = (xn a/f, yn/f, -1),
    so s is the eye-space depth (= clip w)."""
    d = np.stack([xn * aspect / f, yn / f, -np.ones_like(xn)], axis=-1)
    v0, v1, v2 = tri_eye
    e1, e2 = v1 - v0, v2 - v0
    # solve s d - b1 e1 - b2 e2 = v0
    M = np.stack([d, np.broadcast_to(-e1, d.shape), np.broadcast_to(-e2, d.shape)], axis=-1)
    sol = np.linalg.solve(M, np.broadcast_to(v0, d.shape)[..., None])[..., 0]
    return sol[..., 0], sol[..., 1], sol[..., 2]


# --------------------------------------------------------------------------- #
# coverage
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("ws", [(1, 1, 1, 1), (0.5, 3.0, 7.0, 1.3)])
def test_rectangle_exact_pixels(ws):
    W, H = 40, 30
    a, b, c, d = 7, 23, 4, 19
    tris = rect_tris(a, b, c, d, W, H, z=0.25, ws=ws)
    img, tid, depth = render_static(tris, np.ones((2, 3, 3)), W, H)
    expect = np.zeros((H, W), bool)
    expect[c:d, a:b] = True
    np.testing.assert_array_equal(tid >= 0, expect)
    np.testing.assert_allclose(depth[expect], 0.25, atol=1e-12)
    assert np.all(np.isinf(depth[~expect]))
    np.testing.assert_allclose(img[expect], 1.0, atol=1e-12)
    np.testing.assert_array_equal(img[~expect], 0.0)


def test_rectangle_per_pixel_offsets():
    W, H = 32, 24
    rng = np.random.default_rng(1)
    off = rng.random((H, W, 2))
    x0, x1, y0, y1 = 5.3, 20.8, 3.6, 17.2
    tris = rect_tris(x0, x1, y0, y1, W, H)
    _, tid, _ = render_static(tris, np.zeros((2, 3, 3)), W, H, off)
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    xs, ys = jj + off[..., 0], ii + off[..., 1]
    expect = (xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)
    np.testing.assert_array_equal(tid >= 0, expect)


def test_triangle_area():
    W = H = 128
    rng = np.random.default_rng(2)
    for _ in range(10):
        P = rng.uniform(4, 124, size=(3, 2))
        e1, e2 = P[1] - P[0], P[2] - P[0]
        area = 0.5 * abs(e1[0] * e2[1] - e1[1] * e2[0])
        if area < 200:
            continue
        per = sum(np.linalg.norm(P[k] - P[(k + 1) % 3]) for k in range(3))
        tri = np.array([[pix_to_clip(x, y, W, H, 0.0, w)
                         for (x, y), w in zip(P, rng.uniform(0.5, 4, 3))]])
        _, tid, _ = render_static(tri, np.zeros((1, 3, 3)), W, H)
        assert abs((tid == 0).sum() - area) <= per
        # random per-pixel offsets: unbiased estimate of the area
        counts = [(render_static(tri, np.zeros((1, 3, 3)), W, H,
                                 rng.random((H, W, 2)))[1] == 0).sum()
                  for _ in range(8)]
        assert abs(np.mean(counts) - area) <= 2 * np.sqrt(per) + 2


# --------------------------------------------------------------------------- #
# depth and perspective-correct interpolation
# --------------------------------------------------------------------------- #
def test_depth_of_planes():
    W, H = 48, 40
    rng = np.random.default_rng(3)
    # constant-depth plane with very different w per vertex
    tri = np.array([[pix_to_clip(3, 35, W, H, -0.3, 0.2),
                     pix_to_clip(45, 30, W, H, -0.3, 5.0),
                     pix_to_clip(20, 2, W, H, -0.3, 1.7)]])
    _, tid, depth = render_static(tri, np.zeros((1, 3, 3)), W, H)
    assert (tid == 0).sum() > 300
    np.testing.assert_allclose(depth[tid == 0], -0.3, atol=1e-12)
    # tilted plane z_ndc = a x_ndc + b y_ndc + c: z = a x + b y + c w in clip space
    a, b, c = 0.2, -0.15, 0.1
    v = rng.uniform(-1, 1, (3, 2)) * 0.9
    w = rng.uniform(0.3, 3.0, 3)
    tri = np.zeros((1, 3, 4))
    tri[0, :, 0] = v[:, 0] * w
    tri[0, :, 1] = v[:, 1] * w
    tri[0, :, 3] = w
    tri[0, :, 2] = a * tri[0, :, 0] + b * tri[0, :, 1] + c * w
    off = rng.random((H, W, 2))
    _, tid, depth = render_static(tri, np.zeros((1, 3, 3)), W, H, off)
    X, Y = sample_ndc(W, H, (off[..., 0], off[..., 1]))
    m = tid == 0
    assert m.sum() > 50
    np.testing.assert_allclose(depth[m], (a * X + b * Y + c)[m], atol=1e-12)


def test_perspective_correct_world_attributes():
    W, H = 64, 48
    aspect, fovy, n, F = W / H, np.radians(60), 0.5, 50.0
    P = perspective(fovy, aspect, n, F)
    f = 1 / np.tan(fovy / 2)
    rng = np.random.default_rng(4)
    for _ in range(5):
        # large slanted triangle well inside the frustum depth range
        V = np.array([[-3, -2, -2.0], [4, -1.5, -9.0], [0.5, 3.0, -4.0]])
        V += rng.normal(0, 0.3, V.shape)
        clip = np.c_[V, np.ones(3)] @ P.T
        attrs = np.c_[-V[:, 2], V[:, 0], V[:, 1]]  # depth, x_e, y_e
        off = rng.random((H, W, 2))
        img, tid, depth = render_static(clip[None], attrs[None], W, H, off)
        X, Y = sample_ndc(W, H, (off[..., 0], off[..., 1]))
        s, b1, b2 = raycast(V, X, Y, aspect, f)
        m = tid == 0
        assert m.sum() > 300
        np.testing.assert_allclose(img[m][:, 0], s[m], rtol=1e-10)
        np.testing.assert_allclose(img[m][:, 1], (s * X * aspect / f)[m], rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(img[m][:, 2], (s * Y / f)[m], rtol=1e-9, atol=1e-10)
        zndc = ((F + n) / (n - F) * (-s) + 2 * F * n / (n - F)) / s
        np.testing.assert_allclose(depth[m], zndc[m], atol=1e-11)


# --------------------------------------------------------------------------- #
# near/far clipping against an eye-space ray caster
# --------------------------------------------------------------------------- #
def test_near_far_clipping_matches_raycast():
    W, H = 64, 64
    aspect, fovy, n, F = 1.0, np.radians(70), 1.0, 12.0
    P = perspective(fovy, aspect, n, F)
    f = 1 / np.tan(fovy / 2)
    rng = np.random.default_rng(5)
    X, Y = sample_ndc(W, H)
    n_neg_w = 0
    checked = 0
    for _ in range(60):
        V = np.c_[rng.uniform(-6, 6, (3, 2)), rng.uniform(-16, 3, 3)]
        clip = np.c_[V, np.ones(3)] @ P.T
        n_neg_w += np.any(clip[:, 3] < 0)
        for cull in (False, True):
            _, tid, depth = render_static(clip[None], np.zeros((1, 3, 3)), W, H,
                                          cull_backfaces=cull)
            s, b1, b2 = raycast(V, X, Y, aspect, f)
            b0 = 1 - b1 - b2
            hit = (b0 >= 0) & (b1 >= 0) & (b2 >= 0) & (s >= n) & (s <= F)
            normal = np.cross(V[1] - V[0], V[2] - V[0])
            front = normal @ V[0] < 0  # CCW seen from the eye
            if cull and not front:
                hit[:] = False
            # exclude samples numerically on the boundary
            margin = np.minimum.reduce([np.abs(b0), np.abs(b1), np.abs(b2),
                                        np.abs(s - n), np.abs(s - F)])
            ok = margin > 1e-7
            np.testing.assert_array_equal((tid == 0)[ok], hit[ok])
            assert np.all(depth[tid == 0] >= -1 - 1e-12)
            assert np.all(depth[tid == 0] <= 1 + 1e-12)
            checked += hit.sum()
    assert n_neg_w >= 10 and checked > 1000


def test_triangle_entirely_behind_eye_is_invisible():
    W = H = 16
    tri = np.array([[[0, 0, 0.5, -1.0], [-0.5, -0.5, 0.4, -1.0], [0.5, -0.5, 0.3, -2.0]]])
    _, tid, _ = render_static(tri, np.zeros((1, 3, 3)), W, H)
    assert np.all(tid == -1)


def test_depth_test_and_ties():
    W, H = 20, 20
    near_t = rect_tris(2, 12, 2, 12, W, H, z=-0.5)
    far_t = rect_tris(6, 18, 6, 18, W, H, z=0.5)
    cols = np.zeros((4, 3, 3))
    cols[2:] = 1.0
    img, tid, depth = render_static(np.r_[far_t, near_t], cols, W, H)
    assert np.all(tid[6:12, 6:12] >= 2)
    assert np.all(tid[12:18, 12:18] < 2)
    # equal depth: earlier triangle wins
    _, tid, _ = render_static(np.r_[rect_tris(2, 12, 2, 12, W, H), rect_tris(2, 12, 2, 12, W, H)],
                              np.zeros((4, 3, 3)), W, H)
    assert set(np.unique(tid[2:12, 2:12])) <= {0, 1}


# --------------------------------------------------------------------------- #
# back-face culling
# --------------------------------------------------------------------------- #
def test_backface_culling_flips_with_order():
    W, H = 32, 32
    ccw = np.array([[pix_to_clip(4, 28, W, H), pix_to_clip(28, 26, W, H), pix_to_clip(14, 3, W, H)]])
    cw = ccw[:, ::-1]
    cols = np.zeros((1, 3, 3))
    _, t_ccw, _ = render_static(ccw, cols, W, H, cull_backfaces=True)
    _, t_cw, _ = render_static(cw, cols, W, H, cull_backfaces=True)
    _, t_ccw0, _ = render_static(ccw, cols, W, H)
    _, t_cw0, _ = render_static(cw, cols, W, H)
    assert (t_ccw == 0).sum() > 100
    assert np.all(t_cw == -1)
    np.testing.assert_array_equal(t_ccw, t_ccw0)
    np.testing.assert_array_equal(t_cw0, t_ccw0)


# --------------------------------------------------------------------------- #
# motion blur
# --------------------------------------------------------------------------- #
def _ramp_integral(s):
    s = np.asarray(s, float)
    return np.where(s < 0, 0.0, np.where(s > 1, s - 0.5, 0.5 * s * s))


def box_motion_profile(j, x0, x1, D):
    """Pixel-box-filtered time-averaged coverage of [x0+Dt, x1+Dt] at column j."""
    def cov_int(edge):  # int_j^{j+1} clamp((x - edge)/D, 0, 1) dx
        return D * (_ramp_integral((j + 1 - edge) / D) - _ramp_integral((j - edge) / D))
    return cov_int(x0) - cov_int(x1)


def test_horizontal_motion_profile():
    W, H = 48, 4
    x0, x1, D = 6.3, 17.7, 13.4
    q = rect_tris(x0, x1, -2, H + 2, W, H)
    r = rect_tris(x0 + D, x1 + D, -2, H + 2, W, H)
    pts = stratified_points(1024, seed=7, motion=True, lens=False)
    img = accumulation_render(q, r, None, None, np.ones((2, 3, 3)), W, H, pts)
    prof = box_motion_profile(np.arange(W), x0, x1, D)
    for row in range(H):
        np.testing.assert_allclose(img[row, :, 0], prof, atol=0.01)
    # per-point time coverage (unfiltered): clamp((x-x0)/D) - clamp((x-x1)/D)
    for x in (5.0, 8.1, 12.5, 20.0, 26.9, 33.0):
        expect = np.clip((x - x0) / D, 0, 1) - np.clip((x - x1) / D, 0, 1)
        got = exact_time_coverage(q[0], r[0], x, 1.5, n=512, width=W, height=H) \
            + exact_time_coverage(q[1], r[1], x, 1.5, n=512, width=W, height=H)
        assert abs(got - expect) <= 2 / 512


def test_motion_in_depth_uses_clip_space_lerp():
    # moving w: a single-point accumulation at time t equals the static render
    # of the clip-space-lerped vertices
    W = H = 24
    rng = np.random.default_rng(8)
    q = np.array([[pix_to_clip(3, 20, W, H, 0.1, 1.0), pix_to_clip(20, 18, W, H, 0.1, 2.0),
                   pix_to_clip(10, 2, W, H, 0.1, 1.5)]])
    r = q.copy()
    r[..., 3] *= 1.7
    r[..., 0] += 0.3
    cols = rng.random((1, 3, 3))
    img = accumulation_render(q, r, None, None, cols, W, H, [[0.3, 0.6, 0.25, 0.0, 0.0]])
    ref, tid, _ = render_static(0.75 * q + 0.25 * r, cols, W, H, (0.3, 0.6))
    assert (tid == 0).sum() > 50
    np.testing.assert_allclose(img, ref, atol=1e-12)


# --------------------------------------------------------------------------- #
# thin lens
# --------------------------------------------------------------------------- #
def test_lens_in_focus_is_sharp():
    W, H = 32, 32
    rng = np.random.default_rng(9)
    tris = np.array([[pix_to_clip(*rng.uniform(0, 32, 2), W, H, rng.uniform(-0.9, 0.9), rng.uniform(0.5, 3))
                      for _ in range(3)] for _ in range(6)])
    cols = rng.random((6, 3, 3))
    pts = stratified_points(64, seed=3, motion=False, lens=True)
    pts[:, 0:2] = 0.5
    zero = np.zeros((6, 3, 2))
    img = accumulation_render(tris, tris, zero, zero, cols, W, H, pts)
    ref, _, _ = render_static(tris, cols, W, H)
    np.testing.assert_allclose(img, ref, atol=1e-12)
    img_none = accumulation_render(tris, tris, None, None, cols, W, H, pts)
    np.testing.assert_allclose(img_none, ref, atol=1e-12)


def test_lens_displacement_shifts_ndc():
    # lens_x = k * w at every vertex shifts NDC x by k * u (and y likewise)
    W, H = 40, 40
    rng = np.random.default_rng(10)
    tris = np.array([[pix_to_clip(*rng.uniform(5, 35, 2), W, H, 0.0, rng.uniform(0.5, 3))
                      for _ in range(3)] for _ in range(3)])
    cols = rng.random((3, 3, 3))
    kx, ky = 0.2, -0.1
    lx = np.repeat((kx * tris[..., 3])[..., None], 2, axis=-1)
    ly = np.repeat((ky * tris[..., 3])[..., None], 2, axis=-1)
    u, v = 0.6, -0.5
    img = accumulation_render(tris, tris, lx, ly, cols, W, H, [[0.5, 0.5, 0.3, u, v]])
    shifted = tris.copy()
    shifted[..., 0] += kx * u * tris[..., 3]
    shifted[..., 1] += ky * v * tris[..., 3]
    ref, _, _ = render_static(shifted, cols, W, H)
    np.testing.assert_allclose(img, ref, atol=1e-12)


# --------------------------------------------------------------------------- #
# sample points
# --------------------------------------------------------------------------- #
def test_stratified_points():
    k = 64
    p = stratified_points(k, seed=1, motion=True, lens=True)
    assert p.shape == (k, 5)
    assert np.all((p[:, :3] >= 0) & (p[:, :3] < 1))
    assert np.all(p[:, 3] ** 2 + p[:, 4] ** 2 <= 1 + 1e-12)
    for d in range(3):  # each 1D projection is stratified
        np.testing.assert_array_equal(np.sort(np.floor(p[:, d] * k)), np.arange(k))
    p2 = stratified_points(k, seed=1, motion=False, lens=False)
    assert np.all(p2[:, 2] == 0.5) and np.all(p2[:, 3:] == 0)
    np.testing.assert_array_equal(p2[:, :2], p[:, :2])
