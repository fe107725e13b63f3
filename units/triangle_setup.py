"""Triangle setup: moving, defocused triangles to per-triangle constants.

Implements docs/pipeline.md §2.1. For each triangle of a batch:

* homogeneous normalisation: clip coordinates are homogeneous, so a
  triangle's (x, y, z, w) at t=0 and t=1 and its lens shifts (a shift of x
  and y) may all be multiplied by one positive factor without changing the
  triangle. Setup divides them by the power of two 2^e that brings the
  largest magnitude among them into [0.5, 1): exact in floating point (the
  same bits, only the exponent changes), so every later value is the
  unnormalised one times a power of two, and products of two or three
  coordinates (edge functions, the determinant) neither overflow nor
  underflow in the sample tester's float32 for triangles written at any
  scale. Depth is a ratio (z/w) and unaffected; the moving-plane bounds on w
  are scaled back (``plane_d``), since the draw's depth_w relation takes w
  in the draw's units. A power-of-two scale is an exponent adjustment and
  no float operation: it is not counted;
* clip-space vertices at t=0 and t=1 to pixel-space 2D homogeneous
  coordinates (X, Y, W) with row 0 at the top, pixel centres at +0.5, and the
  per-vertex lens shift (circle of confusion, linear in w; Wu13 §3.1);
* temporal frustum culling: the time span [ts, te] in which any vertex, at
  any lens position, can be inside all six clip planes (Munkberg11 §3);
* conservative facing: the 2DH determinant D(t, u, v) = p0 . (p2 x p1) is a
  cubic in t and bilinear in (u, v); its Bernstein coefficients bound it, so
  a triangle is culled as back-facing only if D < 0 everywhere (Gribel10 §4.3,
  Munkberg and Akenine-Moller 2011);
* zero area throughout (two vertices coincide for every (t, u, v), or D == 0
  everywhere): counted as degenerate. Conservative mode (Nilsson12 §2) keeps
  the triangle, with no facing: edge-on it is a segment or a point that still
  touches pixels, and the tile test's moving bounding box finds them (a
  triangle without facing gets no edge functions). Standard mode drops it,
  since no sample can be covered. In exact arithmetic the sample tester
  misses where D = 0, and the tie rule alone would miss too: off the
  triangle's line some edge function is negative (the three sum to D = 0), on
  it all three are zero, and two of its edges run in opposite directions (the
  edge vectors sum to zero), whose normals are never both top-left, while a
  zero-length edge's normal (0, 0) is not top-left. Coinciding vertices are
  the same float32 bits at every sample, so there the argument holds bit for
  bit; for D == 0 evaluated in float64 it holds up to the rounding of the
  tester's float32 vertices (a sliver of relative width about 2^-24);
* conservative screen bounds: the vertices at ts and te, widened by the lens
  shift at u, v = +-1 (exact extremes, since x = (X + u LX) / W is monotone in
  t and linear in u while W > 0), or the whole screen when a vertex path
  crosses w = 0 during the shutter (Munkberg11 §3);
* the linearized moving-edge constants h and gamma of Munkberg11 eq. 4-7 (for
  motion-only triangles of constant facing), with edge functions
  e_k(x, y, t) = (f t^2 + g t + h) . (x, y, 1) from Gribel10 eq. 3-5.
"""

from __future__ import annotations

import math
from types import ModuleType

import numba as nb
import numpy as np

from pipeline_sim.definitions import N_OPS, OP_CMP, OP_MADD, OP_MUL, OP_RCP
from pipeline_sim.records import TRIANGLE
from units.rounding import F32_REL

