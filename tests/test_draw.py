"""pipeline_sim.draw.draw_from_world (the applications' world -> clip path).

* Against ``build_draw`` (the scene path) on the shipped scenes with a static camera (perspective and
  orthographic, with and without a lens, moving objects): the same clip coordinates at both shutter ends,
  lens shifts and depth mapping (none for the orthographic camera).
* An oblong lens's x and y shifts each follow their own radius (the thin-lens shift of that radius).
* A fixed lens point folded into the vertices is the off-axis camera at that point of the lens: the
  pinhole moved to (u R, v R) in eye space, its frustum sheared so the focus plane stays in place
  (written here as a matrix, Wu13 §3.1), without lens shifts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline_sim.draw import build_draw, draw_from_world, lens_shift
from pipeline_sim.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "workloads" / "scenes"


@pytest.mark.parametrize("name", ["default", "defocus", "static", "motion", "offcentre", "ortho"])
def test_the_scene_path_and_the_world_path_agree(name):
    scene = load_scene(SCENES / f"{name}.toml")
    cam, img = scene.camera, scene.image
    assert not cam.moving
    ends = [np.concatenate([o.world_positions(t)[np.asarray(o.faces)] for o in scene.objects]) for t in (0, 1)]
    lens = cam.lens if cam.lens is not None and cam.lens.radius > 0 else None
    got = draw_from_world(ends[0], ends[1], cam.projection_matrix(img.width / img.height), cam.view_matrix(),
                          width=img.width, height=img.height, lens_radius=lens.radius if lens else 0.0,
                          focus=lens.focus_distance if lens else np.inf)
    want = build_draw(scene)
    for field in ("q", "r", "lens_x", "lens_y"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field))
    assert got.depth_w == want.depth_w and (got.width, got.height) == (want.width, want.height)
    assert got.has_lens == (lens is not None)


def test_an_oblong_lens_shifts_x_and_y_by_their_own_radii():
    rng = np.random.default_rng(0)
    world = rng.uniform(-2.0, 2.0, (5, 3, 3)) + [0.0, 0.0, -6.0]
    proj = np.diag([1.5, 2.0, -1.0, 0.0])
    proj[2, 3], proj[3, 2] = -2.0, -1.0
    d = draw_from_world(world, world, proj, width=32, height=24, lens_radius=(0.3, 0.05), focus=4.0)
    w = -world[..., 2]
    for t in (0, 1):
        np.testing.assert_allclose(d.lens_x[..., t], 1.5 * 0.3 * (w / 4.0 - 1.0), rtol=1e-14)
        np.testing.assert_allclose(d.lens_y[..., t], 2.0 * 0.05 * (w / 4.0 - 1.0), rtol=1e-14)
    assert d.depth_w == (1.0, -2.0)


@pytest.mark.parametrize("u, v, focus", [(0.5, -0.25, 5.0), (-1.0, 0.8, 12.0), (0.3, 0.3, np.inf)])
def test_a_fixed_lens_point_is_the_off_axis_camera_there(u, v, focus):
    rng = np.random.default_rng(1)
    w0 = rng.uniform(-3.0, 3.0, (7, 3, 3)) + [0.0, 0.0, -8.0]
    w1 = w0 + rng.uniform(-0.5, 0.5, (7, 1, 3))
    view = np.eye(4)
    view[:3, 3] = [0.2, -0.1, -0.5]
    proj = np.array([[1.2, 0.0, 0.1, 0.0], [0.0, 1.6, -0.05, 0.0], [0.0, 0.0, -1.05, -0.5], [0.0, 0.0, -1.0, 0.0]])
    radius = 0.4
    d = draw_from_world(w0, w1, proj, view, width=16, height=16, lens_radius=radius, focus=focus, lens_point=(u, v))
    # the pinhole at (u R, v R, 0) in eye space; x_eye - u R at depth -z gains u R (-z) / F back, the focus
    # plane's points staying put: a shear of -P00 u R / F on eye z (none when focused at infinity)
    move = np.eye(4)
    move[:2, 3] = [-u * radius, -v * radius]
    shear = proj.copy()
    shear[0, 2] -= proj[0, 0] * u * radius / focus
    shear[1, 2] -= proj[1, 1] * v * radius / focus
    for got, world in ((d.q, w0), (d.r, w1)):
        hom = np.concatenate([world, np.ones(world.shape[:-1] + (1,))], axis=-1)
        np.testing.assert_allclose(got, hom @ (shear @ move @ view).T, rtol=1e-12, atol=1e-12)
    assert not d.has_lens
    # and the lens shift of a draw with the lens free, at that lens point, moves the vertices there
    free = draw_from_world(w0, w1, proj, view, width=16, height=16, lens_radius=radius, focus=focus)
    np.testing.assert_allclose(free.q[..., 0] + u * free.lens_x[..., 0], d.q[..., 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lens_shift(proj, free.q[..., 3], radius, focus)[1], free.lens_y[..., 0], rtol=1e-15)
