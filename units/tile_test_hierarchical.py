"""The hierarchical tile test of Munkberg11 §4, the default culling algorithm (``units.culling``).

Part of the tile test unit (docs/pipeline.md §2.3). The tile traverser tests
coarse tiles with the moving box first (``COARSE_TEST``); per (triangle,
tile) record, t^ comes from the moving 2DH box against the tile frustum
planes (Munkberg11 §4.1, eq. 1-2), narrowed by the linearized moving edges
(Munkberg11 §4.2, eq. 8-9) or, with ``edge_solver = "quadratic"``, by the
exact quadratic edge equations (``units.tile_test_quadratic``), then by the
box again over the narrowed span; with ``lens_bounds``, u^ and v^ from the
vertices at the ends of t^. The bounds are those of ``units.tile_test_bounds``.
"""

from __future__ import annotations

import numba as nb

from units.tile_test_bounds import (EV_REJ_BOX, EV_REJ_EDGE, NO_TILE_FIELDS, NO_TRIANGLE_FIELDS, box_time_interval,
                                    edge_time_interval, live_lens_bounds, tile_accept, tile_start)
from units.tile_test_quadratic import quadratic_time_interval
from units.triangle_setup import FLAG_EDGE

NAME = "hierarchical"
EVENTS: tuple[str, ...] = ()  # its rejections are the core box, edge and lens ones
TRIANGLE_EXT = NO_TRIANGLE_FIELDS
TILE_EXT = NO_TILE_FIELDS
COARSE_TEST = True  # the traverser tests coarse tiles with the moving box
NEEDS_TUPLES = False
SAMPLE_FILTER = None
setup_extras = None


@nb.njit(cache=True)
def tile_kernel(tiles, tris, ext, cfg, out, ext_out, ops, events):
    """Moving box, moving edges and lens bounds per record (Munkberg11 §4.1-4.2, eq. 1-2, 8-9)."""
    p0, dp, l0, dl = tris.p0, tris.dp, tris.l0, tris.dl
    for i in range(tiles.tri.shape[0]):
        tri, fl, x0, x1, y0, y1, ta, tb = tile_start(tiles, tris, cfg, i)
        lo, hi = box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ta, tb, ops)
        if lo > hi:
            events[EV_REJ_BOX] += 1
            continue
        if cfg.edge_test and (fl & FLAG_EDGE) != 0:
            if cfg.quadratic:
                lo, hi = quadratic_time_interval(tris.edge_f, tris.edge_g, tris.edge_h, tris.edge_abs, tri, x0, x1,
                                                 y0, y1, lo, hi, ops)
            else:
                lo, hi = edge_time_interval(tris.edge_h, tris.edge_gamma, tris.edge_g, tris.edge_fg, tris.edge_abs,
                                            cfg.gamma_per_tile, tri, x0, x1, y0, y1, lo, hi, ops)
            if lo > hi:
                events[EV_REJ_EDGE] += 1
                continue
            # the box taken over the narrowed [lo, hi] is tighter (Munkberg11 §4.1 applied again)
            if lo > ta or hi < tb:
                lo, hi = box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, lo, hi, ops)
                if lo > hi:
                    events[EV_REJ_BOX] += 1
                    continue
        if cfg.lens_bounds:
            ok, ulo, uhi, vlo, vhi = live_lens_bounds(tris, tri, fl, cfg, x0, x1, y0, y1, lo, hi, ops, events)
            if not ok:
                continue
        else:
            ulo, uhi, vlo, vhi = cfg.clips[2], cfg.clips[3], cfg.clips[4], cfg.clips[5]
        tile_accept(tris, cfg, out, i, tri, fl, x0, x1, y0, y1, lo, hi, ulo, uhi, vlo, vhi, ops, events)
