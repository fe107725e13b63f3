"""Triangle setup against independent float64 numpy computations."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.draw import draw_from_clip
from triangles import finite, moving_triangle
from units.triangle_setup import (EV_BACKFACE, EV_DEGENERATE, EVENTS, FLAG_EDGE, FLAG_WPOS, ST_BACKFACE,
                                  ST_DEGENERATE, ST_OK, TriangleSetup)

W, H = 48, 32


def run_setup(q, r, lx=None, ly=None, backface_culling=False, tile_size=8):
    d = draw_from_clip(q, r, lx, ly, width=W, height=H)
    setup = TriangleSetup(load_arch().triangle_setup, d, tile_size, backface_culling)
    alive, ops, events = setup.run(np.arange(d.n, dtype=np.int64))
    return setup, alive, events


def homogeneous_scale(q, r, lx, ly):
    """Per triangle, the power of two setup scales its homogeneous coordinates by:
    the one that brings the largest |clip coordinate| or |lens shift| into [0.5, 1)."""
    m = np.max(np.abs(np.concatenate([a.reshape(len(q), -1) for a in (q, r, lx, ly)], axis=1)), axis=1)
    return np.ldexp(1.0, -np.frexp(m)[1])


def pixel_vertices(q, r, lx, ly, t, u, v):
    """Pixel-space 2DH (X, Y, W) per vertex at (t, u, v), row 0 at the top, in
    the units setup stores them in (times ``homogeneous_scale``)."""
    p = (1 - t) * q + t * r
    X = (p[..., 0] + u * ((1 - t) * lx[..., 0] + t * lx[..., 1]) + p[..., 3]) * W / 2
    Y = (p[..., 3] - p[..., 1] - v * ((1 - t) * ly[..., 0] + t * ly[..., 1])) * H / 2
    return np.stack([X, Y, p[..., 3]], axis=-1) * homogeneous_scale(q, r, lx, ly)[:, None, None]


def test_pixel_space_transform_matches_formula():
    rng = np.random.default_rng(0)
    q = rng.uniform(-1, 1, (20, 3, 4))
    q[..., 3] = rng.uniform(0.5, 2, (20, 3))
    r = q + rng.uniform(-0.2, 0.2, q.shape)
    q[:5] *= 1e-20  # the same triangles at other scales: stored alike, up to a power of two
    r[:5] *= 1e-20
    q[5:10] *= 3e17
    r[5:10] *= 3e17
    setup, _, _ = run_setup(q, r)
    tb = setup.table
    sc = homogeneous_scale(q, r, np.zeros((20, 3, 2)), np.zeros((20, 3, 2)))[:, None]
    assert np.all((sc[:5] > 2.0**60) & (sc[5:10] < 2.0**-55))
    for s, arr in enumerate((q, r)):
        X = (arr[..., 0] + arr[..., 3]) * W / 2 * sc
        Y = (arr[..., 3] - arr[..., 1]) * H / 2 * sc
        np.testing.assert_allclose(tb.p0[..., 0] + s * tb.dp[..., 0], X, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(tb.p0[..., 1] + s * tb.dp[..., 1], Y, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(tb.p0[..., 3] + s * tb.dp[..., 3], arr[..., 3] * sc, rtol=1e-12)
        np.testing.assert_allclose(tb.p0[..., 2] + s * tb.dp[..., 2], arr[..., 2] * sc, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(tb.p0_32, tb.p0.astype(np.float32))


@given(moving_triangle(), st.booleans())
def test_facing_is_claimed_only_when_true_everywhere(tri, cull):
    """facing = +1 (-1) only if D(t, u, v) > 0 (< 0) on a dense grid, computed in float64;
    culled as back-facing only when facing is -1."""
    check_facing(*tri, cull)


@given(moving_triangle(), st.floats(-100.0, 100.0), st.booleans())
def test_facing_holds_at_every_homogeneous_scale(tri, log2_scale, cull):
    """The same check for the triangle's coordinates times 2^log2_scale (not a power of two in general):
    setup normalises each triangle's scale, and the backface test must stay conservative at any scale."""
    scale = 2.0 ** log2_scale
    check_facing(*(a * scale for a in tri), cull)


