"""Two-stage culling of Wu13 §3.3-3.4, a culling algorithm (``units.culling``).

Part of the tile test unit (docs/pipeline.md §2.3). Stage 1 bounds the lens
coordinates from the vertices at the ends of t^ (``lens_interval``);
stage 2 bounds time by two lines in u (x axis) and two in v (y axis)
(``units.tile_test_dual.two_stage_lines``, Wu13 §3.4). The tile's t^ is
narrowed to what the lines allow over u^ and v^, and each record carries
the lines (``lines``, its tile-record extension), which the sample tester
tests per sample (its ``lines`` filter). Its branch of
``units.tile_test.tile_test_kernel_for`` runs the stages.
"""

from __future__ import annotations

import numpy as np

from pipeline_sim.records import Field, RecordType
from units.tile_test_bounds import NO_TRIANGLE_FIELDS

NAME = "two_stage"
EVENT_MEANINGS = {"rejected_two_stage": "tiles rejected by two-stage time bounds"}
EVENTS = tuple(EVENT_MEANINGS)
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
