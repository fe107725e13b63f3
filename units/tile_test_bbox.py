"""BBOX, the baseline culling algorithm (``units.culling``): no tile is rejected.

Part of the tile test unit (docs/pipeline.md §2.3). Every tile of the
triangle's moving, defocused screen bounds is kept with t^ its whole time
span within the clip planes: the baseline of Wu13 and Munkberg11 against
which the sample test efficiency of the other tests is measured. z^ still
comes from the vertex depths (Nilsson12 App. A). Its branch of
``units.tile_test.tile_test_kernel_for`` only bounds z^.
"""

from __future__ import annotations

from units.tile_test_bounds import NO_TILE_FIELDS, NO_TRIANGLE_FIELDS

NAME = "bbox"
EVENT_MEANINGS: dict[str, str] = {}
EVENTS = tuple(EVENT_MEANINGS)
TRIANGLE_EXT = NO_TRIANGLE_FIELDS
TILE_EXT = NO_TILE_FIELDS
COARSE_TEST = False  # the bounding box flat, as Wu13 covers it
NEEDS_TUPLES = False
SAMPLE_FILTER = None
setup_extras = None
