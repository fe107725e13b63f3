"""Planar glossy reflections and refractions (Nilsson12 §6; docs/glossy.md).

* A lens pass's texture against the accumulation of pinhole views through the same window, one per
  sample of the same table: a float64 ray cast from each sample's lens point through its point of the
  surface (``reference_texture``), averaged per texel as the box resolve does; for the reflection and
  for the refraction camera.
* With one lens point (no roughness) the reflection texture is a plain mirror: rays from the main eye
  reflected at the surface by the law of reflection, not through the mirrored camera.
* The refraction camera lies on the refracted central ray (Snell's law in angles, and on the normal
  through the main eye); its rays are exact there and their error grows towards the edges.
* The main pass lays the texture on the surface: a perfect mirror against the main eye's reflected rays.
* The workload through ``pipeline-sim run``; bad input is one line, exit status 2; docs/glossy.md's
  example runs as written.
"""


import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from pipeline_sim.cli import main
from pipeline_sim.config import load_arch
from pipeline_sim.render import run_pass
from pipeline_sim.shaders import standard_params
from pipeline_sim.workload import load_workload
from workloads.apps.raycast import nearest_hits
from runs import refused, run_doc_example

APP = Path(__file__).resolve().parents[1] / "workloads" / "apps" / "glossy"


def workload(tmp_path, scene="floor_scene.toml", surface="floor", **keys):
    text = f'kind = "glossy"\nscene = "{APP / scene}"\nsurface = "{surface}"\n'
    text += "".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items())
    path = tmp_path / "glossy.toml"
    path.write_text(text)
    return path


def prepare(tmp_path, **keys):
    from workloads.apps import glossy

    w = load_workload(workload(tmp_path, **keys), load_arch())
    surface, others, cams = w.cameras()
    light, background = standard_params(w.scene.light), np.asarray(w.scene.background, np.float64)
    return glossy, w, surface, others, cams, glossy.reference_triangles(w.scene, surface.index), light, background


@pytest.mark.parametrize("scene, surface, effect, spt", [("floor_scene.toml", "floor", "reflection", 16),
                                                        ("water_scene.toml", "water", "refraction", 8)])
def test_lens_pass_is_the_accumulation_of_pinhole_views(tmp_path, scene, surface, effect, spt):
    glossy, w, _, others, cams, tris, light, background = prepare(
        tmp_path, scene=scene, surface=surface, effect=effect, roughness=6.0, texels=20, samples_per_texel=spt)
    cam = cams[effect]
    image = run_pass(w.lens_pass(effect, cam, others, spt)).image[..., :3]
    table = glossy.lens_table(spt, 0)
    moving = any(o.moving for o in others)
    reference = glossy.reference_texture(cam, table, tris, moving, light, background)
    assert image.shape == reference.shape == (cam.size[1], cam.size[0], 3)
    assert np.abs(image - reference).max() < 1e-4
    # the check can tell: the same lens through another table of the same size is far off
    other = glossy.reference_texture(cam, glossy.lens_table(spt, 1), tris, moving, light, background)
    assert np.abs(image - other).max() > 100 * np.abs(image - reference).max()


@pytest.mark.parametrize("scene, surface, effect", [("floor_scene.toml", "floor", "reflection"),
                                                    ("water_scene.toml", "water", "refraction")])
def test_window_encloses_the_surface_on_the_near_and_focus_plane(tmp_path, scene, surface, effect):
    """Through the scene camera's own matrices (gluLookAt, glFrustum): the surface's vertices project to
    the frame's edges and corners, at depth -1 (the near plane), with no lens shift (the focus plane)."""
    from pipeline_sim.draw import lens_shift

    glossy, w, found, *_ = prepare(tmp_path, scene=scene, surface=surface, effect=effect, roughness=5.0)
    cam = w.cameras()[2][effect].camera()
    corners = np.concatenate([found.vertices, np.ones((len(found.vertices), 1))], axis=1)
    proj = cam.projection_matrix(1.0)
    clip = corners @ (proj @ cam.view_matrix(0.0)).T
    ndc = clip[:, :3] / clip[:, 3:]
    assert np.allclose(ndc[:, 2], -1.0, atol=1e-12)
    assert np.allclose([ndc[:, 0].min(), ndc[:, 0].max(), ndc[:, 1].min(), ndc[:, 1].max()], [-1, 1, -1, 1],
                       atol=1e-12)
    assert cam.lens.radius == pytest.approx(cam.near * math.tan(math.radians(5.0)))
    assert np.allclose(lens_shift(proj, clip[:, 3], cam.lens.radius, cam.lens.focus_distance), 0.0, atol=1e-12)


