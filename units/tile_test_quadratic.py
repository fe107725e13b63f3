"""Quadratic moving-edge tile test: exact per-tile time intervals of the edges.

The alternative to the linearized moving-edge test (Munkberg11 §4.2, eq. 8-9, in
units/tile_test.py): instead of bounding the edge's slope by Gamma, the
quadratic edge equations of a motion-only triangle (Gribel10 §4.1, eq. 3-5),

    e_k(x, y, t) = n_k(t) . (x, y, 1),   n_k(t) = f t^2 + g t + h,

are solved per tile for exact time intervals from their roots (Gribel10 §4.1).

At a time t the maximum of e_k over the tile is attained at a corner, so the
times at which edge k can admit a point of the tile are the union over the
corners c of {t : q_c(t) >= 0}, q_c(t) = n_k(t) . c. Where the x (y) component
of n_k(t) keeps one sign over the incoming [lo, hi], one x (y) side of the
tile attains the maximum for every t and the other side is skipped: a single
corner per edge in the common case. The hull of each edge's set (its earliest
start and latest end) is intersected with [lo, hi] and the other edges'.

Numerics (everything may only widen the interval, never narrow it):

* each q_c gets the margin M = F32_REL * (A . (max|x|, max|y|, 1)) of the
  linearized test, A = max(|f| + |g| + |h|, edge_abs) per component, so the interval is conservative against
  the float32 vertices of the sample tester; M is the largest over the tile,
  so the single-corner shortcut stays valid, and it also absorbs the small
  tolerance with which a component's sign is called constant;
* each quadratic is scaled by a power of two (exact) so its largest
  coefficient is in [0.5, 1): no overflow or underflow for huge or tiny
  coordinates;
* roots from the stable formulas Q = -(B + sign(B) sqrt(disc)) / 2,
  r1 = Q / A, r2 = C / Q: no division by a vanishing A (near-linear edges);
  A == 0 is solved as a line, A == B == 0 by the sign of C;
* a discriminant that is negative by no more than its rounding error counts
  as zero (a double root), and every root is padded outward by its error
  bound (the rounding of the discriminant, propagated through the sqrt)
  plus 1e-9 (1 + |r|);
* anything non-finite returns the incoming [lo, hi] unchanged.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pipeline_sim.definitions import OP_ADD, OP_CMP, OP_MADD, OP_MUL, OP_RCP
from units.rounding import F32_REL  # tile_test imports this module: no cycle

_EPS = 2.220446049250313e-16  # float64 unit roundoff (2^-52)
ROOT_PAD = 1e-9  # outward pad of every root: ROOT_PAD * (1 + |r|) on top of its error bound
SIGN_TOL = 1e-12  # a component is of one sign if it stays beyond -SIGN_TOL * (|f| + |g| + |h|)


@nb.njit(cache=True, inline="always")
def _finite(a):
    return math.isfinite(a)


@nb.njit(cache=True, inline="always")
def _or(v, fallback):
    """v, or ``fallback`` (the conservative side) when v is NaN (inf - inf)."""
    return v if v == v else fallback


@nb.njit(cache=True)
def _component_range(f, g, h, lo, hi, ops):
    """Min and max of f t^2 + g t + h over [lo, hi] (ends and vertex)."""
    va = (f * lo + g) * lo + h
    vb = (f * hi + g) * hi + h
    mn = min(va, vb)
    mx = max(va, vb)
    ops[OP_MADD] += 4
    ops[OP_CMP] += 3
    if f != 0.0:
        # vertex -g / (2f) strictly inside (lo, hi)? compared without dividing
        a2 = 2.0 * f
        ng = -g
        ops[OP_MUL] += 3
        ops[OP_CMP] += 3
        if (a2 > 0.0 and a2 * lo < ng and ng < a2 * hi) or (a2 < 0.0 and a2 * hi < ng and ng < a2 * lo):
            tv = min(max(ng / a2, lo), hi)
            ops[OP_RCP] += 1
            ops[OP_MUL] += 1
            vv = (f * tv + g) * tv + h
            mn = min(mn, vv)
            mx = max(mx, vv)
            ops[OP_MADD] += 2
            ops[OP_CMP] += 2
    return mn, mx


@nb.njit(cache=True)
def _nonneg_hull(A, B, C, lo, hi, ops):
    """Hull of {t in [lo, hi] : A t^2 + B t + C >= 0}, roots padded outward.

    Returns (start, end); start > end when the set is empty.
    """
    m = max(abs(A), abs(B), abs(C))
    ops[OP_CMP] += 3
    if m == 0.0:  # identically zero: >= 0 everywhere
        return lo, hi
    # exact power-of-two scaling: the largest coefficient lands in [0.5, 1)
    e = math.frexp(m)[1]
    A = math.ldexp(A, -e)
    B = math.ldexp(B, -e)
    C = math.ldexp(C, -e)
    ops[OP_MUL] += 3
    if A == 0.0:
        ops[OP_CMP] += 2
        if B == 0.0:
            if C >= 0.0:
                return lo, hi
            return 1.0, 0.0
        r = -C / B
        ops[OP_RCP] += 1
        ops[OP_MUL] += 1
        ops[OP_MADD] += 2
        ops[OP_CMP] += 3
        if not _finite(r):  # |C| >> |B| (B underflowed): the sign of C decides
            if C >= 0.0:
                return lo, hi
            return 1.0, 0.0
        pad = 4.0 * _EPS * abs(r) + ROOT_PAD * (1.0 + abs(r))
        if B > 0.0:  # non-negative on [r, inf)
            return max(lo, r - pad), hi
        return lo, min(hi, r + pad)  # non-negative on (-inf, r]
    bb = B * B
    ac4 = 4.0 * A * C
    disc = bb - ac4
    # rounding error of disc (B*B, 4AC and their difference, each <= eps/2 relative)
    derr = 4.0 * _EPS * (bb + abs(ac4))
    ops[OP_MUL] += 4
    ops[OP_MADD] += 2
    ops[OP_CMP] += 2
    if disc < -derr:  # no real root: the sign of A everywhere
        if A > 0.0:
            return lo, hi
        return 1.0, 0.0
    if disc < 0.0:
        disc = 0.0  # a double root within rounding
    s = math.sqrt(disc)
    serr = math.sqrt(derr)  # |sqrt(disc + d) - sqrt(disc)| <= sqrt(|d|)
    Q = -0.5 * (B + (s if B >= 0.0 else -s))
    ops[OP_RCP] += 2  # two sqrt
    ops[OP_ADD] += 1
    ops[OP_MUL] += 1
    ops[OP_CMP] += 2
    if Q == 0.0:  # B == 0 and disc == 0: C == 0, the double root t = 0
        r1 = 0.0
        r2 = 0.0
        p1 = ROOT_PAD
        p2 = ROOT_PAD
    else:
        r1 = Q / A
        r2 = C / Q
        # relative error of Q (the sqrt's error plus rounding), carried to both roots
        rel = (0.5 * serr + 2.0 * _EPS * abs(Q)) / abs(Q) + 4.0 * _EPS
        p1 = rel * abs(r1) + ROOT_PAD * (1.0 + abs(r1))
        p2 = rel * abs(r2) + ROOT_PAD * (1.0 + abs(r2))
        ops[OP_RCP] += 3
        ops[OP_MUL] += 5
        ops[OP_MADD] += 5
        if not (r1 == r1 and r2 == r2):  # 0 * inf from an underflowed coefficient
            return lo, hi
    if r1 <= r2:
        ra, pa, rb, pb = r1, p1, r2, p2
    else:
        ra, pa, rb, pb = r2, p2, r1, p1
    ops[OP_CMP] += 1
    if A < 0.0:  # non-negative between the roots
        ops[OP_CMP] += 3
        return max(lo, _or(ra - pa, -np.inf)), min(hi, _or(rb + pb, np.inf))
    # A > 0: non-negative on (-inf, ra] and [rb, inf)
    left = _or(ra + pa, np.inf)
    right = _or(rb - pb, -np.inf)
    ops[OP_ADD] += 2
    ops[OP_CMP] += 4
    if left >= right:
        return lo, hi
    start = lo if left >= lo else right
    end = hi if right <= hi else left
    return max(lo, start), min(hi, end)


@nb.njit(cache=True)
def quadratic_time_interval(edge_f, edge_g, edge_h, edge_abs, tri, x0, x1, y0, y1, lo, hi, ops):
    """Narrow [lo, hi] to the times at which all three moving edges of ``tri``
    can admit a point of the tile [x0, x1] x [y0, y1].

    The quadratic alternative to the linearized moving-edge test of Munkberg11 §4.2:
    the edge equations n_k(t) = f t^2 + g t + h (Gribel10 §4.1, eq. 3-5) are
    solved exactly per tile, the time intervals taken from their roots.
    ``edge_f``, ``edge_g``, ``edge_h`` are the facing-normalized (N,3,3)
    coefficients (components x, y, 1); ``edge_abs`` bounds per component the
    magnitude of the products behind them (see ``TriangleTable``), which sets
    the float32 margin. Returns (lo, hi), empty when lo > hi;
    conservative: every t in [lo, hi] at which some point of the tile is on
    the inner side of all three edges (up to float32 vertex rounding) is kept.
    Non-finite input returns [lo, hi] unchanged.
    """
    in_lo = lo
    in_hi = hi
    ops[OP_CMP] += 1
    if not (lo <= hi):
        return lo, hi
    if not (_finite(x0) and _finite(x1) and _finite(y0) and _finite(y1) and _finite(lo) and _finite(hi)):
        return in_lo, in_hi
    for k in range(3):
        for c in range(3):
            if not (_finite(edge_f[tri, k, c]) and _finite(edge_g[tri, k, c]) and _finite(edge_h[tri, k, c])):
                return in_lo, in_hi
    ax = max(abs(x0), abs(x1))
    ay = max(abs(y0), abs(y1))
    wx = x1 - x0
    wy = y1 - y0
    ops[OP_CMP] += 2
    ops[OP_ADD] += 2
    for k in range(3):
        fx = edge_f[tri, k, 0]
        fy = edge_f[tri, k, 1]
        fw = edge_f[tri, k, 2]
        gx = edge_g[tri, k, 0]
        gy = edge_g[tri, k, 1]
        gw = edge_g[tri, k, 2]
        hx = edge_h[tri, k, 0]
        hy = edge_h[tri, k, 1]
        hw = edge_h[tri, k, 2]
        sx = max(abs(fx) + abs(gx) + abs(hx), edge_abs[tri, k, 0])
        sy = max(abs(fy) + abs(gy) + abs(hy), edge_abs[tri, k, 1])
        sw = max(abs(fw) + abs(gw) + abs(hw), edge_abs[tri, k, 2])
        # float32 margin, the largest over the tile (valid for every corner)
        marg = F32_REL * (sx * ax + sy * ay + sw)
        ops[OP_ADD] += 6
        ops[OP_MADD] += 2
        ops[OP_MUL] += 1
        # which x / y sides of the tile can attain the maximum of e_k
        use_x0 = True
        use_x1 = True
        mn, mx = _component_range(fx, gx, hx, lo, hi, ops)
        tol = SIGN_TOL * sx
        if mn >= -tol:
            use_x0 = False
            marg += 2.0 * tol * wx  # a component >= -tol costs at most tol * width
        elif mx <= tol:
            use_x1 = False
            marg += 2.0 * tol * wx
        use_y0 = True
        use_y1 = True
        mn, mx = _component_range(fy, gy, hy, lo, hi, ops)
        tol = SIGN_TOL * sy
        if mn >= -tol:
            use_y0 = False
            marg += 2.0 * tol * wy
        elif mx <= tol:
            use_y1 = False
            marg += 2.0 * tol * wy
        ops[OP_MUL] += 2
        ops[OP_MADD] += 2
        ops[OP_CMP] += 4
        e_lo = np.inf
        e_hi = -np.inf
        for cx in range(2):
            if (cx == 0 and not use_x0) or (cx == 1 and not use_x1):
                continue
            x = x0 if cx == 0 else x1
            for cy in range(2):
                if (cy == 0 and not use_y0) or (cy == 1 and not use_y1):
                    continue
                y = y0 if cy == 0 else y1
                A = fx * x + fy * y + fw
                B = gx * x + gy * y + gw
                C = hx * x + hy * y + hw + marg
                ops[OP_MADD] += 6
                ops[OP_ADD] += 1
                if not (_finite(A) and _finite(B) and _finite(C)):  # overflow
                    return in_lo, in_hi
                a, b = _nonneg_hull(A, B, C, lo, hi, ops)
                if not (a == a and b == b):
                    return in_lo, in_hi
                if a <= b:
                    e_lo = min(e_lo, a)
                    e_hi = max(e_hi, b)
                    ops[OP_CMP] += 2
                ops[OP_CMP] += 1
        if not (_finite(e_lo) and _finite(e_hi)):
            if e_lo == np.inf and e_hi == -np.inf:  # no corner admits any t
                return 1.0, 0.0
            return in_lo, in_hi  # NaN or overflow: stay conservative
        lo = max(lo, e_lo)
        hi = min(hi, e_hi)
        ops[OP_CMP] += 3
        if lo > hi:
            return 1.0, 0.0
    return lo, hi
