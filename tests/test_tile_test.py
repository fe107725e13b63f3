"""Conservativeness of triangle setup, the traverser and the tile test.

Property (docs/pipeline.md §2.3): the tile test never rejects a (tile, sample) pair
that the exact sample test accepts, and the intervals (u^, v^, t^, z^) it
outputs contain that sample's (u, v, t) and depth. Checked with hypothesis on
random moving, defocused triangles, including ones whose vertex paths cross
w = 0 during the shutter.
"""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.pass_state import ClipPlanes
from triangles import PERSPECTIVE, moving_triangle, sample_inside_points, setup_and_tiles
from units.tile_test import TileTest
from units.tile_traverser import TileTraverser
from units.triangle_setup import ST_DEGENERATE, TriangleSetup

W, H = 48, 32


def assert_conservative(q, r, lx, ly, seed, tile_size=8, coarse_factor=2, edge_test=True, lens_bounds=True,
                        depth_w=None, gamma="triangle", algorithm="hierarchical", edge_solver="linearized"):
    setup, alive, kept = setup_and_tiles(q, r, lx, ly, W, H, tile_size, coarse_factor, edge_test, lens_bounds,
                                         depth_w=depth_w, gamma=gamma, algorithm=algorithm,
                                         edge_solver=edge_solver)
    rng = np.random.default_rng(seed)
    pts = sample_inside_points(setup, 0, rng, 200, W, H)
    if not pts:
        return 0
    if 0 not in alive and setup.last_status[0] == ST_DEGENERATE:
        # dropped as degenerate: it must have no area anywhere in (t, u, v)
        assert relative_det_max(q, r, lx, ly) < 1e-12
        return 0
    assert 0 in alive, "setup culled a triangle that covers samples"
    bx0, bx1, by0, by1 = setup.table.bounds[0]
    ts, te = setup.table.t_span[0]
    for x, y, t, u, v, z in pts:
        assert bx0 <= x < bx1 and by0 <= y < by1, "screen bounds miss a covered sample"
        assert ts <= t <= te, "temporal frustum span misses a covered sample"
        tx, ty = int(x // tile_size), int(y // tile_size)
        hit = np.nonzero((kept["tx"] == tx) & (kept["ty"] == ty))[0]
        assert len(hit) == 1, f"tile ({tx},{ty}) of a covered sample was rejected"
        i = hit[0]
        assert kept["t_lo"][i] <= t <= kept["t_hi"][i], "t^ excludes a covered sample"
        assert kept["u_lo"][i] <= u <= kept["u_hi"][i], "u^ excludes a covered sample"
        assert kept["v_lo"][i] <= v <= kept["v_hi"][i], "v^ excludes a covered sample"
        if "lines" in kept:  # two-stage culling: evaluated in float32, as the sample tester does
            ln = kept["lines"][i]
            t32, u32, v32 = np.float32(t), np.float32(u), np.float32(v)
            assert t32 >= ln[0] + ln[1] * u32 and t32 <= ln[2] + ln[3] * u32, "a time line in u excludes it"
            assert t32 >= ln[4] + ln[5] * v32 and t32 <= ln[6] + ln[7] * v32, "a time line in v excludes it"
        # float32 depth carries rounding (the sample tester clamps it into z^)
        tol = 1e-4 * (1 + abs(z))
        assert kept["z_lo"][i] - tol <= z <= kept["z_hi"][i] + tol, "z^ excludes a covered sample's depth"
    return len(pts)


@given(moving_triangle(), st.integers(0, 2**31))
def test_tile_test_conservative_5d(tri, seed):
    assert_conservative(*tri, seed)


@given(moving_triangle(lens=False), st.integers(0, 2**31), st.sampled_from(["triangle", "tile"]),
       st.sampled_from([1, 4, 8]))
def test_tile_test_conservative_motion_only_edge_test(tri, seed, gamma, tile_size):
    assert_conservative(*tri, seed, edge_test=True, gamma=gamma, tile_size=tile_size)


@given(moving_triangle(motion=False), st.integers(0, 2**31))
def test_tile_test_conservative_defocus_only(tri, seed):
    assert_conservative(*tri, seed)


@given(moving_triangle(allow_w_cross=False), st.integers(0, 2**31), st.sampled_from([1, 2, 4, 16]),
       st.sampled_from([1, 3]))
def test_tile_test_conservative_tile_sizes(tri, seed, tile_size, coarse):
    assert_conservative(*tri, seed, tile_size=tile_size, coarse_factor=coarse)


ALGORITHMS = ["bbox", "hull", "dual_space", "two_stage"]


@given(moving_triangle(), st.integers(0, 2**31), st.sampled_from(ALGORITHMS), st.sampled_from([1, 4, 8]))
def test_every_algorithm_conservative_5d(tri, seed, algorithm, tile_size):
    assert_conservative(*tri, seed, tile_size=tile_size, algorithm=algorithm)


@given(moving_triangle(lens=False), st.integers(0, 2**31), st.sampled_from(ALGORITHMS), st.sampled_from([1, 8]))
def test_every_algorithm_conservative_motion_only(tri, seed, algorithm, tile_size):
    assert_conservative(*tri, seed, tile_size=tile_size, algorithm=algorithm)


@given(moving_triangle(motion=False), st.integers(0, 2**31), st.sampled_from(ALGORITHMS), st.sampled_from([1, 8]))
def test_every_algorithm_conservative_defocus_only(tri, seed, algorithm, tile_size):
    assert_conservative(*tri, seed, tile_size=tile_size, algorithm=algorithm)


# every tile-test algorithm with its edge solvers
EVERY = [("hierarchical", "linearized"), ("hierarchical", "quadratic")] + [(a, "linearized") for a in ALGORITHMS]


@given(moving_triangle(lens=False, view_rays=True), st.integers(0, 2**31), st.sampled_from(EVERY),
       st.sampled_from([1, 4, 8]))
def test_every_algorithm_conservative_view_rays(tri, seed, algorithm, tile_size):
    """Vertices moving along their view rays: each one's two projections differ by rounding only."""
    assert_conservative(*tri, seed, tile_size=tile_size, algorithm=algorithm[0], edge_solver=algorithm[1])


@given(moving_triangle(view_rays=True), st.integers(0, 2**31), st.sampled_from(EVERY), st.sampled_from([1, 8]))
def test_every_algorithm_conservative_view_rays_5d(tri, seed, algorithm, tile_size):
    assert_conservative(*tri, seed, tile_size=tile_size, algorithm=algorithm[0], edge_solver=algorithm[1])


@given(moving_triangle(lens=False), st.integers(0, 2**31), st.sampled_from([1, 4, 8]),
       st.sampled_from([1, 2]))
def test_quadratic_edge_solver_conservative(tri, seed, tile_size, coarse):
    """The per-tile quadratic edge test (exact time intervals per pixel at tile size 1)."""
    assert_conservative(*tri, seed, tile_size=tile_size, coarse_factor=coarse, edge_solver="quadratic")


@given(moving_triangle(perspective=True), st.integers(0, 2**31), st.sampled_from(ALGORITHMS + ["hierarchical"]))
def test_every_algorithm_depth_bounds_conservative(tri, seed, algorithm):
    assert_conservative(*tri, seed, tile_size=4, depth_w=PERSPECTIVE, algorithm=algorithm)


@given(moving_triangle(perspective=True), st.integers(0, 2**31), st.sampled_from([1, 4, 16]))
def test_moving_plane_depth_bounds_conservative(tri, seed, tile_size):
    """z^ with the moving plane equations of Nilsson12 App. A (perspective depth)."""
    assert_conservative(*tri, seed, tile_size=tile_size, depth_w=PERSPECTIVE)


def test_moving_plane_tightens_depth_interval():
    # a large tilted, moving quad-like triangle: per-tile z^ from the planes is
    # much narrower than the vertex range
    q = np.array([[[-1.0, -1.0, 0.0, 1.0], [1.0, -1.0, 0.0, 1.0], [0.0, 2.0, 0.0, 3.0]]])
    q[0, :, 2] = PERSPECTIVE[0] * q[0, :, 3] + PERSPECTIVE[1]
    r = q + np.array([0.1, 0.05, 0.0, 0.0])
    zero = np.zeros((1, 3, 2))
    _, _, plain = setup_and_tiles(q, r, zero, zero, 96, 64)
    _, _, planes = setup_and_tiles(q, r, zero, zero, 96, 64, depth_w=PERSPECTIVE)
    assert len(plain["tri"]) == len(planes["tri"]) > 4
    assert np.all(planes["z_lo"] >= plain["z_lo"] - 1e-6) and np.all(planes["z_hi"] <= plain["z_hi"] + 1e-6)
    width_plain = np.mean(plain["z_hi"] - plain["z_lo"])
    width_planes = np.mean(planes["z_hi"] - planes["z_lo"])
    assert width_planes < 0.5 * width_plain, (width_plain, width_planes)


def test_crossing_w0_triangle_is_kept_and_covers():
    # one vertex goes behind the camera during the shutter
    q = np.array([[[-0.5, -0.5, 0.0, 1.0], [0.5, -0.5, 0.0, 1.0], [0.0, 0.5, 0.0, 1.0]]])
    r = q.copy()
    r[0, 2] = [0.0, 0.5, 0.0, -0.5]
    n = assert_conservative(q, r, np.zeros((1, 3, 2)), np.zeros((1, 3, 2)), 1)
    assert n > 50


def test_tile_test_rejects_most_tiles_for_fast_motion():
    # a small triangle sweeping across the screen: most tiles of the bounds see it only briefly
    q = np.array([[[-0.9, -0.1, 0.0, 1.0], [-0.8, -0.1, 0.0, 1.0], [-0.85, 0.0, 0.0, 1.0]]])
    r = q + np.array([1.7, 0.0, 0.0, 0.0])
    setup, alive, kept = setup_and_tiles(q, r, np.zeros((1, 3, 2)), np.zeros((1, 3, 2)), W, H)
    widths = kept["t_hi"] - kept["t_lo"]
    assert len(kept) > 0
    assert np.median(widths) < 0.35, "t^ should narrow each tile to a fraction of the shutter"


def relative_det_max(q, r, lx, ly, n=9):
    """Independent float64 check: max over a (t, u, v) grid of |D| / (|p0||p1||p2|)."""
    best = 0.0
    for t in np.linspace(0, 1, n):
        for u in np.linspace(-1, 1, 5):
            for v in np.linspace(-1, 1, 5):
                p = (1 - t) * q[0] + t * r[0]
                p = p[:, [0, 1, 3]].copy()
                p[:, 0] += u * ((1 - t) * lx[0, :, 0] + t * lx[0, :, 1])
                p[:, 1] += v * ((1 - t) * ly[0, :, 0] + t * ly[0, :, 1])
                norms = np.prod(np.linalg.norm(p, axis=1))
                if norms > 0:
                    best = max(best, abs(np.linalg.det(p)) / norms)
    return best


def test_clip_planes_set_per_batch_bound_every_interval():
    """``TileTest.clips`` is read at each run (each draw of a pass sets its own): a batch run after
    setting it gives what a tile test configured with those clip planes gives, and no interval
    reaches past them; the same batch with the configured planes again is unclipped."""
    q = np.array([[[-0.9, -0.1, 0.0, 1.0], [-0.8, -0.1, 0.0, 1.0], [-0.85, 0.0, 0.0, 1.0]]])
    r = q + np.array([1.7, 0.0, 0.0, 0.0])
    lx = np.full((1, 3, 2), 0.02)
    d = draw_from_clip(q, r, lx, lx, width=W, height=H)
    clipped = ClipPlanes(t_hi=0.3, u_lo=-0.5).as_array()
    arch = load_arch()
    setup = TriangleSetup(arch.triangle_setup, d, 8)
    alive, _, _ = setup.run(np.arange(1, dtype=np.int64))
    tiles, _, _ = TileTraverser(arch.tile_traverser, setup.table, 8, W, H).run(alive)
    per_batch = TileTest(arch.tile_test, setup.table, 8, W, H)
    configured = TileTest(arch.tile_test, setup.table, 8, W, H, clips=clipped)
    plain, _, _ = per_batch.run(tiles)
    per_batch.clips = clipped
    a, _, ev_a = per_batch.run(tiles)
    b, _, ev_b = configured.run(tiles)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a) and np.array_equal(ev_a, ev_b)
    assert len(a["tri"]) > 0 and a["t_hi"].max() <= 0.3 and a["u_lo"].min() >= -0.5
    assert plain["t_hi"].max() > 0.3 and len(plain["tri"]) > len(a["tri"])
    per_batch.clips = ClipPlanes().as_array()
    again, _, _ = per_batch.run(tiles)
    assert all(np.array_equal(again[k], plain[k]) for k in plain)
