"""The shader helpers of pipeline_sim/shaders.py that project a point through a matrix among the
parameters and compare depths over a texel neighbourhood, against numpy (a matrix product, a brute-force
loop over the neighbourhood with numpy's clamping)."""

from __future__ import annotations

import numba as nb
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.shaders import compare_layer, project


@nb.njit(cache=True)
def _project_all(params, base, points):
    out = np.empty((len(points), 4))
    for i in range(len(points)):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = project(params, base, points[i, 0], points[i, 1], points[i, 2])
    return out


def test_project_is_the_matrix_product_per_layer():
    """Matrix k at params[3 + 16 k]: (s, t) = ((x/w + 1) / 2, (1 - y/w) / 2), depth z/w and w."""
    rng = np.random.default_rng(0)
    matrices = rng.normal(size=(3, 4, 4))
    matrices[:, 3] = [0.1, 0.2, -1.0, 4.0]  # w stays away from 0 for the points below
    params = np.concatenate([np.zeros(3), matrices.reshape(-1)]).astype(np.float32)
    points = rng.uniform(-1, 1, (50, 3)).astype(np.float32)
    for k in range(3):
        matrix = params[3 + 16 * k:3 + 16 * (k + 1)].astype(np.float64).reshape(4, 4)
        clip = np.column_stack([points, np.ones(50)]) @ matrix.T
        want = np.column_stack([0.5 * (clip[:, 0] / clip[:, 3] + 1), 0.5 * (1 - clip[:, 1] / clip[:, 3]),
                                clip[:, 2] / clip[:, 3], clip[:, 3]])
        np.testing.assert_allclose(_project_all(params, 3 + 16 * k, points), want, rtol=1e-5, atol=1e-5)


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.floats(-0.3, 1.3), st.floats(-0.3, 1.3), st.integers(0, 3),
       st.integers(0, 2), st.integers(0, 1000))
def test_compare_layer_is_the_share_of_texels_not_in_front(h, w, s, t, radius, layer, seed):
    rng = np.random.default_rng(seed)
    tex = rng.integers(0, 4, (h, w, 3)).astype(np.float32) / 4
    ref = np.float32(rng.integers(0, 4) / 4)
    cx = int(np.clip(s, 0, 1) * w)
    cy = int(np.clip(t, 0, 1) * h)
    near = [tex[min(max(cy + dy, 0), h - 1), min(max(cx + dx, 0), w - 1), layer]
            for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]
    assert compare_layer(tex, layer, s, t, ref, radius) == np.mean(np.array(near) >= ref)


def test_compare_layer_takes_nan_coordinates_as_the_first_texel():
    tex = np.arange(6, dtype=np.float32).reshape(2, 3, 1)
    assert compare_layer(tex, 0, np.nan, np.nan, np.float32(0.5), 0) == 0.0  # texel (0, 0) holds 0 < 0.5
    assert compare_layer(tex, 0, np.nan, 2.0, np.float32(3.0), 0) == 1.0  # texel (row 1, col 0) holds 3
