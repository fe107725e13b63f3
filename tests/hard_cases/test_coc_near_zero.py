"""Hard case: circle of confusion near zero at the focus plane (docs/pipeline.md §8; Wu13 §3.1).

The lens shift of a vertex is R (w / F - 1) per unit lens coordinate: zero
exactly on the focus plane, tiny near it, changing sign across it. The lens
bounds divide by the shift (u = (edge - x) / beta), so an exactly zero,
tiny or denormal shift is where they would produce inf, NaN or an empty
interval; a triangle straddling or crossing the focus plane has shifts of
both signs, so its u^ is the union of two half-lines.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import (Case, assert_closed_mesh_watertight, assert_exact_coverage, assert_finite,
                                assert_matches_reference, check_bbox, check_conservative_mode, check_continuity,
                                check_exact, check_tiles, document, lens_for, make_draw, mesh_lens, perspective_z,
                                project, render, render_counts, sphere, tri)
from triangles import finite

F = 1.5  # focus distance (w of the focus plane)
TUV = [(0.1, 0.0, 0.0), (0.3, 0.9, -0.3), (0.5, -0.7, 0.7), (0.7, 0.2, 0.95), (0.9, -0.95, -0.2)]


def _named():
    cases = []
    # exactly in focus: every shift is 0.0; a defocused neighbour makes the draw 5D
    q = tri((-0.6, -0.5, 0, F), (0.3, -0.6, 0, F), (-0.2, 0.4, 0, F)) * [F, F, 1, 1]
    n = tri((0.2, 0.1, 0, 2.5), (0.8, 0.0, 0, 2.5), (0.5, 0.7, 0, 2.5)) * [2.5, 2.5, 1, 1]
    qq = np.concatenate([q, n])
    perspective_z(qq)
    lx, ly = lens_for(qq, qq, 0.3, F)
    assert np.all(lx[0] == 0.0)
    cases.append(Case("in_focus_next_to_defocused", qq, qq, lx, ly))
    # vertices in front of, on and behind the focus plane
    q = tri((-0.6, -0.5, 0, 0.7 * F), (0.6, -0.4, 0, F), (0.0, 0.6, 0, 1.6 * F))
    perspective_z(q)
    lx, ly = lens_for(q, q, 0.3, F)
    cases.append(Case("straddles_focus_plane", q, q, lx, ly))
    # moves through the focus plane: every shift changes sign mid-shutter
    q = tri((-0.5, -0.5, 0, 0.6 * F), (0.5, -0.5, 0, 0.6 * F), (0.0, 0.5, 0, 0.6 * F))
    r = q * [2.5, 2.5, 1, 2.5] + [0.1, 0, 0, 0]
    perspective_z(q, r)
    lx, ly = lens_for(q, r, 0.25, F)
    cases.append(Case("moves_through_focus_plane", q, r, lx, ly))
    # tiny and denormal shifts
    q = tri((-0.6, -0.5, 0, 1.0), (0.6, -0.4, 0, 1.3), (0.0, 0.6, 0, 0.8))
    r = q + [0.2, 0.0, 0, 0]
    perspective_z(q, r)
    for name, radius in (("coc_1e-12", 1e-12), ("coc_1e-30", 1e-30)):
        lx, ly = lens_for(q, r, radius, F)
        cases.append(Case(name, q, r, lx, ly))
    lx = np.full(q.shape[:2] + (2,), 5e-310)
    lx[0, 1] = -5e-310
    cases.append(Case("coc_denormal", q, r, lx, lx.copy()))
    # one vertex in focus (shift exactly zero), the others not
    q = tri((-0.6, -0.5, 0, F), (0.6, -0.4, 0, 0.8), (0.0, 0.6, 0, 2.4))
    q[..., :2] *= q[..., 3:4]
    perspective_z(q)
    lx, ly = lens_for(q, q, 0.2, F)
    cases.append(Case("one_vertex_in_focus", q, q, lx, ly))
    return cases


DOCS = {
    "in_focus_next_to_defocused": "every lens shift exactly 0.0 in a 5D draw: the lens bounds divide by it",
    "straddles_focus_plane": "shifts of both signs: u^ is the union of two half-lines",
    "moves_through_focus_plane": "every shift changes sign mid-shutter",
    "coc_1e-12": "shifts ~1e-12: u = (edge - x) / beta is ~1e12",
    "coc_1e-30": "shifts ~1e-30: quotients overflow towards inf",
    "coc_denormal": "denormal shifts (5e-310) of both signs: divisions overflow to inf",
    "one_vertex_in_focus": "one vertex's shift exactly zero, the others not",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage(case):
    check_exact(case, seeds=(0, 1))


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_lens_bounds_change_nothing(case):
    """u^, v^ are a pure optimisation: off, the image and depths are identical."""
    d = case.draw()
    on = render(d, spp=16)
    off = render(d, spp=16, overrides=("tile_test.lens_bounds=false",))
    assert_finite(on, case.name)
    np.testing.assert_array_equal(on.image, off.image)
    np.testing.assert_array_equal(on.depth, off.depth)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_tile_intervals_conservative(case):
    check_tiles(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_continuous(case):
    check_continuity(case, seeds=(0,))


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_float32_matches_float64_reference(case):
    assert_matches_reference(*case.arrays, TUV, what=case.name, min_certain=0.9)


@pytest.mark.parametrize("radius", [1e-15, 1e-9, 1e-6])
def test_vanishing_coc_converges_to_the_pinhole_image(radius):
    """The same (x, y, t) samples with a vanishing lens see nearly the pinhole image."""
    q = tri((-0.6, -0.5, 0, 1.0), (0.6, -0.4, 0, 1.3), (0.0, 0.6, 0, 0.8))
    r = q + [0.3, 0.1, 0, 0]
    perspective_z(q, r)
    pin = render_counts(make_draw(q, r), spp=16)
    lx, ly = lens_for(q, r, radius, F)
    lens = render_counts(make_draw(q, r, lx, ly), spp=16)
    assert_finite(lens, "vanishing coc")
    diff = np.abs(lens.image[..., 0] - pin.image[..., 0])
    assert diff.mean() < 1e-3 and diff.max() <= 2 / 16 + 1e-6, (diff.mean(), diff.max())


def test_samples_at_lens_extremes():
    """Table samples at u, v = +-1 (the lens corners the bounds are taken at) and 0."""
    case = CASES[2]
    table = np.array([[0.5, 0.5, u, v, t] for t in (0.0, 0.4, 1.0) for u, v in ((-1, -1), (1, 1), (0, 0), (1, -1))])
    assert_exact_coverage(case.draw(), spp=len(table), pattern="table", table=table[np.argsort(table[:, 4])],
                          what="lens corners")


@st.composite
def near_focus_triangles(draw):
    """Vertices within 10^-k of the focus plane or straddling it, moving through it
    or not, with lens radii from 1e-12 to 0.4."""
    q = np.zeros((1, 3, 4))
    for k in range(3):
        w = F * (1.0 + draw(st.sampled_from([0.0, 1.0])) * draw(finite(-0.5, 0.5)) * 10.0 ** -draw(st.integers(0, 12)))
        q[0, k] = (draw(finite(-1.0, 1.0)) * w, draw(finite(-1.0, 1.0)) * w, 0.0, w)
    r = q.copy()
    if draw(st.booleans()):
        r[0, :, 3] *= draw(finite(0.5, 2.0))
        r[0, :, 0] += draw(finite(-0.3, 0.3))
    perspective_z(q, r)
    lx, ly = lens_for(q, r, 10.0 ** draw(finite(-12.0, np.log10(0.4))), F)
    return q, r, lx, ly


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(near_focus_triangles(), st.integers(0, 3))
def test_random_near_focus(tri_, seed):
    case = Case("random near focus", *tri_, min_covered=0)
    assert_exact_coverage(case.draw(), spp=16, seed=seed, what=case.name)
    assert_exact_coverage(case.draw(), spp=16, seed=seed, what=case.name,
                          overrides=("tile_traverser.tile_size=2", "tile_traverser.coarse_factor=2"))
    check_tiles(case, seed=seed, n=100)


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)


@pytest.mark.parametrize("focus", [2.5, 2.2, 2.8])
def test_closed_mesh_around_the_focus_plane_is_watertight(focus):
    """A sphere centred at, in front of or behind the focus plane (lens shifts of both
    signs and exactly zero on the focus circle), moving: front hits equal back hits."""
    v, f = sphere()
    q, r = project(v + [0, 0, -2.5], f), project(v + [0.3, 0.1, -2.5], f)
    lx, ly = mesh_lens(q, r, 0.1, focus)
    assert_closed_mesh_watertight(Case(f"sphere focus {focus}", q, r, lx, ly))
