"""Conservativeness and tightness of the dual-space and two-stage time bounds.

``units.tile_test_dual``: Laine11's dual-space time interval (Wu13 §2)
and Wu13 §3.4's stage-2 lines t >= lo_c + lo_s u, t <= hi_c + hi_s u. Both are
checked against brute force: many random 5D samples (x, y in the tile, u, v
in the lens range, t in [ta, tb]) decided by the pipeline's exact inside test
on the float32 vertices; every covered sample must lie within every bound.
"""

import zlib
from types import SimpleNamespace

import numba as nb
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.counters import N_OPS
from pipeline_sim.draw import draw_from_clip
from triangles import moving_triangle
from units.sample_tester import inside_test
from units.tile_test_dual import dual_time_interval, two_stage_lines
from units.triangle_setup import TriangleSetup

W, H = 48, 32
JIT = not nb.config.DISABLE_JIT
N_SAMPLES = 12000 if JIT else 300  # the pure-Python path only checks that it runs
ARCH = load_arch()


def table_from_clip(q, r, lx, ly):
    """Pixel-space tables (and float32 copies) from clip space, via triangle setup."""
    d = draw_from_clip(q, r, lx, ly, width=W, height=H)
    setup = TriangleSetup(ARCH.triangle_setup, d, 8)
    setup.run(np.arange(d.n, dtype=np.int64))
    return setup.table


def table_from_pixels(P0, P1, L0=None, L1=None):
    """Tables built directly from pixel-space vertices (3,4) at t=0, t=1 and lens shifts (3,2)."""
    P0 = np.asarray(P0, float).reshape(1, 3, 4)
    P1 = np.asarray(P1, float).reshape(1, 3, 4)
    L0 = np.zeros((1, 3, 2)) if L0 is None else np.asarray(L0, float).reshape(1, 3, 2)
    L1 = L0.copy() if L1 is None else np.asarray(L1, float).reshape(1, 3, 2)
    dp, dl = P1 - P0, L1 - L0
    m = max(np.max(np.abs(P[..., :2]) + np.abs(L)) for P, L in ((P0, L0), (P1, L1)))
    m = max(m, np.max(np.abs(P0[..., 3])), np.max(np.abs(P1[..., 3])))
    f32 = np.float32
    return SimpleNamespace(p0=P0, dp=dp, l0=L0, dl=dl, p0_32=P0.astype(f32), dp_32=dp.astype(f32),
                           l0_32=L0.astype(f32), dl_32=dl.astype(f32),
                           edge_eps=np.array([2e-6 * m * m * 200.0], f32))


@nb.njit(cache=True)
def _coord(lo, hi, snap):
    """A float32 in [lo, hi] (float32-representable ends); an end with probability ``snap``."""
    r = np.random.random()
    if r < snap:
        return np.float32(lo)
    if r < 2.0 * snap:
        return np.float32(hi)
    c = np.float32(lo + (hi - lo) * np.random.random())
    return min(max(c, np.float32(lo)), np.float32(hi))


@nb.njit(cache=True)
def brute_covered(p0, dp, l0, dl, edge_eps, x0, x1, y0, y1, ulo, uhi, vlo, vhi, ta, tb, n, seed):
    """Covered samples (x, y, t, u, v) among ``n`` random ones in the tile and ranges."""
    np.random.seed(seed)
    out = np.empty((n, 5))
    cnt = 0
    for _ in range(n):
        x = _coord(x0, x1, 0.05)
        y = _coord(y0, y1, 0.05)
        t = _coord(ta, tb, 0.05)
        u = _coord(ulo, uhi, 0.1)
        v = _coord(vlo, vhi, 0.1)
        if inside_test(p0, dp, l0, dl, 0, x, y, t, u, v, False, edge_eps)[0]:
            out[cnt, 0] = x
            out[cnt, 1] = y
            out[cnt, 2] = t
            out[cnt, 3] = u
            out[cnt, 4] = v
            cnt += 1
    return out[:cnt]