# its events, in the order of the kernel's event vector, and what each counts
EVENT_MEANINGS = {
    "culled_frustum": "triangles outside the view frustum at every time and lens position",
    "culled_backface": "triangles facing away at every (t, u, v)",
    "degenerate": "triangles of zero area throughout (dropped, but kept in conservative mode)",
    "crossing_w0": "triangles with a vertex path crossing w = 0",
    "moving": "triangles that move during the shutter",
    "defocused": "triangles with a lens shift",
    "mixed_facing": "triangles whose facing changes over (t, u, v)",
}
EVENTS = tuple(EVENT_MEANINGS)
EV_FRUSTUM, EV_BACKFACE, EV_DEGENERATE, EV_W0, EV_MOVING, EV_DEFOCUS, EV_MIXED = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): none; upstream of z-cull, every triangle is seen whatever the timing
TIMING_DEPENDENT: tuple[str, ...] = ()

ST_OK, ST_FRUSTUM, ST_BACKFACE, ST_DEGENERATE = 0, 1, 2, 3
W_EPS = 1e-9  # w below this counts as crossing the camera plane
# facing (front or back for every (t, u, v)) is claimed only when every
# Bernstein coefficient of D exceeds this fraction of |p0||p1||p2|
FACING_REL = 1e-10


FLAG_LENS, FLAG_WPOS, FLAG_EDGE, FLAG_MOVING, FLAG_PLANE = 1, 2, 4, 8, 16

# the kernel's helpers, called from compiled code only: without the wrappers that let Python call a
# function, which numba otherwise builds and optimises for each (a good part of a helper's compile time),
# and without reference counting (they allocate nothing; the kernel holds every array they take):
# LLVM inlines them into the kernel, but not the count up and down of each array argument, which
# measured a third of setup's run time
_helper = nb.njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, _nrt=False)


@_helper
def _interval_hull_nonneg(a, b, lo, hi):
    """Grow [lo, hi] by the part of [0,1] where a + b t >= 0 (hull of the union)."""
    end = a + b
    if a >= 0.0 and end >= 0.0:
        return 0.0, 1.0
    if a < 0.0 and end < 0.0:
        return lo, hi
    tc = a / (a - end)
    if a >= 0.0:  # non-negative on [0, tc]
        return min(lo, 0.0), max(hi, min(1.0, tc * (1.0 + 1e-9) + 1e-12))
    return min(lo, max(0.0, tc * (1.0 - 1e-9) - 1e-12)), max(hi, 1.0)


@nb.njit(cache=True, inline="always")
def _homogeneous_scale(q, r, lens_x, lens_y, tri):
    """The power of two 2^-e that brings the largest |clip coordinate| or |lens
    shift| of ``tri`` into [0.5, 1); 1 when they are all zero or the largest
    is not finite. (Capped at 2^1023 so it stays finite: only coordinates below
    2^-1024, float64 subnormals, would need more.)"""
    m = 0.0
    for k in range(3):
        for c in range(4):
            m = max(m, abs(q[tri, k, c]), abs(r[tri, k, c]))
        for s in range(2):
            m = max(m, abs(lens_x[tri, k, s]), abs(lens_y[tri, k, s]))
    if not (0.0 < m < np.inf):
        return 1.0
    return math.ldexp(1.0, min(-math.frexp(m)[1], 1023))


@_helper
def _det(x0, y0, w0, x1, y1, w1, x2, y2, w2):
    # D = p0 . (p2 x p1); positive for front-facing (counter-clockwise in NDC)
    cx = y2 * w1 - w2 * y1
    cy = w2 * x1 - x2 * w1
    cw = x2 * y1 - y2 * x1
    return x0 * cx + y0 * cy + w0 * cw


