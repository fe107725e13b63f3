"""Reference ray casting shared by the applications' checks, independent of the 5D pipeline (nothing here
imports pipeline_sim): one ray-triangle intersection (Möller-Trumbore), the nearest hit of rays among
triangles moving linearly over the shutter, and refraction by Snell's law.

``ray_triangle`` runs inside numba kernels on floats; ``ray_triangles`` runs the same arithmetic on numpy
arrays. Not an application: a module, not a package, so no kind is registered for it.
"""

from __future__ import annotations

import numba as nb
import numpy as np


def _moller_trumbore(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Möller-Trumbore in plain arithmetic (floats or broadcasting numpy arrays alike): the ray o + s d
    against triangle abc. Returns s, the barycentrics b1, b2 of b and c (the point a + b1 (b - a) +
    b2 (c - a)) and whether the ray meets the triangle: not parallel to its plane (det != 0) and b1, b2 >= 0,
    b1 + b2 <= 1, on either side of the origin (the caller bounds s)."""
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    tx, ty, tz = ox - ax, oy - ay, oz - az
    qx, qy, qz = ty * e1z - tz * e1y, tz * e1x - tx * e1z, tx * e1y - ty * e1x
    b1 = (tx * px + ty * py + tz * pz) / det
    b2 = (dx * qx + dy * qy + dz * qz) / det
    s = (e2x * qx + e2y * qy + e2z * qz) / det
    return s, b1, b2, (det != 0.0) & (b1 >= 0.0) & (b2 >= 0.0) & (b1 + b2 <= 1.0)


#: ``_moller_trumbore`` on floats, for numba kernels (a ray parallel to the plane divides by zero: inf or
#: NaN, not an exception, and no hit).
ray_triangle = nb.njit(cache=True, error_model="numpy")(_moller_trumbore)


def ray_triangles(o: np.ndarray, d: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``ray_triangle`` over numpy arrays: rays o + s d against triangles abc, each (..., 3), broadcasting
    against each other. Returns s, b1, b2 and whether each ray meets its triangle, each (...)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return _moller_trumbore(*(v[..., i] for v in (o, d, a, b, c) for i in range(3)))


@nb.njit(cache=True)
def nearest_hit(ox, oy, oz, dx, dy, dz, p0, p1, t, near, far):
    """The nearest hit of the ray o + s d, s in (near, far), among triangles whose vertices move linearly
    from ``p0`` at t = 0 to ``p1`` at t = 1 (N, 3, 3), at time ``t``: the triangle's index (-1: none), s,
    b1 and b2 (as ``ray_triangle``)."""
    best, tri, hit_b1, hit_b2 = far, -1, 0.0, 0.0
    for k in range(p0.shape[0]):
        ax = p0[k, 0, 0] + t * (p1[k, 0, 0] - p0[k, 0, 0])
        ay = p0[k, 0, 1] + t * (p1[k, 0, 1] - p0[k, 0, 1])
        az = p0[k, 0, 2] + t * (p1[k, 0, 2] - p0[k, 0, 2])
        bx = p0[k, 1, 0] + t * (p1[k, 1, 0] - p0[k, 1, 0])
        by = p0[k, 1, 1] + t * (p1[k, 1, 1] - p0[k, 1, 1])
        bz = p0[k, 1, 2] + t * (p1[k, 1, 2] - p0[k, 1, 2])
        cx = p0[k, 2, 0] + t * (p1[k, 2, 0] - p0[k, 2, 0])
        cy = p0[k, 2, 1] + t * (p1[k, 2, 1] - p0[k, 2, 1])
        cz = p0[k, 2, 2] + t * (p1[k, 2, 2] - p0[k, 2, 2])
        s, b1, b2, inside = ray_triangle(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, cx, cy, cz)
        if inside and near < s < best:
            best, tri, hit_b1, hit_b2 = s, k, b1, b2
    return tri, best, hit_b1, hit_b2


@nb.njit(cache=True)
def _nearest_hits(p0, p1, origins, dirs, times, near, far, tri, dist, bary):
    for r in range(origins.shape[0]):
        tri[r], dist[r], bary[r, 0], bary[r, 1] = nearest_hit(origins[r, 0], origins[r, 1], origins[r, 2],
                                                              dirs[r, 0], dirs[r, 1], dirs[r, 2], p0, p1,
                                                              times[r], near, far)


def nearest_hits(p0: np.ndarray, p1: np.ndarray, origins: np.ndarray, dirs: np.ndarray, times: np.ndarray,
                 near: float = 0.0, far: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``nearest_hit`` of each ray (origins, directions (M, 3), times (M,)) in float64: the triangle index
    (M,) (-1: none), the ray parameter s (M,) (``far`` where none) and the barycentrics (M, 2) of vertices 1
    and 2."""
    m = len(origins)
    tri, dist, bary = np.empty(m, np.int64), np.empty(m), np.zeros((m, 2))
    _nearest_hits(np.ascontiguousarray(p0, np.float64), np.ascontiguousarray(p1, np.float64),
                  np.ascontiguousarray(origins, np.float64), np.ascontiguousarray(dirs, np.float64),
                  np.ascontiguousarray(times, np.float64), float(near), float(far), tri, dist, bary)
    return tri, dist, bary


def refract(d: np.ndarray, n: np.ndarray, ior: float) -> np.ndarray:
    """Unit directions ``d`` refracted into a medium of index ``ior`` at unit normals ``n`` facing against
    them (Snell's law, vector form), each (..., 3) and one of them a single vector (3,) for the others;
    no total internal reflection (from the thinner medium into the denser)."""
    cos_i = -(d @ n if n.ndim == 1 else n @ d)[..., None]
    eta = 1.0 / ior
    cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
    return eta * d + (eta * cos_i - cos_t) * n
