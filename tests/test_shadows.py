"""Motion-blurred soft shadows from one 5D shadow-map pass (Nilsson12 §7; docs/shadows.md).

* The 5D light pass's K shadow maps equal K shadow maps ray cast in numpy (float64, from each tuple's
  light point at its time, through each texel's centre), but at silhouette texels; and the 5D camera
  pass's per-sample lookups equal an accumulation buffer over the same K tuples written here in numpy
  (per tuple: the scene at t_k, a camera ray per pixel, the point projected by the light camera moved to
  (u_k, v_k), compared with that numpy map), but within one texel of a shadow edge.
* The image converges, as K grows, to a ray-cast reference of visibility averaged over the light and
  the shutter (the workload's ``reference_visibility``, itself checked against a closed form below).
* The static occluder plane's penumbra: width L (d_receiver - d_occluder) / d_occluder, a linear ramp.
* The workload through ``pipeline-sim run``: its 2K accumulation passes against its 5D pass, its results,
  and bad input.
"""


import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from pipeline_sim.cli import main
from pipeline_sim.config import load_arch
from pipeline_sim.render import run_passes
from workloads.apps import shadows as S
from runs import ran_file, refused_file, run_doc_example



def five_d(s: S.Settings, per_sample: bool = False):
    tuples = S.light_tuples(s.tuples, s.light_shape)
    lens = S.camera_lens_points(s.tuples, s.seed)
    arch = load_arch()
    return run_passes([S.light_pass(s, arch, tuples), S.camera_pass(s, arch, tuples, lens, per_sample=per_sample)])


