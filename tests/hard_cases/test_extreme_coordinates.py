"""Hard case: coordinates from 1e-6 to 1e6 (docs/pipeline.md §8).

Homogeneous clip coordinates are scale-free: (x, y, z, w) and s (x, y, z, w)
are the same point, so the image must not depend on s. Every absolute
tolerance (w > eps, a fixed pixel margin, 1e-9 added to a bound) breaks that;
products of three coordinates (the determinant) overflow or underflow first.
Vertices a million pixels off screen make edges whose float32 rounding is a
pixel wide. Scaling by a power of two commutes with rounding, so there the
image must be bit-identical.
"""

import numpy as np
import pytest

from hard_cases.harness import (Case, assert_closed_mesh_watertight, assert_exact_coverage,
                                assert_matches_reference, check_bbox, check_conservative_mode, check_continuity,
                                check_exact, check_tiles, counts_of, document, lens_for, make_draw, mesh_lens,
                                perspective_z, project, render, render_counts, sphere, tri)


def _scene():
    """A moving, defocused triangle, a w-crossing one and a static one behind (clip space)."""
    a = tri((-0.6, -0.5, 0.2, 1.0), (0.6, -0.4, 0.3, 1.3), (0.0, 0.6, 0.1, 0.8))
    b = tri((-0.2, -0.7, 0.1, 0.9), (0.8, 0.1, 0.2, 1.1), (0.3, 0.8, 0.3, 1.2))
    c = tri((-1.5, -1.5, 0.6, 2.0), (1.5, -1.5, 0.6, 2.0), (0.0, 1.8, 0.6, 2.0))
    q = np.concatenate([a, b, c])
    r = q + np.array([0.3, 0.1, 0.0, 0.0])
    r[1, 2] = (0.5, 0.6, -0.2, -0.4)  # crosses w = 0
    r[2] = q[2]
    lx, ly = lens_for(q, r, 0.1, 1.2)
    return q, r, lx, ly


SCENE = _scene()


@pytest.mark.parametrize("k", [-20, -10, 10, 20])
def test_power_of_two_scale_is_bit_identical(k):
    """Scaling every clip coordinate (and lens shift) by 2^k gives bit-identical
    images, depths and coverage counts, with the default and the counting architecture."""
    s = 2.0**k
    base = make_draw(*SCENE)
    scaled = make_draw(*(a * s for a in SCENE))
    for render_fn in (render, render_counts):
        a = render_fn(base, spp=16)
        b = render_fn(scaled, spp=16)
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.depth, b.depth)
        assert a.counter("sample_tester", "samples_covered") == b.counter("sample_tester", "samples_covered")


@pytest.mark.parametrize("s", [1e-6, 1e-3, 1e3, 1e6])
def test_decimal_scale_changes_the_image_only_by_rounding(s):
    """Scaling by 10^k (not exact in binary) perturbs each coordinate by one rounding:
    the image may change in a handful of samples only."""
    base = render_counts(make_draw(*SCENE), spp=16)
    res = render_counts(make_draw(*(a * s for a in SCENE)), spp=16)
    d = np.abs(res.image[..., 0] - base.image[..., 0])
    assert d.mean() < 1e-3 and d.max() <= 2 / 16 + 1e-6, (d.mean(), d.max())


def _named():
    q, r, lx, ly = SCENE
    cases = [Case(f"scene_scaled_{s:g}", q * s, r * s, lx * s, ly * s) for s in (1e-6, 1e6)]
    # a triangle with vertices a million NDC units away covering the whole screen
    big = tri((-1e6, -1e6, 0, 1.0), (1e6, -1e6, 0, 1.0), (0.0, 1e6, 0, 1.0))
    cases.append(Case("screen_inside_1e6_triangle", big, big + [3e5, 1e5, 0, 0]))
    # a vertex at w = 1e-6 projecting a million NDC units away, moving
    near = tri((-0.5, -0.5, 0, 1.0), (0.5, -0.4, 0, 1.0), (0.4, 0.1, 0, 1e-6))
    cases.append(Case("vertex_at_w_1e-6", near, near + [0.1, 0.1, 0, 0]))
    # the same point scaled down to 1e-6 in every coordinate
    tiny = tri((-0.5, -0.5, 0, 1.0), (0.5, -0.4, 0, 1.0), (0.0, 0.5, 0, 0.7)) * 1e-6
    cases.append(Case("all_coordinates_1e-6", tiny, tiny + [2e-7, 0, 0, 0]))
    for c in cases[2:4]:
        perspective_z(c.q, c.r)  # so the clipping reference sees a real near plane
    return cases


