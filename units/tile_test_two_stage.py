"""Two-stage culling of Wu13 §3.3-3.4, a culling algorithm (``units.culling``).

Part of the tile test unit (docs/pipeline.md §2.3). Stage 1 bounds the lens
coordinates from the vertices at the ends of t^ (``live_lens_bounds``);
stage 2 bounds time by two lines in u (x axis) and two in v (y axis)
(``units.tile_test_dual.two_stage_lines``, Wu13 §3.4). The tile's t^ is
narrowed to what the lines allow over u^ and v^, and each record carries
the lines (``lines``, its tile-record extension), which the sample tester
tests per sample (its ``lines`` filter).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import OP_CMP, OP_MADD
from pipeline_sim.records import Field, RecordType
from units.tile_test_bounds import N_CORE, NO_TRIANGLE_FIELDS, live_lens_bounds, tile_accept, tile_start
from units.tile_test_dual import two_stage_lines
from units.triangle_setup import FLAG_WPOS

NAME = "two_stage"
EVENTS = ("rejected_two_stage",)
EV_REJ_TWO = N_CORE  # its own events follow the tile test's core ones
TRIANGLE_EXT = NO_TRIANGLE_FIELDS
TILE_EXT = RecordType("TwoStageLines", (
    Field("lines", np.float32, (8,), NAME, "t >= c + s u, t <= c + s u (x axis), then the same in v (y axis): "
          "(c, s) of each"),
), __name__)
TwoStageLines = TILE_EXT.tuple_class
COARSE_TEST = False
NEEDS_TUPLES = False
SAMPLE_FILTER = "lines"
setup_extras = None
# the float32 evaluation of a time line c + s u in the sample tester rounds by
# at most a few ulps of |c| + |s|; lines are widened by this fraction of it
LINE_F32_REL = 4.0 * 2.0**-23


@nb.njit(cache=True)
def tile_kernel(tiles, tris, ext, cfg, out, ext_out, ops, events):
    """Lens bounds (Wu13 §3.3, stage 1), then time bounds linear in u and in v (Wu13 §3.4, stage 2)."""
    lines = ext_out.lines
    for i in range(tiles.tri.shape[0]):
        tri, fl, x0, x1, y0, y1, ta, tb = tile_start(tiles, tris, cfg, i)
        ok, ulo, uhi, vlo, vhi = live_lens_bounds(tris, tri, fl, cfg, x0, x1, y0, y1, ta, tb, ops, events)
        if not ok:
            continue
        lo, hi = ta, tb
        if (fl & FLAG_WPOS) != 0:
            l_c, l_s, h_c, h_s = two_stage_lines(tris.p0, tris.dp, tris.l0, tris.dl, tri, 0, x0, x1, ulo, uhi, lo, hi,
                                                 ops)
            m_c, m_s, k_c, k_s = two_stage_lines(tris.p0, tris.dp, tris.l0, tris.dl, tri, 1, y0, y1, vlo, vhi, lo, hi,
                                                 ops)
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
        tile_accept(tris, cfg, out, i, tri, fl, x0, x1, y0, y1, lo, hi, ulo, uhi, vlo, vhi, ops, events)