@nb.njit(cache=True, nogil=True)
def setup_kernel(ids, q, r, lens_x, lens_y, width, height, tile_size, backface_culling, keep_degenerate, view, table,
                 depth_planes, status, ops, events):
    """Triangle setup for the triangles ``ids`` (docs/pipeline.md §2.1; Munkberg11 §3-4, Gribel10 eq. 3-5).

    ``keep_degenerate``: keep triangles of zero area throughout (conservative
    mode, Nilsson12 §2) rather than drop them. ``view``: the (u, v, t) of the reference camera whose view keys the
    shading cache (``ref``; Nilsson12 §2, §8). Writes the per-triangle
    ``table`` (``pipeline_sim.records.TRIANGLE``) in place, ``status`` per batch item and accumulates ``ops`` (arithmetic
    classes) and ``events``.

    Each step of the module docstring is a helper of its own, which numba compiles once as a function
    (LLVM inlines it afterwards): numba's compile time grows faster than a function's length, and one
    long body took most of setup's.
    """
    # the table's arrays taken once: each use of a field of the namedtuple counts a reference up and down
    p0, dp, l0, dl = table.p0, table.dp, table.l0, table.dl
    p0_32, dp_32, l0_32, dl_32 = table.p0_32, table.dp_32, table.l0_32, table.dl_32
    t_span, bounds, facing, flags = table.t_span, table.bounds, table.facing, table.flags
    edge_f, edge_h, edge_gamma, edge_g = table.edge_f, table.edge_h, table.edge_gamma, table.edge_g
    edge_fg, edge_abs, ref, edge_eps = table.edge_fg, table.edge_abs, table.ref, table.edge_eps
    plane_n, plane_d = table.plane_n, table.plane_d
    hx = 0.5 * width
    hy = 0.5 * height
    px = np.empty((2, 3, 4))  # pixel-space (X, Y, Z, W) at t=0, t=1
    lx = np.empty((2, 3, 2))
    # scratch rows for the helpers, allocated once: an allocation per triangle would cost more than its arithmetic
    scratch = np.empty((8, 4))
    for b in range(ids.shape[0]):
        tri = ids[b]
        sc, moving, has_lens = _pixel_space(q, r, lens_x, lens_y, tri, hx, hy, px, lx)
        ops[OP_MADD] += 24
        ops[OP_MUL] += 12
        if moving:
            events[EV_MOVING] += 1
        if has_lens:
            events[EV_DEFOCUS] += 1
        _store_vertices(px, lx, view, width, height, tri, p0, dp, l0, dl, p0_32, dp_32, l0_32, dl_32, ref, edge_eps)

        ts, te = _frustum_span(px, lx, width, height, scratch)
        ops[OP_MADD] += 6 * 12
        ops[OP_CMP] += 6 * 12
        if ts > te:
            status[b] = ST_FRUSTUM
            events[EV_FRUSTUM] += 1
            continue
        t_span[tri, 0] = ts
        t_span[tri, 1] = te

        bern_min, bern_max, scale = _determinant_bounds(px, lx, moving, has_lens, scratch)
        nu = 2 if has_lens else 1
        ops[OP_MADD] += (4 if moving else 1) * nu * nu * 15
        ops[OP_MUL] += (4 if moving else 1) * nu * nu * 6
        tol = FACING_REL * scale  # facing is only claimed with a clear margin
        if _vertices_coincide(px, lx) or (bern_max == 0.0 and bern_min == 0.0):
            events[EV_DEGENERATE] += 1
            if not keep_degenerate:
                status[b] = ST_DEGENERATE
                continue
            facing[tri] = 0  # neither front nor back: never culled as back-facing
        elif bern_min > tol:
            facing[tri] = 1
        elif bern_max < -tol:
            facing[tri] = -1
        else:
            facing[tri] = 0
            events[EV_MIXED] += 1
        if backface_culling and facing[tri] == -1:
            status[b] = ST_BACKFACE
            events[EV_BACKFACE] += 1
            continue

        wpos, bx0, bx1, by0, by1 = _screen_bounds(px, lx, ts, te, width, height)
        fl = 0
        if has_lens:
            fl |= FLAG_LENS
        if moving:
            fl |= FLAG_MOVING
        if wpos:
            fl |= FLAG_WPOS
            ops[OP_RCP] += 6
            ops[OP_MUL] += 24
            ops[OP_CMP] += 24
        else:
            events[EV_W0] += 1
        if bx1 <= bx0 or by1 <= by0:
            status[b] = ST_FRUSTUM
            events[EV_FRUSTUM] += 1
            continue
        bounds[tri, 0] = bx0
        bounds[tri, 1] = bx1
        bounds[tri, 2] = by0
        bounds[tri, 3] = by1

        if (not has_lens) and facing[tri] != 0:
            _moving_edges(px, float(facing[tri]), bx0, bx1, by0, by1, tile_size, tri, edge_f, edge_h, edge_gamma, edge_g,
                          edge_fg, edge_abs, scratch)
            fl |= FLAG_EDGE
            ops[OP_MUL] += 3 * 18
            ops[OP_MADD] += 3 * 18
            ops[OP_CMP] += 3 * 6
        if depth_planes and wpos:
            _moving_planes(px, lx, sc, tri, plane_n, plane_d, scratch)
            fl |= FLAG_PLANE
            ops[OP_MUL] += 2 * (6 + 3 * 2 * 5)
            ops[OP_MADD] += 2 * (6 + 3 * 2 * 4)
        flags[tri] = fl
        status[b] = ST_OK