# --------------------------------------------------------------------------- an independent accumulation buffer
def cast(origins: np.ndarray, dirs: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Nearest ray parameter > 0 of each ray (R, 3) against triangles (N, 3, 3), inf for none: the
    barycentric solve by Cramer's rule over every (ray, triangle) pair."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    o, d = origins[:, None, :], dirs[:, None, :]
    shape = (len(origins), len(tris), 3)
    m = np.stack([np.broadcast_to(-d, shape), np.broadcast_to(b - a, shape), np.broadcast_to(c - a, shape)],
                 axis=-1)  # (R, N, 3, 3): columns -d, b - a, c - a
    rhs = o - a
    det = np.linalg.det(m)
    ok = np.abs(det) > 1e-12
    sol = np.linalg.solve(np.where(ok[..., None, None], m, np.eye(3)), rhs[..., None])[..., 0]
    dist, beta, gamma = sol[..., 0], sol[..., 1], sol[..., 2]
    hit = ok & (beta >= 0) & (gamma >= 0) & (beta + gamma <= 1) & (dist > 1e-9)
    return np.where(hit, dist, np.inf).min(axis=1)


def numpy_accumulation(s: S.Settings):
    """Per tuple k: the shadow map (distance along the light's axis, inf where no triangle) and, per pixel
    centre, whether a triangle is seen, whether the seen point is lit, whether it lies within one texel of
    a shadow edge and its percentage-closer visibility over 3 x 3 texels: maps (K, R, R), then (H, W, K)
    each."""
    meshes = S.scene_meshes(s)
    light, camera = S.light_camera(s), S.camera_of(s)
    lproj, lview = light.projection_matrix(1.0), light.view_matrix()
    cproj, cview = camera.projection_matrix(s.width / s.height), camera.view_matrix()
    l_world, c_world = np.linalg.inv(lview), np.linalg.inv(cview)
    tuples = S.light_tuples(s.tuples, s.light_shape)
    lens = S.camera_lens_points(s.tuples, s.seed)
    radius = 0.5 * s.light_size
    res = s.shadow_map
    jj, ii = np.meshgrid(np.arange(res), np.arange(res))
    tx, ty = (2.0 * (jj.ravel() + 0.5) / res - 1.0), (1.0 - 2.0 * (ii.ravel() + 0.5) / res)
    px, py = np.meshgrid(np.arange(s.width), np.arange(s.height))
    cx, cy = (2.0 * (px.ravel() + 0.5) / s.width - 1.0), (1.0 - 2.0 * (py.ravel() + 0.5) / s.height)
    focus = s.focus_distance if s.lens_radius > 0 else 1.0
    maps, seen, lit = [], [], []
    for k, (u, v, t) in enumerate(tuples):
        every = np.concatenate([m.at(t) for m in meshes])
        # shadow map k: rays from light point k, parallel to the light's axis through each texel centre
        o_eye = np.tile([radius * u, radius * v, 0.0], (res * res, 1))
        d_eye = np.stack([tx / lproj[0, 0], ty / lproj[1, 1], -np.ones(res * res)], axis=1)
        depth = cast(o_eye @ l_world[:3, :3].T + l_world[:3, 3], d_eye @ l_world[:3, :3].T, every)
        maps.append(depth.reshape(res, res))  # d_eye's z is -1: the parameter is the distance along the axis
        # camera k: a ray from lens point k through each pixel centre's point on the focus plane
        o_eye = np.tile([s.lens_radius * lens[k, 0], s.lens_radius * lens[k, 1], 0.0], (len(cx), 1))
        d_eye = np.stack([cx * focus / cproj[0, 0], cy * focus / cproj[1, 1], -focus * np.ones(len(cx))], 1) - o_eye
        o, d = o_eye @ c_world[:3, :3].T + c_world[:3, 3], d_eye @ c_world[:3, :3].T
        dist = cast(o, d, np.concatenate([m.at(t) for m in meshes if m.seen]))
        hit = np.isfinite(dist)
        point = o + np.where(hit, dist, 0.0)[:, None] * d
        eye = point @ lview[:3, :3].T + lview[:3, 3] - [radius * u, radius * v, 0.0]
        w = -eye[:, 2]
        col = np.floor((lproj[0, 0] * eye[:, 0] / w + 1.0) / 2.0 * res).astype(int)
        row = np.floor((1.0 - lproj[1, 1] * eye[:, 1] / w) / 2.0 * res).astype(int)
        inside = (col >= 0) & (col < res) & (row >= 0) & (row < res)
        stored = maps[-1][np.clip(row, 0, res - 1), np.clip(col, 0, res - 1)]
        seen.append(hit)
        lit.append(~inside | (w - s.bias <= stored))
        # within one texel of a shadow edge: the 3 x 3 texels around give both answers
        near = [maps[-1][np.clip(row + dy, 0, res - 1), np.clip(col + dx, 0, res - 1)] >= w - s.bias
                for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
        # and the share of those 3 x 3 texels that pass: percentage-closer filtering of radius 1
        lit[-1] = np.stack([lit[-1], inside & np.any(near, axis=0) & ~np.all(near, axis=0),
                            np.where(inside, np.mean(near, axis=0), 1.0)])
    shape = (s.height, s.width, s.tuples)
    every = np.stack(lit, axis=-1)  # (3, pixels, K)
    return (np.stack(maps), np.stack(seen, -1).reshape(shape), every[0].reshape(shape).astype(bool),
            every[1].reshape(shape).astype(bool), every[2].reshape(shape))


@pytest.mark.parametrize("light_shape, lens_radius", [("square", 0.0), ("square", 0.08), ("disk", 0.0)])
def test_five_d_pass_equals_an_accumulation_buffer_up_to_shadow_map_resolution(light_shape, lens_radius):
    s = S.Settings(width=32, height=24, tuples=16, shadow_map=64, light_shape=light_shape, light_size=1.5,
                   lens_radius=lens_radius, focus_distance=8.0)
    res = five_d(s, per_sample=True)
    maps, seen, lit, edge, _ = numpy_accumulation(s)
    # the shadow maps: layer k of the light pass's per-sample depth, as distance along the light's axis
    light = S.light_camera(s).projection_matrix(1.0)
    z = res["light"].depth.transpose(2, 0, 1).astype(np.float64)
    w = np.where(z < 1.0, light[2, 3] / (z + light[2, 2]), np.inf)
    agree = np.isclose(w, maps, rtol=1e-4) | (np.isinf(w) & np.isinf(maps))
    assert 0.0 < np.isfinite(maps).mean() and agree.mean() > 0.99
    # ... the texels that disagree lie at silhouettes: a neighbour texel in numpy's map holds the pass's depth
    k, i, j = np.nonzero(~agree)
    pad = np.pad(maps, ((0, 0), (1, 1), (1, 1)), mode="edge")
    around = np.stack([pad[k, i + 1 + dy, j + 1 + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    assert np.all(np.any(np.isclose(around, w[k, i, j], rtol=1e-4) | (np.isinf(around) & np.isinf(w[k, i, j])),
                         axis=0))
    # the camera's samples: the same points seen, and the same lookups but within one texel of an edge
    data = res["camera"].sample_data["samples"]
    np.testing.assert_array_equal(data[..., 1] == 1.0, seen)
    differ = seen & ((data[..., 0] == 1.0) != lit)
    assert 0.2 < lit[seen].mean() < 0.98  # shadows in view
    assert differ.mean() < 0.01 and np.all(edge[differ])
    # and so the image: the per-pixel mean of the accumulation buffer
    acc = np.where(seen.any(axis=2), (lit & seen).sum(axis=2) / np.maximum(seen.sum(axis=2), 1), 1.0)
    assert np.abs(S.visibility(res["camera"]) - acc).mean() < 0.005


def test_percentage_closer_lookups_against_the_accumulation_buffer():
    """pcf = 1: each lookup is the share of 3 x 3 texels passing; against numpy's over its own maps."""
    s = S.Settings(width=32, height=24, tuples=8, shadow_map=64, light_size=1.5, pcf=1)
    data = five_d(s, per_sample=True)["camera"].sample_data["samples"]
    _, seen, _, _, pcf = numpy_accumulation(s)
    diff = np.abs(data[..., 0] - pcf)[seen]
    assert 0.01 < ((pcf[seen] > 0) & (pcf[seen] < 1)).mean()  # filtered values in view
    assert np.mean(diff > 1e-6) < 0.01 and diff.max() <= 3 / 9 + 1e-6  # a window one texel over at most


def test_the_pipeline_accumulation_passes_match_the_five_d_pass(tmp_path):
    """The workload's own accumulation buffer (2K 2D passes through the pipeline), its results."""
    out, r = ran_file(tmp_path, 'kind = "shadows"\nwidth = 20\nheight = 15\ntuples = 4\nshadow_map = 32\n'
                                'reference_samples = 64\nstudy_tuples = [2]\nstudy_shadow_maps = [16]\n')
    assert r["passes"] == 2 and r["accumulation_passes"] == 8
    assert sorted(p.name for p in (out / "passes").iterdir()) == sorted(
        ["light", "camera", "study_light_k2_r16", "study_camera_k2_r16"]
        + [f"{kind}_{k}" for kind in ("light", "camera") for k in range(4)])
    assert r["accumulation_difference"] < 0.01 and r["accumulation_max_difference"] <= 0.25
    # one lookup per covered sample: the 5D camera pass covers each pixel's K samples as the K passes do
    assert r["shadow_lookups"] == r["accumulation_shadow_lookups"] > 0
    assert r["cycles"] == r["light_cycles"] + r["camera_cycles"] > 0 and r["speedup"] > 1
    assert 0 <= r["error"] < 0.05 and r["error_k2_r16"] == pytest.approx(
        float(np.genfromtxt(out / "study.csv", delimiter=",", names=True)["error"]))


# --------------------------------------------------------------------------- the light frustum's bound
LIGHT_COORD = st.one_of(st.sampled_from([-1.0, 1.0, 0.0]), st.floats(-1.0, 1.0))


@settings(max_examples=300, deadline=None)
@given(st.floats(0.0, 10.0), st.floats(1.0, 100.0), st.floats(0.1, 50.0), st.floats(0.0, 4.0),
       st.lists(st.tuples(LIGHT_COORD, LIGHT_COORD), min_size=1, max_size=6))
def test_every_caster_and_its_shadow_lands_in_every_shadow_map(light_size, light_height, occluder_height, motion,
                                                              points):
    """``shadowed_extent`` (the light camera's window): a caster vertex at t = 0 or 1 (the casters move
    linearly, so their convex hulls over the shutter are those ends'), seen from any point (u, v) of the
    square (or inscribed disk) light, projects into NDC [-1, 1]^2 of that point's matrix, and its shadow
    on the ground (the line from the light point through it, met at y = 0) lies within the extent."""
    s = S.Settings(light_size=light_size, light_height=light_height, occluder_height=occluder_height,
                   motion=motion)
    casters = S.scene_meshes(s)[1:]
    pts = np.concatenate([np.concatenate([m.world0, m.world1]).reshape(-1, 3) for m in casters])
    assume(pts[:, 1].max() <= light_height - 2 * S.LIGHT_NEAR)  # what check() refuses
    uv = np.array(points)
    clip = np.concatenate([pts, np.ones((len(pts), 1))], axis=1) @ S.light_matrices(
        s, np.column_stack([uv, np.zeros(len(uv))])).transpose(0, 2, 1)  # (K, N, 4)
    w = clip[..., 3]
    assert (w > 0).all()
    assert (np.abs(clip[..., :2]) <= w[..., None] * (1 + 1e-9)).all()
    light = S.light_camera(s)
    axes = light.view_matrix()[:2, :3]
    lamps = light.eye + 0.5 * light_size * (uv[:, :1] * axes[0] + uv[:, 1:] * axes[1])  # (K, 3)
    lamp = lamps[:, None, :]
    shadow = lamp + (pts[None] - lamp) * (lamp[..., 1:2] / (lamp[..., 1:2] - pts[None, :, 1:2]))
    assert np.abs(shadow[..., [0, 2]]).max() <= S.shadowed_extent(s) * (1 + 1e-9)


# --------------------------------------------------------------------------- convergence to the ray-cast reference
def test_converges_to_the_ray_cast_reference_as_k_grows():
    base = S.Settings(width=32, height=24, shadow_map=128)
    reference = S.reference_visibility(base, 1024)
    assert 0.02 < ((reference > 0.01) & (reference < 0.99)).mean()  # penumbrae in view
    errors = [np.abs(S.visibility(five_d(dataclasses.replace(base, tuples=k))["camera"]) - reference).mean()
              for k in (16, 64, 256)]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 0.006, errors


def test_reference_visibility_is_the_closed_form_ramp():
    """The reference's own check: under a straight occluder edge, the linear ramp across the penumbra."""
    s = S.Settings(scene="occluder_plane", width=48, height=4, light_size=1.0, occluder_height=2.0)
    ref = S.reference_visibility(s, 256)
    np.testing.assert_allclose(ref, closed_form(s), atol=1.5 / 256 + 0.01)


# --------------------------------------------------------------------------- the closed-form penumbra
def closed_form(s: S.Settings) -> np.ndarray:
    """Visibility of each pixel centre on the receiver: 0 below the occluder's shadow, a linear ramp of
    width L (d_r - d_o) / d_o centred under the occluder's edge (x = 0), 1 beyond."""
    camera = S.camera_of(s)
    proj = camera.projection_matrix(s.width / s.height)
    x = (2.0 * (np.arange(s.width) + 0.5) / s.width - 1.0) * camera.eye[1] / proj[0, 0]
    d_r, d_o = s.light_height, s.light_height - s.occluder_height
    width = s.light_size * (d_r - d_o) / d_o
    return np.broadcast_to(np.clip(0.5 + x / width, 0.0, 1.0), (s.height, s.width))


@pytest.mark.parametrize("light_size, occluder_height", [(1.0, 2.0), (0.6, 3.0)])
def test_penumbra_width_of_the_occluder_plane(light_size, occluder_height):
    s = S.Settings(scene="occluder_plane", width=96, height=8, tuples=64, shadow_map=256, light_size=light_size,
                   occluder_height=occluder_height)
    vis = S.visibility(five_d(s)["camera"])
    want = light_size * occluder_height / (s.light_height - occluder_height)
    assert S.penumbra_width(s) == pytest.approx(want)
    assert S.measured_penumbra(s, vis) == pytest.approx(want, rel=0.03)
    # a staircase of K steps (one per stratum of u) along the ramp, each step within a texel's reach
    texel = 2.0 * (S.FOOTPRINT + 0.5 * light_size) / s.shadow_map * s.light_height / (s.light_height - occluder_height)
    assert np.abs(vis - closed_form(s)).max() <= 1.0 / s.tuples + texel / want + 1e-6


# --------------------------------------------------------------------------- input and the documented example
@pytest.mark.parametrize("text, args, message", [
    ("tuples = 48", [], "tuples = 48 must be a power of two"),
    ("occluder_height = 7.0", [], "above light_height"),
    ("tuple = 8", [], "unknown key 'tuple' (did you mean 'tuples'?)"),
    ("", ["--spp", "4"], "--spp: a shadows workload takes one camera sample per tuple"),
])
def test_bad_input_is_one_line(tmp_path, capsys, text, args, message):
    assert message in refused_file(tmp_path, capsys, "shadows", text, "check", *args)


def test_the_documented_example_runs_as_written():
    scope, printed = run_doc_example("shadows.md")
    assert "penumbra" in printed
    assert scope["measured"] == pytest.approx(scope["closed_form"], rel=0.05)


def test_the_cost_sweep_runs_the_workload_over_k_and_resolution(tmp_path):
    """workloads/sweeps/shadows_cost.toml as shipped (its 9 points, validated against the kind's file),
    then its form on a tiny file: each point's error and the 5D pair's cycles as result columns."""
    import pandas as pd

    from pipeline_sim.sweep import load_sweep

    shipped = Path(__file__).resolve().parent.parent / "workloads" / "sweeps" / "shadows_cost.toml"
    points = load_sweep(shipped).points
    assert sorted((p["workload.tuples"], p["workload.shadow_map"]) for p in points) == [
        (k, r) for k in (16, 64, 256) for r in (64, 128, 256)]
    (tmp_path / "small.toml").write_text('kind = "shadows"\nwidth = 16\nheight = 12\nreference_samples = 16\n')
    text = shipped.read_text().replace("../apps/shadows/moving_object.toml", "small.toml")
    (tmp_path / "sweep.toml").write_text(text.replace("[16, 64, 256]", "[2, 4]").replace("[64, 128, 256]", "[16]"))
    assert main(["sweep", str(tmp_path / "sweep.toml"), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    table = pd.read_csv(tmp_path / "out" / "points.csv")
    assert list(table["workload.tuples"]) == [2, 4] and (table.status == "ok").all()
    assert (table["result.cycles"] == table["frame_cycles"]).all()  # no accumulation passes: the 5D pair's
    assert table["result.error"].notna().all() and "result.accumulation_cycles" not in table
