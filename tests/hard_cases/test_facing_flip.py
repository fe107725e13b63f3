"""Hard case: facing that changes mid-shutter (docs/pipeline.md §8; Gribel10 §4.3).

The 2DH determinant D(t, u, v) is cubic in t and bilinear in (u, v). A
triangle that turns through edge-on changes the sign of D during the
shutter (and, with defocus, at different times for different lens
positions). Setup must not claim a facing it does not have (else backface
culling drops front samples, and the edge test orients its edges wrongly),
and at the instant D = 0 no NaN may come out of the barycentric division.
"""

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import (Case, assert_closed_mesh_watertight, assert_exact_coverage,
                                assert_matches_reference, assert_single_layer_counts, check_bbox,
                                check_conservative_mode, check_continuity, check_exact, check_tiles, document,
                                lens_for, make_draw, mesh_lens, perspective_z, project, render_counts, tri)
from pipeline_sim.config import load_arch
from triangles import finite
from units.triangle_setup import EV_MIXED, TriangleSetup

TUV = [(0.1, 0.0, 0.0), (0.3, 0.4, -0.5), (0.45, 0.0, 0.0), (0.55, -0.2, 0.8), (0.7, 0.0, 0.0), (0.9, 0.6, 0.3)]


def _named():
    out = []
    # CCW at t=0, mirrored in y at t=1: edge-on at t=0.5
    q = tri((-0.6, -0.5, 0, 1.0), (0.6, -0.4, 0, 1.0), (0.0, 0.6, 0, 1.0))
    r = q * [1, -1, 1, 1]
    out.append(("mirror_in_y", q, r, None))
    # turning about a vertical axis through perspective: one side recedes in w
    q = tri((-0.5, -0.5, 0, 1.0), (0.5, -0.5, 0, 1.0), (0.0, 0.5, 0, 1.0))
    r = tri((0.4, -0.5, 0, 2.2), (-0.5, -0.5, 0, 0.8), (0.0, 0.5, 0, 1.5))
    out.append(("turning_in_depth", q, r, None))
    # flips at t ~ 0.5 from the pinhole, at other times from other lens positions
    q = tri((-0.6, -0.5, 0, 1.0), (0.6, -0.4, 0, 1.8), (0.0, 0.6, 0, 0.7))
    r = q * [1, -1, 1, 1] + [0.1, 0.0, 0.0, 0.0]
    out.append(("mirror_with_defocus", q, r, (0.25, 1.0)))
    # flips twice: D is cubic in t (apex swings through the base and back via w)
    q = tri((-0.6, -0.2, 0, 1.0), (0.6, -0.2, 0, 1.0), (0.0, 0.5, 0, 1.0))
    r = tri((-0.6, -0.2, 0, 2.5), (0.6, -0.2, 0, 0.5), (0.0, -0.9, 0, 1.0))
    out.append(("apex_swing_with_w_change", q, r, None))
    cases = []
    for name, q, r, lens in out:
        perspective_z(q, r)
        lx, ly = (None, None) if lens is None else lens_for(q, r, *lens)
        cases.append(Case(name, q, r, lx, ly))
        cases.append(Case(name + "_backface_culled", q, r, lx, ly, backface=True))
    return cases


