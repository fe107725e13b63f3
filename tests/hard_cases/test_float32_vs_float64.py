"""Hard case: float32 sample tests against float64 (docs/pipeline.md §8).

Triangle setup works in float64; the sample tester, as hardware would, lerps
float32 copies of the vertices to each sample's (t, u, v) and evaluates
float32 edge functions, falling back to float64 on the float32 vertices
within an error bound of an edge. Away from edges (by more than float32 can
move them) coverage must agree with an independent float64 renderer
(tests/reference.py: clip, divide, Cramer's rule), and depth must agree to
float32 precision.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import assert_matches_reference, lens_for, make_draw, mesh_lens, perspective_z, project
from pipeline_sim.config import load_arch
from triangles import finite
from units.triangle_setup import TriangleSetup

TUV = [(0.0, 0.0, 0.0), (0.2, 0.5, -0.4), (0.45, -0.8, 0.1), (0.5, 0.0, 0.0), (0.7, 0.3, 0.9), (0.99, -0.2, -0.7)]


def blur_scene(seed, n=12):
    """Overlapping moving, defocused triangles with perspective depth (like test_render's)."""
    rng = np.random.default_rng(seed)
    q = np.zeros((n, 3, 4))
    w = rng.uniform(1.0, 3.0, (n, 1))
    centre = rng.uniform(-0.5, 0.5, (n, 1, 2))
    q[:, :, :2] = (centre + rng.uniform(-0.35, 0.35, (n, 3, 2))) * w[:, :, None]
    q[:, :, 3] = w * rng.uniform(0.8, 1.25, (n, 3))
    r = q.copy()
    r[:, :, 0] += rng.uniform(-0.4, 0.4, (n, 1)) * w
    r[:, :, 3] *= rng.uniform(0.8, 1.2, (n, 1))
    perspective_z(q, r)
    lx, ly = lens_for(q, r, 0.08, 2.0)
    return q, r, lx, ly


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_overlapping_blur_scene_matches_reference(seed):
    """Nearest coverage and depth at pixel centres, 6 (t, u, v) per pixel."""
    assert_matches_reference(*blur_scene(seed), TUV, what=f"blur scene {seed}", ztol=1e-5)


def test_mesh_matches_reference():
    import trimesh

    sph = trimesh.creation.icosphere(subdivisions=1, radius=0.7)
    q = project(sph.vertices + [0.0, 0.0, -2.2], sph.faces)
    r = project(sph.vertices * [1.1, 0.9, 1.0] + [0.3, 0.1, -2.6], sph.faces)
    lx, ly = mesh_lens(q, r, 0.05, 2.4)
    assert_matches_reference(q, r, lx, ly, TUV, what="sphere", ztol=1e-5)


def test_setup_float32_tables_are_the_rounded_float64_ones():
    """The sample tester's float32 vertex tables are the float64 setup values rounded
    once (no drift from computing them in float32)."""
    q, r, lx, ly = blur_scene(4)
    d = make_draw(q, r, lx, ly)
    setup = TriangleSetup(load_arch().triangle_setup, d, 8)
    setup.run(np.arange(d.n))
    tb = setup.table
    for a64, a32 in ((tb.p0, tb.p0_32), (tb.dp, tb.dp_32), (tb.l0, tb.l0_32), (tb.dl, tb.dl_32)):
        np.testing.assert_array_equal(a64.astype(np.float32), a32)
    assert np.all(np.isfinite(tb.edge_eps)) and np.all(tb.edge_eps > 0)


@st.composite
def scenes(draw):
    """1-4 random moving, defocused triangles with perspective depth, some crossing w = 0."""
    n = draw(st.integers(1, 4))
    q = np.zeros((n, 3, 4))
    r = np.zeros((n, 3, 4))
    for arr in (q, r):
        for i in range(n):
            for k in range(3):
                w = draw(finite(-0.5, 4.0))
                s = max(abs(w), 0.2)
                arr[i, k] = (draw(finite(-1.5, 1.5)) * s, draw(finite(-1.5, 1.5)) * s, 0.0, w)
    if draw(st.booleans()):
        r = q + np.array([draw(finite(-0.8, 0.8)), draw(finite(-0.8, 0.8)), 0.0, 0.0])
    perspective_z(q, r)
    lx, ly = lens_for(q, r, draw(st.sampled_from([0.0, 0.05, 0.2])), draw(finite(0.5, 3.0)))
    return q, r, lx, ly


@settings(max_examples=30, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes())
@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the reference divides by w = 0 for vertices on the eye plane
def test_random_scenes_match_reference(scene):
    assert_matches_reference(*scene, TUV[1:5], what="random scene", min_certain=0.0, ztol=1e-4)
