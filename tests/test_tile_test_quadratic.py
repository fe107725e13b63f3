"""Quadratic moving-edge tile test (Munkberg11 §4.2 alternative, Gribel10 §4.1) against independent references.

* conservativeness on random quadratic edges, with adversarial ones (f == 0,
  f tiny, double roots, axis-parallel components, huge translations, huge
  and tiny scales): brute force over a dense t grid refined by bisection at
  every coverage change, and a grid of points of the tile, never finds a
  covered t outside the interval;
* tightness on the same: the interval lies within the hull of the per-edge
  feasible sets found by brute force with a larger (3x) float32 margin;
* real moving triangles (triangle setup): every sample the exact float32
  inside test covers has its t in its tile's interval, and no sample of a
  grid over the tile is covered just outside the interval;
* closed forms: a translating triangle (f == 0) enters and leaves a tile at
  hand-computed times; a curved edge where the linearized test is looser;
* non-finite input returns the incoming interval; an empty one stays empty.
"""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.counters import N_OPS
from pipeline_sim.draw import draw_from_clip
from triangles import finite, moving_triangle, sample_inside_points
from units.sample_tester import inside_test
from units.tile_test_bounds import edge_time_interval
from units.tile_test_quadratic import _nonneg_hull, quadratic_time_interval
from units.triangle_setup import FLAG_EDGE, TriangleSetup

F32_REL = 1e-6  # the documented float32 margin (units.rounding), restated as the test's own constant
W, H = 48, 32


def run(f, g, h, tile, lo, hi, tri=0):
    ops = np.zeros(N_OPS, np.int64)
    # synthetic coefficients carry no products of their own: |f| + |g| + |h| is the magnitude
    a, b = quadratic_time_interval(f, g, h, np.zeros_like(h), tri, float(tile[0]), float(tile[1]), float(tile[2]), float(tile[3]),
                                   float(lo), float(hi), ops)
    return a, b, ops


# ---------------------------------------------------------------- brute force


def tile_points(tile, n=7):
    xs = np.linspace(tile[0], tile[1], n)
    ys = np.linspace(tile[2], tile[3], n)
    X, Y = np.meshgrid(xs, ys)
    return np.stack([X.ravel(), Y.ravel(), np.ones(n * n)], axis=1)  # includes the four corners


def corners(tile):
    return np.array([[tile[cx], tile[2 + cy], 1.0] for cx in range(2) for cy in range(2)])


def edge_values(f, g, h, pts, t):
    """e_k(p, t) for every edge, point and time: shape (3, points, times)."""
    A = pts @ f[0].T  # (points, 3)
    B = pts @ g[0].T
    C = pts @ h[0].T
    t = np.asarray(t, dtype=np.float64)
    return (A.T[:, :, None] * t + B.T[:, :, None]) * t + C.T[:, :, None]


def bisect_changes(pred, ts, lo, hi, iters=60):
    """Grid ``ts`` plus, at every change of pred between neighbours, the
    bisected transition (both sides). pred maps an array of t to booleans."""
    ts = np.unique(np.clip(ts, lo, hi))
    ok = pred(ts)
    extra = []
    for i in np.nonzero(ok[1:] != ok[:-1])[0]:
        a, b = ts[i], ts[i + 1]
        va = ok[i]
        for _ in range(iters):
            m = 0.5 * (a + b)
            if m <= a or m >= b:
                break
            if pred(np.array([m]))[0] == va:
                a = m
            else:
                b = m
        extra += [a, b]
    if extra:
        ts = np.unique(np.concatenate([ts, extra]))
        ok = pred(ts)
    return ts, ok


def vertices(f, g, h, pts, k=None):
    """Vertices -B / (2A) of the quadratics of the given points (all edges or edge k)."""
    out = []
    for kk in range(3) if k is None else [k]:
        A = pts @ f[0, kk]
        B = pts @ g[0, kk]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # non-finite ones are dropped
            v = -B / (2.0 * A)
        out.append(v[np.isfinite(v)])
    return np.concatenate(out)