@_helper
def _pixel_space(q, r, lens_x, lens_y, tri, hx, hy, px, lx):
    """Homogeneous normalisation and the pixel-space transform of ``tri`` (module docstring):
    fills ``px`` with (X, Y, Z, W) and ``lx`` with the lens shift (LX, LY) of each vertex at t=0
    and t=1; returns (the scale 2^-e, whether it moves, whether it has a lens shift)."""
    has_lens = False
    sc = _homogeneous_scale(q, r, lens_x, lens_y, tri)
    for s in range(2):
        src = q if s == 0 else r
        for k in range(3):
            x = src[tri, k, 0] * sc
            y = src[tri, k, 1] * sc
            z = src[tri, k, 2] * sc
            w = src[tri, k, 3] * sc
            px[s, k, 0] = (x + w) * hx
            px[s, k, 1] = (w - y) * hy
            px[s, k, 2] = z
            px[s, k, 3] = w
            lx[s, k, 0] = lens_x[tri, k, s] * sc * hx
            lx[s, k, 1] = -lens_y[tri, k, s] * sc * hy
            if lx[s, k, 0] != 0.0 or lx[s, k, 1] != 0.0:
                has_lens = True
    moving = False
    for k in range(3):
        for c in range(4):
            if px[1, k, c] != px[0, k, c]:
                moving = True
    return sc, moving, has_lens


@_helper
def _store_vertices(px, lx, view, width, height, tri, p0, dp, l0, dl, p0_32, dp_32, l0_32, dl_32, ref, edge_eps):
    """Writes the vertices of ``tri`` (at t=0 and their change to t=1, float64 and float32), the vertices
    its reference camera sees and the float32 edge-function error bound of the sample tester."""
    for k in range(3):
        for c in range(4):
            p0[tri, k, c] = px[0, k, c]
            dp[tri, k, c] = px[1, k, c] - px[0, k, c]
            p0_32[tri, k, c] = np.float32(px[0, k, c])
            dp_32[tri, k, c] = np.float32(px[1, k, c] - px[0, k, c])
        for c in range(2):
            l0[tri, k, c] = lx[0, k, c]
            dl[tri, k, c] = lx[1, k, c] - lx[0, k, c]
            l0_32[tri, k, c] = np.float32(lx[0, k, c])
            dl_32[tri, k, c] = np.float32(lx[1, k, c] - lx[0, k, c])
        # the vertex seen by the reference camera: at time view[2], lens position (view[0], view[1])
        for c in range(3):
            cc = c if c < 2 else 3
            at = (1.0 - view[2]) * px[0, k, cc] + view[2] * px[1, k, cc]
            if c < 2 and view[c] != 0.0:
                at += view[c] * ((1.0 - view[2]) * lx[0, k, c] + view[2] * lx[1, k, c])
            ref[tri, k, c] = np.float32(at)
    # |e32 - e| <= 9 * 2^-24 * m^2 * (|x| + |y| + 1) with m the largest
    # |X|, |Y|, |W| of any vertex at any (t, u, v) (extremes at the corners)
    m = 0.0
    for s in range(2):
        for k in range(3):
            m = max(m, abs(px[s, k, 0]) + abs(lx[s, k, 0]), abs(px[s, k, 1]) + abs(lx[s, k, 1]), abs(px[s, k, 3]))
    edge_eps[tri] = np.float32(2e-6 * m * m * (width + height + 1.0))