def test_lens_table_is_uniform_stratified_circular():
    from workloads.apps import glossy

    table = glossy.lens_table(64, 3)
    r2 = table[:, 2] ** 2 + table[:, 3] ** 2
    assert np.all(r2 <= 1.0) and np.all((table[:, [0, 1, 4]] >= 0) & (table[:, [0, 1, 4]] < 1))
    # 8 x 8 jittered strata of the square, concentric-mapped (square ring k -> disc ring radius in
    # [k/4, (k+1)/4)): 8k + 4 points in ring k, whose areas are 8k + 4 of 64 parts of the disc's; 16 in each
    # quadrant
    assert np.bincount((np.sqrt(r2) * 4).astype(int), minlength=4).tolist() == [4, 12, 20, 28]
    quadrant = (table[:, 2] >= 0).astype(int) * 2 + (table[:, 3] >= 0)
    assert np.bincount(quadrant, minlength=4).tolist() == [16] * 4
    for col in (0, 1, 4):  # one sample in each 1/64 stratum
        assert sorted((table[:, col] * 64).astype(int).tolist()) == list(range(64))


def test_one_lens_point_is_a_plain_mirror(tmp_path):
    glossy, w, surface, others, cams, tris, light, background = prepare(
        tmp_path, roughness=0.0, texels=24, samples_per_texel=4)
    cam = cams["reflection"]
    image = run_pass(w.lens_pass("reflection", cam, others, 4)).image[..., :3]
    # the main eye's rays through each sample's point of the floor, reflected there (d - 2 (d.n) n)
    table = glossy.lens_table(4, 0)
    width, height = cam.size
    col, row = np.meshgrid(np.arange(width), np.arange(height))
    points = cam.plane_points(col[..., None] + table[:, 0], row[..., None] + table[:, 1]).reshape(-1, 3)
    d = points - w.scene.camera.eye
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    mirrored = d - 2.0 * (d @ surface.normal)[:, None] * surface.normal
    times = np.tile(table[:, 4], width * height)
    mirror = glossy.reference_trace(tris, points, mirrored, times, light, background).reshape(height, width, 4, 3)
    assert np.abs(image - mirror.mean(axis=2)).max() < 1e-4
    assert np.ptp(image) > 0.3  # the floor reflects the objects, not only the sky


def test_main_pass_lays_the_texture_on_the_surface(tmp_path):
    """A perfect mirror (reflectance 1, no roughness, a fine texture): where a main-pass sample sees the
    floor, its colour is what the main eye's ray reflected there sees (ray cast), up to the texture's
    bilinear filter at edges."""
    glossy, w, surface, _, _, _, light, background = prepare(tmp_path, roughness=0.0, texels=192, reflectance=1.0,
                                                           samples_per_texel=1, reference_samples=0)
    # the ball held still: a one-sample texture would show it at one time for every main-pass time
    still = [dataclasses.replace(o, transform_close=o.transform_open) for o in w.scene.objects]
    w.scene = w.scene.replace(image=dataclasses.replace(w.scene.image, width=48, height=36, spp=1), objects=still)
    main_pass = w.run().passes["main"]
    cam, img = w.scene.camera, w.scene.image
    x, y = np.meshgrid(np.arange(img.width), np.arange(img.height))
    px, py = x.ravel() + main_pass.samples.x, y.ravel() + main_pass.samples.y
    ndc = np.stack([2 * px / img.width - 1, 1 - 2 * py / img.height, -np.ones_like(px), np.ones_like(px)])
    world = np.linalg.inv(cam.projection_matrix(img.width / img.height) @ cam.view_matrix(0.0)) @ ndc
    d = (world[:3] / world[3]).T - cam.eye
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    everything = glossy.reference_triangles(w.scene, -1)
    times = main_pass.samples.t.astype(np.float64)
    tri, _, _ = nearest_hits(everything.p0, everything.p1, np.tile(cam.eye, (len(d), 1)), d, times)
    on = (tri >= 0) & (everything.object_id[np.maximum(tri, 0)] == surface.index)
    hit = cam.eye + d[on] * (np.dot(surface.point - cam.eye, surface.normal) / (d[on] @ surface.normal))[:, None]
    mirrored = d[on] - 2.0 * (d[on] @ surface.normal)[:, None] * surface.normal
    others = glossy.reference_triangles(w.scene, surface.index)
    expected = glossy.reference_trace(others, hit, mirrored, times[on], light, background)
    got = main_pass.image[..., :3].reshape(-1, 3)[on]
    assert on.sum() > 300
    error = np.abs(got - expected).mean(axis=1)
    # measured: 80% of them within 6e-4, mean 0.011 (edges); the texture upside down: 0.23 and 0.077
    assert np.quantile(error, 0.8) < 0.01 and error.mean() < 0.025