def covered_times(f, g, h, tile, lo, hi):
    """Times in [lo, hi] at which some point of the tile is inside all three edges (float64, no margin)."""
    pts = tile_points(tile)

    def pred(ts):
        return np.any(np.all(edge_values(f, g, h, pts, ts) >= 0.0, axis=0), axis=0)

    grid = np.concatenate([np.linspace(lo, hi, 2001), vertices(f, g, h, corners(tile))])
    ts, ok = bisect_changes(pred, grid, lo, hi)
    return ts[ok]


def reference_hull(f, g, h, tile, lo, hi, scale_margin=3.0):
    """Intersection of the per-edge hulls of {t : max over corners of e_k + M' >= 0}, M' = 3x the margin."""
    cs = corners(tile)
    ax = max(abs(tile[0]), abs(tile[1]))
    ay = max(abs(tile[2]), abs(tile[3]))
    rlo, rhi = lo, hi
    for k in range(3):
        s = np.abs(f[0, k]) + np.abs(g[0, k]) + np.abs(h[0, k])
        marg = scale_margin * F32_REL * (s[0] * ax + s[1] * ay + s[2])
        A, B, C = cs @ f[0, k], cs @ g[0, k], cs @ h[0, k]

        def pred(ts, A=A, B=B, C=C, marg=marg):
            return np.max((A[:, None] * ts + B[:, None]) * ts + C[:, None], axis=0) + marg >= 0.0

        grid = np.concatenate([np.linspace(lo, hi, 2001), vertices(f, g, h, cs, k)])
        ts, ok = bisect_changes(pred, grid, lo, hi)
        if not ok.any():
            return 1.0, 0.0
        rlo, rhi = max(rlo, ts[ok].min()), min(rhi, ts[ok].max())
    return rlo, rhi


# ---------------------------------------------------------------- random quadratic edges

KINDS = ("random", "linear", "tiny_f", "double", "axis")


@st.composite
def quadratic_case(draw):
    tw = draw(finite(0.25, 16.0))
    th = draw(finite(0.25, 16.0))
    L = 2.0 * (tw + th)
    f = np.zeros((1, 3, 3))
    g = np.zeros((1, 3, 3))
    h = np.zeros((1, 3, 3))
    kinds = []
    for k in range(3):
        kind = draw(st.sampled_from(KINDS))
        kinds.append(kind)
        for arr in (f, g, h):
            arr[0, k, 0] = draw(finite(-1, 1))
            arr[0, k, 1] = draw(finite(-1, 1))
            arr[0, k, 2] = draw(finite(-1, 1)) * L
        if kind == "linear":
            f[0, k] = 0.0
        elif kind == "tiny_f":
            f[0, k] *= 1e-12
        elif kind == "axis":
            comp = draw(st.integers(0, 1))
            f[0, k, comp] = g[0, k, comp] = h[0, k, comp] = 0.0
        elif kind == "double":
            # e_k at a corner is s (t - r)^2 up to rounding: a double root
            cx = draw(st.sampled_from([0.0, tw]))
            cy = draw(st.sampled_from([0.0, th]))
            r = draw(st.one_of(finite(0, 1), st.sampled_from([0.0, 1.0, 0.5])))
            s = draw(finite(0.01, 2.0)) * draw(st.sampled_from([-1.0, 1.0])) * L
            f[0, k, 2] = s - f[0, k, 0] * cx - f[0, k, 1] * cy
            g[0, k, 2] = -2.0 * s * r - g[0, k, 0] * cx - g[0, k, 1] * cy
            h[0, k, 2] = s * r * r - h[0, k, 0] * cx - h[0, k, 1] * cy
    # translate the tile far away: n_w -= n_x X0 + n_y Y0 keeps the geometry
    X0 = draw(st.sampled_from([0.0, 0.0, 37.5, -1e3, 2.5e6]))
    Y0 = draw(st.sampled_from([0.0, 0.0, 21.25, 1e4, -3e5]))
    for arr in (f, g, h):
        arr[0, :, 2] -= arr[0, :, 0] * X0 + arr[0, :, 1] * Y0
    scale = draw(st.sampled_from([1.0, 1.0, 1e-150, 3e140, 7.0e-300 * 1e10]))
    f, g, h = f * scale, g * scale, h * scale
    tile = (X0, X0 + tw, Y0, Y0 + th)
    lo = draw(st.one_of(st.just(0.0), finite(0.0, 0.6)))
    hi = draw(st.one_of(st.just(1.0), finite(lo, 1.0)))
    return f, g, h, tile, lo, hi, kinds


