"""Tile test: a (triangle, tile) pair to conservative intervals (u^, v^, t^, z^).

Implements docs/pipeline.md §2.3:

* t^ from the moving axis-aligned box in 2DH against the four tile frustum
  planes (Munkberg11 §4.1, eq. 1-2); the box includes the lens shift at u, v = +-1,
  so it bounds the triangle at every lens position;
* intersected with the linearized moving-edge test (Munkberg11 §4.2, eq. 8-9) for
  motion-only triangles of constant facing;
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
make it looser, never tighter. With ``algorithm = "bbox"`` no tile is
rejected and t^ is the triangle's whole time span: the BBOX baseline of Wu13
and Munkberg11, against which the sample test efficiency of the tests is measured.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import N_OPS, OP_CMP, OP_MADD, OP_MUL, OP_RCP
from units.rounding import F32_REL, MARGIN_PX
from units.tile_test_dual import dual_time_interval, two_stage_lines
from units.tile_test_hull import hull_overlaps_tile
from units.tile_test_interleave import interleave_mask
from units.tile_test_quadratic import quadratic_time_interval
from units.triangle_setup import FLAG_EDGE, FLAG_LENS, FLAG_PLANE, FLAG_WPOS

EVENTS = ("rejected_box", "rejected_edge", "rejected_lens", "accepted", "rejected_hull", "rejected_dual_time",
          "rejected_two_stage", "rejected_tuples")
(EV_REJ_BOX, EV_REJ_EDGE, EV_REJ_LENS, EV_ACCEPT, EV_REJ_HULL, EV_REJ_DUAL, EV_REJ_TWO,
 EV_REJ_TUPLES) = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): none; upstream of z-cull, every tile is seen whatever the timing
TIMING_DEPENDENT: tuple[str, ...] = ()



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
        if d0 > 0.0:
            t = ta + span * (d0 / (d0 - d1))
            lo = max(lo, t)
            ops[OP_RCP] += 1
            ops[OP_MUL] += 1
            ops[OP_MADD] += 1
        elif d1 > 0.0:
            t = ta + span * (d0 / (d0 - d1))
            hi = min(hi, t)
            ops[OP_RCP] += 1
            ops[OP_MUL] += 1
            ops[OP_MADD] += 1
        if lo > hi:
            return lo, hi
    return lo, hi


@nb.njit(cache=True)
def _edge_time_interval(edge_h, edge_gamma, edge_g, edge_fg, edge_abs, gamma_per_tile, tri, x0, x1, y0, y1, lo, hi,
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
def _lens_interval(p0, dp, l0, dl, tri, axis, a0, a1, ta, tb, ops):
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


ALG_HIERARCHICAL, ALG_BBOX, ALG_HULL, ALG_DUAL, ALG_TWO_STAGE, ALG_INTERLEAVE = range(6)
ALGORITHM_CODES = {"hierarchical": ALG_HIERARCHICAL, "bbox": ALG_BBOX, "hull": ALG_HULL, "dual_space": ALG_DUAL,
                   "two_stage": ALG_TWO_STAGE, "interleave_uvt": ALG_INTERLEAVE}
# the float32 evaluation of a time line c + s u in the sample tester rounds by
# at most a few ulps of |c| + |s|; lines are widened by this fraction of it
LINE_F32_REL = 4.0 * 2.0**-23


@nb.njit(cache=True)
def tile_test_kernel(tri_ids, tile_x, tile_y, tile_size, width, height, algorithm, edge_test, quadratic,
                     gamma_per_tile, lens_bounds, clips,
                     p0, dp, l0, dl, t_span, flags, edge_f, edge_h, edge_gamma, edge_g, edge_fg, edge_abs, plane_n,
                     plane_d,
                     hull, hull_n, hull_off, tuples, depth_c1, depth_c0,
                     out_keep, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, lines, mask, ops, events):
    """Test each (triangle, tile) record; fill its intervals and ``out_keep``.

    ``algorithm`` (ALG_*): hierarchical, Munkberg11 §4.1-4.2 (t^ from the moving box
    and the linearized or, with ``quadratic``, the exact quadratic edges) and
    lens bounds (u^, v^); BBOX (no rejection); the convex hull of McGuire10
    (Wu13 §3.2); dual-space bounds (Laine11, Wu13 §2);
    two-stage culling (Wu13 §3.3-3.4), which also writes per-record time
    ``lines`` linear in u and v; Interleave UVT, which writes a tuple
    ``mask``. z^ from Nilsson12 App. A for all of them; clip planes (Nilsson12 §2).
    """
    for i in range(tri_ids.shape[0]):
        tri = tri_ids[i]
        fl = flags[tri]
        x0 = tile_x[i] * tile_size - MARGIN_PX
        x1 = min((tile_x[i] + 1) * tile_size, width) + MARGIN_PX
        y0 = tile_y[i] * tile_size - MARGIN_PX
        y1 = min((tile_y[i] + 1) * tile_size, height) + MARGIN_PX
        ta = max(t_span[tri, 0], clips[0])  # user clip planes bound every interval (Nilsson12 §2)
        tb = min(t_span[tri, 1], clips[1])
        out_keep[i] = False
        wpos = (fl & FLAG_WPOS) != 0
        has_lens = (fl & FLAG_LENS) != 0
        ulo, uhi, vlo, vhi = clips[2], clips[3], clips[4], clips[5]
        lo, hi = ta, tb
        if algorithm == ALG_HIERARCHICAL:
            lo, hi = box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ta, tb, ops)
            if lo > hi:
                events[EV_REJ_BOX] += 1
                continue
            if edge_test and (fl & FLAG_EDGE) != 0:
                if quadratic:
                    lo, hi = quadratic_time_interval(edge_f, edge_g, edge_h, edge_abs, tri, x0, x1, y0, y1, lo, hi,
                                                     ops)
                else:
                    lo, hi = _edge_time_interval(edge_h, edge_gamma, edge_g, edge_fg, edge_abs, gamma_per_tile, tri,
                                                 x0, x1, y0, y1, lo, hi, ops)
                if lo > hi:
                    events[EV_REJ_EDGE] += 1
                    continue
                # the box taken over the narrowed [lo, hi] is tighter (Munkberg11 §4.1 applied again)
                if lo > ta or hi < tb:
                    lo, hi = box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, lo, hi, ops)
                    if lo > hi:
                        events[EV_REJ_BOX] += 1
                        continue
        elif algorithm == ALG_HULL:
            if wpos and not has_lens and hull_n[tri] > 0:
                # the sample tester's float32 vertices move the true hull by ~F32_REL of its coordinates
                mag = 1.0
                for k in range(hull_n[tri]):
                    mag = max(mag, abs(hull[tri, k, 0]) + abs(hull[tri, k, 1]))
                pad = F32_REL * mag
                if not hull_overlaps_tile(hull, hull_n, hull_off, tri, x0 - pad, x1 + pad, y0 - pad, y1 + pad, ops):
                    events[EV_REJ_HULL] += 1
                    continue
        elif algorithm == ALG_INTERLEAVE:
            mk = interleave_mask(p0, dp, l0, dl, tri, tuples, x0, x1, y0, y1, ta, tb, ops)
            if mk == 0:
                events[EV_REJ_TUPLES] += 1
                continue
            mask[i] = mk
        # a triangle without lens shift is seen alike from every lens position
        lens_live = has_lens and wpos and (
            (algorithm == ALG_HIERARCHICAL and lens_bounds) or algorithm == ALG_DUAL or algorithm == ALG_TWO_STAGE)
        if lens_live:  # Wu13 §3.3 (stage 1): lens bounds from the vertices at the ends of t^
            a, b = _lens_interval(p0, dp, l0, dl, tri, 0, x0, x1, lo, hi, ops)
            ulo, uhi = max(ulo, a), min(uhi, b)
            if ulo > uhi:
                events[EV_REJ_LENS] += 1
                continue
            a, b = _lens_interval(p0, dp, l0, dl, tri, 1, y0, y1, lo, hi, ops)
            vlo, vhi = max(vlo, a), min(vhi, b)
            if vlo > vhi:
                events[EV_REJ_LENS] += 1
                continue
        if algorithm == ALG_DUAL and wpos:
            lo, hi = dual_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ulo, uhi, vlo, vhi, lo, hi, ops)
            if lo > hi:
                events[EV_REJ_DUAL] += 1
                continue
        if algorithm == ALG_TWO_STAGE:
            if wpos:  # Wu13 §3.4 (stage 2): time bounds linear in u (x axis) and v (y axis)
                l_c, l_s, h_c, h_s = two_stage_lines(p0, dp, l0, dl, tri, 0, x0, x1, ulo, uhi, lo, hi, ops)
                m_c, m_s, k_c, k_s = two_stage_lines(p0, dp, l0, dl, tri, 1, y0, y1, vlo, vhi, lo, hi, ops)
            else:
                l_c, l_s, h_c, h_s = lo, 0.0, hi, 0.0
                m_c, m_s, k_c, k_s = lo, 0.0, hi, 0.0
            lo = max(lo, min(l_c + l_s * ulo, l_c + l_s * uhi), min(m_c + m_s * vlo, m_c + m_s * vhi))
            hi = min(hi, max(h_c + h_s * ulo, h_c + h_s * uhi), max(k_c + k_s * vlo, k_c + k_s * vhi))
            ops[OP_MADD] += 8
            ops[OP_CMP] += 8
            if lo > hi:
                events[EV_REJ_TWO] += 1
                continue
            lines[i, 0] = l_c - LINE_F32_REL * (abs(l_c) + abs(l_s))
            lines[i, 1] = l_s
            lines[i, 2] = h_c + LINE_F32_REL * (abs(h_c) + abs(h_s))
            lines[i, 3] = h_s
            lines[i, 4] = m_c - LINE_F32_REL * (abs(m_c) + abs(m_s))
            lines[i, 5] = m_s
            lines[i, 6] = k_c + LINE_F32_REL * (abs(k_c) + abs(k_s))
            lines[i, 7] = k_s
        zl, zh = -1.0, 1.0
        if wpos:
            zl, zh = np.inf, -np.inf
            for s in range(2):
                t = lo if s == 0 else hi
                for k in range(3):
                    z = (p0[tri, k, 2] + t * dp[tri, k, 2]) / (p0[tri, k, 3] + t * dp[tri, k, 3])
                    zl = min(zl, z)
                    zh = max(zh, z)
            if (fl & FLAG_PLANE) != 0:
                w_lo, w_hi = plane_w_bounds(plane_n, plane_d, tri, x0, x1, y0, y1, lo, hi, ops)
                # z/w = c1 + c0 / w grows with w (c0 < 0)
                if w_hi < np.inf:
                    zh = min(zh, depth_c1 + depth_c0 / w_hi)
                if w_lo > 0.0:
                    zl = max(zl, depth_c1 + depth_c0 / w_lo)
            pad = 1e-6 * (1.0 + abs(zl) + abs(zh))
            zl = max(-1.0, zl - pad)
            zh = min(1.0, zh + pad)
            ops[OP_MADD] += 12
            ops[OP_RCP] += 6
            ops[OP_MUL] += 6
            ops[OP_CMP] += 12
        ops[OP_CMP] += 6
        if ulo > uhi or vlo > vhi:
            events[EV_REJ_LENS] += 1
            continue
        out_keep[i] = True
        events[EV_ACCEPT] += 1
        t_lo[i] = lo
        t_hi[i] = hi
        u_lo[i] = ulo
        u_hi[i] = uhi
        v_lo[i] = vlo
        v_hi[i] = vhi
        z_lo[i] = zl
        z_hi[i] = zh


class TileTest:
    """Functional model of the tile test unit."""

    name = "tile_test"
    events = EVENTS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, table, tile_size: int, width: int, height: int,
                 depth_w: tuple[float, float] | None = None, clips: np.ndarray | None = None,
                 tuples: np.ndarray | None = None):
        self.config = config
        # the user clip planes (t_lo, t_hi, u_lo, u_hi, v_lo, v_hi) of the draw the next batches belong to
        self.clips = np.array([0.0, 1.0, -1.0, 1.0, -1.0, 1.0]) if clips is None else np.asarray(clips, np.float64)
        self.table = table
        self.tile_size = tile_size
        self.width = width
        self.height = height
        self.depth_c1, self.depth_c0 = depth_w if depth_w is not None else (0.0, 0.0)
        self.algorithm = ALGORITHM_CODES[config.algorithm]
        if self.algorithm == ALG_INTERLEAVE and tuples is None:
            raise ValueError("interleave_uvt needs the sample set's (u, v, t) tuples")
        self.tuples = tuples if tuples is not None else np.zeros((0, 3))

    def run(self, tiles: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Test a batch of tile records; return the survivors with intervals.

        Two-stage culling adds ``lines`` (n, 8) float32 per record: t >= c + s u,
        t <= c + s u (x axis), then the same in v (y axis); Interleave UVT adds
        ``mask``, the (n,) uint64 bit set of tuples that may cover the tile.
        """
        n = len(tiles["tri"])
        keep = np.zeros(n, np.bool_)
        iv = {name: np.empty(n) for name in ("t_lo", "t_hi", "u_lo", "u_hi", "v_lo", "v_hi", "z_lo", "z_hi")}
        lines = np.empty((n if self.algorithm == ALG_TWO_STAGE else 0, 8))
        mask = np.zeros(n if self.algorithm == ALG_INTERLEAVE else 0, np.uint64)
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        t = self.table
        cfg = self.config
        tile_test_kernel(tiles["tri"], tiles["tx"], tiles["ty"], self.tile_size, self.width, self.height,
                         self.algorithm, cfg.edge_test, cfg.edge_solver == "quadratic", cfg.gamma == "tile",
                         cfg.lens_bounds, self.clips,
                         t.p0, t.dp, t.l0, t.dl, t.t_span, t.flags, t.edge_f, t.edge_h, t.edge_gamma, t.edge_g,
                         t.edge_fg, t.edge_abs, t.plane_n, t.plane_d, t.hull, t.hull_n, t.hull_off, self.tuples,
                         self.depth_c1, self.depth_c0, keep,
                         iv["t_lo"], iv["t_hi"], iv["u_lo"], iv["u_hi"], iv["v_lo"], iv["v_hi"],
                         iv["z_lo"], iv["z_hi"], lines if len(lines) else np.empty((n, 8)),
                         mask if len(mask) else np.zeros(n, np.uint64), ops, events)
        out = {name: arr[keep] for name, arr in tiles.items()}
        out.update({name: arr[keep] for name, arr in iv.items()})
        if self.algorithm == ALG_TWO_STAGE:
            out["lines"] = lines[keep].astype(np.float32)
        if self.algorithm == ALG_INTERLEAVE:
            out["mask"] = mask[keep]
        out["noread"] = np.zeros(len(out["tri"]), np.bool_)  # set by z-cull when it runs
        return out, ops, events