@pytest.mark.parametrize("eye, look_at, ior", [((0.3, 2.2, 4.0), (0.0, -0.6, 0.0), 1.33),
                                               ((-1.0, 0.7, 2.0), (0.5, -0.2, -1.0), 1.5),
                                               ((0.0, 3.0, 0.2), (0.0, -1.0, 0.0), 2.4),
                                               ((0.2, 1.0, 0.0), (0.2, 0.0, 0.0), 1.33)])
def test_refraction_camera_lies_on_the_refracted_central_ray(tmp_path, eye, look_at, ior):
    glossy, w, surface, others, _, _, _, _ = prepare(tmp_path, scene="water_scene.toml", surface="water")
    eye, look_at = np.array(eye), np.array(look_at)
    cam = glossy.refraction_camera(surface, eye, look_at, ior, 0.0, 16, others)
    # on the normal through the main eye, on its side of the plane
    assert np.linalg.norm(np.cross(cam.eye - eye, surface.normal)) < 1e-12
    assert np.dot(cam.eye - surface.point, surface.normal) > 0
    # the central ray's hit, from the parametric line and plane
    d = (look_at - eye) / np.linalg.norm(look_at - eye)
    hit = eye + d * (surface.point[1] - eye[1]) / d[1]
    # Snell in angles: sin(theta_i) = ior sin(theta_t), theta_t the angle of the camera's ray to the hit
    theta_i = math.acos(-d[1])
    ray = (hit - cam.eye) / np.linalg.norm(hit - cam.eye)
    theta_t = math.acos(-ray[1])
    assert math.sin(theta_i) == pytest.approx(ior * math.sin(theta_t), abs=1e-12)
    if theta_i == 0.0:  # normal incidence: the paraxial limit h * ior
        assert cam.distance == pytest.approx(eye[1] * ior)
    # its ray through the hit is the refracted central ray: no angle error there
    assert glossy.refraction_angles(cam, surface, eye, ior, hit[None])[2][0] < 1e-9


def test_refraction_error_grows_towards_the_edges(tmp_path):
    glossy, w, surface, others, cams, tris, light, background = prepare(
        tmp_path, scene="water_scene.toml", surface="water", effect="refraction", texels=24)
    eye = w.scene.camera.eye
    hit = glossy.central_hit(surface, eye, w.scene.camera.look_at, "test")
    rings = glossy.reference_refraction(cams["refraction"], surface, eye, hit, 1.33, tris, light, background)
    assert len(rings) == glossy.RINGS
    assert np.all(np.diff(rings.angle_mean_deg) > 0) and np.all(np.diff(rings.angle_max_deg) > 0)
    assert rings.angle_max_deg.iloc[0] < 0.5 * rings.angle_max_deg.iloc[-1]
    # against a closed form: at a texel point p the exact refracted direction and the camera's ray
    p = cams["refraction"].plane_points(np.array([0.5]), np.array([0.5]))
    s = (p[0] - eye) / np.linalg.norm(p[0] - eye)
    sin_t = math.sqrt(s[0] ** 2 + s[2] ** 2) / 1.33
    exact = np.array([s[0], 0.0, s[2]]) / math.sqrt(s[0] ** 2 + s[2] ** 2) * sin_t
    exact[1] = -math.sqrt(1.0 - sin_t**2)
    approx = (p[0] - cams["refraction"].eye) / np.linalg.norm(p[0] - cams["refraction"].eye)
    angle = glossy.refraction_angles(cams["refraction"], surface, eye, 1.33, p)[2][0]
    assert angle == pytest.approx(math.degrees(math.acos(np.clip(exact @ approx, -1, 1))), abs=1e-9)