@given(quadratic_case())
def test_conservative_and_tight_random_quadratics(case):
    f, g, h, tile, lo, hi, _ = case
    a, b, ops = run(f, g, h, tile, lo, hi)
    assert np.isfinite(a) and np.isfinite(b)
    assert ops.sum() > 0
    cov = covered_times(f, g, h, tile, lo, hi)
    if a > b:
        assert cov.size == 0, f"rejected, but covered at t={cov[:5]}"
    else:
        assert lo <= a <= b <= hi
        assert cov.size == 0 or (cov.min() >= a and cov.max() <= b), (a, b, cov.min(), cov.max())
    # tightness: within the hull found with a 3x margin
    rlo, rhi = reference_hull(f, g, h, tile, lo, hi)
    if rlo > rhi:
        assert a > b, f"kept [{a}, {b}] where every edge hull is empty with a 3x margin"
    elif a <= b:
        assert a >= rlo - 1e-9 and b <= rhi + 1e-9, ((a, b), (rlo, rhi))


def test_power_of_two_scale_invariance():
    rng = np.random.default_rng(5)
    tile = (3.0, 11.0, -2.0, 6.0)
    for _ in range(50):
        f, g, h = (rng.normal(size=(1, 3, 3)) * [1, 1, 20] for _ in range(3))
        base = run(f, g, h, tile, 0.0, 1.0)[:2]
        for e in (-900, -300, 300, 900):
            s = 2.0 ** e
            assert run(f * s, g * s, h * s, tile, 0.0, 1.0)[:2] == base


def test_double_root_tangent_tile():
    # edge 0 is e = -(t - 0.4)^2 at the tile's best corner: it touches the tile only at t = 0.4
    f = np.zeros((1, 3, 3))
    g = np.zeros((1, 3, 3))
    h = np.zeros((1, 3, 3))
    f[0, 0, 2], g[0, 0, 2], h[0, 0, 2] = -1.0, 0.8, -0.16
    h[0, 1, 2] = h[0, 2, 2] = 1.0
    a, b, _ = run(f, g, h, (0.0, 4.0, 0.0, 4.0), 0.0, 1.0)
    assert a <= 0.4 <= b and b - a < 1e-2
    # slightly below touching: empty (up to the margin); slightly above: two close roots
    h[0, 0, 2] = -0.16 - 1e-3
    a, b, _ = run(f, g, h, (0.0, 4.0, 0.0, 4.0), 0.0, 1.0)
    assert a > b
    h[0, 0, 2] = -0.16 + 1e-4
    a, b, _ = run(f, g, h, (0.0, 4.0, 0.0, 4.0), 0.0, 1.0)
    assert a <= 0.39 and b >= 0.41 and b - a < 0.03


def test_rounded_double_roots_are_kept():
    # s (t - r)^2 with rounded coefficients: the computed discriminant is often slightly negative
    rng = np.random.default_rng(11)
    negative = 0
    for r in rng.uniform(0.0, 1.0, 400):
        for s in (-3.0, -1e-7, -7e5):
            A, B, C = s, -2.0 * s * r, s * r * r
            negative += B * B - 4.0 * A * C < 0.0
            ops = np.zeros(N_OPS, np.int64)
            a, b = _nonneg_hull(A, B, C, 0.0, 1.0, ops)
            assert a <= r <= b and b - a < 1e-6, (r, s, a, b)
    assert negative > 50


