"""Exact per-pixel time intervals in conservative mode (units/tile_test_exact.py, Gribel10 §4.1) against an
independent predicate sampled densely in time.

The reference decides whether the moving triangle meets a closed pixel square at a time t from the clip-space
vertices directly (viewport mapped here, not by triangle setup), by a different rule than the unit's separating
axes: a vertex of one in the other, or an edge of the triangle crossing a side of the square.

* conservative: every sampled t at which the reference sees contact lies in the pixel's interval, and a pixel
  whose record the exact test drops has no contact at any sampled t;
* tight: the triangle touches the pixel (within 1e-5 px) at both ends of every interval;
* triangles crossing w = 0 or defocused keep the tile test's intervals;
* a pass in conservative mode with ``time_intervals = "exact"`` shades exactly the pixels a dense time sampling
  touches, never more than the tile test's intervals, and hands the shader the same intervals.
"""

import numba as nb
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.definitions import N_OPS
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.pass_state import PassState
from pipeline_sim.render import RenderPass, run_pass
from pipeline_sim.shaders import IN_T_HI, IN_T_LO, IN_X, IN_Y, append_record
from pipeline_sim.targets import AppendBuffer
from triangles import moving_triangle, touches
from units.tile_test import TileTest
from units.tile_test_exact import exact_time_interval
from units.tile_traverser import TileTraverser
from units.triangle_setup import TriangleSetup

W, H = 24, 16
TIMES = np.linspace(0.0, 1.0, 1201)


def screen(q, r, t):
    """(times, 3, 2) pixel positions of the clip-space triangle q -> r at times t."""
    c = (1.0 - t)[:, None, None] * q[0][None] + t[:, None, None] * r[0][None]
    x = (c[..., 0] / c[..., 3] + 1.0) * 0.5 * W
    y = (1.0 - c[..., 1] / c[..., 3]) * 0.5 * H
    return np.stack([x, y], axis=-1)


def records(q, r, exact, lens=None):
    """The tile test's kept 1x1 records (tx, ty, t_lo, t_hi) for one moving triangle (with a constant lens
    shift ``lens``, or none), exact intervals or not."""
    d = draw_from_clip(q, r, lens_x=lens, lens_y=lens, width=W, height=H)
    arch = load_arch()
    setup = TriangleSetup(arch.triangle_setup, d, 1, False)
    alive, _, _ = setup.run(np.arange(1, dtype=np.int64))
    tiles, _, _ = TileTraverser(arch.tile_traverser, setup.table, 1, W, H).run(alive)
    kept, _, events = TileTest(arch.tile_test, setup.table, 1, W, H, exact_time=exact).run(tiles)
    return kept, events


@settings(max_examples=40, deadline=None)
@given(moving_triangle(lens=False, allow_w_cross=False, scale=0.6))
def test_exact_intervals_hold_every_contact_and_end_in_contact(tri):
    q, r, _, _ = tri
    tile, _ = records(q, r, exact=False)
    exact, events = records(q, r, exact=True)
    pos = screen(q, r, TIMES)
    kept = {(int(x), int(y)): (lo, hi) for x, y, lo, hi in zip(exact["tx"], exact["ty"], exact["t_lo"], exact["t_hi"])}
    for x, y in zip(tile["tx"], tile["ty"]):
        hit = TIMES[touches(pos, int(x), int(y))]
        if (int(x), int(y)) not in kept:
            assert len(hit) == 0, f"pixel {(x, y)} dropped but touched at t={hit[:3]}"
            continue
        lo, hi = kept[(int(x), int(y))]
        assert np.all((hit >= lo) & (hit <= hi)), (x, y, lo, hi, hit.min(), hit.max())
        ends = screen(q, r, np.array([lo, hi]))
        assert touches(ends, int(x), int(y), grow=1e-5).all(), (x, y, lo, hi)
    assert len(exact["tri"]) <= len(tile["tri"])


def _cross(u, v):
    return u[0] * v[1] - u[1] * v[0]


@settings(max_examples=300, deadline=None)
@given(ts=st.floats(0.1, 0.9), angle=st.floats(0.0, np.pi), reach=st.tuples(st.floats(0.3, 2.0), st.floats(0.3, 2.0)),
       va=st.tuples(st.floats(-1, 1), st.floats(-1, 1)), vb=st.tuples(st.floats(-1, 1), st.floats(-1, 1)),
       vc=st.tuples(st.floats(-1, 1), st.floats(-1, 1)), height=st.floats(1.0, 3.0))
def test_a_corner_grazing_a_moving_edge_keeps_its_instant(ts, angle, reach, va, vb, vc, height):
    """An edge whose line turns through the pixel corner (5, 5) and back, touching the closed pixel at
    the one instant ``ts`` (a double root of the corner's edge function, Gribel10 eq. 4): the exact
    interval holds ``ts``, however rounding leaves the discriminant."""
    c = np.array([5.0, 5.0])
    d = np.array([np.cos(angle), np.sin(angle)])
    normal = np.array([-d[1], d[0]])
    a_ts, b_ts = c - reach[0] * d, c + reach[1] * d  # the corner on the edge at ts
    va, vb, vc = np.array(va), np.array(vb), np.array(vc)
    # make the edge function's derivative at ts zero (a tangency), moving vb along the edge normal
    rest = _cross(vb - va, c - a_ts) + _cross(b_ts - a_ts, -va)
    vb = vb - rest / _cross(normal, c - a_ts) * normal
    side = np.sign(_cross(b_ts - a_ts, c + 0.5 - a_ts))
    c_ts = 0.5 * (a_ts + b_ts) - side * normal * height  # the third vertex away from the pixel
    p0 = np.zeros((1, 3, 4))
    dp = np.zeros((1, 3, 4))
    for k, (at_ts, v) in enumerate(((a_ts, va), (b_ts, vb), (c_ts, vc))):
        p0[0, k, :2], p0[0, k, 3], dp[0, k, :2] = at_ts - ts * v, 1.0, v
    ops = np.zeros(N_OPS, np.int64)
    lo, hi = exact_time_interval(p0, dp, 0, 5.0, 6.0, 5.0, 6.0, 0.0, 1.0, ops)
    assert lo <= ts + 1e-9 and hi >= ts - 1e-9, (lo, hi, ts)


