"""Tile traverser: visits the tiles of each triangle's bounds, coarse then fine.

Implements docs/pipeline.md §2.2. Tiles are visited in row-major tile order over
the conservative screen bounds from triangle setup. Traversal is
hierarchical: a coarse tile (``coarse_factor`` x ``coarse_factor`` tiles) is
first tested with the moving-box test of Munkberg11 §4.1 over the triangle's time
span; only the fine tiles of surviving coarse tiles are emitted. With a
coarse factor of 1 the traversal is flat.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import N_OPS
from pipeline_sim.records import TILE_IDS
from units.rounding import MARGIN_PX
from units.tile_test_bounds import box_time_interval

# its events, in the order of the kernel's event vector, and what each counts
EVENT_MEANINGS = {
    "coarse_tiles_tested": "coarse tiles tested against a triangle's bounds",
    "coarse_tiles_rejected": "coarse tiles rejected",
    "tiles_emitted": "(triangle, tile) records emitted",
}
EVENTS = tuple(EVENT_MEANINGS)
EV_COARSE, EV_COARSE_REJ, EV_EMIT = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): none; upstream of z-cull, every triangle is seen whatever the timing
TIMING_DEPENDENT: tuple[str, ...] = ()


@nb.njit(cache=True, nogil=True)
def traverse_kernel(ids, bounds, t_span, p0, dp, l0, dl, tile_size, coarse_factor, coarse_test, width, height,
                    row_lo, row_hi, out_tri, out_tx, out_ty, ops, events):
    """Emit (triangle, tile) records for ``ids`` within rows ``[row_lo, row_hi)``
    (a screen region, on coarse-tile rows); returns the number written.

    Coarse tiles are tested against the moving 2DH box (Munkberg11 §4.1, eq. 1-2).
    (The setup table's arrays, not the table: a namedtuple argument measured 3-7% slower.)
    A triangle id is an int32, as in the tile records the tile test passes to the same
    ``box_time_interval``: one signature, so numba compiles it once for both units.
    """
    n = 0
    ctile = tile_size * coarse_factor
    for b in range(ids.shape[0]):
        tri = np.int32(ids[b])
        bx0 = bounds[tri, 0]
        bx1 = bounds[tri, 1]
        by0 = max(bounds[tri, 2], row_lo)
        by1 = min(bounds[tri, 3], row_hi)
        ta = t_span[tri, 0]
        tb = t_span[tri, 1]
        for cy in range(by0 // ctile, (by1 - 1) // ctile + 1):
            for cx in range(bx0 // ctile, (bx1 - 1) // ctile + 1):
                if coarse_factor > 1 and coarse_test:
                    events[EV_COARSE] += 1
                    x0 = cx * ctile - MARGIN_PX
                    x1 = min((cx + 1) * ctile, width) + MARGIN_PX
                    y0 = cy * ctile - MARGIN_PX
                    y1 = min((cy + 1) * ctile, height) + MARGIN_PX
                    lo, hi = box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ta, tb, ops)
                    if lo > hi:
                        events[EV_COARSE_REJ] += 1
                        continue
                fy0 = max(cy * coarse_factor, by0 // tile_size)
                fy1 = min((cy + 1) * coarse_factor, (by1 - 1) // tile_size + 1)
                fx0 = max(cx * coarse_factor, bx0 // tile_size)
                fx1 = min((cx + 1) * coarse_factor, (bx1 - 1) // tile_size + 1)
                for ty in range(fy0, fy1):
                    for tx in range(fx0, fx1):
                        out_tri[n] = tri
                        out_tx[n] = tx
                        out_ty[n] = ty
                        n += 1
    events[EV_EMIT] += n
    return n


class TileTraverser:
    """Functional model of the tile traverser unit."""

    name = "tile_traverser"
    events = EVENTS
    event_meanings = EVENT_MEANINGS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, table, tile_size: int, width: int, height: int, coarse_test: bool = True):
        self.config = config
        self.coarse_test = coarse_test  # off for the BBOX baseline
        self.table = table
        self.tile_size = tile_size
        self.width = width
        self.height = height

    def run(self, ids: np.ndarray, rows: tuple[int, int] | None = None) -> tuple[dict[str, np.ndarray], np.ndarray,
                                                                                 np.ndarray]:
        """Traverse the triangles ``ids`` over rows ``[r0, r1)`` (default: the
        whole frame); return tile records (their fields of ``pipeline_sim.records.TILE``: tri, tx, ty)."""
        t = self.table
        ts = self.tile_size
        r0, r1 = rows if rows is not None else (0, self.height)
        if r0 % (ts * self.config.coarse_factor) or (r1 % (ts * self.config.coarse_factor) and r1 != self.height):
            raise ValueError(f"rows {r0}..{r1} do not start and end on coarse-tile rows")
        b = t.bounds[ids]
        y0 = np.maximum(b[:, 2], r0)
        y1 = np.minimum(b[:, 3], r1)
        ny = np.where(y1 > y0, (y1 - 1) // ts - y0 // ts + 1, 0)
        cap = int(np.sum(((b[:, 1] - 1) // ts - b[:, 0] // ts + 1) * ny))
        out = TILE_IDS.allocate(cap, fill=False)
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        n = traverse_kernel(ids, t.bounds, t.t_span, t.p0, t.dp, t.l0, t.dl, ts, self.config.coarse_factor,
                            self.coarse_test, self.width, self.height, r0, r1, out["tri"], out["tx"], out["ty"], ops,
                            events)
        return {k: a[:n] for k, a in out.items()}, ops, events