@_helper
def _frustum_span(px, lx, width, height, scratch):
    """Temporal frustum culling (Munkberg11 §3), lens-conservative: the span [ts, te] of
    the shutter in which a vertex can be inside each of the six clip planes (empty: ts > te)."""
    g = scratch[0]
    ls = scratch[1]
    ts = 0.0
    te = 1.0
    for plane in range(6):
        lo = 2.0
        hi = -1.0
        for k in range(3):
            for s in range(2):
                X = px[s, k, 0]
                Y = px[s, k, 1]
                Z = px[s, k, 2]
                W = px[s, k, 3]
                if plane == 0:
                    g[s] = X
                    ls[s] = abs(lx[s, k, 0])
                elif plane == 1:
                    g[s] = width * W - X
                    ls[s] = abs(lx[s, k, 0])
                elif plane == 2:
                    g[s] = Y
                    ls[s] = abs(lx[s, k, 1])
                elif plane == 3:
                    g[s] = height * W - Y
                    ls[s] = abs(lx[s, k, 1])
                elif plane == 4:
                    g[s] = Z + W
                    ls[s] = 0.0
                else:
                    g[s] = W - Z
                    ls[s] = 0.0
            # max over u in [-1, 1] of g + u * L(t) is the max of two lines
            for sign in (-1.0, 1.0):
                a = g[0] + sign * (lx[0, k, 0] if plane < 2 else (lx[0, k, 1] if plane < 4 else 0.0))
                e = g[1] + sign * (lx[1, k, 0] if plane < 2 else (lx[1, k, 1] if plane < 4 else 0.0))
                # tolerance: relative to the magnitude of the terms
                # widened by float32 rounding: the sample tester lerps float32 vertices
                tol = 1e-6 * (abs(g[0]) + abs(g[1]) + ls[0] + ls[1] + abs(px[0, k, 3]) + abs(px[1, k, 3])
                              + abs(px[0, k, 0]) + abs(px[1, k, 0]) + abs(px[0, k, 1]) + abs(px[1, k, 1]))
                lo, hi = _interval_hull_nonneg(a + tol, e + tol - (a + tol), lo, hi)
        ts = max(ts, lo)
        te = min(te, hi)
    return ts, te


@_helper
def _determinant_bounds(px, lx, moving, has_lens, scratch):
    """Conservative facing: (min, max) of the Bernstein coefficients of the determinant D(t, u, v)
    over the lens corners, cubic in t (Gribel10 §4.3), and its scale max |p0||p1||p2|."""
    vx = scratch[0]
    vy = scratch[1]
    vw = scratch[2]
    f = scratch[3]
    nu = 2 if has_lens else 1
    bern_min = np.inf
    bern_max = -np.inf
    scale = 0.0
    for iu in range(nu):
        u = (2.0 * iu - 1.0) if has_lens else 0.0
        for iv in range(nu):
            v = (2.0 * iv - 1.0) if has_lens else 0.0
            for it in range(4 if moving else 1):
                t = it / 3.0
                prod = 1.0
                for k in range(3):
                    vx[k] = px[0, k, 0] + t * (px[1, k, 0] - px[0, k, 0]) + u * (lx[0, k, 0] + t * (lx[1, k, 0] - lx[0, k, 0]))
                    vy[k] = px[0, k, 1] + t * (px[1, k, 1] - px[0, k, 1]) + v * (lx[0, k, 1] + t * (lx[1, k, 1] - lx[0, k, 1]))
                    vw[k] = px[0, k, 3] + t * (px[1, k, 3] - px[0, k, 3])
                    prod *= np.sqrt(vx[k] * vx[k] + vy[k] * vy[k] + vw[k] * vw[k])
                # |D| <= |p0| |p1| |p2|: the scale of D, invariant to each vertex's 2DH scale
                scale = max(scale, prod)
                f[it] = _det(vx[0], vy[0], vw[0], vx[1], vy[1], vw[1], vx[2], vy[2], vw[2])
            if moving:
                c1 = (-5.0 * f[0] + 18.0 * f[1] - 9.0 * f[2] + 2.0 * f[3]) / 6.0
                c2 = (2.0 * f[0] - 9.0 * f[1] + 18.0 * f[2] - 5.0 * f[3]) / 6.0
                bern_min = min(bern_min, f[0], c1, c2, f[3])
                bern_max = max(bern_max, f[0], c1, c2, f[3])
            else:
                bern_min = min(bern_min, f[0])
                bern_max = max(bern_max, f[0])
    return bern_min, bern_max, scale


