"""The hierarchical tile test of Munkberg11 §4, the default culling algorithm (``units.culling``).

Part of the tile test unit (docs/pipeline.md §2.3). The tile traverser tests
coarse tiles with the moving box first (``COARSE_TEST``); per (triangle,
tile) record, t^ comes from the moving 2DH box against the tile frustum
planes (Munkberg11 §4.1, eq. 1-2), narrowed by the linearized moving edges
(Munkberg11 §4.2, eq. 8-9) or, with ``edge_solver = "quadratic"``, by the
exact quadratic edge equations (``units.tile_test_quadratic``), then by the
box again over the narrowed span; with ``lens_bounds``, u^ and v^ from the
vertices at the ends of t^. The bounds are those of ``units.tile_test_bounds``;
its branch of ``units.tile_test.tile_test_kernel_for`` applies them.
"""

from __future__ import annotations

from units.tile_test_bounds import NO_TILE_FIELDS, NO_TRIANGLE_FIELDS

NAME = "hierarchical"
EVENT_MEANINGS: dict[str, str] = {}  # its rejections are the core box, edge and lens ones
EVENTS = tuple(EVENT_MEANINGS)
TRIANGLE_EXT = NO_TRIANGLE_FIELDS
TILE_EXT = NO_TILE_FIELDS
COARSE_TEST = True  # the traverser tests coarse tiles with the moving box
NEEDS_TUPLES = False
SAMPLE_FILTER = None
setup_extras = None
