"""The applications' shared reference ray caster (workloads/apps/raycast.py) against closed forms.

* A ray against an axis-aligned square at depth z (two triangles): the hit distance (z - o_z) / d_z, the
  barycentrics solved from the square's sides, and which triangle holds the point, in both forms (numba on
  floats, numpy on arrays); a ray parallel to the square never meets it.
* The nearest hit among squares stacked in depth and moving along z over the shutter: the nearest one in
  front of the origin within (near, far), at the ray's time.
* Refraction against Snell's law in angle form: sin(theta_t) = sin(theta_i) / ior, in the plane of
  incidence.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from workloads.apps.raycast import nearest_hits, ray_triangle, ray_triangles, refract

COORD = st.floats(-5.0, 5.0)


def square(x0: float, x1: float, y0: float, y1: float, z: float) -> np.ndarray:
    """The square [x0, x1] x [y0, y1] at depth z as two triangles (a, b, c) and (a, c, d), (2, 3, 3)."""
    a, b, c, d = (x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)
    return np.array([[a, b, c], [a, c, d]], float)


def closed_form(o, d, x0, x1, y0, y1, z):
    """Where the ray meets the square's plane: s, the point's (x, y), and per triangle its barycentrics
    (b1, b2): in (a, b, c), b2 = (y - y0) / (y1 - y0), b1 = (x - x0) / (x1 - x0) - b2; in (a, c, d),
    b1 = (x - x0) / (x1 - x0), b2 = (y - y0) / (y1 - y0) - b1."""
    s = (z - o[2]) / d[2]
    x, y = o[0] + s * d[0], o[1] + s * d[1]
    fx, fy = (x - x0) / (x1 - x0), (y - y0) / (y1 - y0)
    return s, (x, y), [(fx - fy, fy), (fx, fy - fx)]


@settings(max_examples=300, deadline=None)
@given(st.tuples(COORD, COORD, COORD), st.tuples(COORD, COORD, st.floats(0.1, 5.0) | st.floats(-5.0, -0.1)),
       st.floats(-4.0, 0.0), st.floats(0.5, 4.0), st.floats(-4.0, 0.0), st.floats(0.5, 4.0), COORD)
def test_a_ray_meets_an_axis_aligned_square_where_the_closed_form_says(o, d, x0, wx, y0, wy, z):
    x1, y1 = x0 + wx, y0 + wy
    tris = square(x0, x1, y0, y1, z)
    s, (x, y), barys = closed_form(o, d, x0, x1, y0, y1, z)
    margin = 1e-9 * (1.0 + abs(s))  # points this near an edge may round either way
    inside_square = x0 + margin < x < x1 - margin and y0 + margin < y < y1 - margin
    o_arr, d_arr = np.array(o), np.array(d)
    vectorised = ray_triangles(o_arr[None], d_arr[None], tris[:, 0], tris[:, 1], tris[:, 2])
    for k, (b1, b2) in enumerate(barys):
        got = ray_triangle(*o, *d, *tris[k].ravel())
        for form in (got, tuple(v[k] for v in vectorised)):
            assert form[0] == pytest.approx(s, rel=1e-9, abs=1e-9)
            assert form[1] == pytest.approx(b1, abs=1e-7) and form[2] == pytest.approx(b2, abs=1e-7)
            # the diagonal x - x0 : y - y0 splits the square between the two triangles
            if inside_square and abs(b1) > 1e-7 and abs(b2) > 1e-7:
                assert bool(form[3]) == (b1 > 0 and b2 > 0)
            elif not (x0 - margin <= x <= x1 + margin and y0 - margin <= y <= y1 + margin):
                assert not form[3]


def test_a_ray_parallel_to_the_square_never_meets_it():
    tri = square(-1.0, 1.0, -1.0, 1.0, 0.0)[0].ravel()
    for o in ((0.0, 0.0, 0.0), (0.2, 0.3, 1.0)):
        assert not ray_triangle(*o, 1.0, 0.5, 0.0, *tri)[3]
        assert not ray_triangles(np.array(o), np.array([1.0, 0.5, 0.0]), *square(-1, 1, -1, 1, 0.0)[0])[3]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(-10.0, 10.0), st.floats(-10.0, 10.0)), min_size=1, max_size=6),
       st.floats(-0.9, 0.9), st.floats(-0.9, 0.9), st.floats(0.0, 1.0), st.floats(0.0, 3.0), st.floats(3.0, 30.0))
def test_the_nearest_hit_among_moving_squares(depths, x, y, t, near, far):
    """Squares [-1, 1]^2 moving from z0 to z1 over the shutter, a ray from (x, y, 0) along +z at time t:
    the nearest square whose depth z0 + t (z1 - z0) lies in (near, far), at that distance, with the
    barycentrics of the closed form; none when no depth lies there."""
    p0 = np.concatenate([square(-1, 1, -1, 1, z0) for z0, _ in depths])
    p1 = np.concatenate([square(-1, 1, -1, 1, z1) for _, z1 in depths])
    z = np.array([z0 + t * (z1 - z0) for z0, z1 in depths])
    tri, dist, bary = nearest_hits(p0, p1, np.array([[x, y, 0.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([t]),
                                   near, far)
    if (np.abs(z - near) <= 1e-9).any() or (np.abs(z - far) <= 1e-9).any():
        return  # a square this close to either bound may round to either side of it
    within = (z > near) & (z < far)
    if not within.any():
        assert tri[0] == -1 and dist[0] == far
    else:
        k = int(np.argmin(np.where(within, z, np.inf)))
        assert z[tri[0] // 2] == pytest.approx(z[k], abs=1e-9) and dist[0] == pytest.approx(z[k], abs=1e-9)
        fx, fy = (x + 1.0) / 2.0, (y + 1.0) / 2.0
        want = (fx - fy, fy) if tri[0] % 2 == 0 else (fx, fy - fx)
        assert bary[0] == pytest.approx(want, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1.5), st.floats(0.0, 2 * np.pi), st.floats(1.0, 3.0), st.tuples(COORD, COORD, COORD))
def test_refraction_follows_snells_law(theta_i, phi, ior, axis):
    """A direction at angle theta_i to the normal's opposite leaves at theta_t with sin(theta_t) =
    sin(theta_i) / ior, in the plane of incidence, on the far side; with many directions and one normal,
    and one direction and many normals."""
    normal = np.array(axis) if np.linalg.norm(axis) > 1e-3 else np.array([0.0, 0.0, 1.0])
    normal /= np.linalg.norm(normal)
    tangent = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    tangent /= np.linalg.norm(tangent)
    tangent = np.cos(phi) * tangent + np.sin(phi) * np.cross(normal, tangent)
    d = np.sin(theta_i) * tangent - np.cos(theta_i) * normal
    theta_t = np.arcsin(np.sin(theta_i) / ior)
    want = np.sin(theta_t) * tangent - np.cos(theta_t) * normal
    np.testing.assert_allclose(refract(np.stack([d, d]), normal, ior), [want, want], atol=1e-12)
    np.testing.assert_allclose(refract(d, np.stack([normal, normal]), ior), [want, want], atol=1e-12)