def test_glossy_workload_end_to_end(tmp_path):
    path = workload(tmp_path, scene="water_scene.toml", surface="water", effect="refraction", texels=12,
                    samples_per_texel=4, reference_samples=16, study=[1, 4, 16])
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--spp", "1"]) == 0
    results = json.loads((out / "results.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert results["samples_per_texel"] == 4
    assert set(results["passes"]) == {"reflection", "refraction", "main", "reflection_spt1", "refraction_spt1",
                                      "reflection_spt16", "refraction_spt16"}
    for n in (1, 4, 16):
        assert results[f"cycles_spt{n}"] > 0 and results[f"error_spt{n}"] >= 0
    assert results["cycles"] == results["cycles_spt4"]
    assert results["shader_executions"] == sum(results["passes"][p]["shader_executions"]
                                               for p in ("reflection", "refraction"))
    assert results["refraction_angle_centre_deg"] < 1e-9 < results["refraction_angle_max_deg"]
    assert (out / "error_vs_samples.csv").exists() and (out / "refraction_error.csv").exists()
    assert np.load(out / "images" / "reference_refraction.npy").shape == np.load(
        out / "passes" / "refraction" / "image.npy").shape


@pytest.mark.parametrize("keys, message", [
    ({"surface": "flor"}, "surface 'flor' names no object of the scene (did you mean 'floor'?)"),
    ({"surface": "ball"}, "surface 'ball' moves"),
    ({"surface": "box"}, "surface 'box' is not planar"),
    ({"roughness": 50.0}, "roughness"),
])
def test_bad_input_is_one_line(tmp_path, capsys, keys, message):
    path = workload(tmp_path, **{"surface": "floor", **keys})
    assert message in refused(["check", str(path)], capsys)


def test_the_doc_example_runs_as_written(monkeypatch):
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # the example's paths are the repository's
    _, printed = run_doc_example("glossy.md")
    assert "largest difference from the accumulation" in printed


def test_the_cost_sweep_runs(tmp_path):
    """workloads/sweeps/glossy_cost.toml's points load, and a shrunk copy of it (small textures, a small
    reference, two points) runs with its listed results as columns."""
    import pandas as pd

    from pipeline_sim.sweep import load_sweep, run_sweep

    root = Path(__file__).resolve().parents[1]
    text = (root / "workloads" / "sweeps" / "glossy_cost.toml").read_text()
    assert len(load_sweep(root / "workloads" / "sweeps" / "glossy_cost.toml").points) == 21
    small = text.replace('"../apps/glossy/floor.toml"', json.dumps(str(APP / "floor.toml")))
    small = re.sub(r'"workload.roughness" = .*', '"workload.roughness" = [4.0]\n"workload.texels" = [8]\n'
                   '"workload.reference_samples" = [16]\n"image.spp" = [1]', small)
    small = re.sub(r'"workload.samples_per_texel" = .*', '"workload.samples_per_texel" = [4, 16]', small)
    (tmp_path / "sweep.toml").write_text(small)
    frame = run_sweep(load_sweep(tmp_path / "sweep.toml"), tmp_path / "out", executor="serial", progress=False)
    assert (frame.status == "ok").all() and len(frame) == 2
    points = pd.read_csv(tmp_path / "out" / "points.csv")
    assert [c for c in points.columns if c.startswith("result.")][:3] == ["result.error", "result.cycles",
                                                                         "result.shader_executions"]
    assert points["result.cycles"].iloc[1] > points["result.cycles"].iloc[0]
