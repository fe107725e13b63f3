"""Convex-hull bound of a motion-blurred triangle (Wu13 §3.2, McGuire10).

For a moving triangle without lens (motion blur only), Wu13 §3.2 replaces the
screen-space bounding box of the six vertex positions (the three vertices at
the start ts and at the end te of the triangle's time span) by their 2D
convex hull, built with a Graham scan; here with Andrew's monotone chain, its
sorted variant. While w > 0 on the whole span, each vertex moves along a
straight screen segment: x(t) = X(t) / W(t) with X and W linear in t is a
projective image of a segment, so the vertex at any t in [ts, te] lies on the
segment between its positions at ts and te. The triangle at time t is the
convex hull of its three vertices, hence it lies in the convex hull of the
six end positions at every t of the span.

``hull_setup`` stores the hull per triangle; ``hull_overlaps_tile`` is a
separating-axis test of the hull against a tile rectangle. The caller must
use them only for triangles with w > 0 on the whole span (FLAG_WPOS) and no
lens.

Rounding. The hull only proposes the separating axes; each axis carries
what makes it valid. For hull edge a -> b with outward normal n,
``hull_setup`` stores the support offset off = max over the six points p
of n . (p - a). Whatever n is, all six points, and so the triangle at
every t of the span, lie in the half-plane n . (p - a) <= off: the test is
right even where rounding misled the hull construction, and it can. A
vertex moving along its own view ray (clip coordinates times a positive
factor) stays fixed on the screen; its two projections differ by float64
rounding only, ~1e-15 px. A turn o -> a -> b is judged by the sign of a
cross product whose true value is |a - o| |b - a| sin(turn) and whose
rounding error is up to ~2^-52 |a - o| |b - o|: with |b - a| at rounding
size any turn can be misjudged, the monotone chain keeps a reflex vertex,
and the edge of ~1e-15 px beside it points anywhere. With off = 0 its
normal separated tiles holding covered samples; with its offset it is a
valid, if useless, axis. For a correct hull off is 0 up to rounding. What
remains is the rounding of the projected points and of the test's own
arithmetic, a few float64 ulps of the magnitudes involved (the test counts
the largest hull coordinate among them), far inside its margins.

"Counter-clockwise" is the positive orientation in the (x, y) coordinates as
stored (positive shoelace area); pixel space has row 0 at the top, so on the
screen the order appears clockwise.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import OP_ADD, OP_CMP, OP_MADD, OP_MUL, OP_RCP
from pipeline_sim.records import Field, RecordType
from units.tile_test_bounds import NO_TILE_FIELDS
from units.triangle_setup import FLAG_LENS, FLAG_WPOS

HULL_MAX = 6  # six points have at most six hull vertices

# the culling algorithm "hull" (units.culling): the triangle table gains each triangle's hull
NAME = "hull"
EVENT_MEANINGS = {"rejected_hull": "tiles rejected by the convex hull"}
EVENTS = tuple(EVENT_MEANINGS)
TRIANGLE_EXT = RecordType("HullTable", (
    Field("hull", np.float64, (HULL_MAX, 2), NAME, "screen convex hull of the moving vertices, counter-clockwise"),
    Field("hull_n", np.int32, (), NAME, "its vertex count; 0 when not computed"),
    Field("hull_off", np.float64, (HULL_MAX,), NAME, "support offset of each hull edge"),
), __name__)
HullTable = TRIANGLE_EXT.tuple_class
TILE_EXT = NO_TILE_FIELDS
COARSE_TEST = False
NEEDS_TUPLES = False
SAMPLE_FILTER = None
# "no overlap" is reported only when the separation exceeds this fraction of
# the magnitudes of the coordinates involved plus an absolute pixel margin:
# float64 rounding of the projected vertices, of the hull construction and of
# the test itself can then only make the test looser, never tighter.
HULL_REL = 1e-9
HULL_ABS_PX = 1e-7


@nb.njit(cache=True)
def _cross(ox, oy, ax, ay, bx, by):
    # (a - o) x (b - o): > 0 when o -> a -> b turns counter-clockwise
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@nb.njit(cache=True)
def hull_setup(p0, dp, t_span, tri, hull, hull_n, hull_off, ops):
    """Convex hull of the six screen positions of ``tri`` (Wu13 §3.2, McGuire10).

    Vertices at ts and te (``t_span[tri]``), projected to (X/W, Y/W); needs
    W > 0 on the span. Writes the hull counter-clockwise (positive signed
    area) to ``hull[tri, :hull_n[tri]]`` with collinear points dropped;
    degenerate input stores the two extreme points (all six on a line) or
    one point (all identical). ``hull_off[tri, i]`` is the support offset of
    edge i (from vertex i to the next): how far the six points reach beyond
    its line along its outward normal (module doc), 0 for an exact hull.
    """
    px = np.empty(HULL_MAX)
    py = np.empty(HULL_MAX)
    for s in range(2):
        t = t_span[tri, s]
        for k in range(3):
            X = p0[tri, k, 0] + t * dp[tri, k, 0]
            Y = p0[tri, k, 1] + t * dp[tri, k, 1]
            W = p0[tri, k, 3] + t * dp[tri, k, 3]
            r = 1.0 / W
            px[3 * s + k] = X * r
            py[3 * s + k] = Y * r
    ops[OP_MADD] += 18
    ops[OP_RCP] += 6
    ops[OP_MUL] += 12
    # insertion sort by (x, y)
    order = np.empty(HULL_MAX, np.int64)
    for i in range(HULL_MAX):
        order[i] = i
    ncmp = 0
    for i in range(1, HULL_MAX):
        j = i
        while j > 0:
            a = order[j - 1]
            b = order[j]
            ncmp += 1
            if px[a] > px[b] or (px[a] == px[b] and py[a] > py[b]):
                order[j - 1] = b
                order[j] = a
                j -= 1
            else:
                break
    # drop exact duplicates
    sx = np.empty(HULL_MAX)
    sy = np.empty(HULL_MAX)
    m = 0
    for i in range(HULL_MAX):
        x = px[order[i]]
        y = py[order[i]]
        ncmp += 1
        if m == 0 or x != sx[m - 1] or y != sy[m - 1]:
            sx[m] = x
            sy[m] = y
            m += 1
    ops[OP_CMP] += 2 * ncmp
    if m == 1:
        hull[tri, 0, 0] = sx[0]
        hull[tri, 0, 1] = sy[0]
        hull_n[tri] = 1
        return
    # Andrew's monotone chain: lower hull left to right, upper right to left;
    # a point is kept only on a strict left turn, so collinear ones are dropped
    cx = np.empty(2 * HULL_MAX)
    cy = np.empty(2 * HULL_MAX)
    n = 0
    ncross = 0
    for i in range(m):
        while n >= 2:
            ncross += 1
            if _cross(cx[n - 2], cy[n - 2], cx[n - 1], cy[n - 1], sx[i], sy[i]) <= 0.0:
                n -= 1
            else:
                break
        cx[n] = sx[i]
        cy[n] = sy[i]
        n += 1
    lower_n = n + 1
    for i in range(m - 2, -1, -1):
        while n >= lower_n:
            ncross += 1
            if _cross(cx[n - 2], cy[n - 2], cx[n - 1], cy[n - 1], sx[i], sy[i]) <= 0.0:
                n -= 1
            else:
                break
        cx[n] = sx[i]
        cy[n] = sy[i]
        n += 1
    n -= 1  # the last point repeats the first
    ops[OP_ADD] += 4 * ncross
    ops[OP_MUL] += ncross
    ops[OP_MADD] += ncross
    ops[OP_CMP] += ncross
    for i in range(n):
        hull[tri, i, 0] = cx[i]
        hull[tri, i, 1] = cy[i]
    hull_n[tri] = n
    # support offsets: the edge's own end points give exactly 0, so off >= 0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        nx = cy[j] - cy[i]
        ny = cx[i] - cx[j]
        off = 0.0
        for k in range(m):
            off = max(off, nx * (sx[k] - cx[i]) + ny * (sy[k] - cy[i]))
        hull_off[tri, i] = off
    ops[OP_ADD] += n * (2 + 2 * m)
    ops[OP_MUL] += n * m
    ops[OP_MADD] += n * m
    ops[OP_CMP] += n * m


@nb.njit(cache=True)
def hull_overlaps_tile(hull, hull_n, hull_off, tri, x0, x1, y0, y1, ops):
    """Does the hull of ``tri`` (Wu13 §3.2, McGuire10) overlap [x0, x1] x [y0, y1]?

    Separating-axis test: the tile's two axes, then each hull edge's outward
    normal n with the edge's support offset (for a two-point hull, both
    normals of the segment; a one-point hull needs only the tile axes): the
    tile is separated when n . (c - a) > off at its corner c farthest
    against n. Conservative: a separation counts only beyond HULL_REL times
    the magnitudes involved (those of the hull's points included, module
    doc) plus HULL_ABS_PX pixels.
    """
    n = hull_n[tri]
    hx0 = np.inf
    hx1 = -np.inf
    hy0 = np.inf
    hy1 = -np.inf
    for i in range(n):
        x = hull[tri, i, 0]
        y = hull[tri, i, 1]
        hx0 = min(hx0, x)
        hx1 = max(hx1, x)
        hy0 = min(hy0, y)
        hy1 = max(hy1, y)
    ops[OP_CMP] += 4 * n + 4
    ops[OP_MADD] += 4
    if x0 - hx1 > HULL_REL * (abs(x0) + abs(hx1)) + HULL_ABS_PX:
        return False
    if hx0 - x1 > HULL_REL * (abs(x1) + abs(hx0)) + HULL_ABS_PX:
        return False
    if y0 - hy1 > HULL_REL * (abs(y0) + abs(hy1)) + HULL_ABS_PX:
        return False
    if hy0 - y1 > HULL_REL * (abs(y1) + abs(hy0)) + HULL_ABS_PX:
        return False
    if n < 2:
        return True
    big = max(max(abs(hx0), abs(hx1)), max(abs(hy0), abs(hy1)))  # the largest coordinate of the points
    ops[OP_CMP] += 3
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        ax = hull[tri, i, 0]
        ay = hull[tri, i, 1]
        # outward normal of the counter-clockwise edge a -> b: (ey, -ex)
        nx = hull[tri, j, 1] - ay
        ny = ax - hull[tri, j, 0]
        # the tile corner farthest against the normal
        cx = x0 if nx > 0.0 else x1
        cy = y0 if ny > 0.0 else y1
        d = nx * (cx - ax) + ny * (cy - ay) - hull_off[tri, i]
        nl1 = abs(nx) + abs(ny)  # L1 >= L2 norm: wider in pixels
        mag = abs(nx) * (abs(cx) + abs(ax)) + abs(ny) * (abs(cy) + abs(ay)) + nl1 * big
        eps = HULL_REL * mag + HULL_ABS_PX * nl1
        ops[OP_ADD] += 8
        ops[OP_MUL] += 2
        ops[OP_MADD] += 4
        ops[OP_CMP] += 3
        if d > eps:
            return False
    return True


@nb.njit(cache=True)
def _hulls(ids, p0, dp, t_span, flags, hull, hull_n, hull_off, ops):
    """Convex hulls of the six projected vertices of the motion-only triangles
    in front of the camera (McGuire10, Wu13 §3.2)."""
    for tri in ids:
        if (flags[tri] & FLAG_WPOS) != 0 and (flags[tri] & FLAG_LENS) == 0:
            hull_setup(p0, dp, t_span, tri, hull, hull_n, hull_off, ops)


def setup_extras(ids: np.ndarray, tris, ext, ops: np.ndarray) -> None:
    """Triangle setup's part for the hull test: the hulls of the triangles ``ids`` that survived setup."""
    _hulls(ids, tris.p0, tris.dp, tris.t_span, tris.flags, ext.hull, ext.hull_n, ext.hull_off, ops)
