"""Hard case: samples exactly on shared edges and vertices (docs/pipeline.md §8; Davidovic12 §3.4).

A sample on an edge shared by two triangles, or on a vertex shared by many,
must be covered by exactly one of them: the top-left rule decides, and it
only works if both triangles compute bit-identical edge functions (float32
vertices lerped to the sample's t and lens position, shared operands in the
same order) and the float64 re-test near an edge agrees with the exact
sign. Moving and defocused meshes put samples on edges at some (t, u, v)
that no static test reaches.
"""

import numpy as np
import pytest

from hard_cases.harness import (Case, assert_exact_coverage, check_bbox, full_screen_counts_are_one, lens_for,
                                make_draw, render_counts)


def grid(width, height, step, rng, random_w, origin=(-0.5, -0.5), extra=2):
    """A mesh of squares with vertices at origin + step * (i, j) (pixel space), each
    split along a random diagonal; per-vertex w (shared). Returns clip-space (N,3,4)."""
    nx = int(np.ceil((width + 2 * extra) / step)) + 1
    ny = int(np.ceil((height + 2 * extra) / step)) + 1
    xs = origin[0] - extra + step * np.arange(nx + 1)
    ys = origin[1] - extra + step * np.arange(ny + 1)
    w = rng.uniform(0.5, 2.0, (len(ys), len(xs))) if random_w else np.ones((len(ys), len(xs)))
    tris = []
    for j in range(len(ys) - 1):
        for i in range(len(xs) - 1):
            a, b, c, d = (j, i), (j, i + 1), (j + 1, i), (j + 1, i + 1)
            tris += [(a, c, b), (b, c, d)] if rng.integers(2) else [(a, c, d), (a, d, b)]
    q = np.zeros((len(tris), 3, 4))
    for n, t in enumerate(tris):
        for k, (j, i) in enumerate(t):
            ww = w[j, i]
            q[n, k] = ((2 * xs[i] / width - 1) * ww, (1 - 2 * ys[j] / height) * ww, 0.0, ww)
    return q


WD, HT = 16, 12
# samples on pixel centres (grid vertices), pixel corners and edge midpoints
ON_GRID = [(0.5, 0.5), (0.0, 0.0), (0.0, 0.5), (0.5, 0.0), (0.25, 0.25), (0.75, 0.25)]


def table_at(points, times, lens=((0.0, 0.0),)):
    rows = [(x, y, u, v, t) for t in times for (x, y) in points for (u, v) in lens]
    table = np.array(rows, dtype=float)
    return table[np.argsort(table[:, 4], kind="stable")]


def test_static_grid_samples_on_vertices_and_edges():
    rng = np.random.default_rng(0)
    q = grid(WD, HT, 1.0, rng, random_w=True)
    table = table_at(ON_GRID, [0.5])
    full_screen_counts_are_one(render_counts(make_draw(q, width=WD, height=HT), spp=len(table), pattern="table",
                                             table=table), "static grid")


@pytest.mark.parametrize("random_w", [False, True])
def test_moving_grid_samples_on_vertices_at_exact_times(random_w):
    """The grid moves by exactly (2, 1) px: at t = 0.25, 0.5, 0.75 and 1 its vertices
    sit exactly on pixel corners, edge midpoints or centres, where the table samples are."""
    rng = np.random.default_rng(1)
    q = grid(WD, HT, 1.0, rng, random_w)
    shift = np.array([2 * 2.0 / WD, -2 * 1.0 / HT, 0.0, 0.0])
    r = q + shift * q[..., 3:4]
    table = table_at(ON_GRID, [0.0, 0.25, 0.5, 0.75, 1.0])
    d = make_draw(q, r, width=WD, height=HT)
    full_screen_counts_are_one(render_counts(d, spp=len(table), pattern="table", table=table), "moving grid")
    for seed in (0, 1):
        full_screen_counts_are_one(render_counts(d, spp=16, seed=seed), "moving grid, net samples")