def test_single_corner_when_components_keep_their_sign():
    tile = (0.0, 16.0, 0.0, 8.0)
    f, g, h = simple_edges()
    _, _, ops_one = run(f, g, h, tile, 0.0, 1.0)
    g2 = g.copy()
    g2[0, 0, 0] = -2.0  # x component 1 - 2 t changes sign: both x sides of the tile are candidates
    a, b, ops_two = run(f, g2, h, tile, 0.0, 1.0)
    assert ops_two.sum() > ops_one.sum()
    # e = x (1 - 2t) - 10 - 20 t: feasible at x = 16 while 16 - 32 t >= 10 + 20 t, never at x = 0
    assert a == 0.0 and 6 / 52 <= b < 6 / 52 + 1e-5
    # e = x (1 - 2t) - 10 + 18 t: x = 16 admits t <= 3/7, x = 0 admits t >= 5/9: the hull is [0, 1]
    g2[0, 0, 2] = 18.0
    ts = np.linspace(0.0, 1.0, 10001)
    feasible = np.maximum(0.0, 16.0 * (1 - 2 * ts)) - 10.0 + 18.0 * ts >= 0
    assert feasible[0] and feasible[-1] and not feasible.all()
    assert run(f, g2, h, tile, 0.0, 1.0)[:2] == (0.0, 1.0)


# ---------------------------------------------------------------- real moving triangles


def setup_one(q, r, width=W, height=H, tile_size=8):
    d = draw_from_clip(q, r, np.zeros((1, 3, 2)), np.zeros((1, 3, 2)), width=width, height=height)
    setup = TriangleSetup(load_arch().triangle_setup, d, tile_size)
    alive, _, _ = setup.run(np.arange(1, dtype=np.int64))
    return setup, alive


def table_fgh(tb):
    # f = (f + g) - g until edge_f is in the table (rounding is within the margin)
    return tb.edge_fg - tb.edge_g, tb.edge_g, tb.edge_h


def covered32(tb, x, y, t):
    z = np.float32(0.0)
    return inside_test(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, 0, np.float32(x), np.float32(y), np.float32(t), z,
                       z, False, tb.edge_eps)[0]


@given(moving_triangle(lens=False, allow_w_cross=False), st.integers(0, 2**31), st.sampled_from([1, 4, 8, 16]))
def test_conservative_real_moving_triangles(tri, seed, ts):
    assert_conservative_real(tri, seed, ts)


@given(moving_triangle(lens=False, allow_w_cross=False, view_rays=True), st.integers(0, 2**31),
       st.sampled_from([1, 4, 8, 16]))
def test_conservative_real_view_ray_triangles(tri, seed, ts):
    """Vertices moving along their view rays (fixed on screen, moving in depth)."""
    assert_conservative_real(tri, seed, ts)


