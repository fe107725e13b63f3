"""Tile test: a (triangle, tile) pair to conservative intervals (u^, v^, t^, z^).

Implements docs/pipeline.md §2.3. The culling algorithm (``tile_test.algorithm``)
is a module of ``units.culling``: its tile kernel bounds or rejects each
record with the shared bounds of ``units.tile_test_bounds`` (the moving box
and edges of Munkberg11 §4, lens intervals after Laine11 and Wu13 §2-3, z^
from Nilsson12 App. A) or its own, and may add fields to the records it
passes on (two-stage lines, tuple masks). With ``algorithm = "bbox"`` no
tile is rejected and t^ is the triangle's whole time span: the BBOX
baseline of Wu13 and Munkberg11, against which the sample test efficiency
of the tests is measured.

The user clip planes (Nilsson12 §2) are the unit's ``clips`` attribute
(t_lo, t_hi, u_lo, u_hi, v_lo, v_hi), read at each ``run``: a pass with
several draws sets them per batch. They bound every interval, so the sample
tester never covers a sample outside them.
"""

from __future__ import annotations

import numpy as np

from pipeline_sim.definitions import N_OPS
from pipeline_sim.records import INTERVALS, TILE_IDS
from units import culling
from units.tile_test_bounds import N_CORE, TESTED, TileConfig

EVENTS = culling.EVENTS
# counters timing can move (docs/pipeline.md §4): none; upstream of z-cull, every tile is seen whatever the timing
TIMING_DEPENDENT: tuple[str, ...] = ()
_NO_TUPLES = np.zeros((0, 3))


class TileTest:
    """Functional model of the tile test unit."""

    name = "tile_test"
    events = EVENTS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, table, tile_size: int, width: int, height: int,
                 depth_w: tuple[float, float] | None = None, tuples: np.ndarray | None = None,
                 extension: tuple | None = None):
        """``table``: triangle setup's table; ``extension``: its culling algorithm's fields
        (``TriangleSetup.extension``), needed when the algorithm declares some."""
        self.config = config
        self.table = table
        self.tile_size = tile_size
        self.width = width
        self.height = height
        self.depth_c1, self.depth_c0 = depth_w if depth_w is not None else (0.0, 0.0)
        self.algorithm = culling.algorithm(config.algorithm)
        if self.algorithm.NEEDS_TUPLES and tuples is None:
            raise ValueError(f"{config.algorithm} needs the sample set's (u, v, t) tuples")
        self.tuples = tuples if tuples is not None else _NO_TUPLES
        if extension is None and self.algorithm.TRIANGLE_EXT.names:
            raise ValueError(f"{config.algorithm} needs triangle setup's {self.algorithm.TRIANGLE_EXT.names}: "
                             "TriangleSetup(..., culling=units.culling.algorithm(name)).extension")
        self.extension = extension if extension is not None else self.algorithm.TRIANGLE_EXT.table(0)
        self.offset = culling.event_offset(config.algorithm)
        self.clips = config.clips  # per batch settable (several draws of a pass)

    def run(self, tiles: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Test a batch of tile records; return the survivors with their intervals
        (``pipeline_sim.records.TILE``) and the algorithm's tile-record extension."""
        n = len(tiles["tri"])
        alg = self.algorithm
        out = TESTED.table(n)
        ext_out = alg.TILE_EXT.table(n)
        ops = np.zeros(N_OPS, np.int64)
        own = np.zeros(N_CORE + len(alg.EVENTS), np.int64)
        cfg = self.config
        config = TileConfig(self.tile_size, self.width, self.height, cfg.edge_test, cfg.edge_solver == "quadratic",
                            cfg.gamma == "tile", cfg.lens_bounds, np.asarray(self.clips, np.float64), self.depth_c1,
                            self.depth_c0, self.tuples)
        alg.tile_kernel(TILE_IDS.view(tiles), self.table, self.extension, config, out, ext_out, ops, own)
        keep = out.keep
        res = {name: arr[keep] for name, arr in tiles.items()}
        res.update({name: getattr(out, name)[keep] for name in INTERVALS})
        res.update({name: arr[keep] for name, arr in zip(alg.TILE_EXT.names, ext_out)})
        res["noread"] = np.zeros(len(res["tri"]), np.bool_)  # set by z-cull when it runs
        events = np.zeros(len(EVENTS), np.int64)
        events[:N_CORE] = own[:N_CORE]
        events[self.offset:self.offset + len(alg.EVENTS)] = own[N_CORE:]
        return res, ops, events