DOCS = {
    "scene_scaled_1e-06": "every clip coordinate times 1e-6: absolute epsilons become large",
    "scene_scaled_1e+06": "every clip coordinate times 1e6: products of three reach 1e23",
    "screen_inside_1e6_triangle": "vertices 2.4e7 px away: the screen is deep inside, float32 ulp is 2 px",
    "vertex_at_w_1e-6": "w = 1e-6: the vertex projects a million NDC units away",
    "all_coordinates_1e-6": "a normal triangle written with every coordinate ~1e-6",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage(case):
    check_exact(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_tile_intervals_conservative(case):
    check_tiles(case, n=100)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_continuous(case):
    check_continuity(case, seeds=(0,))


def test_screen_inside_huge_triangle_is_fully_covered():
    big = tri((-1e6, -1e6, 0, 1.0), (1e6, -1e6, 0, 1.0), (0.0, 1e6, 0, 1.0))
    res = render_counts(make_draw(big, big + [3e5, 1e5, 0, 0]), spp=16)
    assert np.all(counts_of(res) == 16)


@pytest.mark.parametrize("case", CASES[2:4], ids=repr)
def test_float32_matches_float64_reference(case):
    assert_matches_reference(*case.arrays, [(0.1, 0, 0), (0.5, 0, 0), (0.9, 0, 0)], what=case.name,
                             min_certain=0.9)


S = 1e6
FAR_EDGE_Q = tri((-S, -0.7 * S, 0, 1.0), (S, 0.7 * S, 0, 1.0), (-S, S, 0, 1.0))


def test_far_vertex_edge_control_without_edge_test():
    """Control for the test below: without the linearized edge test the pipeline
    covers exactly the samples the exact test accepts."""
    d = make_draw(FAR_EDGE_Q, FAR_EDGE_Q + [0.25, 0.25, 0, 0])
    assert_exact_coverage(d, spp=16, seed=0, overrides=("tile_test.edge_test=false",), what="far edge")


def test_far_vertex_edge_through_screen():
    """An edge between two vertices a million NDC units away (2.4e7 px) crossing
    the screen diagonally, the triangle moving 6 px: float32 rounding of the far
    vertices moves the edge by about half a pixel, although h = p_j x p_i has
    cancelled to a small value. The edge tests' margins come from the
    magnitudes of the products behind h, g and f (``edge_abs``), not from h
    itself (which let tile (5, 1) lose the sample (40.05, 8.10, t = 0.571)),
    for the linearized and the quadratic edge test alike."""
    d = make_draw(FAR_EDGE_Q, FAR_EDGE_Q + [0.25, 0.25, 0, 0])
    assert_exact_coverage(d, spp=16, seed=0, what="far edge")
    assert_exact_coverage(d, spp=16, seed=0, overrides=("tile_test.edge_solver='quadratic'",), what="far edge")


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)


@pytest.mark.parametrize("size", [(1, 1), (13, 7), (45, 29)])
def test_screen_sizes_not_multiples_of_the_tile(size):
    """Partial tiles at the right and bottom borders, a one-pixel screen."""
    wd, ht = size
    d = make_draw(*SCENE, width=wd, height=ht)
    for ov in ((), ("tile_traverser.tile_size=16",)):
        assert_exact_coverage(d, spp=16, overrides=ov, what=f"{wd}x{ht}")
    check_bbox(Case(f"{wd}x{ht}", *SCENE, width=wd, height=ht))


@pytest.mark.parametrize("s", [2.0**-20, 1e-6, 1e6, 2.0**20])
def test_scaled_closed_mesh_is_watertight(s):
    """A moving, defocused sphere with every clip coordinate scaled by s."""
    v, f = sphere()
    q, r = project(v + [0, 0, -2.5], f), project(v + [0.3, 0.1, -2.6], f)
    lx, ly = mesh_lens(q, r, 0.08, 2.5)
    assert_closed_mesh_watertight(Case(f"sphere scaled {s:g}", q * s, r * s, lx * s, ly * s))
