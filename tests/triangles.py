"""Random and adversarial moving, defocused clip-space triangles for tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.draw import draw_from_clip
from units.sample_tester import inside_test
from units import culling
from units.tile_test import TileTest
from units.tile_traverser import TileTraverser
from units.triangle_setup import TriangleSetup


def finite(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


# z/w = C1 + C0 / w of a perspective projection with near 0.1 and far 10
PERSPECTIVE = (1.0202020202020203, -0.20202020202020202)

# A vertex moving along its own view ray (clip coordinates times a positive
# factor) stays fixed on the screen: its two projections differ only by
# rounding. Here the first vertex does, by 1.4, the other two move; on a
# 16x16 screen with 4-px tiles its ~1e-15 px hull edge once made the hull
# test reject tile (0, 1), which holds covered samples.
VIEW_RAY_Q = np.array([[[-1.7, 1.4, 0.0, 1.5], [0.5, -1.9, 0.0, 1.1], [0.4, 1.1, 0.0, 2.1]]])
VIEW_RAY_R = np.array([[1.4 * VIEW_RAY_Q[0, 0], [0.6, -1.9, 0.0, 1.7], [0.9, 0.2, 0.0, 1.7]]])


@st.composite
def moving_triangle(draw, *, lens=True, motion=True, allow_w_cross=True, scale=1.0, perspective=False,
                    view_rays=False):
    """A triangle as (q, r, lens_x, lens_y), each (1,3,...) float64 clip space.

    With ``perspective`` every vertex has z = C1 w + C0 (PERSPECTIVE). With
    ``view_rays`` (and ``motion``) one to three vertices move along their view
    rays: the vertex at t=1 is the one at t=0 times a positive factor, fixed on
    the screen and moving in depth, so its two projections differ only by
    rounding (near-coincident points, edges of rounding-noise direction)."""
    wlo = -1.0 if allow_w_cross else 0.2
    q = np.zeros((1, 3, 4))
    r = np.zeros((1, 3, 4))
    for arr, on in ((q, True), (r, motion)):
        for k in range(3):
            w = draw(finite(wlo, 4.0))
            x = draw(finite(-2.0, 2.0)) * max(abs(w), 0.1) * scale
            y = draw(finite(-2.0, 2.0)) * max(abs(w), 0.1) * scale
            z = draw(finite(-1.2, 1.2)) * max(abs(w), 0.1)
            arr[0, k] = (x, y, z, w)
    if not motion:
        r = q.copy()
    if perspective:
        for arr in (q, r):
            arr[0, :, 2] = PERSPECTIVE[0] * arr[0, :, 3] + PERSPECTIVE[1]
    if draw(st.booleans()) and motion:  # adversarial: pure translation (near-linear edges)
        d = np.array([draw(finite(-1, 1)), draw(finite(-1, 1)), 0.0, 0.0])
        r = q + d
        if perspective:
            r[0, :, 2] = PERSPECTIVE[0] * r[0, :, 3] + PERSPECTIVE[1]
    if view_rays and motion:
        for k in sorted(draw(st.sets(st.integers(0, 2), min_size=1))):
            r[0, k] = q[0, k] * draw(finite(0.25, 4.0))
            if perspective:
                r[0, k, 2] = PERSPECTIVE[0] * r[0, k, 3] + PERSPECTIVE[1]
    lx = np.zeros((1, 3, 2))
    ly = np.zeros((1, 3, 2))
    if lens:
        focus = draw(finite(0.3, 4.0))
        radius = draw(finite(0.0, 0.5))
        for s, arr in enumerate((q, r)):
            coc = radius * (arr[0, :, 3] / focus - 1.0)
            lx[0, :, s] = coc * 1.7
            ly[0, :, s] = coc * 1.7
    return q, r, lx, ly


def setup_and_tiles(q, r, lx, ly, width=48, height=32, tile_size=8, coarse_factor=2, edge_test=True,
                    lens_bounds=True, backface_culling=False, depth_w=None, gamma="triangle",
                    algorithm="hierarchical", edge_solver="linearized", tuples=None):
    """Run triangle setup, the traverser and the tile test on one draw.

    ``algorithm`` is any tile-test algorithm; ``tuples`` the (n, 3) (u, v, t)
    set of Interleave UVT. Returns (setup, survivors of setup, tile records
    kept by the tile test).
    """
    d = draw_from_clip(q, r, lx, ly, width=width, height=height)
    d.depth_w = depth_w
    arch = load_arch(overrides=[f"tile_traverser.coarse_factor={coarse_factor}",
                                f"tile_test.edge_test={'true' if edge_test else 'false'}",
                                f"tile_test.lens_bounds={'true' if lens_bounds else 'false'}",
                                f"tile_test.gamma='{gamma}'", f"tile_test.algorithm='{algorithm}'",
                                f"tile_test.edge_solver='{edge_solver}'"])
    alg = culling.algorithm(algorithm)
    setup = TriangleSetup(arch.triangle_setup, d, tile_size, backface_culling, culling=alg)
    ids = np.arange(d.n, dtype=np.int64)
    alive, _, _ = setup.run(ids)
    trav = TileTraverser(arch.tile_traverser, setup.table, tile_size, width, height, coarse_test=alg.COARSE_TEST)
    tiles, _, _ = trav.run(alive)
    tt = TileTest(arch.tile_test, setup.table, tile_size, width, height, depth_w, tuples=tuples,
                  extension=setup.extension)
    kept, _, _ = tt.run(tiles)
    return setup, alive, kept


def sample_inside_points(setup, tri, rng, n, width, height, tuples=None):
    """Random (x, y, t, u, v) samples that the pipeline's exact test accepts.

    Picks (t, u, v) (a random row of ``tuples`` (u, v, t) when given), a random point of the triangle there (positive
    barycentric combination in 2DH with w > 0), keeps those on screen that
    ``inside_test`` accepts. Returns a list of (x, y, t, u, v, z).
    """
    tb = setup.table
    out = []
    for _ in range(n):
        t = np.float32(rng.uniform(0, 1))
        a = rng.uniform(0, 2 * np.pi)
        rad = np.sqrt(rng.uniform(0, 1))
        u = np.float32(rad * np.cos(a))
        v = np.float32(rad * np.sin(a))
        if tuples is not None:
            u, v, t = (np.float32(c) for c in tuples[rng.integers(len(tuples))])
        kind = rng.integers(3)
        if kind == 0:  # anywhere inside
            lam = rng.dirichlet([1, 1, 1])
        elif kind == 1:  # near a vertex: the extremes of the triangle, where bounds are tight
            lam = rng.dirichlet([0.02, 0.02, 0.02])
        else:  # on an edge
            lam = rng.dirichlet([1, 1, 1])
            lam[rng.integers(3)] = 1e-7
            lam /= lam.sum()
        P = np.zeros(3)
        for k in range(3):
            X = tb.p0[tri, k, 0] + t * tb.dp[tri, k, 0] + u * (tb.l0[tri, k, 0] + t * tb.dl[tri, k, 0])
            Y = tb.p0[tri, k, 1] + t * tb.dp[tri, k, 1] + v * (tb.l0[tri, k, 1] + t * tb.dl[tri, k, 1])
            W = tb.p0[tri, k, 3] + t * tb.dp[tri, k, 3]
            P += lam[k] * np.array([X, Y, W])
        if P[2] <= 1e-9:
            continue
        x, y = np.float32(P[0] / P[2]), np.float32(P[1] / P[2])
        if not (0 <= x < width and 0 <= y < height):
            continue
        ok, b0, b1, b2, z = inside_test(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, tri, np.float32(x),
                                        np.float32(y), t, u, v, False, tb.edge_eps)
        if ok:
            out.append((float(np.float32(x)), float(np.float32(y)), float(t), float(u), float(v), float(z)))
    return out


def _orient(a, b, c):
    return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])


def touches(poly, px, py, grow=1e-9):
    """Does each convex polygon of ``poly`` (n, k, 2, vertices in order) meet the closed square of pixel
    (px, py), widened by ``grow``? A vertex of one in the other, or an edge of the polygon crossing a side
    of the square (not the separating-axis rule of the units)."""
    x0, x1, y0, y1 = px - grow, px + 1 + grow, py - grow, py + 1 + grow
    inside = ((poly[..., 0] >= x0) & (poly[..., 0] <= x1) & (poly[..., 1] >= y0) & (poly[..., 1] <= y1)).any(axis=1)
    sq = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    k = poly.shape[1]
    for corner in sq:
        o = np.stack([_orient(poly[:, i], poly[:, (i + 1) % k], corner) for i in range(k)])
        inside |= (o >= 0).all(axis=0) | (o <= 0).all(axis=0)
    for i in range(k):
        p, q = poly[:, i], poly[:, (i + 1) % k]
        for m in range(4):
            s, e = sq[m], sq[(m + 1) % 4]
            d1, d2 = _orient(p, q, s), _orient(p, q, e)
            d3, d4 = _orient(s, e, p), _orient(s, e, q)
            inside |= (d1 * d2 <= 0) & (d3 * d4 <= 0)
    return inside
