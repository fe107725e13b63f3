"""Hard case: zero area at some t (docs/pipeline.md §8; Gribel10 eq. 10-13).

A triangle that collapses to a segment or a point at some instant has
D = 0 there: barycentrics e_k / sum(e) and depth sum(e Z) / sum(e W) divide
by zero, the plane through the triangle has no normal, facing is undefined,
and the time where the area vanishes can coincide with a sample's t. Setup
must keep it (it has area at other times) unless it has none at all, and no
NaN may reach a buffer.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import (Case, assert_closed_mesh_watertight, assert_exact_coverage, assert_finite,
                                assert_matches_reference, assert_tiles_conservative, centre_table, check_bbox,
                                check_conservative_mode, check_continuity, check_exact, check_tiles, counts_of,
                                document, lens_for, make_draw, mesh_lens, perspective_z, project, render,
                                render_counts, sphere, tri)
from triangles import PERSPECTIVE, finite, setup_and_tiles

TUV = [(0.1, 0.0, 0.0), (0.3, 0.4, -0.5), (0.49, 0.0, 0.0), (0.51, -0.2, 0.8), (0.7, 0.0, 0.0), (0.9, 0.6, 0.3)]


def _named():
    out = []
    # the apex moves through the base: collinear exactly at t = 0.5
    q = tri((-0.6, -0.3, 0, 1.0), (0.6, -0.3, 0, 1.0), (0.1, 0.5, 0, 1.0))
    r = tri((-0.6, -0.3, 0, 1.0), (0.6, -0.3, 0, 1.0), (-0.1, -1.1, 0, 1.0))
    out.append(("apex_through_base_at_half", q, r, None))
    # shrinks to a point at t = 1
    q = tri((-0.6, -0.5, 0, 1.0), (0.6, -0.4, 0, 1.2), (0.0, 0.6, 0, 0.8))
    p = np.array([0.1, 0.05, 0.0, 1.0])
    r = np.array([[p * 1.0, p * 1.2, p * 0.8]])
    out.append(("collapse_to_point_at_end", q, r, None))
    # grows from a point at t = 0, defocused
    out.append(("born_from_point_defocused", r.copy(), q.copy(), (0.15, 1.5)))
    # two vertices coincide at t = 0 and separate
    q = tri((-0.5, -0.4, 0, 1.0), (-0.5, -0.4, 0, 1.0), (0.3, 0.6, 0, 1.0))
    r = tri((-0.5, -0.4, 0, 1.0), (0.6, -0.5, 0, 1.0), (0.3, 0.6, 0, 1.0))
    out.append(("two_vertices_coincide_at_start", q, r, None))
    # collapses onto a line of clip space (so its plane at t = 1 has no normal), with depth planes
    q = tri((-0.5, -0.5, 0, 1.0), (0.5, -0.5, 0, 2.0), (0.0, 0.5, 0, 1.5))
    r = tri((-0.5, 0.1, 0, 1.0), (0.5, 0.1, 0, 1.0), (0.1, 0.1, 0, 1.0))
    out.append(("flattened_at_end_with_planes", q, r, None))
    cases = []
    for name, q, r, lens in out:
        perspective_z(q, r)
        lx, ly = (None, None) if lens is None else lens_for(q, r, *lens)
        depth_w = PERSPECTIVE if "planes" in name else None
        cases.append(Case(name, q, r, lx, ly, depth_w=depth_w))
    return cases


DOCS = {
    "apex_through_base_at_half": "collinear exactly at t = 0.5 (a sample time and the shading reference time)",
    "collapse_to_point_at_end": "all three vertices meet at t = 1: every edge function vanishes",
    "born_from_point_defocused": "grows from a point at t = 0, with a lens",
    "two_vertices_coincide_at_start": "an edge of zero length at t = 0: its normal is zero",
    "flattened_at_end_with_planes": "on a line of clip space at t = 1: the depth plane has no normal",
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
    assert_matches_reference(*case.arrays, TUV, what=case.name, min_certain=0.9)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_samples_at_the_degenerate_instant(case):
    """Table samples exactly at t = 0, 0.5 and 1, where some case has D = 0: finite and exact."""
    table = centre_table([(0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.5, 0.3, 0.3), (1.0, 0.0, 0.0)])
    for shading in ("per_sample", "cache"):
        res = assert_exact_coverage(case.draw(), spp=len(table), pattern="table", table=table, what=case.name,
                                    overrides=(f"pass.shading_mode='{shading}'",))
        assert_finite(res, case.name)


def test_plane_without_normal_switches_plane_test_off():
    """At t = 1 the flattened triangle lies on a line of clip space: its plane has no
    normal. The depth bounds must come from the other plane and the vertices only:
    finite and conservative."""
    case = CASES[-1]
    r = case.r[0][:, [0, 1, 3]]
    assert np.allclose(np.cross(r[1] - r[0], r[2] - r[0]), 0.0), "the t = 1 triangle should have no plane"
    setup, alive, kept = setup_and_tiles(*case.arrays, depth_w=PERSPECTIVE)
    assert np.all(np.isfinite(kept["z_lo"])) and np.all(np.isfinite(kept["z_hi"]))
    assert_tiles_conservative(*case.arrays, depth_w=PERSPECTIVE, what=case.name, min_points=50)


@pytest.mark.parametrize("lens", [None, (0.2, 1.3)])
def test_degenerate_for_the_whole_shutter(lens):
    """Collinear at every t (a segment sliding along itself): dropped by setup or
    covering nothing; nothing non-finite anywhere."""
    q = tri((-0.6, -0.3, 0, 1.0), (0.6, 0.3, 0, 1.0), (0.2, 0.1, 0, 1.0))
    r = q + [0.2, 0.1, 0, 0]
    perspective_z(q, r)
    lx, ly = (None, None) if lens is None else lens_for(q, r, *lens)
    d = make_draw(q, r, lx, ly)
    for shading in ("per_sample", "cache"):
        res = render_counts(d, spp=16, overrides=(f"pass.shading_mode='{shading}'",))
        assert_finite(res, "collinear")
        assert counts_of(res).sum() <= 2, "a segment covered a visible area"
    assert_finite(render(d, spp=16), "collinear default arch")
    assert_exact_coverage(d, spp=16, what="collinear")


@st.composite
def collapsing_triangles(draw):
    """A triangle whose third vertex is on the line of the other two at a random
    t_c (exactly representable: k / 16), maybe defocused."""
    q = np.zeros((1, 3, 4))
    r = np.zeros((1, 3, 4))
    for arr in (q, r):
        for k in range(2):
            w = draw(finite(0.4, 3.0))
            arr[0, k] = (draw(finite(-1.0, 1.0)) * w, draw(finite(-1.0, 1.0)) * w, 0.0, w)
    tc = draw(st.integers(0, 16)) / 16.0
    a = draw(finite(-0.5, 1.5))
    p0 = (1 - tc) * q[0, 0] + tc * r[0, 0]
    p1 = (1 - tc) * q[0, 1] + tc * r[0, 1]
    target = (1 - a) * p0 + a * p1  # on the line (in clip space) at t_c
    w2 = draw(finite(0.4, 3.0))
    other = np.array([draw(finite(-1.0, 1.0)) * w2, draw(finite(-1.0, 1.0)) * w2, 0.0, w2])
    if tc == 0.0:
        q[0, 2], r[0, 2] = target, other
    else:  # p2(t) = other + (target - other) t / t_c reaches the line at t_c (its w may cross 0)
        q[0, 2], r[0, 2] = other, other + (target - other) / tc
    perspective_z(q, r)
    lx, ly = lens_for(q, r, draw(st.sampled_from([0.0, 0.15])), draw(finite(0.5, 3.0)))
    return q, r, lx, ly


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(collapsing_triangles(), st.integers(0, 3))
def test_random_collapses(tri_, seed):
    case = Case("random collapse", *tri_, min_covered=0)
    table = centre_table([(k / 16.0, 0.0, 0.0) for k in range(0, 17, 2)])
    assert_exact_coverage(case.draw(), spp=16, seed=seed, what=case.name)
    assert_exact_coverage(case.draw(), spp=len(table), pattern="table", table=table, what=case.name)
    check_tiles(case, seed=seed, n=100)


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)


@pytest.mark.parametrize("radius", [0.0, 0.08])
def test_closed_mesh_collapsing_edge_on_is_watertight(radius):
    """A sphere mirrored in x through the view axis: at t = 0.5 every face lies in
    the plane x = 0, seen edge-on (all areas zero at a sample time); front hits
    still equal back hits on every sample ray."""
    v, f = sphere()
    q, r = project(v + [0, 0, -2.5], f), project(v * [-1, 1, 1] + [0, 0, -2.5], f)
    lx, ly = mesh_lens(q, r, radius, 2.5)
    assert_closed_mesh_watertight(Case("collapsing sphere", q, r, lx, ly))