@_helper
def _vertices_coincide(px, lx):
    """Whether two vertices coincide for every (t, u, v): zero area throughout. (An exactly zero
    determinant is the other case; a tiny one can still cover samples: a vertex near the 2DH
    origin keeps its direction.) Conservative mode keeps such a triangle (an edge-on triangle is
    a segment or a point that still touches pixels; its tiles are found by the moving bounding
    box, without edge functions, since it has no facing); standard mode drops it, since the
    sample tester covers no sample of it (module docstring)."""
    for k in range(3):
        j = (k + 1) % 3
        same = True
        for s in range(2):
            for c in (0, 1, 3):
                if px[s, k, c] != px[s, j, c]:
                    same = False
            for c in range(2):
                if lx[s, k, c] != lx[s, j, c]:
                    same = False
        if same:
            return True
    return False


@_helper
def _screen_bounds(px, lx, ts, te, width, height):
    """Conservative screen bounds over [ts, te] (Munkberg11 §3): (w > 0 throughout, x0, x1, y0, y1)
    in pixels, exclusive ends; the whole screen when a vertex path crosses w = 0."""
    for s in range(2):
        for k in range(3):
            wt = px[0, k, 3] + (ts if s == 0 else te) * (px[1, k, 3] - px[0, k, 3])
            if not wt > W_EPS:
                return False, 0, width, 0, height
    xmin = np.inf
    xmax = -np.inf
    ymin = np.inf
    ymax = -np.inf
    for s in range(2):
        t = ts if s == 0 else te
        for k in range(3):
            X = px[0, k, 0] + t * (px[1, k, 0] - px[0, k, 0])
            Y = px[0, k, 1] + t * (px[1, k, 1] - px[0, k, 1])
            W = px[0, k, 3] + t * (px[1, k, 3] - px[0, k, 3])
            LX = abs(lx[0, k, 0] + t * (lx[1, k, 0] - lx[0, k, 0]))
            LY = abs(lx[0, k, 1] + t * (lx[1, k, 1] - lx[0, k, 1]))
            inv = 1.0 / W
            xmin = min(xmin, (X - LX) * inv)
            xmax = max(xmax, (X + LX) * inv)
            ymin = min(ymin, (Y - LY) * inv)
            ymax = max(ymax, (Y + LY) * inv)
    pad = 1e-3
    bx0 = int(max(0.0, min(float(width), np.floor(xmin - pad))))
    bx1 = int(max(0.0, min(float(width), np.ceil(xmax + pad))))
    by0 = int(max(0.0, min(float(height), np.floor(ymin - pad))))
    by1 = int(max(0.0, min(float(height), np.ceil(ymax + pad))))
    return True, bx0, bx1, by0, by1


