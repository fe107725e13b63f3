"""Per-tile (or per-pixel) time bounds in the dual space of the lens and time.

Two culling bounds of Wu13 for a tile (or pixel) column range [a0, a1]:

* ``dual_time_interval``: the dual-space time bounds of Laine11
  as Wu13 §2 describes them (Wu13 §3.3-3.4 compare against them);
* ``two_stage_lines``: Wu13 §3.4 "Culling Stage 2" (eq. 1 and the rational
  function of the lens coordinate that follows it), two lines in (t, u).

Both rest on one fact. The triangle is the convex hull of its vertices, so a
sample at x in [a0, a1] can be inside it only if some vertex has screen x
>= a0 and some vertex has screen x <= a1. With W > 0, vertex k at screen
x >= a0 is

    delta_k(t, u) = X_k(t, u) - a0 W_k(t) >= 0,
    X_k = X0 + t dX + u (L0 + t dL),  W_k = W0 + t dW,

which is bilinear in (t, u): linear in t at fixed u and linear in u at fixed
t (Laine11's dual space, Wu13 §2). "Some vertex <= a1" is the mirror
condition a1 W_k - X_k >= 0. The same holds along y with the lens
coordinate v.

Rounding: the sample tester decides on float32-rounded vertices lerped in
float32 (``units.sample_tester``). Each condition g = A + B t + u (C + E t)
>= 0 is therefore relaxed to g + P0 + P1 t >= 0 with

    P0 = F32_REL (|X0| + umax |L0| + |a| |W0|),
    P1 = F32_REL (|dX| + umax |dL| + |a| |dW|),

which bounds |g(float32 vertices) - g(float64)| for t in [0, 1] and |u| <=
umax (a few float32 roundings of ~6e-8 of those magnitudes each). The
relaxed g is again bilinear, so everything below is exact in the relaxed
problem; float64 rounding of the bounds themselves is covered by a tiny
relative pad (dual interval) or an absolute 1e-6 plus relative pad (lines).
Callers keep [ta, tb] within [0, 1] and W > 0 for every vertex over it.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import OP_ADD, OP_CMP, OP_MADD, OP_MUL, OP_RCP
from units.rounding import F32_REL
from units.tile_test_bounds import NO_TILE_FIELDS, NO_TRIANGLE_FIELDS

# the culling algorithm "dual_space" (units.culling): lens bounds, then time bounds over that lens range
NAME = "dual_space"
EVENT_MEANINGS = {"rejected_dual_time": "tiles rejected by dual-space time bounds"}
EVENTS = tuple(EVENT_MEANINGS)
TRIANGLE_EXT = NO_TRIANGLE_FIELDS
TILE_EXT = NO_TILE_FIELDS
COARSE_TEST = False
NEEDS_TUPLES = False
SAMPLE_FILTER = None
setup_extras = None

T_PAD_ABS = 1e-6  # absolute time pad of the stage-2 lines
T_PAD_REL = 1e-12  # relative pad: float64 rounding of the bounds themselves
BIG = 1e6  # per-vertex line values beyond this (times 1 + |ta| + |tb|) fall back to the trivial bound


@nb.njit(cache=True, inline="always")
def _condition(p0, dp, l0, dl, tri, k, axis, cond, a, umax, ta, tb):
    """Coefficients (A, B, C, E) of the relaxed condition A + B t + u (C + E t) >= 0.

    cond 0: vertex k at screen >= a (X - a W >= 0); cond 1: at <= a
    (a W - X >= 0). Includes the float32 rounding pad P0 + P1 t (module doc).
    """
    X0 = p0[tri, k, axis]
    dX = dp[tri, k, axis]
    W0 = p0[tri, k, 3]
    dW = dp[tri, k, 3]
    L0 = l0[tri, k, axis]
    dL = dl[tri, k, axis]
    sg = 1.0 if cond == 0 else -1.0
    P0 = F32_REL * (abs(X0) + umax * abs(L0) + abs(a) * abs(W0))
    P1 = F32_REL * (abs(dX) + umax * abs(dL) + abs(a) * abs(dW))
    if ta < 0.0:  # the linear pad needs t >= 0; otherwise a constant one
        P0 += P1 * max(abs(ta), abs(tb))
        P1 = 0.0
    A = sg * (X0 - a * W0) + P0
    B = sg * (dX - a * dW) + P1
    return A, B, sg * L0, sg * dL


@nb.njit(cache=True)
def dual_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ulo, uhi, vlo, vhi, ta, tb, ops):
    """Dual-space time bounds of Laine11 (Wu13 §2) for a tile.

    Returns (lo, hi) within [ta, tb]: the times at which the triangle, seen
    from some lens position in [ulo, uhi] x [vlo, vhi], can have a sample in
    the tile [x0, x1] x [y0, y1]; empty when lo > hi. For each of the four
    conditions (some vertex right of x0, left of x1, below y0, above y1) and
    each vertex, delta_k is linear in u at fixed t, so some lens position
    satisfies it exactly when a lens corner does; at each corner delta_k is
    linear in t and its feasible set is a half-line. The condition's set is
    the union of those half-lines; the result intersects their hulls. The
    lens and time ranges are treated independently (the coupling between them
    is lost), which is what makes this loose under simultaneous motion and
    defocus (Wu13 §3.4, Table 4.1).
    """
    lo = ta
    hi = tb
    for c4 in range(4):
        axis = c4 // 2
        cond = c4 % 2
        if axis == 0:
            a = x0 if cond == 0 else x1
            clo, chi = ulo, uhi
        else:
            a = y0 if cond == 0 else y1
            clo, chi = vlo, vhi
        umax = max(abs(clo), abs(chi))
        start_min = np.inf  # min start of the half-lines [s, inf)
        end_max = -np.inf  # max end of the half-lines (-inf, e]
        below = False  # some set unbounded below
        above = False  # some set unbounded above
        for k in range(3):
            A, B, C, E = _condition(p0, dp, l0, dl, tri, k, axis, cond, a, umax, ta, tb)
            for corner in range(2):
                u = clo if corner == 0 else chi
                n = A + C * u
                s = B + E * u
                if s > 0.0:
                    start_min = min(start_min, -n / s)
                    above = True
                elif s < 0.0:
                    end_max = max(end_max, -n / s)
                    below = True
                elif n >= 0.0:
                    below = True
                    above = True
        ops[OP_MADD] += 3 * 4 + 6 * 2
        ops[OP_MUL] += 3 * 6
        ops[OP_RCP] += 6
        ops[OP_MUL] += 6
        ops[OP_CMP] += 6 * 3 + 2
        c_lo = ta if below else start_min
        c_hi = tb if above else end_max
        # clamp before padding (no inf - inf), then pad for float64 rounding
        c_lo = min(max(c_lo, ta - 1.0), tb + 1.0)
        c_hi = min(max(c_hi, ta - 1.0), tb + 1.0)
        lo = max(lo, c_lo - T_PAD_REL * (1.0 + abs(c_lo)))
        hi = min(hi, c_hi + T_PAD_REL * (1.0 + abs(c_hi)))
        ops[OP_CMP] += 8
        if not (lo <= hi):
            break
    if lo != lo or hi != hi:  # non-finite input: no culling
        return ta, tb
    return lo, hi


@nb.njit(cache=True)
def two_stage_lines(p0, dp, l0, dl, tri, axis, a0, a1, ulo, uhi, ta, tb, ops):
    """Stage-2 time bounds of Wu13 §3.4 as two lines in the lens coordinate.

    Along ``axis`` (0: x with lens u, 1: y with v) for the column range
    [a0, a1] and lens range [ulo, uhi], returns (lo_c, lo_s, hi_c, hi_s): every
    (t, u), t in [ta, tb], u in [ulo, uhi], at which a sample with x in
    [a0, a1] can be covered satisfies lo_c + lo_s u <= t <= hi_c + hi_s u.
    A lower line above tb (or an upper one below ta) means no such (t, u).

    Wu13 §3.4, eq. 1 gives each vertex's crossing time as a rational function
    of u. Here: at fixed u the root in t of the relaxed condition
    A + B t + u (C + E t) = 0 is the Moebius function f(u) = -(A + C u) /
    (B + E u), monotone and either convex or concave where the slope
    s(u) = B + E u keeps a strict sign. With s > 0 the vertex's feasible set
    is [f(u), inf): f is bounded below by its chord (concave) or its tangent
    at the middle (convex); taking at each end of [ulo, uhi] the smaller of
    the chord's and the tangent's value gives a line below both, hence below f
    whichever case holds (no reliance on the sign of f''). Other vertices
    (s <= 0 somewhere) contribute the trivial bound ta, or tb + 1 when the
    vertex fails the condition everywhere on the (t, u) box. The condition's
    lower end, the minimum over vertices of these lines, is concave, so the
    chord through its values at ulo and uhi bounds it below. Upper bounds
    mirror this (s < 0, feasible (-inf, f(u)], larger of chord and tangent,
    trivial tb or ta - 1, maximum over vertices is convex). Of the two
    conditions (some vertex >= a0, some vertex <= a1) the lower line higher
    at the middle and the upper line lower there are returned, each padded
    outward by T_PAD_ABS + T_PAD_REL (|c| + |s| umax). Unlike Wu13's fixed
    chord/tangent pair this is conservative for either curvature.
    """
    if not (ulo <= uhi) or not (ta <= tb):
        return ta, 0.0, tb, 0.0
    umax = max(abs(ulo), abs(uhi))
    um = 0.5 * (ulo + uhi)
    w = uhi - ulo
    point = w <= 1e-6 * (1.0 + umax)  # too narrow for a chord: constant lines
    big = BIG * (1.0 + abs(ta) + abs(tb))
    best_lo0 = ta
    best_lo1 = ta
    best_hi0 = tb
    best_hi1 = tb
    best_lo_mid = -np.inf
    best_hi_mid = np.inf
    for cond in range(2):
        a = a0 if cond == 0 else a1
        lv0 = np.inf  # min over vertices of their lower lines, at ulo and uhi
        lv1 = np.inf
        hv0 = -np.inf  # max over vertices of their upper lines
        hv1 = -np.inf
        for k in range(3):
            A, B, C, E = _condition(p0, dp, l0, dl, tri, k, axis, cond, a, umax, ta, tb)
            n0 = A + C * ulo
            n1 = A + C * uhi
            s0 = B + E * ulo
            s1 = B + E * uhi
            ops[OP_MADD] += 4 + 4
            ops[OP_MUL] += 6
            # fails everywhere on the box (g is bilinear: its maximum is at a corner)
            gmax = max(max(n0 + s0 * ta, n0 + s0 * tb), max(n1 + s1 * ta, n1 + s1 * tb))
            ops[OP_MADD] += 4
            ops[OP_CMP] += 4
            if gmax < 0.0:
                l_0, l_1, h_0, h_1 = tb + 1.0, tb + 1.0, ta - 1.0, ta - 1.0
            else:
                l_0, l_1, h_0, h_1 = ta, ta, tb, tb
                thr = 1e-9 * (abs(A) + abs(C) * umax) + 1e-300
                sgn = 0.0
                if s0 > thr and s1 > thr:
                    sgn = 1.0
                elif s0 < -thr and s1 < -thr:
                    sgn = -1.0
                ops[OP_MADD] += 1
                ops[OP_CMP] += 4
                if sgn != 0.0:
                    f0 = -n0 / s0
                    f1 = -n1 / s1
                    sm = B + E * um
                    fm = -(A + C * um) / sm
                    d = (E * A - C * B) / (sm * sm)  # f'(um)
                    g0 = fm + d * (ulo - um)  # tangent at the middle, at the ends
                    g1 = fm + d * (uhi - um)
                    ops[OP_RCP] += 4
                    ops[OP_MUL] += 5
                    ops[OP_MADD] += 6
                    ops[OP_ADD] += 2
                    ops[OP_CMP] += 6
                    ok = (abs(f0) <= big and abs(f1) <= big and abs(fm) <= big and abs(d) * w <= big)
                    if ok and sgn > 0.0:  # feasible [f, inf): lower line below chord and tangent
                        l_0 = min(f0, g0)
                        l_1 = min(f1, g1)
                    elif ok:  # feasible (-inf, f]: upper line above both
                        h_0 = max(f0, g0)
                        h_1 = max(f1, g1)
            lv0 = min(lv0, l_0)
            lv1 = min(lv1, l_1)
            hv0 = max(hv0, h_0)
            hv1 = max(hv1, h_1)
            ops[OP_CMP] += 4
        # clamps that keep the lines valid: lower ends may only go down, upper ends up
        lv0 = min(lv0, tb + 1.0)
        lv1 = min(lv1, tb + 1.0)
        hv0 = max(hv0, ta - 1.0)
        hv1 = max(hv1, ta - 1.0)
        if point:
            lv0 = lv1 = min(lv0, lv1)  # concave: its minimum is at an end
            hv0 = hv1 = max(hv0, hv1)  # convex: its maximum is at an end
        if min(lv0, lv1) < ta - big:  # useless and ill-conditioned
            lv0 = lv1 = ta
        if max(hv0, hv1) > tb + big:
            hv0 = hv1 = tb
        lmid = 0.5 * (lv0 + lv1)
        hmid = 0.5 * (hv0 + hv1)
        ops[OP_CMP] += 10
        ops[OP_ADD] += 2
        ops[OP_MUL] += 2
        if lmid > best_lo_mid:
            best_lo_mid = lmid
            best_lo0, best_lo1 = lv0, lv1
        if hmid < best_hi_mid:
            best_hi_mid = hmid
            best_hi0, best_hi1 = hv0, hv1
        ops[OP_CMP] += 2
    if point:
        lo_s = 0.0
        hi_s = 0.0
        lo_c = best_lo0
        hi_c = best_hi0
    else:
        inv = 1.0 / w
        lo_s = (best_lo1 - best_lo0) * inv
        hi_s = (best_hi1 - best_hi0) * inv
        lo_c = best_lo0 - lo_s * ulo
        hi_c = best_hi0 - hi_s * ulo
        ops[OP_RCP] += 1
        ops[OP_ADD] += 2
        ops[OP_MUL] += 2
        ops[OP_MADD] += 2
    lo_c -= T_PAD_ABS + T_PAD_REL * (abs(lo_c) + abs(lo_s) * umax)
    hi_c += T_PAD_ABS + T_PAD_REL * (abs(hi_c) + abs(hi_s) * umax)
    ops[OP_MADD] += 4
    ops[OP_ADD] += 2
    if not (np.isfinite(lo_c) and np.isfinite(lo_s) and np.isfinite(hi_c) and np.isfinite(hi_s)):
        return ta, 0.0, tb, 0.0
    return lo_c, lo_s, hi_c, hi_s
