"""Hard case: motion of 500 pixels per frame, the fence of Gribel10 Fig. 11 (docs/pipeline.md §8).

Thin slats sweeping 500 px during the shutter: each pixel of the swept band
sees a slat for under 1% of the shutter, the moving bounds are 250 times the
slat's area, and the tile test has to narrow t^ to a few thousandths of the
shutter to be worth anything. Time and screen bounds are computed at large
|dX| where a relative rounding error is a large absolute one; a slat
leaving through a screen edge is culled by the temporal frustum test at the
instant its last vertex leaves.
"""

import numpy as np
import pytest

from hard_cases.harness import (Case, VARIANTS, assert_exact_coverage, check_bbox, check_continuity, check_exact,
                                check_tiles, counts_of, document, lens_for, make_draw, render, render_counts)
from triangles import setup_and_tiles

FW, FH = 640, 32  # wide enough that the fence stays on screen for the whole shutter


def px_to_clip(x, y, w=1.0, width=FW, height=FH):
    return ((2.0 * x / width - 1.0) * w, (1.0 - 2.0 * y / height) * w, 0.0, w)


def slats(x0s, dx, *, width=2.0, top=4.0, bottom=28.0, dy=0.0, lean=0.0, w=(1.0, 1.0), image=(FW, FH)):
    """Quads [x, x + width] x [top, bottom] (pixels), two triangles each, moving by (dx, dy)."""
    q, r = [], []
    for x in x0s:
        for arr, off, ww in ((q, (0.0, 0.0), w[0]), (r, (dx, dy), w[1])):
            a = (x + off[0] + lean, top + off[1])
            b = (x + width + off[0] + lean, top + off[1])
            c = (x + width + off[0], bottom + off[1])
            d = (x + off[0], bottom + off[1])
            to = [px_to_clip(*p, ww, *image) for p in (a, b, c, d)]
            arr += [[to[0], to[3], to[2]], [to[0], to[2], to[1]]]
    return np.array(q), np.array(r)


def _named():
    q, r = slats([20.0, 60.0, 100.0], 500.0)
    cases = [Case("fence_500px_right", q, r, width=FW, height=FH, min_covered=1000)]
    q, r = slats([520.0, 560.0, 600.0], -500.0, lean=6.0)
    cases.append(Case("leaning_fence_500px_left", q, r, width=FW, height=FH, min_covered=1000))
    q, r = slats([20.0, 60.0, 100.0], 500.0, dy=3.0, w=(1.0, 1.6))
    lx, ly = lens_for(q, r, 0.1, 1.3)
    cases.append(Case("fence_500px_receding_defocused", q, r, lx, ly, width=FW, height=FH, min_covered=500))
    # slats entering and leaving through the left and right screen edges
    q, r = slats([-300.0, -200.0, 450.0, 560.0], 500.0)
    cases.append(Case("fence_crossing_screen_edges", q, r, width=FW, height=FH, min_covered=500))
    return cases


DOCS = {
    "fence_500px_right": "three 2 px slats moving 500 px: each pixel sees a slat for 0.4% of the shutter",
    "leaning_fence_500px_left": "leaning slats moving left: moving edges not axis-aligned",
    "fence_500px_receding_defocused": "500 px with a w change and a lens: 5D with extreme motion",
    "fence_crossing_screen_edges": "slats entering and leaving through both screen edges mid-shutter",
}
CASES = document(_named(), DOCS)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_finite_and_exact_coverage(case):
    check_exact(case, variants=VARIANTS[:3])  # big frames: flat, default and small tiles


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_bbox_and_zcull_change_nothing(case):
    check_bbox(case)


@pytest.mark.parametrize("case", CASES, ids=repr)
def test_tile_intervals_conservative(case):
    check_tiles(case, n=60)


@pytest.mark.parametrize("case", CASES[:2], ids=repr)
def test_continuous(case):
    check_continuity(case, seeds=(0,))


def test_fence_energy_is_conserved():
    """Summed over the frame, covered samples / spp estimate the time-integrated
    area: three 2 x 24 px slats on screen all shutter long give 144 px^2."""
    q, r = slats([20.0, 60.0, 100.0], 500.0)
    d = make_draw(q, r, width=FW, height=FH)
    total = [counts_of(render_counts(d, spp=16, seed=s)).sum() / 16 for s in range(2)]
    assert abs(np.mean(total) - 144.0) < 0.02 * 144.0, total


def test_tile_test_narrows_time_to_the_slat():
    """t^ per kept tile is a few thousandths of the shutter (an 8 px tile and a 2 px
    slat at 500 px/frame: 0.02 plus margins), and the hierarchical test does far
    fewer sample tests than BBOX for the same image."""
    q, r = slats([20.0, 60.0, 100.0], 500.0)
    for i in range(0, len(q), 2):
        _, alive, kept = setup_and_tiles(q[i:i + 1], r[i:i + 1], np.zeros((1, 3, 2)), np.zeros((1, 3, 2)), FW, FH)
        widths = kept["t_hi"] - kept["t_lo"]
        assert len(widths) > 100 and np.median(widths) < 0.05, np.median(widths)
    d = make_draw(q, r, width=FW, height=FH)
    h = render(d, spp=16)
    b = render(d, spp=16, algorithm="bbox")
    np.testing.assert_array_equal(h.image, b.image)
    assert h.ste > 5 * b.ste, (h.ste, b.ste)


def _leaving_left_edge():
    """A 12 x 24 px wedge moving 524 px left during the shutter; its right edge
    (two vertices) crosses the screen's left edge x = 0 at t_c ~ 0.99739682."""
    x0, x1 = 522.9160511011289, -1.3647966679423806
    to = lambda x, y: px_to_clip(x, y, 1.0, 48, 32)  # noqa: E731
    q = np.array([[to(x0, 4), to(x0 - 12, 16), to(x0, 28)]])
    r = np.array([[to(x1, 4), to(x1 - 12, 16), to(x1, 28)]])
    return q, r


def test_leaving_left_edge_random_samples():
    """Control: with samples comfortably inside the screen the span is fine."""
    q, r = _leaving_left_edge()
    assert_exact_coverage(make_draw(q, r), spp=16, what="wedge leaving left edge")


def test_leaving_left_edge_sample_on_the_screen_edge():
    """A table sample exactly on the left screen edge (x = 0) at the float32 t just
    after the float64 exit time: the float32 vertices p0_32 + t dp_32 put the right
    edge at X = +6.1e-5 px, so the exact test covers it; setup's time span must too.
    (Regression: with a 1e-9 relative tolerance setup ended the span at
    te = 0.99739682 and culled this sample.)"""
    q, r = _leaving_left_edge()
    table = np.array([[0.0, 0.5, 0.0, 0.0, 0.9973968267440796]])
    assert_exact_coverage(make_draw(q, r), spp=1, pattern="table", table=table, what="sample on the screen edge")