def test_defocused_grid_samples_on_edges_at_lens_corners():
    """Uniform depth: the lens shifts every vertex by (u LX, v LY); with LX = 1 px
    (w = 1) at u = +-0.5, +-1 the vertices land on pixel corners and centres."""
    rng = np.random.default_rng(2)
    q = grid(WD, HT, 1.0, rng, random_w=False)
    lx = np.full(q.shape[:2] + (2,), 2.0 / WD)  # one pixel per unit u
    ly = np.full(q.shape[:2] + (2,), 2.0 / HT)
    table = table_at(ON_GRID, [0.5], lens=[(0.0, 0.0), (0.5, -0.5), (-1.0, 1.0), (1.0, 0.5)])
    d = make_draw(q, q, lx, ly, width=WD, height=HT)
    full_screen_counts_are_one(render_counts(d, spp=len(table), pattern="table", table=table), "defocused grid")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_moving_defocused_perspective_grid_is_watertight(seed):
    """Random w per vertex, motion and defocus with random samples: covered once."""
    rng = np.random.default_rng(10 + seed)
    q = grid(WD, HT, 1.37, rng, random_w=True)
    r = q + np.array([0.3, -0.2, 0.0, 0.0]) * q[..., 3:4]
    r[..., 3] *= 1.2
    r[..., :2] *= 1.2
    lx, ly = lens_for(q, r, 0.05, 1.1)
    d = make_draw(q, r, lx, ly, width=WD, height=HT)
    full_screen_counts_are_one(render_counts(d, spp=32, seed=seed), "perspective grid")


def fan(n, centre, width, height, radius=500.0, w=None):
    ang = 2 * np.pi * np.arange(n) / n
    rim = [(centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)) for a in ang]
    q = np.zeros((n, 3, 4))
    for i in range(n):
        for k, p in enumerate((centre, rim[i], rim[(i + 1) % n])):
            ww = 1.0 if w is None else w(k, i)
            q[i, k] = ((2 * p[0] / width - 1) * ww, (1 - 2 * p[1] / height) * ww, 0.0, ww)
    return q


@pytest.mark.parametrize("n", [4, 8, 12])
def test_fan_around_a_sample(n):
    """n triangles share a vertex exactly on a pixel centre; the spokes at multiples
    of 90 degrees run through samples: every sample once, the shared vertex too."""
    q = fan(n, (8.5, 6.5), WD, HT)
    table = table_at([(0.5, 0.5), (0.0, 0.5), (0.5, 0.0), (0.25, 0.5), (0.5, 0.75)], [0.5])
    d = make_draw(q, width=WD, height=HT)
    full_screen_counts_are_one(render_counts(d, spp=len(table), pattern="table", table=table), f"fan of {n}")
    assert_exact_coverage(d, spp=len(table), pattern="table", table=table, what=f"fan of {n}")


def test_shared_edges_bbox_matches_hierarchical():
    rng = np.random.default_rng(3)
    q = grid(WD, HT, 1.0, rng, random_w=True)
    r = q + np.array([2 * 2.0 / WD, 0.0, 0.0, 0.0]) * q[..., 3:4]
    check_bbox(Case("moving grid", q, r, width=WD, height=HT))


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("specialize", [True, False])
def test_neighbours_on_different_test_paths_share_edges(seed, specialize):
    """Some vertices move, some have a lens shift, most neither: a static triangle
    (2D test, edges once per tile) shares edges with moving or defocused ones (3D,
    4D, 5D tests at each sample). Every sample is still covered exactly once."""
    rng = np.random.default_rng(seed)
    q = grid(WD, HT, 1.7, rng, random_w=True)
    r = q.copy()
    lx = np.zeros(q.shape[:2] + (2,))
    ly = np.zeros(q.shape[:2] + (2,))
    per_vertex = {}
    for n in range(len(q)):
        for k in range(3):
            key = tuple(q[n, k])
            if key not in per_vertex:
                move = rng.uniform(-0.1, 0.1, 2) * q[n, k, 3] if rng.integers(3) == 0 else np.zeros(2)
                shift = rng.uniform(-0.05, 0.05) * q[n, k, 3] if rng.integers(3) == 0 else 0.0
                per_vertex[key] = (move, shift)
            move, shift = per_vertex[key]
            r[n, k, :2] += move
            lx[n, k] = shift
            ly[n, k] = 0.7 * shift
    d = make_draw(q, r, lx, ly, width=WD, height=HT)
    res = render_counts(d, spp=16, seed=seed, overrides=(f"pipeline.specialize={str(specialize).lower()}",))
    full_screen_counts_are_one(res, "mixed test paths")
    if specialize:
        assert res.counter("sample_tester", "tests_2d") > 0 and res.counter("sample_tester", "tests_5d") > 0
