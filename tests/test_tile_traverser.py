"""The tile traverser: every tile of the bounds, in order; coarse rejection consistent with the tile test."""

import numpy as np

from pipeline_sim.config import load_arch
from pipeline_sim.draw import draw_from_clip
from units.tile_test import TileTest
from units.tile_traverser import TileTraverser
from units.triangle_setup import TriangleSetup

W, H = 64, 48


def traverse(q, r, tile_size, coarse_factor):
    d = draw_from_clip(q, r, width=W, height=H)
    arch = load_arch(overrides=[f"tile_traverser.coarse_factor={coarse_factor}"])
    setup = TriangleSetup(arch.triangle_setup, d, tile_size)
    alive, _, _ = setup.run(np.arange(d.n, dtype=np.int64))
    trav = TileTraverser(arch.tile_traverser, setup.table, tile_size, W, H)
    tiles, _, events = trav.run(alive)
    return setup, alive, tiles, events, arch


def test_flat_traversal_visits_every_tile_of_the_bounds_in_row_order():
    rng = np.random.default_rng(2)
    q = rng.uniform(-1, 1, (5, 3, 4))
    q[..., 3] = 1.0
    r = q + np.array([0.3, 0.1, 0, 0])
    for ts in (1, 4, 8, 16):
        setup, alive, tiles, _, _ = traverse(q, r, ts, 1)
        at = 0
        for tri in alive:
            bx0, bx1, by0, by1 = setup.table.bounds[tri]
            want = [(tri, tx, ty) for ty in range(by0 // ts, (by1 - 1) // ts + 1)
                    for tx in range(bx0 // ts, (bx1 - 1) // ts + 1)]
            got = list(zip(tiles["tri"][at:at + len(want)], tiles["tx"][at:at + len(want)],
                           tiles["ty"][at:at + len(want)]))
            assert got == want
            at += len(want)
        assert at == len(tiles["tri"])


def test_coarse_rejection_never_drops_a_tile_the_tile_test_keeps():
    """Hierarchical traversal emits a subset of the flat traversal's tiles that
    still contains every tile the tile test accepts."""
    q = np.array([[[-0.9, -0.8, 0.0, 1.0], [-0.8, -0.8, 0.0, 1.0], [-0.85, -0.7, 0.0, 1.0]]])
    r = q + np.array([1.6, 1.4, 0.0, 0.0])  # a small triangle on a long diagonal path
    _, _, flat, _, arch = traverse(q, r, 4, 1)
    setup, _, coarse, events, _ = traverse(q, r, 4, 4)
    assert events[1] > 0, "some coarse tiles should be rejected"
    flat_set = set(zip(flat["tx"], flat["ty"]))
    coarse_set = set(zip(coarse["tx"], coarse["ty"]))
    assert coarse_set < flat_set
    kept, _, _ = TileTest(arch.tile_test, setup.table, 4, W, H).run(flat)
    assert set(zip(kept["tx"], kept["ty"])) <= coarse_set
