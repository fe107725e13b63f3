"""Exact per-pixel time intervals of a moving triangle in conservative mode (Gribel10 §3-4).

The tile test's t^ (Munkberg11 §4, units/tile_test.py) is one conservative
interval per (triangle, tile). In conservative mode (1x1 tiles, Nilsson12 §2)
a pass may ask instead for the exact set of times at which the moving
triangle touches the closed pixel square, from the roots of its edge
functions (Gribel10 §4.1, eq. 3-7). With vertices moving linearly in 2DH,
q_i(t) = a_i + t b_i (x, y, w in pixels, w > 0), the triangle T(t) and the
square S = [x0, x1] x [y0, y1] are convex, so whether they meet changes only
at a contact of a vertex of one with an edge line of the other:

* a vertex of T(t) on a side line of S: X_i(t) - s W_i(t) = 0 (s = x0, x1; the
  same in y), linear in t;
* a corner c of S on an edge line of T(t): e_k(c, t) = (q_i(t) x q_j(t)) . (c, 1)
  = 0, quadratic in t (Gribel10 eq. 4-7).

Between two consecutive roots in [lo, hi] the answer is that of the midpoint,
at a root that of the root itself (a touch at one instant), each decided by
the separating-axis test of the two convex polygons at that time (the axes of
S and the three edge normals of T(t), whatever its winding). The result is
the hull of that set, [first, last], or empty. Every answer is taken for the
square widened by ``EXACT_MARGIN`` (times 1 + the largest corner coordinate)
and every end is padded by ``ROOT_PAD`` (1 + |t|) outward, so rounding can only
widen the interval.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pipeline_sim.definitions import OP_ADD, OP_CMP, OP_MADD, OP_MUL, OP_RCP

EXACT_MARGIN = 1e-7  # pixels, times 1 + the largest corner coordinate
ROOT_PAD = 1e-9
MAX_ROOTS = 12 + 2 * 12  # 12 linear contacts, 12 quadratic ones


@nb.njit(cache=True)
def _touches(p0, dp, tri, t, x0, x1, y0, y1, ops):
    """Whether the triangle at time ``t`` meets the square [x0, x1] x [y0, y1] (separating axes)."""
    w0 = p0[tri, 0, 3] + t * dp[tri, 0, 3]
    w1 = p0[tri, 1, 3] + t * dp[tri, 1, 3]
    w2 = p0[tri, 2, 3] + t * dp[tri, 2, 3]
    xs = ((p0[tri, 0, 0] + t * dp[tri, 0, 0]) / w0, (p0[tri, 1, 0] + t * dp[tri, 1, 0]) / w1,
          (p0[tri, 2, 0] + t * dp[tri, 2, 0]) / w2)
    ys = ((p0[tri, 0, 1] + t * dp[tri, 0, 1]) / w0, (p0[tri, 1, 1] + t * dp[tri, 1, 1]) / w1,
          (p0[tri, 2, 1] + t * dp[tri, 2, 1]) / w2)
    ops[OP_MADD] += 9
    ops[OP_RCP] += 3
    ops[OP_MUL] += 6
    ops[OP_CMP] += 4
    if min(xs[0], xs[1], xs[2]) > x1 or max(xs[0], xs[1], xs[2]) < x0:
        return False
    if min(ys[0], ys[1], ys[2]) > y1 or max(ys[0], ys[1], ys[2]) < y0:
        return False
    for k in range(3):
        i = (k + 1) % 3
        j = (k + 2) % 3
        nx = ys[i] - ys[j]  # a normal of edge (i, j); the sign does not matter
        ny = xs[j] - xs[i]
        opp = nx * (xs[k] - xs[i]) + ny * (ys[k] - ys[i])
        c_lo = np.inf
        c_hi = -np.inf
        for cx in (x0, x1):
            for cy in (y0, y1):
                d = nx * (cx - xs[i]) + ny * (cy - ys[i])
                c_lo = min(c_lo, d)
                c_hi = max(c_hi, d)
        ops[OP_ADD] += 4
        ops[OP_MADD] += 10
        ops[OP_CMP] += 8
        if c_lo > max(0.0, opp) or c_hi < min(0.0, opp):
            return False
    return True


@nb.njit(cache=True)
def _add_root(roots, n, r, lo, hi):
    if lo < r < hi:
        roots[n] = r
        return n + 1
    return n


@nb.njit(cache=True)
def _quadratic_roots(a, b, c, roots, n, lo, hi, ops):
    """Append the real roots of a t^2 + b t + c in (lo, hi) (stable formulas; a == 0 as a line)."""
    ops[OP_MADD] += 2
    ops[OP_CMP] += 3
    if a == 0.0:
        if b != 0.0:
            ops[OP_RCP] += 1
            n = _add_root(roots, n, -c / b, lo, hi)
        return n
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        # a corner grazing a moving edge line touches it at a double root, which rounding can turn into
        # a slightly negative discriminant: the parabola's vertex is then the time to look at
        ops[OP_RCP] += 1
        return _add_root(roots, n, -0.5 * b / a, lo, hi)
    ops[OP_RCP] += 3
    q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
    n = _add_root(roots, n, q / a, lo, hi)
    if q != 0.0:
        n = _add_root(roots, n, c / q, lo, hi)
    return n


@nb.njit(cache=True)
def exact_time_interval(p0, dp, tri, x0, x1, y0, y1, lo, hi, ops):
    """The hull of the times in [lo, hi] at which triangle ``tri`` (2DH vertices ``p0 + t dp``, all
    w > 0) meets the closed square [x0, x1] x [y0, y1]; (inf, -inf) when it never does. Gribel10 §4.1,
    eq. 3-7, on the pixel square instead of its centre (see the module)."""
    roots = np.empty(MAX_ROOTS + 2)
    roots[0] = lo
    n = 1
    for k in range(3):  # vertex k on a side line: X - s W = 0 (and Y)
        for axis in range(2):
            for s in ((x0, x1) if axis == 0 else (y0, y1)):
                a = p0[tri, k, axis] - s * p0[tri, k, 3]
                b = dp[tri, k, axis] - s * dp[tri, k, 3]
                ops[OP_MADD] += 2
                if b != 0.0:
                    ops[OP_RCP] += 1
                    n = _add_root(roots, n, -a / b, lo, hi)
    for k in range(3):  # corner c on edge line (i, j): (q_i x q_j) . (c, 1), q = (X, Y, W)
        i = (k + 1) % 3
        j = (k + 2) % 3
        ax, ay, aw = p0[tri, i, 0], p0[tri, i, 1], p0[tri, i, 3]
        bx, by, bw = dp[tri, i, 0], dp[tri, i, 1], dp[tri, i, 3]
        cx_, cy_, cw = p0[tri, j, 0], p0[tri, j, 1], p0[tri, j, 3]
        dx, dy, dw = dp[tri, j, 0], dp[tri, j, 1], dp[tri, j, 3]
        # h = a_i x a_j, g = a_i x b_j + b_i x a_j, f = b_i x b_j (Gribel10 eq. 4)
        h = (ay * cw - aw * cy_, aw * cx_ - ax * cw, ax * cy_ - ay * cx_)
        g = (ay * dw - aw * dy + by * cw - bw * cy_, aw * dx - ax * dw + bw * cx_ - bx * cw,
             ax * dy - ay * dx + bx * cy_ - by * cx_)
        f = (by * dw - bw * dy, bw * dx - bx * dw, bx * dy - by * dx)
        ops[OP_MUL] += 9
        ops[OP_MADD] += 18
        for px in (x0, x1):
            for py in (y0, y1):
                ops[OP_MADD] += 6
                n = _quadratic_roots(f[0] * px + f[1] * py + f[2], g[0] * px + g[1] * py + g[2],
                                     h[0] * px + h[1] * py + h[2], roots, n, lo, hi, ops)
    roots[n] = hi
    n += 1
    ts = np.sort(roots[:n])
    ops[OP_CMP] += n * max(1, int(math.log2(n)))
    m = EXACT_MARGIN * (1.0 + max(abs(x0), abs(x1), abs(y0), abs(y1)))
    wx0, wx1, wy0, wy1 = x0 - m, x1 + m, y0 - m, y1 + m
    first = np.inf
    last = -np.inf
    for r in range(n):
        if _touches(p0, dp, tri, ts[r], wx0, wx1, wy0, wy1, ops):
            first = min(first, ts[r])
            last = max(last, ts[r])
        if r + 1 < n and ts[r + 1] > ts[r] and _touches(p0, dp, tri, 0.5 * (ts[r] + ts[r + 1]), wx0, wx1, wy0, wy1,
                                                        ops):
            first = min(first, ts[r])
            last = max(last, ts[r + 1])
    if first > last:
        return np.inf, -np.inf
    return max(lo, first - ROOT_PAD * (1.0 + abs(first))), min(hi, last + ROOT_PAD * (1.0 + abs(last)))


@nb.njit(cache=True, nogil=True)
def exact_kernel(tri_ids, tile_x, tile_y, wpos_lens_ok, p0, dp, keep, t_lo, t_hi, ops):
    """Narrow each kept 1x1-tile record's [t_lo, t_hi] to the exact hull (``exact_time_interval``) for
    the triangles ``wpos_lens_ok`` marks (motion only, w > 0); clear ``keep`` where it is empty.
    Returns the number of records it cleared."""
    cleared = 0
    for r in range(tri_ids.shape[0]):
        tri = tri_ids[r]
        if not keep[r] or not wpos_lens_ok[tri]:
            continue
        x0 = float(tile_x[r])
        y0 = float(tile_y[r])
        lo, hi = exact_time_interval(p0, dp, tri, x0, x0 + 1.0, y0, y0 + 1.0, t_lo[r], t_hi[r], ops)
        if lo > hi:
            keep[r] = False
            cleared += 1
        else:
            t_lo[r] = lo
            t_hi[r] = hi
    return cleared