def check_facing(q, r, lx, ly, cull):
    setup, alive, events = run_setup(q, r, lx, ly, backface_culling=cull)
    status = setup.last_status[0]
    if status not in (ST_OK, ST_BACKFACE):
        return
    facing = setup.table.facing[0]
    dets = []
    for t in np.linspace(0, 1, 9):
        for u in (-1.0, 0.0, 1.0):
            for v in (-1.0, 0.0, 1.0):
                p = pixel_vertices(q, r, lx, ly, t, u, v)[0]
                dets.append(-np.linalg.det(p))  # D = p0 . (p2 x p1) = -det[p0; p1; p2]
    dets = np.array(dets)
    if facing == 1:
        assert np.all(dets > 0)
    elif facing == -1:
        assert np.all(dets < 0)
    assert (status == ST_BACKFACE) == (cull and facing == -1)


def test_degenerate_triangles_dropped_and_counted():
    q = np.array([[[0.1, 0.1, 0.0, 1.0], [0.1, 0.1, 0.0, 1.0], [0.5, -0.2, 0.0, 1.0]],  # repeated vertex
                  [[-0.5, -0.5, 0.0, 1.0], [0.5, -0.5, 0.0, 1.0], [0.0, 0.5, 0.0, 1.0]]])  # a real one
    setup, alive, events = run_setup(q, q)
    assert list(alive) == [1]
    assert setup.last_status[0] == ST_DEGENERATE
    assert events[EV_DEGENERATE] == 1 and EVENTS[EV_DEGENERATE] == "degenerate"


def test_back_facing_static_triangle_culled_when_enabled():
    ccw = np.array([[[-0.5, -0.5, 0.0, 1.0], [0.5, -0.5, 0.0, 1.0], [0.0, 0.5, 0.0, 1.0]]])
    cw = ccw[:, ::-1].copy()
    for tri, front in ((ccw, True), (cw, False)):
        setup, alive, events = run_setup(tri, tri, backface_culling=True)
        assert (len(alive) == 1) == front
        assert events[EV_BACKFACE] == (0 if front else 1)


def test_temporal_frustum_span_brackets_the_visible_times():
    """A triangle entering the screen from the left at t ~ 0.4: the span starts
    before the first visible time found by dense sampling and not much earlier."""
    q = np.array([[[-3.0, -0.2, 0.0, 1.0], [-2.6, -0.2, 0.0, 1.0], [-2.8, 0.2, 0.0, 1.0]]])
    r = q + np.array([3.0, 0.0, 0.0, 0.0])
    setup, alive, _ = run_setup(q, r)
    ts, te = setup.table.t_span[0]
    # first t at which a vertex is inside x >= -w: x(t) = -2.6 + 3 t >= -1  ->  t >= 0.5333
    assert ts <= 1.6 / 3 + 1e-9
    assert ts > 0.5 and te == 1.0


@given(moving_triangle(lens=False, allow_w_cross=False), st.integers(0, 2**31))
def test_linearized_edges_bound_the_edge_functions(tri, seed):
    """Munkberg11 eq. 4-7: h . s + Gamma t bounds the oriented edge function from above
    for every s in the tile-aligned bounds and t in [0, 1] (checked in float64)."""
    q, r, lx, ly = tri
    setup, alive, _ = run_setup(q, r, lx, ly)
    tb = setup.table
    if len(alive) == 0 or not tb.flags[0] & FLAG_EDGE:
        return
    x0, x1, y0, y1 = tb.bounds[0]
    x0, y0 = (x0 // 8) * 8, (y0 // 8) * 8
    x1, y1 = -(-x1 // 8) * 8, -(-y1 // 8) * 8
    rng = np.random.default_rng(seed)
    sgn = float(tb.facing[0])
    for _ in range(50):
        t = rng.uniform()
        s = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1), 1.0])
        p = pixel_vertices(q, r, lx, ly, t, 0.0, 0.0)[0]
        for k in range(3):
            i, j = (k + 1) % 3, (k + 2) % 3
            e = sgn * np.dot(np.cross(p[j], p[i]), s)
            bound = np.dot(tb.edge_h[0, k], s) + tb.edge_gamma[0, k] * t
            assert e <= bound + 1e-9 * (1 + abs(bound) + abs(e))


