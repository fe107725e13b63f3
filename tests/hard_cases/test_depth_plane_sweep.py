"""Hard case: the moving depth plane of Nilsson12 App. A sweeping through the
camera and through the lens (docs/pipeline.md §8).

With perspective depth (z/w = C1 + C0 / w) the tile test bounds w along the
tile's rays by the triangle's plane, moved linearly between its t = 0 and
t = 1 positions, and turns those into bounds on depth. Along a ray
P = w (x, y, 1) the plane gives w = -D(t) / N: when the plane passes through
the camera point D(t) changes sign and the bound flips from "w <= ..." to
"w >= ..." (or to nothing); with a lens the camera point is anywhere on the
lens, so a plane that misses the pinhole can still pass through the lens.
There the plane test must switch itself off, and z^ must still contain the
depth of every covered sample (up to float32 rounding).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import (Case, assert_exact_coverage, assert_matches_reference, check_bbox,
                                check_conservative_mode, check_continuity, check_exact, check_tiles, document,
                                mesh_lens, project)
from triangles import PERSPECTIVE, finite, setup_and_tiles

TUV = [(0.1, 0.0, 0.0), (0.3, 0.5, -0.5), (0.5, 0.0, 0.0), (0.5, -0.3, -0.9), (0.7, 0.8, 0.1), (0.9, 0.0, -0.6)]
FLOOR = np.array([[-1.5, 0.0, -0.8], [1.2, 0.0, -1.0], [0.2, 0.0, -7.0]])
FACES = np.array([[0, 1, 2]])


def _named():
    out = []
    # a floor rising from below to above the camera: edge-on (through the camera) at t = 0.5
    out.append(("floor_rising_through_camera", FLOOR + [0, -0.5, 0], FLOOR + [0.2, 0.5, 0], 0.0))
    # a wall sliding sideways through the camera at t = 0.4
    wall = FLOOR[:, [1, 0, 2]] * [1, 0.8, 1]
    out.append(("wall_sliding_through_camera", wall + [-0.4, 0, 0], wall + [0.6, 0.1, -0.3], 0.0))
    # plane through the camera point at t = 0 exactly
    out.append(("through_camera_at_start", FLOOR, FLOOR + [0.0, -0.6, 0.4], 0.0))
    # static floor missing the pinhole but passing through the lens (v R = -0.05)
    out.append(("static_floor_through_lens", FLOOR + [0, -0.05, 0], FLOOR + [0, -0.05, 0], 0.2))
    # a floor rising from -0.3 to -0.1 with a 0.25 lens: through the lens for part of the shutter
    out.append(("rising_floor_through_lens", FLOOR + [0, -0.3, 0], FLOOR + [0.1, -0.1, 0.2], 0.25))
    # and through both: rising through the camera with a lens
    out.append(("rising_through_camera_and_lens", FLOOR + [0, -0.4, 0], FLOOR + [0.1, 0.3, 0], 0.15))
    # control: a tilted plane well away from the camera, where the plane test pays off
    tilt = np.array([[-1.0, -0.8, -2.0], [1.0, -0.6, -2.5], [0.0, 0.9, -5.0]])
    out.append(("tilted_plane_far_from_camera", tilt, tilt + [0.3, 0.1, -0.5], 0.05))
    cases = []
    for name, v0, v1, radius in out:
        q, r = project(v0, FACES), project(v1, FACES)
        lx, ly = mesh_lens(q, r, radius, 2.0)
        cases.append(Case(name, q, r, lx, ly, depth_w=PERSPECTIVE, min_covered=100))
    return cases


DOCS = {
    "floor_rising_through_camera": "the plane passes through the camera point at t = 0.5 (D(t) changes sign)",
    "wall_sliding_through_camera": "a vertical plane sweeping sideways through the camera",
    "through_camera_at_start": "the plane contains the camera point at t = 0 (D(0) = 0)",
    "static_floor_through_lens": "misses the pinhole but passes through the lens (v R = -0.05)",
    "rising_floor_through_lens": "through the lens for part of the shutter only",
    "rising_through_camera_and_lens": "through the pinhole and the lens, at different times",
    "tilted_plane_far_from_camera": "control: the plane test is valid here and must tighten z^",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage_and_depth(case):
    """Exact coverage, and every written depth equals the exact depth (the sample
    tester clamps depths into z^, so a z^ that missed one would show here)."""
    check_exact(case, seeds=(0, 1, 2))


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_depth_interval_conservative(case):
    """z^ of the kept tile contains every covered sample's depth, up to float32 rounding."""
    for tile_size in (1, 4, 8, 16):
        check_tiles(case, seed=tile_size, n=150, tile_size=tile_size, ztol=1e-5)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_continuous(case):
    check_continuity(case, seeds=(0,))


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_float32_matches_float64_reference(case):
    assert_matches_reference(*case.arrays, TUV, what=case.name, min_certain=0.9, ztol=1e-5)


