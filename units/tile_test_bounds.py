"""The tile test's shared bounds, which the culling algorithms (``units.culling``) combine.

Part of the tile test unit (docs/pipeline.md §2.3); ``units.tile_test.tile_test_kernel_for``
applies them per (triangle, tile) record. The bounds:

* t^ from the moving axis-aligned box in 2DH against the four tile frustum
  planes (Munkberg11 §4.1, eq. 1-2); the box includes the lens shift at u, v = +-1,
  so it bounds the triangle at every lens position;
* the linearized moving-edge test (Munkberg11 §4.2, eq. 8-9) for motion-only
  triangles of constant facing;
* lens intervals u^, v^: for each vertex at the two ends of t^, the screen
  position x = (X + u LX) / W is a line in u (the dual-space view of
  Laine11 that Wu13 §2 describes); a sample at lens u can be covered only if
  some vertex lies right of the tile's left side and some vertex left of its
  right side, which bounds u to an interval;
* optional axis-aligned user clip planes on t, u and v (Nilsson12 §2) bound every
  interval by min/max, so samples outside them are never covered;
* z^ from the vertex depths at the ends of t^ (the near and far faces of the
  moving box, Nilsson12 App. A first test): the depth of any point of the
  triangle is a convex combination of vertex depths while w > 0.

Every bound is widened by a small margin so floating-point rounding can only
make it looser, never tighter.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import OP_CMP, OP_MADD, OP_MUL, OP_RCP
from pipeline_sim.records import RecordType
from units.rounding import F32_REL

# the events of every tile test, first in its event vector; an algorithm's own follow (units.culling)
CORE_EVENT_MEANINGS = {
    "rejected_box": "tiles rejected by the moving-box test",
    "rejected_edge": "tiles rejected by the moving-edge test",
    "rejected_lens": "tiles rejected by the lens bounds",
    "accepted": "tiles passed on",
}
CORE_EVENTS = tuple(CORE_EVENT_MEANINGS)
EV_REJ_BOX, EV_REJ_EDGE, EV_REJ_LENS, EV_ACCEPT = range(len(CORE_EVENTS))

# an algorithm without fields of its own extends the records by these
NO_TRIANGLE_FIELDS = RecordType("NoTriangleFields", (), __name__)
NO_TILE_FIELDS = RecordType("NoTileFields", (), __name__)
NoTriangleFields = NO_TRIANGLE_FIELDS.tuple_class
NoTileFields = NO_TILE_FIELDS.tuple_class


@nb.njit(cache=True)
def _box_at(p0, dp, l0, dl, tri, t):
    """The triangle's 2DH box at time t, lens shifts included: x, y, w extents."""
    xmn = np.inf
    xmx = -np.inf
    ymn = np.inf
    ymx = -np.inf
    wmn = np.inf
    wmx = -np.inf
    for k in range(3):
        X = p0[tri, k, 0] + t * dp[tri, k, 0]
        Y = p0[tri, k, 1] + t * dp[tri, k, 1]
        W = p0[tri, k, 3] + t * dp[tri, k, 3]
        LX = abs(l0[tri, k, 0] + t * dl[tri, k, 0])
        LY = abs(l0[tri, k, 1] + t * dl[tri, k, 1])
        xmn = min(xmn, X - LX)
        xmx = max(xmx, X + LX)
        ymn = min(ymn, Y - LY)
        ymx = max(ymx, Y + LY)
        wmn = min(wmn, W)
        wmx = max(wmx, W)
    return xmn, xmx, ymn, ymx, wmn, wmx


@nb.njit(cache=True)
def _outside_distance(plane, x0, x1, y0, y1, xmn, xmx, ymn, ymx, wmn, wmx):
    """How far a box lies outside one tile frustum plane (> 0: wholly outside), beyond float32 rounding."""
    if plane == 0:  # left side: outside when x0 W - X > 0
        wv = wmn if x0 > 0 else wmx
        d = x0 * wv - xmx
        mag = abs(x0 * wv) + abs(xmx)
    elif plane == 1:  # right side: outside when X - x1 W > 0
        wv = wmx if x1 > 0 else wmn
        d = xmn - x1 * wv
        mag = abs(x1 * wv) + abs(xmn)
    elif plane == 2:  # top
        wv = wmn if y0 > 0 else wmx
        d = y0 * wv - ymx
        mag = abs(y0 * wv) + abs(ymx)
    else:  # bottom
        wv = wmx if y1 > 0 else wmn
        d = ymn - y1 * wv
        mag = abs(y1 * wv) + abs(ymn)
    return d - F32_REL * mag