@given(moving_triangle(allow_w_cross=False))
def test_screen_bounds_hold_every_projected_vertex_and_no_more(tri):
    """Munkberg11 §3: the screen bounds hold each vertex's position X / W, Y / W (pixels, clamped to the
    screen) at every t in [ts, te] and lens position u, v in [-1, 1], sampled densely in float64, and start
    and end within a pixel of those positions' extremes (the extremes are at the ends of the span and of the lens)."""
    q, r, lx, ly = tri
    setup, alive, _ = run_setup(q, r, lx, ly)
    tb = setup.table
    if len(alive) == 0 or not tb.flags[0] & FLAG_WPOS:
        return
    ts, te = tb.t_span[0]
    p = np.array([pixel_vertices(q, r, lx, ly, t, u, v)[0] for t in np.linspace(ts, te, 17)
                  for u in np.linspace(-1, 1, 5) for v in np.linspace(-1, 1, 5)])
    x = np.clip(p[..., 0] / p[..., 2], 0, W)
    y = np.clip(p[..., 1] / p[..., 2], 0, H)
    x0, x1, y0, y1 = tb.bounds[0]
    assert x0 <= x.min() and x.max() <= x1 and y0 <= y.min() and y.max() <= y1
    assert x0 >= np.floor(x.min()) - 1 and x1 <= np.ceil(x.max()) + 1
    assert y0 >= np.floor(y.min()) - 1 and y1 <= np.ceil(y.max()) + 1


@given(moving_triangle(), st.tuples(finite(-1.0, 1.0), finite(-1.0, 1.0), finite(0.0, 1.0)))
def test_reference_camera_sees_the_projected_vertices(tri, view):
    """``ref``: each vertex's (X, Y, W) at the shading view's (t, u, v) (Nilsson12 §8), as the float64
    projection computes it, up to float32 rounding."""
    q, r, lx, ly = tri
    u, v, t = view
    d = draw_from_clip(q, r, lx, ly, width=W, height=H)
    setup = TriangleSetup(load_arch().triangle_setup, d, 8, shading_view=view)
    setup.run(np.arange(d.n, dtype=np.int64))
    expect = pixel_vertices(q, r, lx, ly, t, u, v)[0]
    np.testing.assert_allclose(setup.table.ref[0], expect, rtol=0, atol=1e-6 * np.abs(expect).max())


def test_zero_area_triangles_kept_without_facing_in_conservative_mode():
    """A repeated vertex and a horizontal segment (exactly zero determinant): dropped in standard mode,
    kept with no facing (never culled as back-facing) in conservative mode; both counted."""
    q = np.array([[[0.1, 0.1, 0.0, 1.0], [0.1, 0.1, 0.0, 1.0], [0.5, -0.2, 0.0, 1.0]],
                  [[-0.5, 0.0, 0.0, 1.0], [0.25, 0.0, 0.0, 1.0], [0.75, 0.0, 0.0, 1.0]]])
    for keep in (False, True):
        d = draw_from_clip(q, q, width=W, height=H)
        setup = TriangleSetup(load_arch().triangle_setup, d, 1, backface_culling=True, keep_degenerate=keep)
        alive, _, events = setup.run(np.arange(d.n, dtype=np.int64))
        assert events[EV_DEGENERATE] == 2
        assert list(alive) == ([0, 1] if keep else [])
        if keep:
            assert list(setup.table.facing) == [0, 0] and not np.any(setup.table.flags & FLAG_EDGE)