def test_the_sweeps_really_pass_through_camera_or_lens():
    """Guard the geometry: the plane's offset from the camera (pinhole or a lens
    point) changes sign, or is zero, during the shutter for the sweeping cases."""
    for case in CASES[:-1]:
        q, r = case.q[0], case.r[0]
        signs = set()
        for t in np.linspace(0, 1, 41):
            p = (1 - t) * q + t * r
            P = p[:, [0, 1, 3]]
            for u in (-1.0, 0.0, 1.0):
                for v in (-1.0, 0.0, 1.0):
                    lx = (1 - t) * case.lx[0, :, 0] + t * case.lx[0, :, 1]
                    ly = (1 - t) * case.ly[0, :, 0] + t * case.ly[0, :, 1]
                    Pl = P + np.c_[u * lx, v * ly, np.zeros(3)]
                    signs.add(np.sign(np.round(np.dot(np.cross(Pl[1] - Pl[0], Pl[2] - Pl[0]), Pl[0]), 12)))
        assert {-1.0, 1.0} <= signs or 0.0 in signs, case.name


def test_plane_test_tightens_where_valid():
    """Control: away from the camera the plane test narrows z^ (it is on), while
    staying conservative (test above)."""
    case = CASES[-1]
    _, _, plain = setup_and_tiles(*case.arrays)
    _, _, planes = setup_and_tiles(*case.arrays, depth_w=PERSPECTIVE)
    assert len(plain["tri"]) == len(planes["tri"]) > 4
    assert np.mean(planes["z_hi"] - planes["z_lo"]) < 0.8 * np.mean(plain["z_hi"] - plain["z_lo"])


@st.composite
def sweeping_planes(draw):
    """A world-space triangle on a plane moving through (or near) the camera height,
    seen with a lens of random size."""
    y0 = draw(finite(-0.8, 0.8))
    y1 = draw(finite(-0.8, 0.8))
    tilt = draw(finite(-0.3, 0.3))
    v0 = FLOOR.copy()
    v0[:, 1] = y0 + tilt * v0[:, 2]
    v1 = FLOOR + [draw(finite(-0.3, 0.3)), 0.0, draw(finite(-0.5, 0.5))]
    v1[:, 1] = y1 + tilt * FLOOR[:, 2]
    q, r = project(v0, FACES), project(v1, FACES)
    lx, ly = mesh_lens(q, r, draw(st.sampled_from([0.0, 0.1, 0.3])), draw(finite(0.5, 4.0)))
    return q, r, lx, ly


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sweeping_planes(), st.integers(0, 3), st.sampled_from([1, 4, 8, 16]))
def test_random_sweeps_keep_depth_conservative(tri_, seed, tile_size):
    case = Case("random sweep", *tri_, depth_w=PERSPECTIVE, min_covered=0)
    assert_exact_coverage(case.draw(), spp=16, seed=seed, what=case.name,
                          overrides=(f"tile_traverser.tile_size={tile_size}", "tile_traverser.coarse_factor=2"))
    check_tiles(case, seed=seed, n=100, tile_size=tile_size, ztol=1e-5)


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)