@nb.njit(cache=True)
def box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ta, tb, ops):
    """Moving 2DH box of the triangle against the tile frustum planes (Munkberg11 eq. 1-2).

    The box is taken at the ends of [ta, tb] and moves linearly between them:
    the vertices (and the lens shifts) are linear in t, so at any t in
    [ta, tb] they lie in the interpolated box, and the narrower [ta, tb] is,
    the tighter the box. Returns the sub-interval of [ta, tb] where the box
    may overlap the tile [x0, x1] x [y0, y1] (pixel units, already widened);
    empty when lo > hi.
    """
    xmn0, xmx0, ymn0, ymx0, wmn0, wmx0 = _box_at(p0, dp, l0, dl, tri, ta)
    xmn1, xmx1, ymn1, ymx1, wmn1, wmx1 = _box_at(p0, dp, l0, dl, tri, tb)
    ops[OP_MADD] += 30
    ops[OP_CMP] += 36
    lo = ta
    hi = tb
    span = tb - ta
    for plane in range(4):
        d0 = _outside_distance(plane, x0, x1, y0, y1, xmn0, xmx0, ymn0, ymx0, wmn0, wmx0)
        d1 = _outside_distance(plane, x0, x1, y0, y1, xmn1, xmx1, ymn1, ymx1, wmn1, wmx1)
        ops[OP_MADD] += 2
        ops[OP_CMP] += 2
        if d0 > 0.0 and d1 > 0.0:
            return 1.0, 0.0
        if d0 > 0.0 or d1 > 0.0:  # outside at one end only: the crossing time bounds that end
            t = ta + span * (d0 / (d0 - d1))
            if d0 > 0.0:
                lo = max(lo, t)
            else:
                hi = min(hi, t)
            ops[OP_RCP] += 1
            ops[OP_MUL] += 1
            ops[OP_MADD] += 1
        if lo > hi:
            return lo, hi
    return lo, hi


@nb.njit(cache=True)
def edge_time_interval(edge_h, edge_gamma, edge_g, edge_fg, edge_abs, gamma_per_tile, tri, x0, x1, y0, y1, lo, hi,
                        ops):
    """Linearized moving-edge test (Munkberg11 eq. 8-9); narrows [lo, hi].

    Gamma is the triangle's (eq. 7 over its bounds) or, with
    ``gamma_per_tile``, recomputed over this tile's extents as Munkberg11 suggests,
    which is tighter: max over the tile of g . s and (f + g) . s.
    """
    for k in range(3):
        hx = edge_h[tri, k, 0]
        hy = edge_h[tri, k, 1]
        hw = edge_h[tri, k, 2]
        sx = x1 if hx > 0 else x0
        sy = y1 if hy > 0 else y0
        o = hx * sx + hy * sy + hw
        # float32 vertices move e by up to ~2^-23 of the products behind f, g, h
        mag = edge_abs[tri, k, 0] * max(abs(x0), abs(x1)) + edge_abs[tri, k, 1] * max(abs(y0), abs(y1)) + edge_abs[tri, k, 2]
        o += F32_REL * mag
        gam = edge_gamma[tri, k]
        if gamma_per_tile:
            gt = -np.inf
            for which in range(2):
                ax = edge_g[tri, k, 0] if which == 0 else edge_fg[tri, k, 0]
                ay = edge_g[tri, k, 1] if which == 0 else edge_fg[tri, k, 1]
                aw = edge_g[tri, k, 2] if which == 0 else edge_fg[tri, k, 2]
                gt = max(gt, aw + (ax * x1 if ax > 0 else ax * x0) + (ay * y1 if ay > 0 else ay * y0))
            gam = min(gam, gt + F32_REL * mag)  # both bound the slope: keep the tighter
            ops[OP_MADD] += 4
            ops[OP_CMP] += 6
        ops[OP_MADD] += 2
        ops[OP_CMP] += 3
        if gam > 0.0:
            lo = max(lo, -o / gam)
        elif gam < 0.0:
            hi = min(hi, -o / gam)
        elif o < 0.0:
            return 1.0, 0.0
        if lo > hi:
            return lo, hi
    return lo, hi


@nb.njit(cache=True)
def _add_half_line(diff, beta, left_end, right_start, everything):
    """Add {u : beta u >= diff} to a union of (-inf, left_end], [right_start, inf)
    and, when ``everything``, the whole line."""
    if beta == 0.0:
        if diff <= 0.0:
            everything = True
    elif beta > 0.0:
        right_start = min(right_start, diff / beta)
    else:
        left_end = max(left_end, diff / beta)
    return left_end, right_start, everything