def bounds(tb, x0, x1, y0, y1, ulo, uhi, vlo, vhi, ta, tbe):
    ops = np.zeros(N_OPS, np.int64)
    dual = dual_time_interval(tb.p0, tb.dp, tb.l0, tb.dl, 0, x0, x1, y0, y1, ulo, uhi, vlo, vhi, ta, tbe, ops)
    lx = two_stage_lines(tb.p0, tb.dp, tb.l0, tb.dl, 0, 0, x0, x1, ulo, uhi, ta, tbe, ops)
    ly = two_stage_lines(tb.p0, tb.dp, tb.l0, tb.dl, 0, 1, y0, y1, vlo, vhi, ta, tbe, ops)
    assert np.all(np.isfinite(dual)) and np.all(np.isfinite(lx)) and np.all(np.isfinite(ly))
    assert ops.sum() > 0
    return dual, lx, ly


def check(tb, x0, x1, y0, y1, ulo, uhi, vlo, vhi, ta, tbe, seed, n=N_SAMPLES):
    """Brute force: every covered sample satisfies every bound. Returns the covered count."""
    f = [float(np.float32(c)) for c in (x0, x1, y0, y1, ulo, uhi, vlo, vhi, ta, tbe)]
    x0, x1, y0, y1, ulo, uhi, vlo, vhi, ta, tbe = f
    (lo, hi), lx, ly = bounds(tb, *f)
    S = brute_covered(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, tb.edge_eps, x0, x1, y0, y1, ulo, uhi, vlo, vhi,
                      ta, tbe, n, seed)
    t, u, v = S[:, 2], S[:, 3], S[:, 4]
    ctx = dict(tile=(x0, x1, y0, y1), lens=(ulo, uhi, vlo, vhi), t=(ta, tbe), dual=(lo, hi), lx=lx, ly=ly)
    assert np.all(t >= lo) and np.all(t <= hi), ("dual interval misses a covered sample", ctx,
                                                  S[(t < lo) | (t > hi)][:3])
    for name, (lc, ls, hc, hs), c in (("x", lx, u), ("y", ly, v)):
        below = t < lc + ls * c
        above = t > hc + hs * c
        assert not below.any(), (f"{name} lower line excludes a covered sample", ctx, S[below][:3])
        assert not above.any(), (f"{name} upper line excludes a covered sample", ctx, S[above][:3])
    return len(S)


def screen_point(tb, rng, t, u, v):
    """A random point of the triangle at (t, u, v): inside, near a vertex or on an edge."""
    lam = rng.dirichlet([0.05, 0.05, 0.05] if rng.random() < 0.5 else [1.0, 1.0, 1.0])
    P = np.zeros(3)
    for k in range(3):
        X = tb.p0[0, k, 0] + t * tb.dp[0, k, 0] + u * (tb.l0[0, k, 0] + t * tb.dl[0, k, 0])
        Y = tb.p0[0, k, 1] + t * tb.dp[0, k, 1] + v * (tb.l0[0, k, 1] + t * tb.dl[0, k, 1])
        Wk = tb.p0[0, k, 3] + t * tb.dp[0, k, 3]
        P += lam[k] * np.array([X, Y, Wk])
    return P[0] / P[2], P[1] / P[2]


def random_query(rng, tb, lens_kind, time_kind, size):
    """A tile of ``size`` pixels near the triangle and lens / time sub-ranges."""
    def rng_range(kind):
        if kind == "full":
            return -1.0, 1.0
        if kind == "point":
            c = rng.uniform(-1, 1)
            return c, c
        a, b = np.sort(rng.uniform(-1, 1, 2))
        return a, b
    ulo, uhi = rng_range(lens_kind)
    vlo, vhi = rng_range(lens_kind if rng.random() < 0.7 else "full")
    if time_kind == "full":
        ta, tbe = 0.0, 1.0
    elif time_kind == "point":
        ta = tbe = rng.uniform(0, 1)
    else:
        ta, tbe = np.sort(rng.uniform(0, 1, 2))
    # tile around a point of the triangle at a random (t, u, v) of the ranges
    px, py = screen_point(tb, rng, rng.uniform(ta, tbe), rng.uniform(ulo, uhi), rng.uniform(vlo, vhi))
    x0 = np.floor(px) - rng.integers(size) + rng.integers(-1, 2)
    y0 = np.floor(py) - rng.integers(size) + rng.integers(-1, 2)
    return x0, x0 + size, y0, y0 + size, ulo, uhi, vlo, vhi, ta, tbe


query = st.tuples(st.integers(0, 2**31), st.sampled_from(["full", "sub", "sub", "point"]),
                  st.sampled_from(["full", "full", "sub", "point"]), st.sampled_from([1, 1, 2, 4, 16]))


