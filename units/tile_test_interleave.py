"""Interleave UVT tile test: which of the fixed (u, v, t) tuples can cover a tile.

Part of the tile test unit (docs/pipeline.md §2.3, §7). Interleave UVT
(Fatahalian09, as Wu13 §2 and Munkberg11 §2 describe it) rasterizes the
triangle once per tuple of a fixed set of n (u, v, t) values, as an ordinary
2D triangle; every pixel owns samples of only some of the tuples. Per
(triangle, tile) record this kernel tests the 2D bounding box of the triangle
as seen at each tuple against the tile and returns an n-bit mask of the
tuples that may cover a sample in it; the sample tester then tests only
samples whose tuple bit is set.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import OP_CMP, OP_MADD, OP_MUL, OP_RCP
from pipeline_sim.records import Field, RecordType
from units.rounding import F32_REL
from units.tile_test_bounds import NO_TRIANGLE_FIELDS

# the culling algorithm "interleave_uvt" (units.culling): needs the sample set's tuples
NAME = "interleave_uvt"
EVENT_MEANINGS = {"rejected_tuples": "tiles no (u, v, t) tuple of the set reaches"}
EVENTS = tuple(EVENT_MEANINGS)
TRIANGLE_EXT = NO_TRIANGLE_FIELDS
TILE_EXT = RecordType("TupleMask", (
    Field("mask", np.uint64, (), NAME, "bit i: tuple i may cover a sample of the tile"),
), __name__)
TupleMask = TILE_EXT.tuple_class
COARSE_TEST = False
NEEDS_TUPLES = True
SAMPLE_FILTER = "mask"
setup_extras = None


@nb.njit(cache=True)
def interleave_mask(p0, dp, l0, dl, tri, tuples, x0, x1, y0, y1, ta, tb, ops):
    """Bit i set when the 2D triangle at tuple i = (u, v, t) may overlap the tile.

    A tuple outside [ta, tb] (the triangle's time span, already narrowed by
    the clip planes) is off; a tuple at which a vertex has w <= 0 keeps its bit
    (the exact sample test decides). The 2D bounds are widened by the float32
    rounding of the vertices the sample tester uses (F32_REL).
    """
    mask = np.uint64(0)
    for i in range(tuples.shape[0]):
        u = tuples[i, 0]
        v = tuples[i, 1]
        t = tuples[i, 2]
        ops[OP_CMP] += 2
        if t < ta or t > tb:
            continue
        xmn = np.inf
        xmx = -np.inf
        ymn = np.inf
        ymx = -np.inf
        behind = False
        for k in range(3):
            X = p0[tri, k, 0] + t * dp[tri, k, 0] + u * (l0[tri, k, 0] + t * dl[tri, k, 0])
            Y = p0[tri, k, 1] + t * dp[tri, k, 1] + v * (l0[tri, k, 1] + t * dl[tri, k, 1])
            W = p0[tri, k, 3] + t * dp[tri, k, 3]
            if not W > 0.0:
                behind = True
                break
            inv = 1.0 / W
            pad = F32_REL * (abs(X) + abs(Y) + abs(W) + abs(l0[tri, k, 0]) + abs(dl[tri, k, 0])
                             + abs(l0[tri, k, 1]) + abs(dl[tri, k, 1])) * inv
            x = X * inv
            y = Y * inv
            xmn = min(xmn, x - pad)
            xmx = max(xmx, x + pad)
            ymn = min(ymn, y - pad)
            ymx = max(ymx, y + pad)
        ops[OP_MADD] += 3 * 7
        ops[OP_RCP] += 3
        ops[OP_MUL] += 6
        ops[OP_CMP] += 12 + 4
        if behind or (xmx >= x0 and xmn <= x1 and ymx >= y0 and ymn <= y1):
            mask |= np.uint64(1) << np.uint64(i)
    return mask