@_helper
def _moving_edges(px, sgn, bx0, bx1, by0, by1, tile_size, tri, edge_f, edge_h, edge_gamma, edge_g, edge_fg, edge_abs,
                  scratch):
    """The linearized moving edges of a motion-only triangle of facing ``sgn`` (Munkberg11 eq. 4-7):
    per edge, n(t) = f t^2 + g t + h (Gribel10 eq. 3-5) and the slope bound Gamma over the bounds."""
    di = scratch[0]
    dj = scratch[1]
    hv = scratch[2]
    fv = scratch[3]
    ga = scratch[4]
    gb = scratch[5]
    gv = scratch[6]
    ab = scratch[7]
    # bounds aligned to the tile grid: every tile sample lies inside S
    sx0 = float((bx0 // tile_size) * tile_size)
    sy0 = float((by0 // tile_size) * tile_size)
    sx1 = float(((bx1 + tile_size - 1) // tile_size) * tile_size)
    sy1 = float(((by1 + tile_size - 1) // tile_size) * tile_size)
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        qi = px[0, i]
        qj = px[0, j]
        for c in range(4):
            di[c] = px[1, i, c] - px[0, i, c]
            dj[c] = px[1, j, c] - px[0, j, c]
        # n(t) = p_j(t) x p_i(t) over (X, Y, W) = f t^2 + g t + h
        _cross3(qj[0], qj[1], qj[3], qi[0], qi[1], qi[3], hv)
        _cross3(dj[0], dj[1], dj[3], di[0], di[1], di[3], fv)
        _cross3(qj[0], qj[1], qj[3], di[0], di[1], di[3], ga)
        _cross3(dj[0], dj[1], dj[3], qi[0], qi[1], qi[3], gb)
        for c in range(3):
            gv[c] = ga[c] + gb[c]
        gam = -np.inf
        for pass_ in range(2):
            ax = sgn * (gv[0] + (fv[0] if pass_ == 1 else 0.0))
            ay = sgn * (gv[1] + (fv[1] if pass_ == 1 else 0.0))
            aw = sgn * (gv[2] + (fv[2] if pass_ == 1 else 0.0))
            m = aw + (ax * sx1 if ax > 0 else ax * sx0) + (ay * sy1 if ay > 0 else ay * sy0)
            gam = max(gam, m)
        # the magnitudes of the products behind h, g and f: float32 vertices move
        # the edge function by up to ~2^-23 of these, however much f, g, h cancel
        _abs_cross3(qj[0], qj[1], qj[3], qi[0], qi[1], qi[3], ab)
        for c in range(3):
            edge_abs[tri, k, c] = ab[c]
        _abs_cross3(qj[0], qj[1], qj[3], di[0], di[1], di[3], ab)
        for c in range(3):
            edge_abs[tri, k, c] += ab[c]
        _abs_cross3(dj[0], dj[1], dj[3], qi[0], qi[1], qi[3], ab)
        for c in range(3):
            edge_abs[tri, k, c] += ab[c]
        _abs_cross3(dj[0], dj[1], dj[3], di[0], di[1], di[3], ab)
        for c in range(3):
            edge_abs[tri, k, c] += ab[c]
        # widen by that rounding so the bound stays conservative
        mag = (edge_abs[tri, k, 0] * max(abs(sx0), abs(sx1)) + edge_abs[tri, k, 1] * max(abs(sy0), abs(sy1))
               + edge_abs[tri, k, 2])
        edge_gamma[tri, k] = gam + F32_REL * mag
        for c in range(3):
            edge_f[tri, k, c] = sgn * fv[c]
            edge_h[tri, k, c] = sgn * hv[c]
            edge_g[tri, k, c] = sgn * gv[c]
            edge_fg[tri, k, c] = sgn * (fv[c] + gv[c])


@_helper
def _moving_planes(px, lx, sc, tri, plane_n, plane_d, scratch):
    """Moving plane equations for depth bounds (Nilsson12 App. A): the triangle's plane at t=0
    and t=1 and, per side, its offsets over the vertices and lens positions, in the draw's units."""
    e1 = scratch[0]
    e2 = scratch[1]
    nv = scratch[2]
    for which in range(2):
        # plane through the triangle at t=0 (which=0) or t=1 (which=1), in (X, Y, W)
        for c in range(4):
            e1[c] = px[which, 1, c] - px[which, 0, c]
            e2[c] = px[which, 2, c] - px[which, 0, c]
        _cross3(e1[0], e1[1], e1[3], e2[0], e2[1], e2[3], nv)
        nl = abs(nv[0]) + abs(nv[1]) + abs(nv[2])
        if nl == 0.0:
            plane_n[tri, which, 0] = np.nan  # no plane: test off
            continue
        for c in range(3):
            plane_n[tri, which, c] = nv[c] / nl
        # extremes of n . p over the vertices and lens positions at t=0 and t=1
        for s in range(2):
            hi_v = -np.inf
            lo_v = np.inf
            for k in range(3):
                base = (plane_n[tri, which, 0] * px[s, k, 0] + plane_n[tri, which, 1] * px[s, k, 1]
                        + plane_n[tri, which, 2] * px[s, k, 3])
                spread = abs(plane_n[tri, which, 0] * lx[s, k, 0]) + abs(plane_n[tri, which, 1] * lx[s, k, 1])
                hi_v = max(hi_v, base + spread)
                lo_v = min(lo_v, base - spread)
            # side + : n.P + D(t) <= 0 for the triangle; side - : n.P + D(t) >= 0
            # with D(t) = d0 + v t; value at s=0 is d0, at s=1 is d0 + v; in
            # the draw's units (w bounds become depth through its depth_w)
            hi_v /= sc
            lo_v /= sc
            if s == 0:
                plane_d[tri, which, 0, 0] = -hi_v
                plane_d[tri, which, 1, 0] = -lo_v
            else:
                plane_d[tri, which, 0, 1] = -hi_v - plane_d[tri, which, 0, 0]
                plane_d[tri, which, 1, 1] = -lo_v - plane_d[tri, which, 1, 0]


@_helper
def _abs_cross3(ax, ay, aw, bx, by, bw, out):
    """Per component, the sum of the absolute products of a x b (a bound on its rounding)."""
    out[0] = abs(ay * bw) + abs(aw * by)
    out[1] = abs(aw * bx) + abs(ax * bw)
    out[2] = abs(ax * by) + abs(ay * bx)


@_helper
def _cross3(ax, ay, aw, bx, by, bw, out):
    out[0] = ay * bw - aw * by
    out[1] = aw * bx - ax * bw
    out[2] = ax * by - ay * bx


class TriangleSetup:
    """Functional model of the triangle setup unit over a whole draw.

    ``table``: the per-triangle table (``pipeline_sim.records.TRIANGLE``);
    ``extension``: the fields the culling algorithm ``culling`` (a module of
    ``units.culling``) adds to it, filled by its ``setup_extras``; None when it adds none;
    ``keep_degenerate``: keep triangles of zero area throughout (conservative mode).
    """

    name = "triangle_setup"
    events = EVENTS
    event_meanings = EVENT_MEANINGS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, draw, tile_size: int, backface_culling: bool = False,
                 culling: ModuleType | None = None, shading_view: tuple[float, float, float] = (0.0, 0.0, 0.5),
                 keep_degenerate: bool = False):
        self.config = config
        self.backface_culling = backface_culling
        self.keep_degenerate = keep_degenerate  # conservative mode: zero-area triangles still touch pixels
        self.shading_view = np.array(shading_view, np.float64)  # (u, v, t) of the shading cache's reference camera
        self.draw = draw
        self.tile_size = tile_size
        self.table = TRIANGLE.table(draw.n)
        self.extras = culling.setup_extras if culling is not None else None
        self.extension = culling.TRIANGLE_EXT.table(draw.n) if culling is not None and culling.TRIANGLE_EXT.names \
            else None

    def run(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Set up ``ids``; return (surviving ids, ops vector, events vector)."""
        d = self.draw
        status = np.zeros(len(ids), np.int8)
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        setup_kernel(ids, d.q, d.r, d.lens_x, d.lens_y, d.width, d.height, self.tile_size,
                     self.backface_culling, self.keep_degenerate, self.shading_view, self.table, d.depth_w is not None, status, ops, events)
        self.last_status = status
        kept = ids[status == ST_OK]
        if self.extras is not None:
            self.extras(kept, self.table, self.extension, ops)
        return kept, ops, events