@given(moving_triangle(lens=True, motion=True, allow_w_cross=False), query)
def test_bounds_conservative_5d(tri, q):
    seed, lens_kind, time_kind, size = q
    tb = table_from_clip(*tri)
    rng = np.random.default_rng(seed)
    check(tb, *random_query(rng, tb, lens_kind, time_kind, size), seed)


@given(moving_triangle(lens=True, motion=False, allow_w_cross=False), query)
def test_bounds_conservative_defocus_only(tri, q):
    seed, lens_kind, time_kind, size = q
    tb = table_from_clip(*tri)
    check(tb, *random_query(np.random.default_rng(seed), tb, lens_kind, time_kind, size), seed)


@given(moving_triangle(lens=False, motion=True, allow_w_cross=False), query)
def test_bounds_conservative_motion_only(tri, q):
    seed, lens_kind, time_kind, size = q
    tb = table_from_clip(*tri)
    check(tb, *random_query(np.random.default_rng(seed), tb, lens_kind, time_kind, size), seed)


@given(moving_triangle(lens=True, motion=True, allow_w_cross=False, view_rays=True), query)
def test_bounds_conservative_view_rays(tri, q):
    """Vertices moving along their view rays (fixed on screen, moving in depth)."""
    seed, lens_kind, time_kind, size = q
    tb = table_from_clip(*tri)
    check(tb, *random_query(np.random.default_rng(seed), tb, lens_kind, time_kind, size), seed)


# ---- adversarial cases (clip space q, r and lens shifts at t=0, t=1) ------------------------------------
_Q = np.array([[[-0.5, -0.4, 0.0, 1.0], [0.6, -0.3, 0.0, 1.2], [0.0, 0.6, 0.0, 0.9]]])


def _lens(coc0, coc1):
    lx = np.zeros((1, 3, 2))
    lx[0, :, 0] = coc0
    lx[0, :, 1] = coc1
    return lx


ADVERSARIAL = {
    # no motion and no lens: every slope is exactly zero
    "static": (_Q, _Q.copy(), np.zeros((1, 3, 2)), np.zeros((1, 3, 2))),
    "static_defocus": (_Q, _Q.copy(), _lens([0.3, -0.2, 0.1], [0.3, -0.2, 0.1]),
                       _lens([0.3, -0.2, 0.1], [0.3, -0.2, 0.1])),
    # towards the camera: w shrinks 4x, screen motion accelerates
    "toward_camera": (_Q * 3.0, _Q * 0.75 + np.array([0.1, 0.0, 0.0, 0.0]), _lens([0.5, 0.6, 0.4], [0.05, 0.1, 0.02]),
                      _lens([0.5, 0.6, 0.4], [0.05, 0.1, 0.02])),
    "away_from_camera": (_Q * 0.5, _Q * 3.5 - np.array([0.2, 0.1, 0.0, 0.0]), _lens([-0.1, -0.2, 0.0], [0.6, 0.5, 0.7]),
                         _lens([-0.1, -0.2, 0.0], [0.6, 0.5, 0.7])),
    # circle of confusion changes sign: the vertex crosses the focus plane
    "coc_sign_change": (_Q, _Q * 2.0 + np.array([0.3, -0.2, 0.0, 0.0]), _lens([0.4, -0.3, 0.2], [-0.5, 0.35, -0.25]),
                        _lens([-0.3, 0.4, 0.2], [0.3, -0.4, -0.2])),
    # pure translation in x with a strong lens (near-linear root functions)
    "translate_defocus": (_Q, _Q + np.array([0.8, 0.0, 0.0, 0.0]), _lens([0.3, 0.3, 0.3], [0.3, 0.3, 0.3]),
                          _lens([0.2, 0.2, 0.2], [0.2, 0.2, 0.2])),
}


@pytest.mark.parametrize("name", sorted(ADVERSARIAL))
@pytest.mark.parametrize("lens_kind", ["full", "sub", "point"])
def test_bounds_conservative_adversarial(name, lens_kind):
    tb = table_from_clip(*ADVERSARIAL[name])
    rng = np.random.default_rng(zlib.crc32(f"{name}-{lens_kind}".encode()))
    covered = 0
    for i in range(12 if JIT else 2):
        time_kind = ("full", "sub", "point")[i % 3]
        size = (1, 2, 8, 16)[i % 4]
        covered += check(tb, *random_query(rng, tb, lens_kind, time_kind, size), 1000 + i)
    assert covered > 0


