"""Sample tester: the exact 5D inside test for the samples of each tile.

Implements docs/pipeline.md §2.5. For each pixel of a surviving tile, the samples
whose t lies in t^ form a contiguous range of the pixel's t-ordered samples
(a binary-search range lookup, Munkberg11 §5); those whose (u, v) also lie in
(u^, v^) get the exact test at their own (x, y, u, v, t):

* vertices lerped to t and shifted by the lens: p_k = (X + u LX, Y + v LY, W)
  (Wu13 §3.1);
* 2DH edge functions e_k = (p_j x p_i) . (x, y, 1) (Olano and Greer; Gribel10 eq. 3
  at a fixed t) and the orientation D = p_0 . (p_2 x p_1);
* inside when every e_k has the sign of D; a zero e_k counts only on a
  top-left edge (normal (a, b) with a > 0, or a == 0 and b > 0, after
  orienting by D), so samples on a shared edge or vertex are covered exactly
  once (Davidovic12 §3.4);
* perspective-correct barycentrics b_k = e_k / sum(e) and depth
  z/w = sum(e_k z_k) / D (Gribel10 eq. 10-13), clipped to [-1, 1] (near and far).

Arithmetic is float32, as in hardware; the computation is bit-for-bit the
same for the two triangles that share an edge, which makes it watertight.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numba as nb
import numpy as np

from pipeline_sim.definitions import COMMON, N_OPS, OP_CMP, OP_MADD, OP_MUL, OP_RCP
from pipeline_sim.records import SAMPLE
from units.made_ahead import MadeAhead

# its events, in the order of the kernel's event vector, and what each counts
EVENT_MEANINGS = {
    "samples_tested": "samples inside-tested",
    "samples_covered": "samples found covered",
    "samples_in_range": "samples within the tile's time and lens intervals",
    "pixels_visited": "pixels whose sample range was looked up",
    "tests_2d": "inside tests of static, focused triangles",
    "tests_3d_xyt": "inside tests in x, y, t",
    "tests_4d_xyuv": "inside tests in x, y, u, v",
    "tests_5d": "inside tests in all five dimensions",
}
EVENTS = tuple(EVENT_MEANINGS)
EV_TESTED, EV_COVERED, EV_INRANGE, EV_PIXELS, EV_2D, EV_3D, EV_4D, EV_5D = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): all, since its input is what z-cull passes, and z-cull
# tests against the depth the ROP has refreshed by that simulated time
TIMING_DEPENDENT = COMMON + EVENTS

# arithmetic of one inside test by dimension (index: 0 = 2D, 1 = 3D xyt, 2 =
# 4D xyuv, 3 = 5D): vertex positions at the sample (none in 2D: the edges are
# set up once per tile; t: 3 madd for X, Y, W per vertex; lens: 2 madd per
# X, Y; both: 3 + 3 + 1 per vertex), the three edge normals (9 mul + 9 madd,
# none in 2D), the orientation D (1 mul + 2 madd) and three edge values
# (2 madd each)
TEST_OPS_MADD = (6, 9 + 9 + 2 + 6, 6 + 9 + 2 + 6, 21 + 9 + 2 + 6)
TEST_OPS_MUL = (0, 9 + 1, 9 + 1, 9 + 1)
# arithmetic of one covered sample (barycentrics and depth)
COVER_OPS_RCP = 1
COVER_OPS_MUL = 4
COVER_OPS_MADD = 3 + 3


@nb.njit(cache=True)
def _top_left(a, b):
    return a > 0.0 or (a == 0.0 and b > 0.0)


@nb.njit(cache=True)
def _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2):
    """Edge k opposite vertex k: n_k = p_j x p_i, (i, j) = (k+1, k+2) mod 3, and
    the orientation D = p0 . (p2 x p1) (Gribel10 eq. 3 at fixed t; Olano and Greer)."""
    a0 = Y2 * W1 - W2 * Y1
    b0 = W2 * X1 - X2 * W1
    c0 = X2 * Y1 - Y2 * X1
    a1 = Y0 * W2 - W0 * Y2
    b1 = W0 * X2 - X0 * W2
    c1 = X0 * Y2 - Y0 * X2
    a2 = Y1 * W0 - W1 * Y0
    b2 = W1 * X0 - X1 * W0
    c2 = X1 * Y0 - Y1 * X0
    D = X0 * a0 + Y0 * b0 + W0 * c0
    return a0, b0, c0, a1, b1, c1, a2, b2, c2, D


MISS = (False, np.float32(0.0), np.float32(0.0), np.float32(0.0), np.float32(0.0))


@nb.njit(cache=True, inline="always")
def _decide(a0, b0, c0, a1, b1, c1, a2, b2, c2, D, X0, Y0, W0, Z0, X1, Y1, W1, Z1, X2, Y2, W2, Z2,
            x, y, backface_culling, eps):
    """Inside decision, barycentrics and depth of one sample at (x, y).

    Edge functions are evaluated in float32; a sample within the float32 error
    bound ``eps`` of an edge is re-evaluated in float64 from the same float32
    vertices (products of two float32 are exact), so the decision matches
    exact arithmetic: shared edges (exactly negated functions) and shared
    vertices are covered once. Ties follow the top-left rule (Davidovic12 §3.4).
    """
    e0 = np.float64(a0 * x + b0 * y + c0)
    e1 = np.float64(a1 * x + b1 * y + c1)
    e2 = np.float64(a2 * x + b2 * y + c2)
    fa0, fb0, fa1, fb1, fa2, fb2 = (np.float64(a0), np.float64(b0), np.float64(a1), np.float64(b1),
                                    np.float64(a2), np.float64(b2))
    if abs(e0) <= eps or abs(e1) <= eps or abs(e2) <= eps:
        g = _edges(np.float64(X0), np.float64(Y0), np.float64(W0), np.float64(X1), np.float64(Y1),
                   np.float64(W1), np.float64(X2), np.float64(Y2), np.float64(W2))
        xd = np.float64(x)
        yd = np.float64(y)
        fa0, fb0, fa1, fb1, fa2, fb2 = g[0], g[1], g[3], g[4], g[6], g[7]
        e0 = g[0] * xd + g[1] * yd + g[2]
        e1 = g[3] * xd + g[4] * yd + g[5]
        e2 = g[6] * xd + g[7] * yd + g[8]
    if D == 0.0 or (backface_culling and D < 0.0):
        return MISS
    if D < 0.0:
        e0, e1, e2 = -e0, -e1, -e2
        fa0, fa1, fa2 = -fa0, -fa1, -fa2
        fb0, fb1, fb2 = -fb0, -fb1, -fb2
    if e0 < 0.0 or e1 < 0.0 or e2 < 0.0:
        return MISS
    if ((e0 == 0.0 and not _top_left(fa0, fb0)) or (e1 == 0.0 and not _top_left(fa1, fb1))
            or (e2 == 0.0 and not _top_left(fa2, fb2))):
        return MISS
    tot = e0 + e1 + e2
    # z/w = sum(e_k Z_k) / sum(e_k W_k) (the denominator is |D| in exact
    # arithmetic; summing non-negative e_k avoids D's cancellation)
    den = e0 * W0 + e1 * W1 + e2 * W2
    if tot == 0.0 or den == 0.0:
        return MISS
    z = np.float32((e0 * Z0 + e1 * Z1 + e2 * Z2) / den)
    if not (z >= -1.0 and z <= 1.0):
        return MISS
    inv = 1.0 / tot
    return True, np.float32(e0 * inv), np.float32(e1 * inv), np.float32(e2 * inv), z


@nb.njit(cache=True)
def _at(p0, d, l0, dl, t, u):
    """A vertex coordinate at time t and lens coordinate u (Wu13 §3.1)."""
    return p0 + t * d + u * (l0 + t * dl)


@nb.njit(cache=True)
def inside_test(p0, dp, l0, dl, tri, x, y, t, u, v, backface_culling, edge_eps):
    """Exact 5D test of one sample; returns (covered, b0, b1, b2, z_ndc).

    Vertices at (t, u, v) are computed in float32 and taken as exact inputs;
    see ``_decide`` for the decision itself.
    """
    X0 = _at(p0[tri, 0, 0], dp[tri, 0, 0], l0[tri, 0, 0], dl[tri, 0, 0], t, u)
    Y0 = _at(p0[tri, 0, 1], dp[tri, 0, 1], l0[tri, 0, 1], dl[tri, 0, 1], t, v)
    W0 = p0[tri, 0, 3] + t * dp[tri, 0, 3]
    Z0 = p0[tri, 0, 2] + t * dp[tri, 0, 2]
    X1 = _at(p0[tri, 1, 0], dp[tri, 1, 0], l0[tri, 1, 0], dl[tri, 1, 0], t, u)
    Y1 = _at(p0[tri, 1, 1], dp[tri, 1, 1], l0[tri, 1, 1], dl[tri, 1, 1], t, v)
    W1 = p0[tri, 1, 3] + t * dp[tri, 1, 3]
    Z1 = p0[tri, 1, 2] + t * dp[tri, 1, 2]
    X2 = _at(p0[tri, 2, 0], dp[tri, 2, 0], l0[tri, 2, 0], dl[tri, 2, 0], t, u)
    Y2 = _at(p0[tri, 2, 1], dp[tri, 2, 1], l0[tri, 2, 1], dl[tri, 2, 1], t, v)
    W2 = p0[tri, 2, 3] + t * dp[tri, 2, 3]
    Z2 = p0[tri, 2, 2] + t * dp[tri, 2, 2]
    a0, b0, c0, a1, b1, c1, a2, b2, c2, D = _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2)
    return _decide(a0, b0, c0, a1, b1, c1, a2, b2, c2, D, X0, Y0, W0, Z0, X1, Y1, W1, Z1, X2, Y2, W2, Z2,
                   x, y, backface_culling, edge_eps[tri])

@nb.njit(cache=True)
def _f32_at_least(a):
    """The smallest float32 >= a: for float32 t, t >= a exactly when t >= this."""
    f = np.float32(a)
    if f < a:
        f = np.nextafter(f, np.float32(np.inf))
    return f


@nb.njit(cache=True)
def _f32_at_most(a):
    """The largest float32 <= a."""
    f = np.float32(a)
    if f > a:
        f = np.nextafter(f, np.float32(-np.inf))
    return f


# Pass-1 arithmetic of the inside test (``kind``): a static, pinhole
# triangle's edge functions are set up once per triangle, and a static,
# defocused one's vertices are computed at each sample's (u, v) without the
# time terms (its motion terms are +-0: dropping them changes at most the
# sign of a zero result, never a non-zero value or a comparison, for finite
# t; a non-finite t, which ``_decide`` rejects, may only be kept); any other
# triangle's vertices are computed at each sample's (t, u, v) with the full
# 5D formula that ``_decide`` evaluates. (A separate xyt formula would save
# less: moving triangles keep most of the terms.) With vertices per sample,
# pass 1 takes each edge value in the vertex form of ``_keep`` (12
# multiplications instead of 30 for the normals, the values and D).
K_2D, K_XYUV, K_5D = 0, 2, 3
F32_MAX = float(np.finfo(np.float32).max)


@nb.njit(cache=True, inline="always")
def _keep(kind, t, u, v, x, y, c, n0, n1, n2):
    """Pass 1's test of one sample: False when an edge excludes it for certain.

    ``c`` holds the triangle's float32 constants (see ``_constants``); ``n_k``
    is minus the tolerance of edge k (``_tolerances``). A static, pinhole
    triangle's float32 edge values are ``_decide``'s own: oriented by D, one
    below ``n_k`` is outside in float32 and in its float64 re-test alike.
    Otherwise pass 1 computes the vertices as ``_decide`` does (without the
    time terms for ``K_XYUV``, see above), then each edge value in vertex
    form: with A_i = X_i - x W_i and B_i = Y_i - y W_i,
    e_k = B_i A_j - A_i B_j, (i, j) = (k + 1, k + 2) mod 3, which is
    (p_j x p_i) . (x, y, 1) in exact arithmetic though rounded differently;
    ``n_k`` then bounds both roundings, and the sample is kept when its three
    values reach ``n_k`` with one sign or the other (no D: whichever sign D
    has, a covered sample's values all have it)."""
    if kind == K_2D:
        sg = c[39]
        e0 = (c[30] * x + c[31] * y + c[32]) * sg
        e1 = (c[33] * x + c[34] * y + c[35]) * sg
        e2 = (c[36] * x + c[37] * y + c[38]) * sg
    else:
        if kind == K_XYUV:
            X0 = c[0] + u * c[18]
            X1 = c[1] + u * c[19]
            X2 = c[2] + u * c[20]
            Y0 = c[3] + v * c[21]
            Y1 = c[4] + v * c[22]
            Y2 = c[5] + v * c[23]
            W0 = c[6]
            W1 = c[7]
            W2 = c[8]
        else:
            X0 = _at(c[0], c[9], c[18], c[24], t, u)
            X1 = _at(c[1], c[10], c[19], c[25], t, u)
            X2 = _at(c[2], c[11], c[20], c[26], t, u)
            Y0 = _at(c[3], c[12], c[21], c[27], t, v)
            Y1 = _at(c[4], c[13], c[22], c[28], t, v)
            Y2 = _at(c[5], c[14], c[23], c[29], t, v)
            W0 = c[6] + t * c[15]
            W1 = c[7] + t * c[16]
            W2 = c[8] + t * c[17]
        A0 = X0 - x * W0
        A1 = X1 - x * W1
        A2 = X2 - x * W2
        B0 = Y0 - y * W0
        B1 = Y1 - y * W1
        B2 = Y2 - y * W2
        e0 = B1 * A2 - A1 * B2
        e1 = B2 * A0 - A2 * B0
        e2 = B0 * A1 - A0 * B1
        return ((e0 >= n0) & (e1 >= n1) & (e2 >= n2)) | ((e0 <= -n0) & (e1 <= -n1) & (e2 <= -n2))
    return (e0 >= n0) & (e1 >= n1) & (e2 >= n2)


@nb.njit(cache=True, inline="always")
def _mark_range_fused(kind, n, k0, st, su, sv, ax, ay, cand, ta, tb, ua, ub, va, vb, c, n0, n1, n2):
    """The interval test and pass 1 in one pass over the contiguous samples
    ``k0 + i``, i < n (runs expected to lie mostly in the intervals, or
    samples packed beforehand, with unbounded intervals): candidates
    (``cand[i]``) are the samples in the intervals that ``_keep`` keeps.
    Branch-free, unsigned indices (no negative-index checks) and int32
    counts (an int64 one halves the vector width): numba vectorizes it.
    Returns (in t^, in all intervals, candidates)."""
    n_t = np.int32(0)
    n_a = np.int32(0)
    nc = np.int32(0)
    for i in range(n):
        k = np.uint64(k0 + i)
        t = st[k]
        u = su[k]
        v = sv[k]
        in_t = (t >= ta) & (t <= tb)
        in_a = in_t & (u >= ua) & (u <= ub) & (v >= va) & (v <= vb)
        keep = _keep(kind, t, u, v, ax[k], ay[k], c, n0, n1, n2) & in_a
        cand[i] = keep
        n_t = np.int32(n_t + np.int32(in_t))
        n_a = np.int32(n_a + np.int32(in_a))
        nc = np.int32(nc + np.int32(keep))
    return n_t, n_a, nc


@nb.njit(cache=True, inline="always")
def _intervals(n, k0, st, su, sv, msk, ta, tb, ua, ub, va, vb):
    """Interval test of the contiguous samples ``k0 + i``, i < n, into ``msk[i]``;
    (in t^, in all intervals) as int32 counts."""
    n_t = np.int32(0)
    n_a = np.int32(0)
    for i in range(n):
        k = np.uint64(k0 + i)
        t = st[k]
        u = su[k]
        v = sv[k]
        in_t = (t >= ta) & (t <= tb)
        in_a = in_t & (u >= ua) & (u <= ub) & (v >= va) & (v <= vb)
        msk[i] = in_a
        n_t = np.int32(n_t + np.int32(in_t))
        n_a = np.int32(n_a + np.int32(in_a))
    return n_t, n_a


@nb.njit(cache=True, inline="always")
def _intervals_extra(n, k0, st, su, sv, stup, tup_mask, msk, ta, tb, ua, ub, va, vb, ln, mk):
    """``_intervals`` with two-stage culling's time lines ``ln`` (t >= c + s u,
    t <= c + s u, then the same in v; Wu13 §3.4) and Interleave UVT's tuple
    mask ``mk`` (tuple indices ``stup[k & tup_mask]``)."""
    lc, ls, hc, hs, mc, ms, kc, ks = ln[0], ln[1], ln[2], ln[3], ln[4], ln[5], ln[6], ln[7]
    n_t = np.int32(0)
    n_a = np.int32(0)
    for i in range(n):
        k = np.uint64(k0 + i)
        t = st[k]
        u = su[k]
        v = sv[k]
        in_t = (t >= ta) & (t <= tb)
        in_a = in_t & (u >= ua) & (u <= ub) & (v >= va) & (v <= vb)
        in_a = (in_a & (t >= lc + ls * u) & (t <= hc + hs * u) & (t >= mc + ms * v) & (t <= kc + ks * v)
                & (((mk >> np.uint64(stup[k & tup_mask])) & np.uint64(1)) != 0))
        msk[i] = in_a
        n_t = np.int32(n_t + np.int32(in_t))
        n_a = np.int32(n_a + np.int32(in_a))
    return n_t, n_a


@nb.njit(cache=True)
def _tolerances(c, ta, tb, ua, ub, va, vb, x_max, y_max, eps, kind):
    """Per-edge pass-1 tolerances of a tile for ``_keep``'s ``kind``:
    (-tol_0, -tol_1, -tol_2, every), ``every`` when no finite bound holds.

    ``_decide`` re-tests in float64 every sample with an |e_k| <= eps, from
    the same float32 vertices and (x, y). The float32 value of edge k differs
    from that float64 value by at most 5.01 u (A_k |x| + B_k |y| + C_k),
    u = 2^-24, where A_k, B_k, C_k are the sums of the magnitudes of the two
    products forming the edge's coefficients a_k, b_k, c_k (3 roundings in
    evaluating e, 2 in each coefficient; the float64 re-test's own error is
    below 4 * 2^-53 of the same sum). Over a tile, |X|, |Y|, |W| of each
    vertex are bounded from the intervals, and |x| <= x_max, |y| <= y_max.
    delta_k is that bound with the factor 8 u, plus a tiny absolute term for
    float32 underflow; it bounds both values' distance from the exact E_k.

    ``K_2D`` (``_decide``'s own float32 values): tol_k = min(eps, delta_k). A
    sample whose oriented float32 value is below -delta_k is below 0 in
    float64 too, so ``_decide`` rejects it on either path; below -eps, pass 1
    always excluded it (a NaN or an infinite delta_k: eps).

    The vertex form: a sample ``_decide`` accepts has sigma E_k >= -delta_k
    for sigma the sign of its D (its float32 or its float64 values, whichever
    it used, are >= 0 oriented). The vertex form's value differs from E_k by
    at most 6.01 u (MB_i MA_j + MA_i MB_j), MA_i = |X_i| + x_max |W_i| and
    MB_i = |Y_i| + y_max |W_i| bounding |A_i| and |B_i| (2 roundings in each
    of A_i and B_i, 3 in the difference of their products); gamma_k is that
    bound with the factor 8 u, and tol_k = delta_k + gamma_k. ``every`` when
    a tolerance is not finite, or when MA_i, MB_i or a sum of products
    MB_i MA_j + MA_i MB_j may reach float32's largest value: the vertex form
    could then overflow to inf or NaN, which no tolerance keeps, where
    ``_decide``'s values (without its x y W_i W_j terms, which cancel) stay
    finite. Pass 1 then keeps every sample in the intervals. Either way only
    which samples reach ``_decide`` changes, never its answer.
    """
    T = max(abs(np.float64(ta)), abs(np.float64(tb)))
    U = max(abs(np.float64(ua)), abs(np.float64(ub)))
    V = max(abs(np.float64(va)), abs(np.float64(vb)))
    mx0 = abs(np.float64(c[0])) + T * abs(np.float64(c[9])) + U * (abs(np.float64(c[18])) + T * abs(np.float64(c[24])))
    mx1 = abs(np.float64(c[1])) + T * abs(np.float64(c[10])) + U * (abs(np.float64(c[19])) + T * abs(np.float64(c[25])))
    mx2 = abs(np.float64(c[2])) + T * abs(np.float64(c[11])) + U * (abs(np.float64(c[20])) + T * abs(np.float64(c[26])))
    my0 = abs(np.float64(c[3])) + T * abs(np.float64(c[12])) + V * (abs(np.float64(c[21])) + T * abs(np.float64(c[27])))
    my1 = abs(np.float64(c[4])) + T * abs(np.float64(c[13])) + V * (abs(np.float64(c[22])) + T * abs(np.float64(c[28])))
    my2 = abs(np.float64(c[5])) + T * abs(np.float64(c[14])) + V * (abs(np.float64(c[23])) + T * abs(np.float64(c[29])))
    mw0 = abs(np.float64(c[6])) + T * abs(np.float64(c[15]))
    mw1 = abs(np.float64(c[7])) + T * abs(np.float64(c[16]))
    mw2 = abs(np.float64(c[8])) + T * abs(np.float64(c[17]))
    # float32 vertex values may exceed these real-valued bounds by a few roundings
    k = 8.0 * 2.0 ** -24 * (1.0 + 1e-5) ** 3
    ab = 1e-30 * (1.0 + x_max + y_max)
    d0 = k * ((my2 * mw1 + mw2 * my1) * x_max + (mw2 * mx1 + mx2 * mw1) * y_max + (mx2 * my1 + my2 * mx1)) + ab
    d1 = k * ((my0 * mw2 + mw0 * my2) * x_max + (mw0 * mx2 + mx0 * mw2) * y_max + (mx0 * my2 + my0 * mx2)) + ab
    d2 = k * ((my1 * mw0 + mw1 * my0) * x_max + (mw1 * mx0 + mx1 * mw0) * y_max + (mx1 * my0 + my1 * mx0)) + ab
    if kind == K_2D:
        # (a NaN or an infinite bound falls back to eps)
        f0 = np.float32(d0) * np.float32(1.0001)
        f1 = np.float32(d1) * np.float32(1.0001)
        f2 = np.float32(d2) * np.float32(1.0001)
        return -(f0 if f0 < eps else eps), -(f1 if f1 < eps else eps), -(f2 if f2 < eps else eps), False
    ma0 = mx0 + x_max * mw0
    ma1 = mx1 + x_max * mw1
    ma2 = mx2 + x_max * mw2
    mb0 = my0 + y_max * mw0
    mb1 = my1 + y_max * mw1
    mb2 = my2 + y_max * mw2
    s0 = mb1 * ma2 + ma1 * mb2
    s1 = mb2 * ma0 + ma2 * mb0
    s2 = mb0 * ma1 + ma0 * mb1
    under = 1e-30 * (1.0 + ma0 + ma1 + ma2 + mb0 + mb1 + mb2)
    f0 = np.float32(d0 + k * s0 + under) * np.float32(1.0001)
    f1 = np.float32(d1 + k * s1 + under) * np.float32(1.0001)
    f2 = np.float32(d2 + k * s2 + under) * np.float32(1.0001)
    # a product or a difference of products that may leave float32's range would make the value inf or NaN,
    # which no tolerance keeps (the bounds here are float64 and grow with every input, NaN included)
    top = max(s0, s1, s2, ma0, ma1, ma2, mb0, mb1, mb2) * 1.0001
    every = not (np.isfinite(f0) and np.isfinite(f1) and np.isfinite(f2) and top < F32_MAX)
    return -f0, -f1, -f2, every


@nb.njit(cache=True, inline="always")
def _decide_lanes(static, n, pt, pu, pv, px, py, c, z3, backface_culling, eps, pok, pz, pb0, pb1, pb2):
    """Pass 2 on packed candidates: ``_decide`` for each (``inside_test``'s
    arithmetic at the sample's (t, u, v), the float64 re-test near edges, the
    top-left rule, depth), written branch-free so that numba vectorizes it:
    both the float32 and the float64 edge values are computed and the one
    ``_decide`` would use is selected; a zero denominator only yields a
    value that ``pok`` discards (the kernel uses numpy's error model).
    Outputs per candidate: covered (``pok``), depth, barycentrics.
    With ``static`` (a literal) the vertices are the triangle's constants
    (see ``_static_exact``), which numba hoists out of the loop."""
    one = np.float32(1.0)
    for q in range(n):
        x = px[q]
        y = py[q]
        if static:
            X0 = c[0]
            Y0 = c[3]
            W0 = c[6]
            Z0 = z3[0]
            X1 = c[1]
            Y1 = c[4]
            W1 = c[7]
            Z1 = z3[1]
            X2 = c[2]
            Y2 = c[5]
            W2 = c[8]
            Z2 = z3[2]
        else:
            t = pt[q]
            u = pu[q]
            v = pv[q]
            X0 = _at(c[0], c[9], c[18], c[24], t, u)
            Y0 = _at(c[3], c[12], c[21], c[27], t, v)
            W0 = c[6] + t * c[15]
            Z0 = z3[0] + t * z3[3]
            X1 = _at(c[1], c[10], c[19], c[25], t, u)
            Y1 = _at(c[4], c[13], c[22], c[28], t, v)
            W1 = c[7] + t * c[16]
            Z1 = z3[1] + t * z3[4]
            X2 = _at(c[2], c[11], c[20], c[26], t, u)
            Y2 = _at(c[5], c[14], c[23], c[29], t, v)
            W2 = c[8] + t * c[17]
            Z2 = z3[2] + t * z3[5]
        a0, b0, c0, a1, b1, c1, a2, b2, c2, D = _edges(X0, Y0, W0, X1, Y1, W1, X2, Y2, W2)
        f0 = np.float64(a0 * x + b0 * y + c0)
        f1 = np.float64(a1 * x + b1 * y + c1)
        f2 = np.float64(a2 * x + b2 * y + c2)
        near = (abs(f0) <= eps) | (abs(f1) <= eps) | (abs(f2) <= eps)
        g0, g1, g2, g3, g4, g5, g6, g7, g8, _ = _edges(np.float64(X0), np.float64(Y0), np.float64(W0),
                                                       np.float64(X1), np.float64(Y1), np.float64(W1),
                                                       np.float64(X2), np.float64(Y2), np.float64(W2))
        xd = np.float64(x)
        yd = np.float64(y)
        e0 = g0 * xd + g1 * yd + g2 if near else f0
        e1 = g3 * xd + g4 * yd + g5 if near else f1
        e2 = g6 * xd + g7 * yd + g8 if near else f2
        fa0 = g0 if near else np.float64(a0)
        fb0 = g1 if near else np.float64(b0)
        fa1 = g3 if near else np.float64(a1)
        fb1 = g4 if near else np.float64(b1)
        fa2 = g6 if near else np.float64(a2)
        fb2 = g7 if near else np.float64(b2)
        flip = D < 0.0
        ok = (D != 0.0) & ((backface_culling & flip) ^ True)
        e0 = -e0 if flip else e0
        e1 = -e1 if flip else e1
        e2 = -e2 if flip else e2
        fa0 = -fa0 if flip else fa0
        fa1 = -fa1 if flip else fa1
        fa2 = -fa2 if flip else fa2
        fb0 = -fb0 if flip else fb0
        fb1 = -fb1 if flip else fb1
        fb2 = -fb2 if flip else fb2
        ok = ok & (((e0 < 0.0) | (e1 < 0.0) | (e2 < 0.0)) ^ True)
        ok = ok & ((e0 != 0.0) | (fa0 > 0.0) | ((fa0 == 0.0) & (fb0 > 0.0)))
        ok = ok & ((e1 != 0.0) | (fa1 > 0.0) | ((fa1 == 0.0) & (fb1 > 0.0)))
        ok = ok & ((e2 != 0.0) | (fa2 > 0.0) | ((fa2 == 0.0) & (fb2 > 0.0)))
        tot = e0 + e1 + e2
        den = e0 * W0 + e1 * W1 + e2 * W2
        ok = ok & (tot != 0.0) & (den != 0.0)
        z = np.float32((e0 * Z0 + e1 * Z1 + e2 * Z2) / den)
        ok = ok & (z >= -1.0) & (z <= 1.0)
        inv = 1.0 / tot
        pok[q] = ok
        pz[q] = z
        pb0[q] = np.float32(e0 * inv)
        pb1[q] = np.float32(e1 * inv)
        pb2[q] = np.float32(e2 * inv)
    return one


# the set bytes of a uint64 holding eight 0/1 bytes, as an 8-bit pattern: (w * _BYTE_BITS) >> 56
_BYTE_BITS = np.uint64(0x0102040810204080)
# for each 8-bit pattern, the positions of its set bits (then padding) and their number
_LUT_POS = np.array([[i for i in range(8) if p >> i & 1] + [0] * (8 - bin(p).count("1")) for p in range(256)],
                    np.int32).ravel()
_LUT_POP = np.array([bin(p).count("1") for p in range(256)], np.int32)


# The passes' loops, compiled as functions of their own (the kernel calls
# them once per tile): inlined into the kernel, its many live values cost
# them registers; each dispatches on the kind so that every loop is
# specialized.


@nb.njit(cache=True)
def _pass1_fused(kind, n, k0, st, su, sv, ax, ay, cand, ta, tb, ua, ub, va, vb, c, n0, n1, n2):
    if kind == K_2D:
        return _mark_range_fused(K_2D, n, k0, st, su, sv, ax, ay, cand, ta, tb, ua, ub, va, vb, c, n0, n1, n2)
    if kind == K_XYUV:
        return _mark_range_fused(K_XYUV, n, k0, st, su, sv, ax, ay, cand, ta, tb, ua, ub, va, vb, c, n0, n1, n2)
    return _mark_range_fused(K_5D, n, k0, st, su, sv, ax, ay, cand, ta, tb, ua, ub, va, vb, c, n0, n1, n2)


@nb.njit(cache=True, error_model="numpy")
def _pass2(static, n, pt, pu, pv, px, py, c, z3, backface_culling, eps, pok, pz, pb0, pb1, pb2):
    if static:
        _decide_lanes(True, n, pt, pu, pv, px, py, c, z3, backface_culling, eps, pok, pz, pb0, pb1, pb2)
    else:
        _decide_lanes(False, n, pt, pu, pv, px, py, c, z3, backface_culling, eps, pok, pz, pb0, pb1, pb2)


@nb.njit(cache=True, inline="always")
def _put(o, q, b_tri, pix0, za, zb, nr, poff, psid, pz, pb0, pb1, pb2, out_tri, out_pix, out_sidx, out_z, out_b0,
         out_b1, out_b2, out_noread):
    """Covered candidate ``q`` of the batch out as covered sample ``o``."""
    out_tri[o] = b_tri
    out_pix[o] = pix0 + poff[q]
    out_sidx[o] = psid[q]
    # the true depth lies in z^; clamping removes float32 rounding so z-cull
    # decisions made on z^ agree with the ROP's
    out_z[o] = min(max(pz[q], za), zb)
    out_b0[o] = pb0[q]
    out_b1[o] = pb1[q]
    out_b2[o] = pb2[q]
    out_noread[o] = nr


@nb.njit(cache=True)
def _flush(n, nb, nq, b_tri, b_static, b_c, b_z3, backface_culling, b_eps, pt, pu, pv, px, py, pok, pz, pb0, pb1,
           pb2, poff, psid, ppix, rb_end, rb_pix0, rb_area, rb_za, rb_zb, rb_nr, cnt, order, out_tri, out_pix, out_sidx,
           out_z, out_b0, out_b1, out_b2, out_noread):
    """Pass 2 on a batch (the candidates of consecutive records of one
    triangle) and its covered samples out from record ``n``; returns the
    next free record."""
    nan = np.float32(np.nan)
    zero = np.float32(0.0)
    nq_pad = (nq + 7) // 8 * 8
    for q in range(nq, nq_pad):  # NaN fails every test
        pt[q] = nan
        pu[q] = zero
        pv[q] = zero
        px[q] = nan
        py[q] = nan
    _pass2(b_static, nq_pad, pt, pu, pv, px, py, b_c, b_z3, backface_culling, b_eps, pok, pz, pb0, pb1, pb2)
    # covered samples out, record by record, in pixel-major order (row,
    # column, sample) as a scan of the tile's pixels meets them: the
    # candidates come slot by slot, so a counting sort by pixel (stable) of
    # their indices in ``order``, then the outputs written in order
    q0 = 0
    for r in range(nb):
        q1 = rb_end[r]
        za = rb_za[r]
        zb = rb_zb[r]
        nr = rb_nr[r]
        pix0 = rb_pix0[r]
        area = rb_area[r]
        for p_ in range(area):
            cnt[p_] = 0
        for q in range(q0, q1):
            uq = np.uint64(q)
            if pok[uq]:
                cnt[np.uint64(ppix[uq])] += 1
        m = 0
        for p_ in range(area):
            c_ = cnt[p_]
            cnt[p_] = m
            m += c_
        for q in range(q0, q1):
            uq = np.uint64(q)
            if pok[uq]:
                kp = np.uint64(ppix[uq])
                o = np.uint64(cnt[kp])
                cnt[kp] = o + 1
                order[o] = q
        for o in range(m):
            _put(np.uint64(n + o), np.uint64(order[np.uint64(o)]), b_tri, pix0, za, zb, nr, poff, psid, pz, pb0, pb1,
                 pb2, out_tri, out_pix, out_sidx, out_z, out_b0, out_b1, out_b2, out_noread)
        n += m
        q0 = q1
    return n


@nb.njit(cache=True)
def _intervals_fn(n, k0, st, su, sv, msk, ta, tb, ua, ub, va, vb):
    return _intervals(n, k0, st, su, sv, msk, ta, tb, ua, ub, va, vb)


@nb.njit(cache=True)
def _intervals_extra_fn(n, k0, st, su, sv, stup, tup_mask, msk, ta, tb, ua, ub, va, vb, ln, mk):
    return _intervals_extra(n, k0, st, su, sv, stup, tup_mask, msk, ta, tb, ua, ub, va, vb, ln, mk)


@nb.njit(cache=True, inline="always")
def _triangle_constants(p0, dp, l0, dl, tri, tc):
    """Triangle ``tri``'s float32 constants into ``tc`` (46 entries), laid out as ``_keep`` reads them: X,
    Y, W of the vertices at t = 0 (0-8), their motion (9-17), the lens shifts of X and Y and their motion
    (18-29), the shutter-open 2D edges a, b, c (30-38) with D's sign (39), Z and its motion (40-45)."""
    for k in range(3):
        tc[k] = p0[tri, k, 0]
        tc[3 + k] = p0[tri, k, 1]
        tc[6 + k] = p0[tri, k, 3]
        tc[9 + k] = dp[tri, k, 0]
        tc[12 + k] = dp[tri, k, 1]
        tc[15 + k] = dp[tri, k, 3]
        tc[18 + k] = l0[tri, k, 0]
        tc[21 + k] = l0[tri, k, 1]
        tc[24 + k] = dl[tri, k, 0]
        tc[27 + k] = dl[tri, k, 1]
        tc[40 + k] = p0[tri, k, 2]
        tc[43 + k] = dp[tri, k, 2]
    # 2D path: vertices and edges once per tile (t, u, v do not matter)
    a0, b0, c0, a1, b1, c1, a2, b2, c2, D = _edges(tc[0], tc[3], tc[6], tc[1], tc[4], tc[7], tc[2], tc[5], tc[8])
    tc[30], tc[31], tc[32], tc[33], tc[34], tc[35], tc[36], tc[37], tc[38] = a0, b0, c0, a1, b1, c1, a2, b2, c2
    tc[39] = np.float32(1.0) if D > 0 else np.float32(-1.0)


@nb.njit(cache=True)
def triangle_constants(p0, dp, l0, dl, tri):
    """``_triangle_constants`` of triangle ``tri`` as a tuple of 40 (``_keep``'s ``c``; for tests)."""
    tc = np.zeros(46, np.float32)
    _triangle_constants(p0, dp, l0, dl, tri, tc)
    return _constants(tc)


@nb.njit(cache=True)
def _constants(tc):
    """The triangle's float32 constants as a tuple (layout: see ``_keep``)."""
    return (tc[0], tc[1], tc[2], tc[3], tc[4], tc[5], tc[6], tc[7], tc[8], tc[9], tc[10], tc[11], tc[12], tc[13],
            tc[14], tc[15], tc[16], tc[17], tc[18], tc[19], tc[20], tc[21], tc[22], tc[23], tc[24], tc[25], tc[26],
            tc[27], tc[28], tc[29], tc[30], tc[31], tc[32], tc[33], tc[34], tc[35], tc[36], tc[37], tc[38], tc[39])


@nb.njit(cache=True)
def _static_exact(p0, dp, l0, dl, tri):
    """Whether a static, pinhole triangle's vertices at any finite (t, u, v)
    are exactly its shutter-open vertices p0, so that pass 2 may hoist them:
    its motion and lens terms are +-0, so t * d and u * (l0 + t * dl) are +-0
    too, and adding +-0 leaves every value unchanged but a zero (whose sign
    it may flip): no coordinate of p0 may be zero."""
    for k in range(3):
        for c in range(4):
            if p0[tri, k, c] == 0 or dp[tri, k, c] != 0:
                return False
        for c in range(2):
            if l0[tri, k, c] != 0 or dl[tri, k, c] != 0:
                return False
    return True


@nb.njit(cache=True)
def _positions(words, n_words, out):
    """The positions (from 0) of the set bytes among the 0/1 bytes viewed as
    ``words[:n_words]``, into ``out`` (which needs 8 entries of slack); returns
    their number. Branch-free within a word."""
    m = np.uint64(0)
    for w in range(n_words):
        word = words[np.uint64(w)]
        if word != 0:
            p = ((word * _BYTE_BITS) >> np.uint64(56)) * np.uint64(8)
            b = np.int32(w * 8)
            for i in range(8):
                out[m + np.uint64(i)] = b + _LUT_POS[p + np.uint64(i)]
            m += np.uint64(_LUT_POP[p >> np.uint64(3)])
    return np.int64(m)


@nb.njit(cache=True, nogil=True)
def _tile_major(width, height, row0, spp, tile_size, ty0, ty1, x, y, u, v, t, tup, ax, ay, tu, tv, tt, ttup, slot_lo,
                slot_hi, stats):
    """The samples of tile rows ``ty0 .. ty1 - 1`` in the sample tester's
    tile-major, slot-major order, in one pass over them (``slot_lo``,
    ``slot_hi`` and ``stats`` cover those rows).

    Every tile's samples become contiguous, from ``base = (ty * tile_size *
    width + tx * tile_size * h) * spp`` (w x h: the tile's size, smaller at
    the right and bottom edges). Within the tile, pixel (r, c) sample s (its
    index in the pixel's t-ordered samples) goes to ``base + s * w * h + r *
    w + c``: slot by slot, so that a range of slots is a contiguous run.
    ``ax, ay`` are absolute: the pixel's float32 coordinates plus the
    offsets, exactly as the tester adds them (the rows start at image row
    ``row0``). ``slot_lo[s], slot_hi[s]``: the smallest and largest t of slot
    s over all pixels (NaN ignored), so a tile's t^ selects a contiguous range
    of slots that holds every sample with t in t^. ``stats``: the largest |x|
    and the largest |y| (each NaN if one is NaN), the smallest and largest u
    and v (NaN ignored; 0 included).

    Each pixel's samples are read in order and written a tile's area apart
    (into a block of 5 x 4 bytes a sample: 80 KB for a 4 x 4 tile at 256
    spp, which stays in cache while it fills).
    """
    for s in range(spp):
        slot_lo[s] = np.inf
        slot_hi[s] = -np.inf
    has_tup = tup.shape[0] == x.shape[0]
    zero = np.float32(0.0)
    mx = zero
    my = zero
    nan_x = False
    nan_y = False
    u_lo = zero
    u_hi = zero
    v_lo = zero
    v_hi = zero
    for ty in range(ty0, ty1):
        y0 = ty * tile_size
        h = min(tile_size, height - y0)
        for tx in range((width + tile_size - 1) // tile_size):
            x0 = tx * tile_size
            w = min(tile_size, width - x0)
            base = (y0 * width + x0 * h) * spp
            area = w * h
            for r in range(h):
                fy = np.float32(y0 + r + row0)
                for cl in range(w):
                    fx = np.float32(x0 + cl)
                    src = ((y0 + r) * width + x0 + cl) * spp
                    kp = base + r * w + cl
                    for s in range(spp):
                        j = src + s
                        k = kp + s * area
                        xs = x[j]
                        ys = y[j]
                        us = u[j]
                        vs = v[j]
                        tk = t[j]
                        ax[k] = fx + xs
                        ay[k] = fy + ys
                        tu[k] = us
                        tv[k] = vs
                        tt[k] = tk
                        slot_lo[s] = tk if tk < slot_lo[s] else slot_lo[s]
                        slot_hi[s] = tk if tk > slot_hi[s] else slot_hi[s]
                        nan_x |= xs != xs
                        nan_y |= ys != ys
                        a = abs(xs)
                        mx = a if a > mx else mx
                        a = abs(ys)
                        my = a if a > my else my
                        u_lo = us if us < u_lo else u_lo
                        u_hi = us if us > u_hi else u_hi
                        v_lo = vs if vs < v_lo else v_lo
                        v_hi = vs if vs > v_hi else v_hi
                    if has_tup:
                        for s in range(spp):
                            ttup[kp + s * area] = tup[src + s]
    stats[0] = np.nan if nan_x else mx
    stats[1] = np.nan if nan_y else my
    stats[2] = u_lo
    stats[3] = u_hi
    stats[4] = v_lo
    stats[5] = v_hi


@nb.njit(cache=True, nogil=True, error_model="numpy")
def sample_test_kernel(tri_ids, tile_x, tile_y, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, noread_in,
                       lines, masks, tile_size, width, height, spp, sx, sy, su, sv, st, stup, slot_lo, slot_hi,
                       uv_range, xy_max, row0,
                       p0, dp, l0, dl, edge_eps, backface_culling, specialize, first, start, covered,
                       out_tri, out_pix, out_sidx, out_z, out_b0, out_b1, out_b2, out_noread, ops, events):
    """Interval lookup on the tile's samples and exact inside tests (Munkberg11 §5; Gribel10 eq. 3, 10-13).

    The samples (x, y, u, v, t, tuple index) come tile by tile, slot-major
    within each tile (``_tile_major``). Per (triangle, tile) record:

    * the tile's t^ selects the slots that can hold a t in t^ (from the
      slots' t ranges over the frame, ``slot_lo``, ``slot_hi``): a range of
      them, a contiguous run of the tile's samples;
    * the interval test (t in t^, u in u^, v in v^ and, with two-stage
      culling or Interleave UVT, between the time lines and in the tuple
      mask) and pass 1: the float32 edge functions (in vertex form for a
      triangle whose vertices move or shift with the lens, ``_keep``),
      keeping as candidates the samples in the intervals that no edge
      excludes for certain (within a per-edge tolerance bounding float32
      rounding, ``_tolerances``). Both
      in one pass over the run unless u^ and v^ hold only a small share of
      the samples (``uv_range``: the samples' u and v range), else the
      interval test first and pass 1 on the samples in the intervals,
      packed;
    * pass 2, the full decision (``_decide_lanes``: ``_decide``'s float64
      re-test near edges, top-left ties, depth), on the packed candidates of
      consecutive records of one triangle at once (``_flush``), and the
      covered samples out in each record's pixel-major order (a counting
      sort by pixel).

    The passes are branch-free loops that numba vectorizes. A static,
    pinhole triangle's edge functions are set up once (a 2D test per sample
    in pass 1); other triangles' vertices are computed at each sample's
    (t, u, v). Results are bit-identical on every path (pass 2 evaluates
    exactly what ``_decide`` does, from the same vertices) and neighbours
    stay watertight. The modelled hardware looks the t-range up with a
    binary search on the t-ordered samples; its compares are counted as
    such. ``xy_max`` bounds |x| and |y| of every sample's offset in its
    pixel. The samples may be those of a screen region: rows from image row
    ``row0`` (a tile row), ``height`` of them; ``tile_y`` then counts tile
    rows from ``row0``, and the pixels written are numbered from the
    region's first pixel plus ``first``.

    It starts at record ``start`` with ``covered`` samples already written,
    and stops before a record whose covered samples might not fit in the
    outputs (a record needs room for a whole tile's samples after those
    pending). Returns (covered samples in the outputs, the record it
    stopped at: the number of records when done); the caller grows the
    outputs and calls again from there. Stopping between records changes no
    output (pass 2 may run on any run of whole records).
    """
    u_min, u_max, v_min, v_max = uv_range[0], uv_range[1], uv_range[2], uv_range[3]
    none = tri_ids.shape[0] * 0  # 0, not a literal: the callees compile once
    n = none + covered
    out_cap = out_tri.shape[0]
    tested = 0
    by_dims = np.zeros(4, np.int64)
    in_range = 0
    pixels = 0
    searches = 0
    nan = np.float32(np.nan)
    inf = np.float32(np.inf)
    zero = np.float32(0.0)
    tile_len = tile_size * tile_size * spp
    pad = 32  # packed arrays end on whole vector-loop iterations
    cap = (tile_len + pad + 7) // 8 * 8
    msk = np.zeros(cap, np.uint8)  # in the intervals, per sample of the tile's run
    mskw = msk.view(np.uint64)
    cand = np.zeros(cap, np.uint8)  # candidates (fused pass)
    candw = cand.view(np.uint64)
    pos = np.empty(cap + 8, np.int32)  # positions of set bytes
    ct = np.empty(cap, np.float32)  # samples in the intervals packed for pass 1
    cu = np.empty(cap, np.float32)
    cv = np.empty(cap, np.float32)
    cx = np.empty(cap, np.float32)
    cy = np.empty(cap, np.float32)
    cq = np.empty(cap, np.int32)  # their position in the tile
    cc = np.zeros(cap, np.uint8)  # candidates among them
    ccw = cc.view(np.uint64)
    # pass 2 runs on the candidates of consecutive records of one triangle
    # at once (a batch); their records' details wait in the rb_ arrays
    bcap = max(cap, 8192)
    pt = np.empty(bcap + 8, np.float32)  # candidates packed for pass 2
    pu = np.empty(bcap + 8, np.float32)
    pv = np.empty(bcap + 8, np.float32)
    px = np.empty(bcap + 8, np.float32)
    py = np.empty(bcap + 8, np.float32)
    poff = np.empty(bcap + 8, np.int32)  # their pixel's offset r * width + c from the tile's first pixel,
    psid = np.empty(bcap + 8, np.int32)  # sample index and
    ppix = np.empty(bcap + 8, np.int32)  # pixel in the tile r * w + c (the tables change with the tile's size)
    pok = np.empty(bcap + 8, np.bool_)  # pass 2's results
    pz = np.empty(bcap + 8, np.float32)
    pb0 = np.empty(bcap + 8, np.float32)
    pb1 = np.empty(bcap + 8, np.float32)
    pb2 = np.empty(bcap + 8, np.float32)
    rb_end = np.empty(bcap, np.int64)  # per record of the batch: end of its candidates,
    rb_pix0 = np.empty(bcap, np.int64)  # first pixel, pixels in the tile,
    rb_area = np.empty(bcap, np.int64)
    rb_za = np.empty(bcap, np.float32)  # depth range, noread flag
    rb_zb = np.empty(bcap, np.float32)
    rb_nr = np.empty(bcap, np.bool_)
    nb = none  # records in the batch
    nq = none  # candidates in the batch
    b_tri = none - 1
    b_static = none > 0  # False
    # per position in a w x h tile's slot-major run: the pixel's offset
    # r * width + c in the frame, the sample index, the pixel r * w + c in
    # the tile
    off_s = np.empty(tile_len, np.int32)
    sid_s = np.empty(tile_len, np.int32)
    pix_s = np.empty(tile_len, np.int32)
    cnt = np.empty(tile_size * tile_size, np.int64)  # covered samples per pixel of the tile
    order = np.empty(tile_len, np.int32)  # a record's covered candidates in pixel-major order
    cur_w = -1
    cur_h = -1
    tc = np.zeros(46, np.float32)  # the current triangle's constants (see _keep; Z at 40..45)
    ln = np.empty(8, np.float32)  # the current tile's time lines (two-stage culling)
    has_lines = lines.shape[0] == tri_ids.shape[0]
    has_masks = masks.shape[0] == tri_ids.shape[0]
    extra_tests = 0
    # without Interleave UVT masks: every tuple bit set, tuple index 0
    mk = np.uint64(0xFFFFFFFFFFFFFFFF)
    tup_mask = np.uint64(0xFFFFFFFFFFFFFFFF) if has_masks else np.uint64(0)
    prev = -1
    dims = 0
    kind = K_5D
    static = b_static
    c = _constants(tc)
    z3 = (tc[40], tc[41], tc[42], tc[43], tc[44], tc[45])
    b_c = c
    b_z3 = z3
    b_eps = np.float32(0.0)
    n_rec = tri_ids.shape[0]
    stop = n_rec
    for i in range(start, n_rec + 1):
        # ---- pass 2 on the batch: when the triangle changes, before the
        # buffers or the outputs could overflow, and at the end ---------------
        room = n + nq + tile_len <= out_cap
        if nb > 0 and (i == n_rec or tri_ids[i] != b_tri or nq + tile_len > bcap or not room):
            n = _flush(n, nb, nq, b_tri, b_static, b_c, b_z3, backface_culling, b_eps, pt, pu, pv, px, py, pok, pz,
                       pb0, pb1, pb2, poff, psid, ppix, rb_end, rb_pix0, rb_area, rb_za, rb_zb, rb_nr,
                       cnt, order, out_tri, out_pix, out_sidx, out_z, out_b0, out_b1, out_b2, out_noread)
            nb = 0
            nq = 0
        if i == n_rec:
            break
        if n + tile_len > out_cap:
            stop = i
            break
        tri = tri_ids[i]
        if tri != prev:
            # the triangle's constants; consecutive records usually share a triangle
            prev = tri
            _triangle_constants(p0, dp, l0, dl, tri, tc)
            moving = False
            for k_ in range(9, 18):
                moving = moving or tc[k_] != 0
            for k_ in range(24, 30):
                moving = moving or tc[k_] != 0
            for k_ in range(43, 46):
                moving = moving or tc[k_] != 0
            lens = False
            for k_ in range(18, 24):
                lens = lens or tc[k_] != 0
            # the dimensions this triangle uses: 0 = 2D, 1 = xyt, 2 = xyuv, 3 = xyuvt
            dims = (1 if moving else 0) + (2 if lens else 0)
            kind = dims if specialize and (dims == K_2D or dims == K_XYUV) else K_5D
            static = kind == K_2D and _static_exact(p0, dp, l0, dl, tri)
            c = _constants(tc)
            z3 = (tc[40], tc[41], tc[42], tc[43], tc[44], tc[45])
        general = dims != 0 or not specialize
        # two-stage lines and tuple masks matter only where t, u or v do
        extra = (has_lines or has_masks) and general
        ta = _f32_at_least(t_lo[i])
        tb = _f32_at_most(t_hi[i])
        ua = _f32_at_least(u_lo[i])
        ub = _f32_at_most(u_hi[i])
        va = _f32_at_least(v_lo[i])
        vb = _f32_at_most(v_hi[i])
        if extra:
            if has_masks:
                mk = masks[i]
            if has_lines:
                for c_ in range(8):
                    ln[c_] = lines[i, c_]
            else:
                ln[0], ln[1], ln[2], ln[3], ln[4], ln[5], ln[6], ln[7] = 0, 0, 1, 0, 0, 0, 1, 0
        full_t = t_lo[i] <= 0.0 and t_hi[i] >= 1.0
        px0 = tile_x[i] * tile_size
        px1 = min(px0 + tile_size, width)
        py0 = tile_y[i] * tile_size
        py1 = min(py0 + tile_size, height)
        w_t = px1 - px0
        h_t = py1 - py0
        area = w_t * h_t
        pixels += area
        if not full_t:
            searches += area
        if w_t != cur_w or h_t != cur_h:
            cur_w = w_t
            cur_h = h_t
            for r_ in range(h_t):
                for c_ in range(w_t):
                    for s_ in range(spp):
                        q_ = s_ * area + r_ * w_t + c_
                        off_s[q_] = r_ * width + c_
                        sid_s[q_] = s_
                        pix_s[q_] = r_ * w_t + c_
        # ---- the slots that can hold a t in t^, then the interval test ------
        # (slot_lo, slot_hi do not decrease: the slots below s0 end before t^,
        # those from s1 on start after it)
        s0 = 0
        s1 = 0
        for s_ in range(spp):
            s0 += slot_hi[s_] < ta
            s1 += slot_lo[s_] <= tb
        if s1 <= s0:
            continue
        qa = s0 * area  # the run's start in the tile
        k0 = (tile_y[i] * tile_size * width + px0 * h_t) * spp + qa
        nlen = (s1 - s0) * area
        n_words = (nlen + 7) // 8
        # the share of the samples u^ and v^ hold, if u and v are spread evenly
        fu = (min(ub, u_max) - max(ua, u_min)) / (u_max - u_min) if u_max > u_min else 1.0
        fv = (min(vb, v_max) - max(va, v_min)) / (v_max - v_min) if v_max > v_min else 1.0
        # (packing first pays only for a small share: fused measured faster from 15% on)
        fused = not extra and fu * fv >= 0.15
        n0, n1, n2, every = _tolerances(c, ta, tb, ua, ub, va, vb, np.float64(px1) + xy_max,
                                        np.float64(py1 + row0) + xy_max, edge_eps[tri], kind)
        if fused and every:  # no finite pass-1 bound: every sample in the intervals is a candidate
            tile_t, tile_all = _intervals_fn(nlen, k0, st, su, sv, cand, ta, tb, ua, ub, va, vb)
            nc = tile_all
        elif fused:
            tile_t, tile_all, nc = _pass1_fused(kind, nlen, k0, st, su, sv, sx, sy, cand, ta, tb, ua, ub, va, vb, c,
                                                n0, n1, n2)
        elif extra:
            tile_t, tile_all = _intervals_extra_fn(nlen, k0, st, su, sv, stup, tup_mask, msk, ta, tb, ua, ub, va, vb,
                                                   ln, mk)
            extra_tests += tile_t
        else:
            tile_t, tile_all = _intervals_fn(nlen, k0, st, su, sv, msk, ta, tb, ua, ub, va, vb)
        tested += tile_all
        by_dims[dims if specialize else 3] += tile_all
        in_range += tile_t
        if tile_all == 0:
            continue
        # ---- pass 1: the candidates, appended to the batch (pt..ppix) -------
        base = nq
        if fused:
            if nc == 0:
                continue
            for j in range(nlen, n_words * 8):
                cand[j] = 0
            m = _positions(candw, n_words, pos)
            for q in range(m):
                j = pos[np.uint64(q)]
                k = np.uint64(k0 + j)
                uq = np.uint64(base + q)
                pt[uq] = st[k]
                pu[uq] = su[k]
                pv[uq] = sv[k]
                px[uq] = sx[k]
                py[uq] = sy[k]
                q_ = qa + j
                poff[uq] = off_s[q_]
                psid[uq] = sid_s[q_]
                ppix[uq] = pix_s[q_]
        else:
            # the interval test first, then pass 1 on the samples in the intervals, packed
            for j in range(nlen, n_words * 8):
                msk[j] = 0
            m = _positions(mskw, n_words, pos)
            for q in range(m):
                uq = np.uint64(q)
                j = pos[uq]
                k = np.uint64(k0 + j)
                ct[uq] = st[k]
                cu[uq] = su[k]
                cv[uq] = sv[k]
                cx[uq] = sx[k]
                cy[uq] = sy[k]
                cq[uq] = qa + j
            m_pad = (m + pad - 1) // pad * pad
            for q in range(m, m_pad):  # NaN fails every test
                ct[q] = nan
                cu[q] = zero
                cv[q] = zero
                cx[q] = nan
                cy[q] = nan
            if every:  # no finite pass-1 bound: every packed sample is a candidate
                cc[:m] = 1
                cc[m:m_pad] = 0
                nc = m
            else:  # (the fused pass with unbounded intervals: the packed samples lie in them)
                _, _, nc = _pass1_fused(kind, m_pad, none, ct, cu, cv, cx, cy, cc, -inf, inf, -inf, inf, -inf, inf, c,
                                        n0, n1, n2)
            if nc == 0:
                continue
            m = _positions(ccw, m_pad // 8, pos)
            for q in range(m):
                s_ = np.uint64(pos[np.uint64(q)])
                uq = np.uint64(base + q)
                pt[uq] = ct[s_]
                pu[uq] = cu[s_]
                pv[uq] = cv[s_]
                px[uq] = cx[s_]
                py[uq] = cy[s_]
                q_ = cq[s_]
                poff[uq] = off_s[q_]
                psid[uq] = sid_s[q_]
                ppix[uq] = pix_s[q_]
        # ---- the record joins the batch -------------------------------------
        finite = (np.isfinite(ta) and np.isfinite(tb) and np.isfinite(ua) and np.isfinite(ub) and np.isfinite(va)
                  and np.isfinite(vb))
        if nb == 0:
            b_tri = tri
            b_static = static and finite
            b_c = c
            b_z3 = z3
            b_eps = edge_eps[tri]
        else:
            b_static = b_static and finite
        nq = base + m
        rb_end[nb] = nq
        rb_pix0[nb] = py0 * width + px0 + first
        rb_area[nb] = area
        rb_za[nb] = np.float32(z_lo[i])
        rb_zb[nb] = np.float32(z_hi[i])
        rb_nr[nb] = noread_in[i]
        nb += 1
    log_spp = 1
    while (1 << log_spp) <= spp:
        log_spp += 1
    ops[OP_CMP] += 2 * searches * log_spp
    # per sample in t^: four time lines (4 madd + 4 compares) or a mask bit (1 compare)
    ops[OP_MADD] += extra_tests * (4 if has_lines else 0)
    ops[OP_CMP] += extra_tests * (4 if has_lines else 1)
    events[EV_TESTED] += tested
    for d_ in range(4):
        events[EV_2D + d_] += by_dims[d_]
    events[EV_INRANGE] += in_range
    events[EV_PIXELS] += pixels
    events[EV_COVERED] += n - covered
    return n, stop


_NO_LINES = np.zeros((0, 8), np.float32)
_NO_MASKS = np.zeros(0, np.uint64)
_NO_TUPLES = np.zeros(0, np.int8)
#: the per-sample filters the kernel applies, by the tile-record field a culling algorithm adds
#: (``units.culling``): time lines t >= c + s u etc. (Wu13 §3.4) and a tuple mask (Fatahalian09)
SAMPLE_FILTERS = ("lines", "mask")


class TileMajorLayouts:
    """The samples of sample sets in the sample tester's tile-major order (``_tile_major``).

    ``prepare`` builds a set's layout on the thread that calls it: a screen
    region's as its samples are made, on the thread that makes the next
    region's ahead (``pipeline_sim.regions.RegionSamples``), so that the
    tester finds it ready when its batches reach the region. ``take`` hands
    the tester a set's layout (built then if it was not prepared) and
    ``release`` takes it back: its buffers go to the next set's layout, since
    memory a process touches for the first time costs far more than writing
    it again. Thread-safe.
    """

    KEEP_FREE = 1  # released buffer sets kept for reuse (the next region's layout takes one)

    def __init__(self, tile_size: int):
        self.tile_size = tile_size
        self.ahead = MadeAhead()  # the layouts prepared, by sample set
        self._lock = threading.Lock()
        self._free: list[tuple] = []  # buffer sets of released layouts

    def prepare(self, samples, waited_for: bool = False):
        """Build the layout of ``samples`` now, for a later ``take``; returns ``samples``. ``waited_for``:
        the pipeline is waiting for it (little else is running), so it lays out on both cores."""
        self.ahead.hold(samples, self._build(samples, 2 if waited_for else 1))
        return samples

    def take(self, samples) -> tuple:
        """The layout of ``samples``: the one prepared, else built now. Layouts prepared for sets of
        earlier rows (regions the pipeline has passed) are released."""
        got, passed, _ = self.ahead.take(samples)
        for layout in passed:
            self.release(layout)
        return got if got is not None else self._build(samples)

    def release(self, layout: tuple) -> None:
        """Take back a layout the tester no longer reads; its buffers serve a later one."""
        with self._lock:
            if len(self._free) < self.KEEP_FREE:
                self._free.append(layout[-1])

    def _buffers(self, n: int, has_tup: bool) -> tuple:
        with self._lock:
            for i, (f32, i8) in enumerate(self._free):
                if len(f32[0]) >= n and (not has_tup or (i8 is not None and len(i8) >= n)):
                    return self._free.pop(i)
        return (tuple(np.empty(n, np.float32) for _ in range(5)), np.empty(n, np.int8) if has_tup else None)

    def _build(self, s, threads: int = 1) -> tuple:
        """(x, y, u, v, t, tuple index, slot_lo, slot_hi, uv_range, xy_max, buffers): the kernel's
        arguments, tile by tile and slot-major in each tile, views of ``buffers``; on two threads, each
        laying out half the tile rows, with ``threads`` 2."""
        n = len(s.t)
        if s.width * s.height * s.spp != n:
            raise ValueError("the sample tester needs the samples of whole rows")
        if s.row0 % self.tile_size:
            raise ValueError(f"a screen region starts at row {s.row0}, not on a tile row")
        has_tup = s.tup is not None
        buffers = self._buffers(n, has_tup)
        f32, i8 = buffers
        tup = i8[:n] if has_tup else np.zeros(1, np.int8)  # (the kernel reads index 0)
        arrays = tuple(a[:n] for a in f32) + (tup,)
        rows = (s.height + self.tile_size - 1) // self.tile_size
        parts = [(0, rows)] if threads < 2 or rows < 2 else [(0, rows // 2), (rows // 2, rows)]
        out = [(np.empty(s.spp, np.float32), np.empty(s.spp, np.float32), np.empty(6, np.float64)) for _ in parts]

        def lay_out(part: int) -> None:
            _tile_major(s.width, s.height, s.row0, s.spp, self.tile_size, *parts[part], s.x, s.y, s.u, s.v, s.t,
                        s.tup if has_tup else _NO_TUPLES, *arrays, *out[part])

        if len(parts) == 1:
            lay_out(0)
        else:  # (the kernel runs without the interpreter lock; the halves write apart)
            helper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tile-major-layout")
            later_rows = helper.submit(lay_out, 1)
            try:
                lay_out(0)
            finally:
                helper.shutdown(wait=True)
            later_rows.result()  # the helper's error, if any, raised here
        lo, hi, stats = out[0]
        for lo_b, hi_b, st_b in out[1:]:  # the later rows' bounds as one pass over all rows would take them
            lo[:] = np.where(lo_b < lo, lo_b, lo)
            hi[:] = np.where(hi_b > hi, hi_b, hi)
            stats[:2] = np.where(np.isnan(st_b[:2]) | (st_b[:2] > stats[:2]), st_b[:2], stats[:2])
            stats[2:] = np.where([st_b[2] < stats[2], st_b[3] > stats[3], st_b[4] < stats[4], st_b[5] > stats[5]],
                                 st_b[2:], stats[2:])
        if not (np.all(np.diff(lo) >= 0) and np.all(np.diff(hi) >= 0)):
            lo[:] = -np.inf  # slots not in t order: every record takes them all
            hi[:] = np.inf
        m = max(float(stats[0]), float(stats[1]))
        xy_max = m * (1.0 + 1e-6) if np.isfinite(m) else np.inf
        return arrays + (lo, hi, stats[2:], xy_max, buffers)


class SampleTester:
    """Functional model of the sample tester unit.

    ``samples``: the samples of the screen region its batches are in, whole
    tile rows; the pipeline hands it those of each region as its batches move
    on (``use_samples``). It tests them in their tile-major layout, taken from
    ``layouts`` (which may have prepared it ahead) on the region's first batch.
    """

    name = "sample_tester"
    events = EVENTS
    event_meanings = EVENT_MEANINGS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, table, samples, tile_size: int, backface_culling: bool, specialize: bool = True,
                 layouts: TileMajorLayouts | None = None):
        self.config = config
        self.specialize = specialize
        self.table = table
        self.tile_size = tile_size
        self.backface_culling = backface_culling
        self.layouts = TileMajorLayouts(tile_size) if layouts is None else layouts
        if self.layouts.tile_size != tile_size:
            raise ValueError(f"layouts of {self.layouts.tile_size}-pixel tiles for a {tile_size}-pixel tester")
        self.samples = None
        self._layout = None
        self._per_record = 0.0  # covered samples per tile record in the last batch (sizes the next one's outputs)
        if samples is not None:
            self.use_samples(samples)

    def use_samples(self, samples) -> None:
        """Test the next batches against ``samples`` (a region's: whole tile rows from image row ``row0``)."""
        if samples is not self.samples:
            if samples.row0 % self.tile_size:
                raise ValueError(f"a screen region starts at row {samples.row0}, not on a tile row")
            if self._layout is not None:
                self.layouts.release(self._layout)
            self.samples = samples
            self._layout = None

    def layout(self) -> tuple:
        """The samples in the kernel's tile-major order (``TileMajorLayouts``), on first use:
        (x, y, u, v, t, tuple index, slot_lo, slot_hi, uv_range, xy_max)."""
        if self._layout is None:
            self._layout = self.layouts.take(self.samples)
        return self._layout[:-1]

    def kernel_args(self, tiles: dict[str, np.ndarray], out: dict[str, np.ndarray], ops: np.ndarray,
                    events: np.ndarray, start: int = 0, covered: int = 0) -> tuple:
        """The arguments of ``sample_test_kernel`` for a batch of tile records, from record ``start`` with
        ``covered`` samples already in ``out``."""
        s = self.samples
        t = self.table
        ty = tiles["ty"] - np.int32(s.row0 // self.tile_size) if s.row0 else tiles["ty"]  # rows from row0
        return (tiles["tri"], tiles["tx"], ty, tiles["t_lo"], tiles["t_hi"],
                tiles["u_lo"], tiles["u_hi"], tiles["v_lo"], tiles["v_hi"], tiles["z_lo"],
                tiles["z_hi"], tiles["noread"], tiles.get("lines", _NO_LINES), tiles.get("mask", _NO_MASKS),
                self.tile_size, s.width, s.height, s.spp, *self.layout(), s.row0,
                t.p0_32, t.dp_32, t.l0_32, t.dl_32, t.edge_eps, self.backface_culling, self.specialize,
                s.row0 * s.width, start, covered, out["tri"], out["pix"], out["sidx"], out["z"], out["b0"],
                out["b1"], out["b2"], out["noread"], ops, events)

    def run(self, tiles: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Test a batch of tile records; its covered samples come out in arrays of their own (the kernel
        writes them there; when they run out of room it stops between records, and they are grown, copying
        what was written). Sized at 2.5 times the last batch's covered samples per record: the default
        pass at 256 spp then grows them at 19 of its 353 batches, copying 2.7 million samples (5.2 million
        at 1.25 times); memory is touched only where written."""
        s = self.samples
        n_rec = len(tiles["tri"])
        tile_len = self.tile_size * self.tile_size * s.spp  # a record's covered samples at most
        bound = n_rec * tile_len
        size = min(bound, int(2.5 * self._per_record * n_rec) + 2 * tile_len)
        out = SAMPLE.allocate(size, fill=False)
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        m, i = sample_test_kernel(*self.kernel_args(tiles, out, ops, events))
        while i < n_rec:  # out of room before record i: grow (to at least a tile's samples more) and go on
            size = min(bound, max(2 * size, m + tile_len))
            grown = SAMPLE.allocate(size, fill=False)
            for k, v in out.items():
                grown[k][:m] = v[:m]
            out = grown
            m, i = sample_test_kernel(*self.kernel_args(tiles, out, ops, events, i, m))
        self._per_record = m / max(n_rec, 1)
        tested = events[EV_TESTED]
        for d_ in range(4):
            ops[OP_MADD] += events[EV_2D + d_] * TEST_OPS_MADD[d_]
            ops[OP_MUL] += events[EV_2D + d_] * TEST_OPS_MUL[d_]
        ops[OP_CMP] += tested * 4
        ops[OP_RCP] += m * COVER_OPS_RCP
        ops[OP_MUL] += m * COVER_OPS_MUL
        ops[OP_MADD] += m * COVER_OPS_MADD
        return {k: v[:m] for k, v in out.items()}, ops, events