def assert_conservative_real(tri, seed, ts):
    """Covered samples in their tile's interval; no grid point covered just outside it."""
    q, r, _, _ = tri
    setup, alive = setup_one(q, r)
    tb = setup.table
    if 0 not in alive or (tb.flags[0] & FLAG_EDGE) == 0:
        return
    f, g, h = table_fgh(tb)
    lo, hi = tb.t_span[0]
    rng = np.random.default_rng(seed)
    intervals = {}

    def interval(tx, ty):
        if (tx, ty) not in intervals:
            tile = (tx * ts, (tx + 1) * ts, ty * ts, (ty + 1) * ts)  # not widened: the strictest case
            intervals[tx, ty] = run(f, g, h, tile, lo, hi)[:2]
        return intervals[tx, ty]

    # every covered sample lies in its tile's interval
    for x, y, t, _, _, _ in sample_inside_points(setup, 0, rng, 150, W, H):
        a, b = interval(int(x // ts), int(y // ts))
        assert a <= t <= b, f"covered sample t={t} at ({x}, {y}) outside [{a}, {b}]"
    # no point of a grid over the tile is covered just outside the interval
    bx0, bx1, by0, by1 = tb.bounds[0]
    for _ in range(3):
        tx = int(rng.integers(bx0 // ts, (bx1 - 1) // ts + 1))
        ty = int(rng.integers(by0 // ts, (by1 - 1) // ts + 1))
        a, b = interval(tx, ty)
        probes = [lo + (hi - lo) * rng.uniform()] if a > b else []
        if a <= b:
            probes = [a - d for d in (1e-7, 1e-4, 1e-2)] + [b + d for d in (1e-7, 1e-4, 1e-2)]
        for t in probes:
            if not (lo <= t <= hi) or (a <= t <= b):
                continue
            for x in np.linspace(tx * ts, (tx + 1) * ts, 6):
                for y in np.linspace(ty * ts, (ty + 1) * ts, 6):
                    assert not covered32(tb, x, y, t), f"({x}, {y}, t={t}) covered outside [{a}, {b}]"


def test_quadratic_is_within_linearized_on_real_triangles():
    # a triangle that turns in depth: curved edges (f != 0)
    q = np.array([[[-0.6, -0.5, 0.0, 1.0], [0.5, -0.4, 0.0, 1.0], [0.0, 0.6, 0.0, 1.0]]])
    r = np.array([[[-0.9, -0.3, 0.0, 2.5], [0.7, -0.6, 0.0, 1.0], [0.4, 0.5, 0.0, 1.6]]])
    setup, alive = setup_one(q, r, 96, 64)
    tb = setup.table
    assert 0 in alive and tb.flags[0] & FLAG_EDGE
    f, g, h = table_fgh(tb)
    assert np.abs(f).max() > 1e-3 * np.abs(g).max()
    lo, hi = tb.t_span[0]
    bx0, bx1, by0, by1 = tb.bounds[0]
    gains = []
    for tx in range(bx0 // 8, (bx1 - 1) // 8 + 1):
        for ty in range(by0 // 8, (by1 - 1) // 8 + 1):
            x0, x1, y0, y1 = tx * 8.0, tx * 8.0 + 8, ty * 8.0, ty * 8.0 + 8
            ops = np.zeros(N_OPS, np.int64)
            la, lb = edge_time_interval(tb.edge_h, tb.edge_gamma, tb.edge_g, tb.edge_fg, tb.edge_abs, True, 0, x0, x1, y0, y1,
                                         lo, hi, ops)
            a, b, _ = run(f, g, h, (x0, x1, y0, y1), lo, hi)
            if la > lb:
                assert a > b
                continue
            if a <= b:
                assert a >= la - 1e-5 and b <= lb + 1e-5
                gains.append((lb - la) - (b - a))
            else:
                gains.append(lb - la)
    assert max(gains) > 0.05


# ---------------------------------------------------------------- closed forms


def test_translating_triangle_closed_form():
    # pixel space, W = 1: vertices (a, b), (a + L, b), (a, b + L) moving by (v, 0) over the shutter
    a, b, L, v = 4.0, 20.0, 12.0, 40.0
    hx = hy = 32.0  # 64 x 64 screen
    pix = np.array([[a, b], [a + L, b], [a, b + L]])
    q = np.zeros((1, 3, 4))
    q[0, :, 0] = pix[:, 0] / hx - 1.0
    q[0, :, 1] = 1.0 - pix[:, 1] / hy
    q[0, :, 3] = 1.0
    r = q.copy()
    r[0, :, 0] += v / hx
    setup, alive = setup_one(q, r, 64, 64)
    tb = setup.table
    assert 0 in alive and tb.flags[0] & FLAG_EDGE
    f, g, h = table_fgh(tb)
    assert np.abs(f).max() <= 1e-12 * np.abs(g).max()  # linear in t
    for x0, y0 in ((24.0, 24.0), (8.0, 20.0), (40.0, 28.0), (16.0, 30.0)):
        x1, y1 = x0 + 8.0, y0 + 8.0
        # left edge x >= a + v t: the tile's right side; hypotenuse x + y <= a + b + L + v t: its top-left corner
        t_in = max(0.0, (x0 + max(y0, b) - a - b - L) / v)
        t_out = min(1.0, (x1 - a) / v)
        ka, kb, _ = run(f, g, h, (x0, x1, y0, y1), 0.0, 1.0)
        # conservative, and loose only by the float32 margin (>= F32_REL in t by construction)
        assert ka <= t_in <= t_out <= kb
        assert t_in - ka < 1e-5 and kb - t_out < 1e-5, ((ka, kb), (t_in, t_out))
    # a tile the triangle never reaches (right of where it ends)
    ka, kb, _ = run(f, g, h, (60.0, 64.0, 24.0, 28.0), 0.0, 1.0)
    assert ka > kb


def test_curved_edge_tighter_than_linearized():
    # e_0 = g t (1 - t) - g / 8 everywhere on the tile: non-negative on [(1 - sqrt(1/2)) / 2, (1 + sqrt(1/2)) / 2]
    f = np.zeros((1, 3, 3))
    g = np.zeros((1, 3, 3))
    h = np.zeros((1, 3, 3))
    f[0, 0, 2], g[0, 0, 2], h[0, 0, 2] = -1.0, 1.0, -0.125
    h[0, 1, 2] = h[0, 2, 2] = 1.0
    tile = (0.0, 8.0, 0.0, 8.0)
    a, b, _ = run(f, g, h, tile, 0.0, 1.0)
    e_in, e_out = (1 - np.sqrt(0.5)) / 2, (1 + np.sqrt(0.5)) / 2
    assert a <= e_in and b >= e_out and e_in - a < 1e-5 and b - e_out < 1e-5
    ops = np.zeros(N_OPS, np.int64)
    gamma = np.full((1, 3), np.inf)
    la, lb = edge_time_interval(h, gamma, g, f + g, np.abs(f) + np.abs(g) + np.abs(h), True, 0, *tile, 0.0, 1.0,
                                 ops)
    assert la <= a and lb >= b  # the linearized test is conservative too ...
    assert lb - b > 0.1  # ... but misses that the edge turns back


# ---------------------------------------------------------------- non-finite and empty input


def simple_edges():
    f = np.zeros((1, 3, 3))
    g = np.zeros((1, 3, 3))
    h = np.zeros((1, 3, 3))
    h[0, 0] = [1.0, 0.0, -10.0]
    g[0, 0, 2] = -20.0  # x >= 10 + 20 t
    h[0, 1, 2] = h[0, 2, 2] = 1.0
    return f, g, h


def test_non_finite_returns_incoming():
    tile = (0.0, 16.0, 0.0, 8.0)
    f, g, h = simple_edges()
    a, b, _ = run(f, g, h, tile, 0.1, 0.9)
    assert 0.1 <= a <= b < 0.31  # the finite case narrows
    for arr, val in ((f, np.nan), (g, np.inf), (h, -np.inf)):
        bad = arr.copy()
        bad[0, 1, 0] = val
        args = [bad if arr is x else x for x in (f, g, h)]
        assert run(*args, tile, 0.1, 0.9)[:2] == (0.1, 0.9)
    assert run(f, g, h, (0.0, np.inf, 0.0, 8.0), 0.1, 0.9)[:2] == (0.1, 0.9)
    assert run(f, g, h, (0.0, 16.0, np.nan, 8.0), 0.1, 0.9)[:2] == (0.1, 0.9)
    # overflow of the corner products: conservative, never NaN
    big = 1e300
    a, b, _ = run(f * big, g * big, h * big, (0.0, 1e10, 0.0, 8.0), 0.1, 0.9)
    assert (a, b) == (0.1, 0.9)


def test_empty_incoming_stays_empty():
    f, g, h = simple_edges()
    a, b, _ = run(f, g, h, (0.0, 16.0, 0.0, 8.0), 0.6, 0.4)
    assert a > b
    # fully rejected: the tile lies left of x = 10 + 20 t at every t
    a, b, _ = run(f, g, h, (0.0, 8.0, 0.0, 8.0), 0.0, 1.0)
    assert a > b
