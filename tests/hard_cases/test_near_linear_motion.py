"""Hard case: near-linear edge motion (docs/pipeline.md §8; Munkberg11 §4.2, Gribel10 eq. 3-5).

A moving edge's function is e(t) = (f t^2 + g t + h) . (x, y, 1) with
f = d_j x d_i, the cross product of the two vertices' motion vectors. Under
a pure translation f is exactly zero, and under a translation with a tiny
rotation it is tiny: code that divides by f (the quadratic formula) or solves
for the roots by subtracting nearly equal terms blows up or loses every digit
exactly here, the commonest motion of all. The linearized edge test must stay
conservative and every value finite.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import (Case, assert_closed_mesh_watertight, assert_exact_coverage, assert_intervals_sane,
                                check_bbox, check_conservative_mode, check_continuity, check_exact, check_tiles,
                                document, lens_for, mesh_lens, project, render, sphere, tri)
from triangles import finite, setup_and_tiles
from units.triangle_setup import FLAG_EDGE

BASE = tri((-0.55, -0.45, 0.1, 1.0), (0.45, -0.5, 0.2, 1.3), (-0.1, 0.6, 0.3, 0.9))


def rotated(q, angle, centre=(0.0, 0.0)):
    """Rotate the projected triangle in the image plane (clip x, y scaled by w)."""
    c, s = np.cos(angle), np.sin(angle)
    out = q.copy()
    w = q[..., 3]
    x = q[..., 0] / w - centre[0]
    y = q[..., 1] / w - centre[1]
    out[..., 0] = (c * x - s * y + centre[0]) * w
    out[..., 1] = (s * x + c * y + centre[1]) * w
    return out


def _cases():
    cases = [
        Case("pure_translation_x", BASE, BASE + [0.6, 0.0, 0.0, 0.0]),
        Case("pure_translation_diagonal", BASE, BASE + [-0.5, 0.35, 0.0, 0.0]),
        # the same change of w for every vertex: still f = d x d = 0
        Case("translation_with_common_w_change", BASE, BASE + [0.3, -0.2, 0.1, 0.25]),
        Case("translation_plus_1e-12_rotation", BASE, rotated(BASE, 1e-12) + [0.4, 0.1, 0.0, 0.0]),
        Case("translation_plus_1e-9_rotation", BASE, rotated(BASE, 1e-9) + [0.4, 0.1, 0.0, 0.0]),
        Case("translation_plus_1e-5_rotation", BASE, rotated(BASE, 1e-5) + [-0.3, 0.2, 0.0, 0.0]),
        # an edge sliding along itself: its function does not change at all
        Case("motion_along_an_edge", BASE, BASE + 0.5 * (BASE[0, 1] - BASE[0, 0]) * [1, 1, 0, 0]),
        Case("no_motion_at_all_but_one_ulp", BASE, BASE + [np.spacing(0.55), 0.0, 0.0, 0.0]),
    ]
    q, r = BASE, BASE + [0.5, 0.1, 0.0, 0.0]
    lx, ly = lens_for(q, r, 0.15, 1.6)
    cases.append(Case("translation_with_defocus", q, r, lx, ly))
    return cases


DOCS = {
    "pure_translation_x": "f = d x d is exactly 0: a root solver dividing by f divides by zero",
    "pure_translation_diagonal": "f = 0 with motion in x and y: both edge-normal components move",
    "translation_with_common_w_change": "every vertex gains the same w: still f = 0, but the projection scales",
    "translation_plus_1e-12_rotation": "f ~ 1e-12 |g|: the quadratic formula cancels catastrophically",
    "translation_plus_1e-9_rotation": "f ~ 1e-9 |g|: as above, a step further from exact translation",
    "translation_plus_1e-5_rotation": "f small but resolvable: the transition regime",
    "motion_along_an_edge": "an edge slides along itself: its function is constant in t (f = g = 0)",
    "no_motion_at_all_but_one_ulp": "moving by one ulp: flagged as moving, g and f at the rounding level",
    "translation_with_defocus": "f = 0 with a lens: the 5D path, where the linearized edge test is off",
}
CASES = document(_cases(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage(case):
    """No NaN or inf anywhere; every sample the exact test accepts is covered (all tile configurations)."""
    check_exact(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_tile_intervals_conservative(case):
    assert check_tiles(case) > 50


@pytest.mark.parametrize("case", CASES[:5], ids=repr)
def test_continuous(case):
    check_continuity(case)


@pytest.mark.parametrize("case", [c for c in CASES if not c.lx.any()], ids=repr)
def test_edge_test_engaged_and_finite(case):
    """The linearized edge test runs for these (motion only, constant facing),
    its constants are finite, and switching it off changes no pixel."""
    setup, alive, kept = setup_and_tiles(*case.arrays)
    tb = setup.table
    assert tb.flags[0] & FLAG_EDGE, "edge test not engaged for a motion-only triangle"
    assert np.all(np.isfinite(tb.edge_h[0])) and np.all(np.isfinite(tb.edge_gamma[0]))
    assert_intervals_sane(kept, case.name)
    d = case.draw()
    on = render(d, spp=16)
    off = render(d, spp=16, overrides=("tile_test.edge_test=false",))
    np.testing.assert_array_equal(on.image, off.image)
    np.testing.assert_array_equal(on.depth, off.depth)


@st.composite
def near_translation(draw):
    """A triangle translated by d and perturbed by 10^-k (k in 3..15): f ~ 10^-k."""
    q = np.zeros((1, 3, 4))
    for k in range(3):
        w = draw(finite(0.3, 3.0))
        q[0, k] = (draw(finite(-1.0, 1.0)) * w, draw(finite(-1.0, 1.0)) * w, draw(finite(-0.8, 0.8)) * w, w)
    d = np.array([draw(finite(-1, 1)), draw(finite(-1, 1)), 0.0, draw(finite(-0.2, 0.2))])
    k = draw(st.integers(3, 15))
    noise = np.array([[[draw(finite(-1, 1)) for _ in range(4)] for _ in range(3)]]) * 10.0**-k
    return q, q + d + noise


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(near_translation(), st.integers(0, 3))
def test_random_near_translations(tri_, seed):
    q, r = tri_
    case = Case("random near-translation", q, r)
    d = case.draw()
    assert_exact_coverage(d, spp=8, seed=seed, what=case.name)
    assert_exact_coverage(d, spp=8, seed=seed, what=case.name, overrides=("tile_traverser.coarse_factor=1",))
    check_tiles(case, seed=seed, n=100)


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)


def test_edge_test_stays_useful_and_continuous_as_f_vanishes():
    """A long diagonal triangle translating across its long edge: the edge test
    rejects tiles the moving box keeps, and t^ varies continuously as the
    quadratic coefficient goes from 1e-5 to exactly 0 (no division by it)."""
    q = tri((-0.9, -0.8, 0, 1.0), (0.9, 0.7, 0, 1.0), (-0.7, -0.8, 0, 1.0))
    zero = np.zeros((1, 3, 2))
    kept = {}
    for angle in (0.0, 1e-12, 1e-9, 1e-5):
        r = rotated(q, angle) + [0.5, -0.5, 0, 0]
        _, _, kept[angle] = setup_and_tiles(q, r, zero, zero, edge_test=True)
        _, _, box_only = setup_and_tiles(q, r, zero, zero, edge_test=False)
        assert len(kept[angle]["tri"]) < len(box_only["tri"])
        assert_intervals_sane(kept[angle], f"angle {angle}")
    for angle in (1e-12, 1e-9, 1e-5):
        assert len(kept[angle]["tri"]) == len(kept[0.0]["tri"])
        for name in ("t_lo", "t_hi"):
            assert np.max(np.abs(kept[angle][name] - kept[0.0][name])) < 1e-3 * max(angle / 1e-5, 1e-6)


@pytest.mark.parametrize("radius", [0.0, 0.08])
def test_translating_closed_mesh_is_watertight(radius):
    """A sphere in pure translation (every edge has f = 0): front hits equal back hits."""
    v, f = sphere()
    q, r = project(v + [-0.4, 0.1, -2.5], f), project(v + [0.5, -0.1, -2.5], f)
    lx, ly = mesh_lens(q, r, radius, 2.5)
    assert_closed_mesh_watertight(Case("translating sphere", q, r, lx, ly))