DOCS = {
    "mirror_in_y": "mirrored in y: D changes sign at t = 0.5 (edge-on)",
    "turning_in_depth": "turns about a vertical axis through perspective: the sign change comes from w",
    "mirror_with_defocus": "the flip time differs across the lens (D is bilinear in u, v)",
    "apex_swing_with_w_change": "D is cubic in t: the Bernstein bounds straddle zero",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage(case):
    """Exact coverage with and without backface culling: setup keeps the
    triangle (mixed facing), the sample tester decides per sample."""
    check_exact(case, seeds=(0, 1))


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", CASES[::2], ids=repr)
def test_tile_intervals_conservative(case):
    check_tiles(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_continuous(case):
    check_continuity(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_float32_matches_float64_reference(case):
    """Front-facing coverage at pixel centres, before and after the flip, agrees
    with the reference (which culls by the sign of the NDC area)."""
    assert_matches_reference(*case.arrays, TUV, what=case.name, backface=case.backface, min_certain=0.9)


@pytest.mark.parametrize("case", CASES[::2], ids=repr)
def test_setup_reports_mixed_facing(case):
    """Setup must not claim a facing: the triangle survives backface culling."""
    d = case.draw()
    setup = TriangleSetup(load_arch().triangle_setup, d, 8, backface_culling=True)
    alive, _, events = setup.run(np.arange(1))
    assert list(alive) == [0]
    assert setup.table.facing[0] == 0 and events[EV_MIXED] == 1


def test_flipping_quad_shared_edge_single_layer():
    """Two triangles sharing a diagonal, the quad flipping through edge-on: no sample
    is covered twice, and the quad's interior rows are covered while it faces the camera."""
    a, b, c, d = (-0.8, -0.6), (0.8, -0.6), (0.8, 0.6), (-0.8, 0.6)
    quad = np.array([[(*a, 0, 1), (*b, 0, 1), (*c, 0, 1)], [(*a, 0, 1), (*c, 0, 1), (*d, 0, 1)]], dtype=float)
    r = quad * [1, -1, 1, 1]
    perspective_z(quad, r)
    for lens in (None, (0.1, 1.2)):
        lx, ly = (None, None) if lens is None else lens_for(quad, r, *lens)
        dr = make_draw(quad, r, lx, ly)
        res = render_counts(dr, spp=16, seed=3)
        assert_single_layer_counts(res, what="flipping quad")
        check_exact(Case("flipping quad", quad, r, lx, ly), variants=[()])


def _rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


@pytest.mark.parametrize("motion", ["spin", "invert"])
def test_closed_mesh_turning_is_watertight(motion):
    """A sphere spinning by 115 degrees (its faces turn front to back) or turned
    inside out through flat: front hits equal back hits on every sample ray."""
    sph = trimesh.creation.icosphere(subdivisions=1, radius=0.6)
    v, f = sph.vertices, sph.faces
    if motion == "spin":
        q, r = project(v + [0, 0, -2.5], f), project(v @ _rot_y(2.0).T + [0.2, 0, -2.5], f)
    else:
        q, r = project(v + [0, 0, -2.5], f), project(v * [1, -1, 1] + [0, 0, -2.5], f)
    for radius in (0.0, 0.08):
        lx, ly = mesh_lens(q, r, radius, 2.5)
        assert_closed_mesh_watertight(Case(f"{motion} radius {radius}", q, r, lx, ly))


@st.composite
def flipping_triangles(draw):
    """A triangle and its mirror image (through a random line), in perspective, maybe
    defocused: D changes sign during the shutter."""
    q = np.zeros((1, 3, 4))
    for k in range(3):
        w = draw(finite(0.3, 3.0))
        q[0, k] = (draw(finite(-1.0, 1.0)) * w, draw(finite(-1.0, 1.0)) * w, 0.0, w)
    a = draw(finite(0.0, np.pi))
    c, s = np.cos(2 * a), np.sin(2 * a)
    r = q.copy()
    r[0, :, 0] = c * q[0, :, 0] + s * q[0, :, 1]
    r[0, :, 1] = s * q[0, :, 0] - c * q[0, :, 1]  # reflection: orientation reversed
    r[0, :, 3] *= draw(finite(0.7, 1.4))
    perspective_z(q, r)
    lx, ly = lens_for(q, r, draw(st.sampled_from([0.0, 0.2])), draw(finite(0.5, 3.0)))
    return q, r, lx, ly


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(flipping_triangles(), st.integers(0, 3), st.booleans())
def test_random_flips(tri_, seed, backface):
    case = Case("random flip", *tri_, backface=backface, min_covered=0)
    assert_exact_coverage(case.draw(), spp=16, seed=seed, backface=backface, what=case.name)
    check_tiles(case, seed=seed, n=100)


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)
