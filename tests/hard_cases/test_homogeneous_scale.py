"""Hard case: homogeneous scale (docs/pipeline.md §8).

Clip coordinates are homogeneous: (x, y, z, w) and s (x, y, z, w) with s > 0
are the same point, and a triangle with every coordinate (and its lens
shifts, which move x and y) times s is the same triangle. Products of two or
three coordinates make the edge functions and the determinant: in the
sample tester's float32 (largest 3.4e38, smallest normal 1.2e-38) they
overflow or underflow long before the input does. Before triangle setup
normalised each triangle (divided its coordinates by a power of two, which
is exact), the first case below lost 45% of its covered samples scaled by
1e-16 and 60% scaled by 1e12, with a finite image, and all of them beyond
1e16 or below 1e-20. test_extreme_coordinates covers scales 1e-6 to 1e6
and powers of two; this file 1e-30 to 1e30, for every tile-test
configuration.
"""

import pytest

from hard_cases.harness import Case, check_scale_invariant, check_tiles, document, mesh_lens, project, sphere
from hard_cases.test_extreme_coordinates import SCENE
from triangles import VIEW_RAY_Q, VIEW_RAY_R

# 1e-30 to 1e30 with the scales where the float32 test began to lose samples (1e-16, 1e12), and
# powers of two at both ends (bit-identical renders)
FACTORS = (1e-30, 1e-22, 1e-16, 1e-10, 1e10, 1e12, 1e22, 1e30, 2.0**-100, 2.0**100)


def _named():
    # a moving, defocused triangle, one whose vertex crosses w = 0, a static one behind
    cases = [Case("blur_w_crossing_and_static", *SCENE)]
    # motion only, a vertex moving along its view ray (the hull algorithm's hard case)
    cases.append(Case("vertex_on_its_view_ray", VIEW_RAY_Q, VIEW_RAY_R, width=16, height=16))
    # a closed mesh, moving and defocused: shared edges at every scale
    v, f = sphere()
    q, r = project(v + [0, 0, -2.5], f), project(v + [0.3, 0.1, -2.6], f)
    lx, ly = mesh_lens(q, r, 0.08, 2.5)
    cases.append(Case("moving_defocused_sphere", q, r, lx, ly, spp=8))
    return cases


DOCS = {
    "blur_w_crossing_and_static": "motion, defocus, a vertex path through w = 0 and a static triangle behind",
    "vertex_on_its_view_ray": "a vertex fixed on screen moving in depth; motion only, so the hull test runs",
    "moving_defocused_sphere": "80 triangles sharing edges, moving and defocused",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_scaled_covers_the_same_samples(case):
    """From 1e-30 to 1e30, every tile-test configuration covers exactly the
    samples (and depths) of the unscaled case, which are the exact test's."""
    check_scale_invariant(case, FACTORS)


@pytest.mark.parametrize("s", [1e-30, 1e30])
@pytest.mark.parametrize("case", CASES[:2], ids=repr)
def test_scaled_tile_intervals_conservative(case, s):
    """Unit level, every algorithm: covered samples of the scaled case lie in kept tiles and their intervals."""
    scaled = Case(f"{case.name} x {s:g}", *(a * s for a in case.arrays), width=case.width, height=case.height)
    check_tiles(scaled, n=100, min_points=50)
