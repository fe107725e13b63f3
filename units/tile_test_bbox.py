"""BBOX, the baseline culling algorithm (``units.culling``): no tile is rejected.

Part of the tile test unit (docs/pipeline.md §2.3). Every tile of the
triangle's moving, defocused screen bounds is kept with t^ its whole time
span within the clip planes: the baseline of Wu13 and Munkberg11 against
which the sample test efficiency of the other tests is measured. z^ still
comes from ``tile_accept`` (Nilsson12 App. A).
"""

from __future__ import annotations

import numba as nb

from units.tile_test_bounds import NO_TILE_FIELDS, NO_TRIANGLE_FIELDS, tile_accept, tile_start

NAME = "bbox"
EVENTS: tuple[str, ...] = ()
TRIANGLE_EXT = NO_TRIANGLE_FIELDS
TILE_EXT = NO_TILE_FIELDS
COARSE_TEST = False  # the bounding box flat, as Wu13 covers it
NEEDS_TUPLES = False
SAMPLE_FILTER = None
setup_extras = None


@nb.njit(cache=True)
def tile_kernel(tiles, tris, ext, cfg, out, ext_out, ops, events):
    """Every record kept with its clipped time span and z^ (the BBOX baseline of Wu13; Nilsson12 App. A)."""
    for i in range(tiles.tri.shape[0]):
        tri, fl, x0, x1, y0, y1, ta, tb = tile_start(tiles, tris, cfg, i)
        tile_accept(tris, cfg, out, i, tri, fl, x0, x1, y0, y1, ta, tb, cfg.clips[2], cfg.clips[3], cfg.clips[4],
                    cfg.clips[5], ops, events)