@nb.njit(cache=True)
def lens_interval(p0, dp, l0, dl, tri, axis, a0, a1, ta, tb, ops):
    """Interval of the lens coordinate (u for axis 0, v for axis 1) that can
    put a sample of the tile span [a0, a1] inside the triangle; needs w > 0."""
    # condition A: some vertex at >= a0 ; condition B: some vertex at <= a1.
    # Per condition: the union of (-inf, e] (left_end), of [s, inf)
    # (right_start), and whether some vertex satisfies it at every u.
    left_a = -np.inf
    right_a = np.inf
    every_a = False
    left_b = -np.inf
    right_b = np.inf
    every_b = False
    for s in range(2):
        t = ta if s == 0 else tb
        for k in range(3):
            W = p0[tri, k, 3] + t * dp[tri, k, 3]
            X = p0[tri, k, axis] + t * dp[tri, k, axis]
            L = l0[tri, k, axis] + t * dl[tri, k, axis]
            alpha = X / W
            beta = L / W
            # A: alpha + beta u >= a0, i.e. beta u >= a0 - alpha
            left_a, right_a, every_a = _add_half_line(a0 - alpha, beta, left_a, right_a, every_a)
            # B: alpha + beta u <= a1, i.e. -beta u >= -(a1 - alpha)
            left_b, right_b, every_b = _add_half_line(-(a1 - alpha), -beta, left_b, right_b, every_b)
    lo_all = -1.0
    hi_all = 1.0
    for cond in range(2):
        ops[OP_RCP] += 6
        ops[OP_MUL] += 12
        ops[OP_MADD] += 18
        ops[OP_CMP] += 12
        everything = every_a if cond == 0 else every_b
        left_end = left_a if cond == 0 else left_b
        right_start = right_a if cond == 0 else right_b
        if everything:
            continue
        if left_end == -np.inf and right_start == np.inf:
            return 1.0, -1.0
        if left_end == -np.inf:
            lo_c, hi_c = right_start, 1.0
        elif right_start == np.inf:
            lo_c, hi_c = -1.0, left_end
        elif left_end >= right_start:
            lo_c, hi_c = -1.0, 1.0
        else:
            lo_c, hi_c = -1.0, 1.0
        pad = 1e-7 * (1.0 + abs(lo_c) + abs(hi_c))
        lo_all = max(lo_all, lo_c - pad)
        hi_all = min(hi_all, hi_c + pad)
    return max(lo_all, -1.0), min(hi_all, 1.0)


@nb.njit(cache=True)
def plane_w_bounds(plane_n, plane_d, tri, x0, x1, y0, y1, ta, tb, ops):
    """Bounds on w over the tile and [ta, tb] from the moving planes (Nilsson12 App. A).

    The triangle stays on one side of the plane n . P + d0 + v t = 0 for all
    t. On the ray P = w (x, y, 1) that gives w <= -D(t) / N or w >= -D(t) / N
    with N = n . (x, y, 1), depending on the side and the sign of N. A plane
    is used only where N keeps one sign over the tile and -D(t) keeps the
    bound's sign over [ta, tb] (the plane does not sweep through the camera).
    """
    w_lo = 0.0
    w_hi = np.inf
    for which in range(2):
        nx = plane_n[tri, which, 0]
        ny = plane_n[tri, which, 1]
        nw = plane_n[tri, which, 2]
        if nx != nx:
            continue
        n_min = np.inf
        n_max = -np.inf
        for cx in range(2):
            for cy in range(2):
                val = nx * (x0 if cx == 0 else x1) + ny * (y0 if cy == 0 else y1) + nw
                n_min = min(n_min, val)
                n_max = max(n_max, val)
        ops[OP_MADD] += 8
        ops[OP_CMP] += 8
        if n_min > 0.0:
            sgn = 1.0
            a_min = n_min
            a_max = n_max
        elif n_max < 0.0:
            sgn = -1.0
            a_min = -n_max
            a_max = -n_min
        else:
            continue
        # upper bound from the side whose sign matches N's, lower from the other
        for side in range(2):
            side_sgn = 1.0 if side == 0 else -1.0
            d0 = sgn * plane_d[tri, which, side, 0]
            v = sgn * plane_d[tri, which, side, 1]
            ga = -(d0 + v * ta)
            gb = -(d0 + v * tb)
            if side_sgn == sgn:  # w <= -D / N
                if ga > 0.0 and gb > 0.0:
                    w_hi = min(w_hi, max(ga, gb) / a_min)
            else:  # w >= -D / N
                g = min(ga, gb)
                if g > 0.0:
                    w_lo = max(w_lo, g / a_max)
        ops[OP_MADD] += 4
        ops[OP_RCP] += 2
        ops[OP_MUL] += 2
    return w_lo, w_hi