def test_static_triangle_bounds_are_the_whole_range():
    tb = table_from_clip(*ADVERSARIAL["static"])
    x, y = screen_point(tb, np.random.default_rng(0), 0.5, 0.0, 0.0)
    x0, y0 = float(np.floor(x)), float(np.floor(y))
    (lo, hi), lx, ly = bounds(tb, x0, x0 + 1, y0, y0 + 1, -1.0, 1.0, -1.0, 1.0, 0.0, 1.0)
    assert (lo, hi) == (0.0, 1.0)
    # far away from the triangle: empty
    (lo, hi), lx, ly = bounds(tb, x0 + 100, x0 + 101, y0, y0 + 1, -1.0, 1.0, -1.0, 1.0, 0.0, 1.0)
    assert lo > hi
    assert min(lx[0] + lx[1] * u for u in (-1.0, 1.0)) > 1.0  # lower line above tb: nothing to test


def test_bounds_cover_float32_rounding_far_from_origin():
    # a vertical right edge at screen x ~ 1e4 (X ~ 1e6, W ~ 100) sliding right by 1 px: rounding X up
    # and W down, the float32 vertices reach the tile's left side ~4e-4 earlier than float64 says
    # (without the F32_REL pad both bounds miss those samples)
    a0 = 10000.0
    w = 100.3
    while float(np.float32(w)) >= w:
        w += 1e-6
    X0 = (a0 - 0.3) * w
    while float(np.float32(X0)) <= X0:
        X0 += 1e-3
    P0 = np.array([[X0, 0.0, 0.0, w], [X0, 100.0 * w, 0.0, w], [X0 - 50.0 * w, 50.0 * w, 0.0, w]])
    tb = table_from_pixels(P0, P0 + np.array([w, 0.0, 0.0, 0.0]))
    t_e = (a0 * w - X0) / w
    n = 0
    for i, (ta, tbe) in enumerate(((t_e - 3e-3, t_e + 3e-3), (0.0, 1.0))):
        n += check(tb, a0, a0 + 1.0, 40.0, 41.0, -1.0, 1.0, -1.0, 1.0, ta, tbe, 21 + i, n=4 * N_SAMPLES)
    assert n > 0


# ---- closed forms and tightness --------------------------------------------------------------------------
def _translating(dx):
    # W = 1, no lens; x in [-2, -1] at t = 0, moving by dx; y static and spanning [-5, 5]
    P0 = np.array([[-2.0, -5.0, 0.0, 1.0], [-1.0, 0.0, 0.0, 1.0], [-2.0, 5.0, 0.0, 1.0]])
    P1 = P0 + np.array([dx, 0.0, 0.0, 0.0])
    return table_from_pixels(P0, P1)


def test_dual_interval_closed_form_translation():
    tb = _translating(20.0)
    (lo, hi), lx, ly = bounds(tb, 0.0, 1.0, 0.0, 1.0, -1.0, 1.0, -1.0, 1.0, 0.0, 1.0)
    # entry: max x = -1 + 20 t reaches 0; exit: min x = -2 + 20 t reaches 1
    assert lo <= 0.05 <= lo + 1e-6 and hi - 1e-6 <= 0.15 <= hi, (lo, hi)
    # no lens: the stage-2 lines are the same times (plus their 1e-6 pad), flat in u
    assert abs(lx[1]) < 1e-9 and abs(lx[3]) < 1e-9
    assert lx[0] <= 0.05 <= lx[0] + 3e-6 and lx[2] - 3e-6 <= 0.15 <= lx[2], lx
    # the y lines must not cull anything within the range
    assert ly[0] + abs(ly[1]) <= 0.0 and ly[2] - abs(ly[3]) >= 1.0
    assert check(tb, 0.0, 1.0, 0.0, 1.0, -1.0, 1.0, -1.0, 1.0, 0.0, 1.0, 7) > 0


