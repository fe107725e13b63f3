"""Hard case: sliver and sub-pixel triangles (docs/pipeline.md §8).

A sliver's determinant is tiny next to the products it is computed from, so
its sign and its edge functions are dominated by rounding; a sub-pixel
triangle has bounds narrower than a pixel, edge functions whose coefficients
are tiny, and covers samples rarely. Both must be neither dropped while they
cover a sample, nor cover a sample twice where they meet their neighbours
(a mesh of slivers or of sub-pixel triangles is still watertight).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hard_cases.harness import (Case, assert_exact_coverage, check_bbox, check_conservative_mode, check_continuity,
                                check_exact, check_tiles, document, full_screen_counts_are_one, lens_for, make_draw,
                                perspective_z, render_counts)
from triangles import finite


def px(x, y, w=1.0, width=48, height=32):
    """Pixel coordinates (row 0 at the top) to clip space with the given w."""
    return ((2.0 * x / width - 1.0) * w, (1.0 - 2.0 * y / height) * w, 0.0, w)


def _named():
    cases = []
    # 2000 px long, 1e-3 px wide across the middle of the screen, moving 10 px
    q = np.array([[px(-980, 3), px(1020, 29), px(20, 16.0 + 1e-3)]])
    cases.append(Case("long_sliver_1e-3px", q, q + [0.3, -0.1, 0, 0]))
    # nearly collinear in 2DH with different w per vertex
    q = np.array([[px(-500, 16, 0.7), px(600, 16.3, 2.1), px(24, 16.14 + 1e-4, 1.3)]])
    cases.append(Case("sliver_perspective_1e-4px", q, q + [0.0, 0.05, 0, 0.1]))
    # a needle 30 px long and 0.05 px wide turning by 40 degrees about its base
    a0, a1 = 0.2, 0.9
    base = (24.0, 16.0)
    def needle(a):
        tip = (base[0] + 30 * np.cos(a), base[1] - 30 * np.sin(a))
        off = 0.025 * np.array([np.sin(a), np.cos(a)])
        return np.array([[px(base[0] - off[0], base[1] - off[1]), px(*tip), px(base[0] + off[0], base[1] + off[1])]])
    cases.append(Case("turning_needle", needle(a0), needle(a1), min_covered=3))
    # sub-pixel triangles: 0.3 px moving 12 px with defocus; 1e-2 px; 1e-6 px
    q = np.array([[px(10.0, 10.0), px(10.3, 10.05), px(10.1, 10.3)]])
    r = q + [0.5, 0.3, 0, 0]
    perspective_z(q, r)
    lx, ly = lens_for(q, r, 0.05, 2.0)
    cases.append(Case("subpixel_0.3px_moving_defocused", q, r, lx, ly, spp=64, min_covered=1))
    q = np.array([[px(20.2, 11.1), px(20.21, 11.1), px(20.2, 11.11)]])
    cases.append(Case("subpixel_1e-2px_moving", q, q + [0.4, -0.2, 0, 0], min_covered=0))
    q = np.array([[px(20.2, 11.1), px(20.2 + 1e-6, 11.1), px(20.2, 11.1 + 1e-6)]])
    cases.append(Case("subpixel_1e-6px", q, q, min_covered=0))
    cases.append(Case("subpixel_1e-6px_moving", q, q + [0.5, 0.1, 0, 0], min_covered=0))
    return cases


DOCS = {
    "long_sliver_1e-3px": "2000 px long, 1e-3 px wide: D is a tiny difference of large products",
    "sliver_perspective_1e-4px": "nearly collinear in 2DH with different w per vertex",
    "turning_needle": "0.05 px wide and 30 px long, turning: thin at every t",
    "subpixel_0.3px_moving_defocused": "bounds narrower than a pixel, moving 12 px with a lens",
    "subpixel_1e-2px_moving": "edge coefficients ~1e-2 of the pixel scale",
    "subpixel_1e-6px": "edge coefficients at the float32 resolution of the sample positions",
    "subpixel_1e-6px_moving": "as above, moving: the candidate filter's error bound dominates",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage(case):
    check_exact(case, seeds=(0, 1))


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", [c for c in CASES if c.min_covered > 0], ids=repr)
def test_tile_intervals_conservative(case):
    check_tiles(case, n=300)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_continuous(case):
    check_continuity(case)


def sliver_fan(n, centre, radius, jitter=0.0, rng=None):
    """A fan of n slivers around a shared centre vertex, the rim far off screen
    (every sample of the screen inside): pixel-space (n, 3, 2)."""
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    if jitter:
        ang = ang + rng.uniform(-jitter, jitter, n) / n
    rim = np.c_[centre[0] + radius * np.cos(ang), centre[1] + radius * np.sin(ang)]
    tris = [(centre, tuple(rim[i]), tuple(rim[(i + 1) % n])) for i in range(n)]
    return np.array(tris)


def to_clip(tris_px, wfun, width=48, height=32):
    q = np.zeros(tris_px.shape[:2] + (4,))
    for i in range(tris_px.shape[0]):
        for k in range(3):
            q[i, k] = px(*tris_px[i, k], wfun(tuple(tris_px[i, k])), width, height)
    return q


@pytest.mark.parametrize("centre", [(24.5, 16.5), (17.123, 9.877)])
def test_sliver_fan_is_watertight(centre):
    """512 slivers (0.7 degrees, 1e4 px long) sharing a centre vertex, moving and
    defocused, per-vertex w: every sample of the screen is covered exactly once."""
    rng = np.random.default_rng(1)
    fan = sliver_fan(512, centre, 1e4, jitter=0.5, rng=rng)
    wv = {}
    q = to_clip(fan, lambda p: wv.setdefault(p, rng.uniform(0.5, 2.0)))
    r = q + np.array([0.15, -0.1, 0.0, 0.0]) * q[..., 3:4]
    lx, ly = lens_for(q, r, 0.05, 1.2)
    for d in (make_draw(q), make_draw(q, r, lx, ly)):
        for seed in (0, 1):
            full_screen_counts_are_one(render_counts(d, spp=16, seed=seed), "sliver fan")
    # samples exactly at the shared vertex and along slivers through it
    cx, cy = centre
    if cx % 1 == 0.5:
        table = np.array([[0.5, 0.5, 0, 0, 0.5], [0.25, 0.5, 0, 0, 0.5], [0.5, 0.75, 0, 0, 0.5]])
        full_screen_counts_are_one(render_counts(make_draw(q), spp=3, pattern="table", table=table), "fan vertex")


def subpixel_grid(cell, width, height, rng, margin=3.0):
    """A grid of sub-pixel triangles covering the screen with a margin, random w per
    vertex (shared), random diagonal per cell."""
    xs = np.arange(-margin, width + margin + cell, cell)
    ys = np.arange(-margin, height + margin + cell, cell)
    w = rng.uniform(0.5, 2.0, (len(ys), len(xs)))
    tris = []
    for j in range(len(ys) - 1):
        for i in range(len(xs) - 1):
            a, b, c, d = (j, i), (j, i + 1), (j + 1, i), (j + 1, i + 1)
            tris += [(a, c, b), (b, c, d)] if rng.integers(2) else [(a, c, d), (a, d, b)]
    q = np.zeros((len(tris), 3, 4))
    for n, t in enumerate(tris):
        for k, (j, i) in enumerate(t):
            q[n, k] = px(xs[i], ys[j], w[j, i], width, height)
    return q


def test_subpixel_mesh_is_watertight():
    """~4000 triangles of 0.37 px, moving 2 px and defocused: every sample covered once."""
    rng = np.random.default_rng(2)
    wd, ht = 16, 12
    q = subpixel_grid(0.37, wd, ht, rng)
    r = q + np.array([0.2, 0.1, 0.0, 0.0]) * q[..., 3:4]
    lx, ly = lens_for(q, r, 0.02, 1.0)
    for seed in (0, 1):
        res = render_counts(make_draw(q, r, lx, ly, width=wd, height=ht), spp=16, seed=seed)
        full_screen_counts_are_one(res, "sub-pixel mesh")


def hexagon_with_sliver(delta, rng=None):
    """Six triangles covering a hexagon larger than the screen; one is a sliver of
    height ``delta`` px along row y = 16.5, 4000 px long (pixel space)."""
    TL, TR, BR, BL = (-3000, -3000), (3000, -3000), (3000, 3000), (-3000, 3000)
    P, Q = (-2000, 16.5), (2000, 16.5)
    R = (24.3, 16.5 - delta)
    tris = np.array([(R, P, TL), (R, TL, TR), (R, TR, Q), (P, Q, R), (P, BL, BR), (P, BR, Q)], dtype=float)
    wv = {}
    return to_clip(tris, lambda p: 1.0 if rng is None else wv.setdefault(p, rng.uniform(0.5, 2.0)))


@pytest.mark.parametrize("delta", [1e-3, 1e-5, 2.0**-19, 1e-7, 0.0])
@pytest.mark.parametrize("wseed", [None, 1])
def test_sliver_between_neighbours_is_watertight(delta, wseed):
    """Samples on and just around a sliver between two neighbours (and the shared
    line itself when delta = 0) are covered exactly once."""
    rng = None if wseed is None else np.random.default_rng(wseed)
    q = hexagon_with_sliver(delta, rng)
    ys = [0.5, 0.5 - delta / 2, 0.5 - delta, float(np.nextafter(np.float32(0.5), np.float32(0))),
          float(np.nextafter(np.float32(0.5), np.float32(1)))]
    table = np.zeros((len(ys), 5))
    table[:, 0] = 0.5
    table[:, 1] = ys
    table[:, 4] = 0.5
    d = make_draw(q)
    full_screen_counts_are_one(render_counts(d, spp=len(ys), pattern="table", table=table), f"sliver {delta}")
    full_screen_counts_are_one(render_counts(d, spp=16, seed=3), f"sliver {delta}")


@st.composite
def slivers(draw):
    """Three nearly collinear vertices (relative offset 10^-k), moving, maybe defocused."""
    q = np.zeros((1, 3, 4))
    for k in range(2):
        w = draw(finite(0.3, 3.0))
        q[0, k] = (draw(finite(-3.0, 3.0)) * w, draw(finite(-3.0, 3.0)) * w, 0.0, w)
    a = draw(finite(-0.5, 1.5))
    off = np.array([draw(finite(-1, 1)) for _ in range(4)]) * 10.0 ** -draw(st.integers(2, 12))
    q[0, 2] = (1 - a) * q[0, 0] + a * q[0, 1] + off
    q[0, 2, 3] = abs(q[0, 2, 3]) + 0.05
    r = q + np.array([draw(finite(-0.5, 0.5)), draw(finite(-0.5, 0.5)), 0.0, 0.0])
    perspective_z(q, r)
    lx, ly = lens_for(q, r, draw(st.sampled_from([0.0, 0.1])), 1.5)
    return q, r, lx, ly


@settings(max_examples=30, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(slivers(), st.integers(0, 3))
def test_random_slivers(tri_, seed):
    case = Case("random sliver", *tri_, min_covered=0)
    assert_exact_coverage(case.draw(), spp=16, seed=seed, what=case.name)
    check_tiles(case, seed=seed, n=100)


@pytest.mark.parametrize("case", [c for c in CASES if len(c.q) == 1], ids=repr)
def test_conservative_mode_bounds(case):
    """Conservative mode: every covered (pixel, t) inside the emitted t^ and z^."""
    check_conservative_mode(case)