def test_translating_triangle_enters_and_leaves_at_hand_computed_times():
    """A triangle sliding right by 8 px: pixel (x, y) meets it from when its right vertex column reaches the
    pixel's left side to when its left side passes the pixel's right side."""
    # screen: x_pix = (x + 1) * 12, so clip 1/12 is one pixel; a right triangle with legs of 4 px
    px = 1.0 / 12.0
    q = np.array([[[-0.5, -0.5, 0.0, 1.0], [-0.5 + 4 * px, -0.5, 0.0, 1.0], [-0.5, -0.5 + 4 / 8, 0.0, 1.0]]])
    r = q + np.array([8 * px, 0.0, 0.0, 0.0])
    exact, _ = records(q, r, exact=True)
    # the row just above the bottom edge (y pixel 11 spans [11, 12]; the bottom edge is at y = 12)
    row = {int(x): (lo, hi) for x, y, lo, hi in zip(exact["tx"], exact["ty"], exact["t_lo"], exact["t_hi"])
           if y == 11}
    # pixel 14 (x in [14, 15]): the right vertex (x = 10 + 8t) reaches 14 at t = 0.5; the leg (x = 6 + 8t)
    # passes 15 at t = 9/8, beyond the shutter
    assert abs(row[14][0] - 0.5) < 1e-6 and row[14][1] == 1.0
    # pixel 6: touched from t = 0 until the leg passes x = 7 at t = 1/8
    assert row[6][0] == 0.0 and abs(row[6][1] - 0.125) < 1e-6


@nb.njit
def record_shader(inputs, params, textures, out, append):
    rec = np.empty(4, np.float32)
    for i in range(inputs.shape[1]):
        rec[0], rec[1], rec[2], rec[3] = inputs[IN_X, i], inputs[IN_Y, i], inputs[IN_T_LO, i], inputs[IN_T_HI, i]
        append_record(append, rec)
        out[i, 0] = out[i, 1] = out[i, 2] = out[i, 3] = 1.0


def shaded(q, r, mode):
    d = draw_from_clip(q, r, width=W, height=H)
    res = run_pass(RenderPass(draw=d, arch=load_arch(), spp=1, shader=record_shader,
                              state=PassState(mode="conservative", depth_test="always", depth_write=False,
                                              blend="add", time_intervals=mode),
                              append=AppendBuffer(fields=("x", "y", "t_lo", "t_hi"), capacity=W * H)))
    rec = res.append.records
    assert len(rec) == res.counter("shading", "shader_executions")
    return {(int(x), int(y)): (lo, hi) for x, y, lo, hi in rec}


def test_pass_shades_exactly_the_pixels_dense_sampling_touches():
    """A perspective triangle turning and receding: the exact pass shades the pixels a dense time sampling
    touches (and only those), fewer than the tile test's, each with an interval inside the tile test's."""
    q = np.array([[[-0.8, -0.6, 0.5, 1.0], [0.1, -0.7, 0.5, 1.2], [-0.3, 0.5, 0.5, 1.0]]])
    r = np.array([[[0.2, 0.3, 0.5, 2.0], [0.9, 0.1, 0.5, 1.5], [0.6, 0.9, 0.5, 1.8]]])
    exact, tile = shaded(q, r, "exact"), shaded(q, r, "tile")
    pos = screen(q, r, np.linspace(0.0, 1.0, 20001))
    dense = {(x, y) for x in range(W) for y in range(H) if touches(pos, x, y).any()}
    assert set(exact) == dense
    assert len(exact) < len(tile)
    for p, (lo, hi) in exact.items():
        assert tile[p][0] <= lo <= hi <= tile[p][1]


def test_triangles_crossing_w_zero_or_defocused_keep_the_tile_intervals():
    """The exact intervals need w > 0 and no lens: other triangles keep the tile test's t^ (Nilsson12 §2)."""
    crossing_q = np.array([[[-0.5, -0.5, 0.5, 1.0], [0.5, -0.5, 0.5, 1.0], [0.0, 0.5, 0.5, 1.0]]])
    crossing_r = crossing_q.copy()
    crossing_r[0, 2, 3] = -0.5  # the third vertex passes behind the eye
    for q, r, lens in ((crossing_q, crossing_r, None), (crossing_q, crossing_q + [0.3, 0.0, 0.0, 0.0], 0.02)):
        lx = None if lens is None else np.full((1, 3, 2), lens)
        out = [records(q, r, exact, lx)[0] for exact in (False, True)]
        assert len(out[0]["tri"]) > 0
        for name in ("tx", "ty", "t_lo", "t_hi"):
            assert np.array_equal(out[0][name], out[1][name])