def test_dual_interval_closed_form_perspective():
    # no lens; vertex 1 the rightmost; W grows 1 -> 2: screen x = X / W crosses a0 at (a0 W0 - X0) / (dX - a0 dW)
    P0 = np.array([[-3.0, -5.0, 0.0, 1.0], [-1.0, 0.0, 0.0, 1.0], [-3.0, 5.0, 0.0, 1.0]])
    P1 = P0 + np.array([12.0, 0.0, 0.0, 1.0])
    tb = table_from_pixels(P0, P1)
    (lo, hi), _, _ = bounds(tb, 2.0, 3.0, 0.0, 1.0, -1.0, 1.0, -1.0, 1.0, 0.0, 1.0)
    entry = (2.0 * 1.0 + 1.0) / (12.0 - 2.0 * 1.0)  # vertex 1 reaches x = 2
    exit_ = (3.0 * 1.0 + 3.0) / (12.0 - 3.0 * 1.0)  # vertices 0, 2 reach x = 3
    assert lo <= entry <= lo + 2e-6 and hi - 2e-6 <= exit_ <= hi, (lo, hi, entry, exit_)


def _motion_and_defocus(dw):
    # small triangle moving 20 px right with a large lens shift in x and y (W from 1 to 1 + dw)
    P0 = np.array([[10.0, 0.0, 0.0, 1.0], [12.0, 0.0, 0.0, 1.0], [11.0, 40.0, 0.0, 1.0]])
    P1 = P0 * np.array([1.0 + dw, 1.0 + dw, 1.0, 1.0 + dw]) + np.array([20.0, 0.0, 0.0, 0.0])
    L0 = np.full((3, 2), 8.0)
    L1 = np.full((3, 2), 8.0 * (1.0 + 2.0 * dw))
    return table_from_pixels(P0, P1, L0, L1)


@pytest.mark.parametrize("dw", [0.0, 0.3])
def test_two_stage_lines_cull_more_than_dual_space(dw):
    tb = _motion_and_defocus(dw)
    x0, x1, y0, y1 = 20.0, 21.0, 20.0, 21.0
    (lo, hi), lx, ly = bounds(tb, x0, x1, y0, y1, -1.0, 1.0, -1.0, 1.0, 0.0, 1.0)
    rng = np.random.default_rng(3)
    t = rng.uniform(0, 1, 20000)
    u = rng.uniform(-1, 1, 20000)
    v = rng.uniform(-1, 1, 20000)
    culled_dual = np.mean((t < lo) | (t > hi))
    culled_lines = np.mean((t < lx[0] + lx[1] * u) | (t > lx[2] + lx[3] * u)
                           | (t < ly[0] + ly[1] * v) | (t > ly[2] + ly[3] * v))
    # the covered band (dw = 0) is t ~ 0.4 - 0.4 u +- 0.08: the dual interval keeps nearly all of [0, 1]
    # (measured: dual culls 5% / 0%, the lines 85% / 72% for dw = 0 / 0.3)
    assert culled_dual < 0.2, culled_dual
    assert culled_lines > 0.6 and culled_lines > culled_dual + 0.5, (culled_dual, culled_lines)
    assert check(tb, x0, x1, y0, y1, -1.0, 1.0, -1.0, 1.0, 0.0, 1.0, 11) > 0


def test_nonfinite_and_degenerate_inputs():
    tb = _motion_and_defocus(0.3)
    ops = np.zeros(N_OPS, np.int64)
    # empty lens range and reversed time range: trivial lines, no NaN
    assert two_stage_lines(tb.p0, tb.dp, tb.l0, tb.dl, 0, 0, 20.0, 21.0, 0.5, -0.5, 0.0, 1.0, ops) == (0.0, 0.0, 1.0, 0.0)
    # zero-width lens range and a time point
    r = two_stage_lines(tb.p0, tb.dp, tb.l0, tb.dl, 0, 0, 20.0, 21.0, 0.25, 0.25, 0.3, 0.3, ops)
    assert np.all(np.isfinite(r)) and r[1] == 0.0 and r[3] == 0.0
    bad = SimpleNamespace(p0=tb.p0.copy(), dp=tb.dp, l0=tb.l0, dl=tb.dl)
    bad.p0[0, 0, 0] = np.nan
    r = two_stage_lines(bad.p0, bad.dp, bad.l0, bad.dl, 0, 0, 20.0, 21.0, -1.0, 1.0, 0.0, 1.0, ops)
    assert np.all(np.isfinite(r))
    lo, hi = dual_time_interval(bad.p0, bad.dp, bad.l0, bad.dl, 0, 20.0, 21.0, 20.0, 21.0, -1.0, 1.0, -1.0, 1.0,
                                0.0, 1.0, ops)
    assert np.isfinite(lo) and np.isfinite(hi)