R = 16  # pixels per side of the conservative passes below
# clip coordinates on pixel boundaries (multiples of 2/R) and pixel centres, where rounding is at its worst
ON_GRID = st.integers(-R // 2 - 2, R // 2 + 2).map(lambda k: 2.0 * k / R) | \
    st.integers(-R // 2 - 2, R // 2 + 1).map(lambda k: (2.0 * k + 1.0) / R)
COORD = ON_GRID | st.floats(-1.3, 1.3)


@st.composite
def edge_on_triangles(draw):
    """A triangle whose third vertex is on the segment of the first two (at a grid point, an end point or
    anywhere along it), or off it by a tiny distance (near edge-on), static or moving so that it stays on
    the moving segment (the same parameter on both end poses), with depths in [-0.9, 0.9]; w = 1 (an
    orthographic view). Returns (q, r), each (1, 3, 4)."""
    poses = []
    along = draw(st.sampled_from([0.0, 1.0, 0.5]) | st.floats(0.0, 1.0))
    off = draw(st.sampled_from([0.0, 0.0, 1e-12, 1e-9, 1e-6, 1e-3, 3e-2]))
    motion = draw(st.sampled_from(["static", "translate", "segment"]))
    for pose in range(2 if motion == "segment" else 1):
        a = np.array([draw(COORD), draw(COORD)])
        b = a if draw(st.integers(0, 9)) == 0 else np.array([draw(COORD), draw(COORD)])  # 1 in 10: a point
        c = a + along * (b - a)
        if off:
            n = np.array([a[1] - b[1], b[0] - a[0]])
            c = c + off * (n / np.linalg.norm(n) if np.any(n) else np.array([1.0, 0.0]))
        tri = np.zeros((1, 3, 4))
        tri[0, :, :2] = [a, b, c]
        tri[0, :, 2] = [draw(st.floats(-0.9, 0.9)) for _ in range(3)]
        tri[0, :, 3] = 1.0
        poses.append(tri)
    if motion == "translate":
        poses.append(poses[0] + [draw(st.floats(-0.5, 0.5)), draw(st.floats(-0.5, 0.5)), 0.0, 0.0])
    q, r = poses[0], poses[-1]
    return q, r


def conservative_boxes(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Per pixel of an R x R conservative pass, the union of the tz-boxes (t_lo, z_lo, t_hi, z_hi) of
    the (triangle, pixel) fragments; (2, 2, -2, -2) where there are none."""
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.render import RenderPass, run_pass
    from pipeline_sim.shaders import interval_shader
    from pipeline_sim.targets import ShaderOutput, Target

    p = RenderPass(draw=draw_from_clip(q, r, width=R, height=R), arch=load_arch(), spp=1, name="edge_on",
                   state=PassState(mode="conservative", depth_test="always", depth_write=False),
                   shader=interval_shader, outputs=(ShaderOutput("box", 4),),
                   targets=(Target("box", source="box", blend=("min", "min", "max", "max"),
                                   clear=(2.0, 2.0, -2.0, -2.0), depth="always"),))
    return run_pass(p).images["box"][0]


@settings(max_examples=150, deadline=None)
@given(edge_on_triangles())
def test_conservative_mode_covers_every_pixel_an_edge_on_triangle_touches(tri):
    """Nilsson12 §2: in conservative mode every pixel a point of the triangle falls in at some time gets
    a fragment whose tz-box holds that (t, z), also when the triangle is seen edge-on (a segment or a
    point for every t) or nearly so. Dense sampling in float64: 41 times x 66 barycentric points, each
    projected by hand (pixel boundaries at multiples of 2/R in clip space, row 0 at the top)."""
    q, r = tri
    box = conservative_boxes(q, r)
    s, u = np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 11))
    keep = s + u <= 1
    bary = np.stack([1 - s[keep] - u[keep], s[keep], u[keep]], axis=1)
    for t in np.linspace(0, 1, 41):
        pts = bary @ ((1 - t) * q[0] + t * r[0])
        col = np.floor((pts[:, 0] + 1) / 2 * R).astype(int)
        row = np.floor((1 - pts[:, 1]) / 2 * R).astype(int)
        on = (col >= 0) & (col < R) & (row >= 0) & (row < R)
        cell = box[row[on], col[on]]
        eps = 1e-6
        assert np.all(cell[:, 0] <= t + eps) and np.all(t - eps <= cell[:, 2]), (t, cell)
        z = pts[on, 2]
        assert np.all(cell[:, 1] <= z + eps) and np.all(z - eps <= cell[:, 3]), (t, cell, z)
