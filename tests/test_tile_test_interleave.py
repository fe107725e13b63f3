"""Interleave UVT: the tile test's tuple masks never drop a covered sample.

Reference: random points inside the triangle as seen at a random tuple of the
set (positive barycentric combinations, accepted by the exact sample test);
the tile holding each must be kept with that tuple's bit set.
"""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from pipeline_sim.sampling import interleave_tuple_set
from triangles import moving_triangle, sample_inside_points, setup_and_tiles
from units.triangle_setup import ST_DEGENERATE

W, H = 48, 32


def assert_masks_conservative(q, r, lx, ly, seed, n_tuples, tile_size):
    tuples = interleave_tuple_set(n_tuples, 4).astype(np.float32).astype(np.float64)
    setup, alive, kept = setup_and_tiles(q, r, lx, ly, W, H, tile_size, 1, algorithm="interleave_uvt",
                                         tuples=tuples)
    rng = np.random.default_rng(seed)
    pts = sample_inside_points(setup, 0, rng, 200, W, H, tuples=tuples)
    if pts and 0 not in alive and setup.last_status[0] == ST_DEGENERATE:
        return  # zero area for every (t, u, v): test_tile_test checks such drops are right
    if pts:
        assert 0 in alive
    for x, y, t, u, v, _ in pts:
        i = int(np.nonzero((tuples[:, 0] == u) & (tuples[:, 1] == v) & (tuples[:, 2] == t))[0][0])
        hit = np.nonzero((kept["tx"] == int(x // tile_size)) & (kept["ty"] == int(y // tile_size)))[0]
        assert len(hit) == 1, "the tile of a covered sample was rejected"
        assert (int(kept["mask"][hit[0]]) >> i) & 1, f"tuple {i} of a covered sample is masked off"


@given(moving_triangle(), st.integers(0, 2**31), st.sampled_from([4, 16, 64]), st.sampled_from([1, 4, 8]))
def test_interleave_masks_conservative_5d(tri, seed, n_tuples, tile_size):
    assert_masks_conservative(*tri, seed, n_tuples, tile_size)


@given(moving_triangle(lens=False, allow_w_cross=False), st.integers(0, 2**31))
def test_interleave_masks_conservative_motion_only(tri, seed):
    assert_masks_conservative(*tri, seed, 64, 2)


@given(moving_triangle(view_rays=True), st.integers(0, 2**31), st.sampled_from([4, 64]), st.sampled_from([1, 8]))
def test_interleave_masks_conservative_view_rays(tri, seed, n_tuples, tile_size):
    """Vertices moving along their view rays (fixed on screen, moving in depth)."""
    assert_masks_conservative(*tri, seed, n_tuples, tile_size)


def test_interleave_mask_is_tight_for_a_fast_small_triangle():
    """A small triangle crossing the screen: each tile sees only the few tuples
    whose times put the triangle over it (brute force: its 2D bounds per tuple)."""
    q = np.array([[[-0.9, 0.0, 0.5, 1.0], [-0.85, 0.0, 0.5, 1.0], [-0.9, 0.05, 0.5, 1.0]]])
    r = q.copy()
    r[0, :, 0] += 1.7
    z = np.zeros((1, 3, 2))
    tuples = interleave_tuple_set(16, 4).astype(np.float32).astype(np.float64)
    _, _, kept = setup_and_tiles(q, r, z, z, W, H, 4, 1, algorithm="interleave_uvt", tuples=tuples)
    bits = np.array([bin(int(m)).count("1") for m in kept["mask"]])
    assert bits.max() <= 4 and bits.mean() < 3
    # the independent count: tuples whose projected triangle's x-range overlaps each kept tile
    for tx, m in zip(kept["tx"], kept["mask"]):
        for i, (_, _, t) in enumerate(tuples):
            xs = (q[0, :, 0] + t * (r[0, :, 0] - q[0, :, 0]) + 1.0) * 0.5 * W
            overlaps = xs.max() > tx * 4 and xs.min() < tx * 4 + 4
            if overlaps:
                assert (int(m) >> i) & 1
