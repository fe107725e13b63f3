"""Hard case: vertex paths crossing w = 0 during the shutter (docs/pipeline.md §8; Munkberg11 §3).

While a vertex is behind the camera its projection X/W is undefined and the
triangle is an "external" one: the visible part is not the hull of the
projected vertices. Screen bounds must fall back to the whole screen, every
test that divides by W must be off, the 2DH edge functions must still
select exactly the points in front, and a w of exactly zero at a sample's t
must not make a NaN.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import (Case, assert_closed_mesh_watertight, assert_exact_coverage,
                                assert_matches_reference, assert_single_layer_counts, centre_table, check_bbox,
                                check_conservative_mode, check_continuity, check_exact, check_tiles, document,
                                grid_mesh, lens_for, make_draw, mesh_lens, perspective_z, project, render_counts,
                                tri)
from triangles import finite, setup_and_tiles
from units.triangle_setup import FLAG_WPOS

TUV = [(0.05, 0.0, 0.0), (0.3, 0.5, -0.2), (0.5, -0.3, 0.4), (0.62, 0.0, 0.0), (0.8, 0.2, 0.7), (0.97, -0.6, -0.1)]


def _named():
    base = tri((-0.5, -0.5, 0, 1.0), (0.5, -0.5, 0, 1.0), (0.0, 0.5, 0, 1.0))
    cases = []
    q, r = base.copy(), base.copy()
    r[0, 2] = (0.0, 0.5, 0.0, -0.5)  # from test_tile_test: the apex goes behind the camera
    cases.append(("one_vertex_goes_behind", q, r, None))
    q, r = base.copy(), base.copy()
    r[0, 0] = (-0.3, -0.6, 0.0, -0.4)
    r[0, 1] = (0.6, -0.2, 0.0, -1.0)
    cases.append(("two_vertices_go_behind", q, r, None))
    q = tri((-0.6, -0.4, 0, 0.6), (0.7, -0.3, 0, 0.9), (0.1, 0.7, 0, 0.4))
    r = q.copy()
    r[0, :, 3] = (-0.5, -0.2, -0.9)  # the whole triangle passes the camera plane, vertices at different times
    r[0, :, 0] += 0.2
    cases.append(("whole_triangle_passes_camera_plane", q, r, None))
    q = tri((-0.4, -0.5, 0, -0.6), (0.5, -0.4, 0, -0.3), (0.0, 0.6, 0, 1.2))
    r = tri((-0.5, -0.5, 0, 1.0), (0.4, -0.5, 0, 1.4), (0.2, 0.5, 0, 0.8))
    cases.append(("comes_from_behind", q, r, None))
    q, r = base.copy(), base.copy()
    r[0, 2] = (0.3, 0.4, 0.0, -0.8)
    cases.append(("crossing_with_defocus", q, r, (0.2, 1.5)))
    # w = 1 + t (-2) is exactly 0 at t = 0.5, a sample time of the tables below
    q, r = base.copy(), base.copy()
    r[0, 1] = (0.5, -0.5, 0.0, -1.0)
    cases.append(("w_exactly_zero_at_t_half", q, r, None))
    q, r = base.copy(), base.copy()
    q[0, 0] = (-0.2, -0.3, 0.0, 0.0)  # starts on the camera plane
    cases.append(("w_exactly_zero_at_t0", q, r, None))
    out = []
    for name, q, r, lens in cases:
        perspective_z(q, r)
        lx, ly = (None, None) if lens is None else lens_for(q, r, *lens)
        out.append(Case(name, q, r, lx, ly))
    return out


DOCS = {
    "one_vertex_goes_behind": "the apex's w goes from 1 to -0.5: an external triangle for t > 2/3",
    "two_vertices_go_behind": "two vertex paths cross w = 0 at different times",
    "whole_triangle_passes_camera_plane": "all three vertices cross w = 0, at three different times",
    "comes_from_behind": "two vertices start behind the camera and come in front",
    "crossing_with_defocus": "crossing w = 0 with a lens: lens bounds divide by w and must be off",
    "w_exactly_zero_at_t_half": "w = 1 - 2t is exactly 0 at t = 0.5, a float32 sample time",
    "w_exactly_zero_at_t0": "a vertex starts exactly on the camera plane (w = 0 at t = 0)",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage(case):
    check_exact(case, seeds=(0, 1))


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_tile_intervals_conservative(case):
    check_tiles(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_continuous(case):
    check_continuity(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_float32_matches_float64_reference(case):
    """Coverage and depth at pixel centres agree with the clipping reference."""
    assert_matches_reference(*case.arrays, TUV, what=case.name, min_certain=0.9)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_sample_at_the_crossing_time(case):
    """Table samples at t = 0, 0.5 and 1 (w exactly zero for some cases): finite, exact."""
    table = centre_table([(0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.5, 0.7, -0.7), (1.0, 0.0, 0.0)])
    table[:, 0] = [0.5, 0.25, 0.5, 0.75]
    assert_exact_coverage(case.draw(), spp=len(table), pattern="table", table=table, what=case.name)


def test_crossing_means_whole_screen_bounds():
    """A crossing triangle is flagged (no w > 0 assumptions) and bounded by the screen."""
    case = CASES[0]
    setup, alive, kept = setup_and_tiles(*case.arrays)
    assert 0 in alive
    assert not setup.table.flags[0] & FLAG_WPOS
    assert list(setup.table.bounds[0]) == [0, 48, 0, 32]


def floor_through_camera():
    """A floor grid reaching behind the camera (w < 0), rising and sliding backwards
    so that vertex paths cross w = 0 (some start exactly on it)."""
    verts, faces = grid_mesh(-30.0, 30.0, -20.0, 5.0, 8, 10, -1.0)
    q = project(verts, faces)
    r = project(verts + [0.3, 0.2, 3.0], faces)
    return q, r


@pytest.mark.parametrize("radius", [0.0, 0.05])
def test_floor_through_camera_plane_is_watertight(radius):
    """Every sample is covered at most once, and the rows looking down at the floor
    (NDC y < -0.43, hit distance 2..6 whatever t and lens) completely."""
    q, r = floor_through_camera()
    assert np.any((q[..., 3] > 0) & (r[..., 3] < 0)), "no vertex path crosses w = 0"
    lx, ly = mesh_lens(q, r, radius, 3.0)
    d = make_draw(q, r, lx, ly)
    for seed in (0, 1):
        res = render_counts(d, spp=8, seed=seed)
        assert_single_layer_counts(res, full_rows=range(23, 32), what=f"floor radius {radius}")
    check_exact(Case("floor_through_camera", q, r, lx, ly, spp=8), variants=[()])


def test_corridor_crossing_camera_plane_is_watertight():
    """A closed box beside the camera reaching behind it, moving: front hits equal back hits."""
    import trimesh

    box = trimesh.creation.box(extents=[0.6, 0.6, 5.0]).subdivide()
    q = project(box.vertices + [0.7, 0.0, -1.0], box.faces)
    r = project(box.vertices + [0.6, 0.1, -1.8], box.faces)
    assert np.any(q[..., 3] < 0) and np.any(q[..., 3] > 0)
    for radius in (0.0, 0.08):
        lx, ly = mesh_lens(q, r, radius, 2.5)
        assert_closed_mesh_watertight(Case(f"corridor radius {radius}", q, r, lx, ly))


@st.composite
def crossing_triangles(draw):
    """A triangle with at least one vertex path crossing w = 0, perspective depth,
    maybe defocused."""
    q = np.zeros((1, 3, 4))
    r = np.zeros((1, 3, 4))
    for k in range(3):
        for arr, lo, hi in ((q, 0.2, 3.0), (r, -2.0, 3.0)):
            w = draw(finite(lo, hi))
            s = max(abs(w), 0.2)
            arr[0, k] = (draw(finite(-1.5, 1.5)) * s, draw(finite(-1.5, 1.5)) * s, 0.0, w)
    k = draw(st.integers(0, 2))
    r[0, k, 3] = -abs(r[0, k, 3]) - 0.05  # at least one crossing
    if draw(st.booleans()):
        q, r = r, q  # or coming from behind
    perspective_z(q, r)
    lx, ly = lens_for(q, r, draw(st.sampled_from([0.0, 0.1, 0.3])), draw(finite(0.5, 3.0)))
    return q, r, lx, ly


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(crossing_triangles(), st.integers(0, 3))
def test_random_crossings(tri_, seed):
    case = Case("random w crossing", *tri_, min_covered=0)
    assert_exact_coverage(case.draw(), spp=16, seed=seed, what=case.name)
    check_tiles(case, seed=seed, n=100)


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)
