"""Tests for the TOML scene loader (pipeline_sim.scene).

Expectations are computed independently of the implementation: geometric
properties of the matrices (where known points must land), closed-form
rotations, divergence-theorem volumes, and mesh files read back without
trimesh where practical.
"""

from __future__ import annotations

import math
import shutil
import struct
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.errors import UserError
from pipeline_sim.scene import (
    Camera,
    Lens,
    Scene,
    load_scene,
    parse_scene,
)

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "workloads" / "scenes"
MESHES = ROOT / "workloads" / "meshes"

EXAMPLE_SCENES = [
    "default",
    "static",
    "motion",
    "defocus",
    "camera_motion",
    "offcentre",
    "ortho",
    "meshes",
]

MINIMAL = """
[image]
width = 64
height = 32
spp = 4

[camera]
eye = [0.0, 0.0, 5.0]
look_at = [0.0, 0.0, 0.0]
fov_y = 60.0
near = 0.5
far = 20.0
"""

SPHERE = """
[[objects]]
primitive = "sphere"
"""


def write_scene(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def load_text(tmp_path: Path, text: str) -> Scene:
    return load_scene(write_scene(tmp_path, text))


def project(camera: Camera, aspect: float, p_world, t: float = 0.0) -> np.ndarray:
    """World point -> (x_ndc, y_ndc, z_ndc, w_clip)."""
    clip = camera.projection_matrix(aspect) @ camera.view_matrix(t) @ np.append(p_world, 1.0)
    return np.append(clip[:3] / clip[3], clip[3])


def eye_to_ndc(m: np.ndarray, p_eye) -> np.ndarray:
    clip = m @ np.append(np.asarray(p_eye, float), 1.0)
    return clip[:3] / clip[3]


def make_camera(**kw) -> Camera:
    args = dict(
        projection="perspective",
        eye=[1.0, 2.0, 3.0],
        look_at=[0.0, 0.5, -1.0],
        up=[0.0, 1.0, 0.0],
        eye_close=[1.0, 2.0, 3.0],
        look_at_close=[0.0, 0.5, -1.0],
        fov_y=50.0,
        near=0.25,
        far=40.0,
    )
    args.update(kw)
    return Camera(**args)


# --------------------------------------------------------------------------
# Camera matrices


def test_view_matrix_is_rigid_and_maps_eye_and_look_at():
    cam = make_camera()
    v = cam.view_matrix(0.0)
    r = v[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(v @ [1.0, 2.0, 3.0, 1.0], [0, 0, 0, 1], atol=1e-12)
    d = np.linalg.norm(np.array([0.0, 0.5, -1.0]) - [1.0, 2.0, 3.0])
    np.testing.assert_allclose(v @ [0.0, 0.5, -1.0, 1.0], [0, 0, -d, 1], atol=1e-12)
    # A point above the eye (world +y) ends up in the eye's upper half, x = 0 plane
    # contains the world up vector.
    above = v @ [1.0, 3.0, 3.0, 1.0]
    assert above[1] > 0 and abs(above[0]) < 1e-12


def test_perspective_look_at_projects_to_centre_and_depth_range():
    cam = make_camera()
    forward = (cam.look_at - cam.eye) / np.linalg.norm(cam.look_at - cam.eye)
    np.testing.assert_allclose(project(cam, 1.7, cam.look_at)[:2], [0, 0], atol=1e-12)
    near_pt = cam.eye + cam.near * forward
    far_pt = cam.eye + cam.far * forward
    assert project(cam, 1.7, near_pt)[2] == pytest.approx(-1.0)
    assert project(cam, 1.7, far_pt)[2] == pytest.approx(1.0)
    # clip w = -z_eye = distance along the view direction
    assert project(cam, 1.7, cam.eye + 3.0 * forward)[3] == pytest.approx(3.0)


def test_perspective_field_of_view_edges():
    cam = make_camera(eye=[0, 0, 0], look_at=[0, 0, -1], eye_close=[0, 0, 0], look_at_close=[0, 0, -1])
    aspect = 2.0
    half = math.radians(50.0) / 2.0
    z = 7.0
    top = [0.0, z * math.tan(half), -z]
    right = [aspect * z * math.tan(half), 0.0, -z]
    np.testing.assert_allclose(project(cam, aspect, top)[:2], [0, 1], atol=1e-12)
    np.testing.assert_allclose(project(cam, aspect, right)[:2], [1, 0], atol=1e-12)


def test_glfrustum_off_centre_window_edges_map_to_ndc_corners():
    l, r, b, t = -0.05, 0.03, -0.02, 0.04
    n, f = 0.1, 30.0
    cam = make_camera(frustum=(l, r, b, t), near=n, far=f)
    m = cam.projection_matrix(aspect=123.0)  # aspect is ignored with an explicit frustum
    np.testing.assert_allclose(eye_to_ndc(m, [l, b, -n]), [-1, -1, -1], atol=1e-12)
    np.testing.assert_allclose(eye_to_ndc(m, [r, t, -n]), [1, 1, -1], atol=1e-12)
    s = f / n  # the window scaled to the far plane
    np.testing.assert_allclose(eye_to_ndc(m, [l * s, t * s, -f]), [-1, 1, 1], atol=1e-9)
    np.testing.assert_allclose(eye_to_ndc(m, [r * s, b * s, -f]), [1, -1, 1], atol=1e-9)
    assert (m @ [0.3, 0.2, -4.0, 1.0])[3] == pytest.approx(4.0)


def test_orthographic_extents_and_depth():
    cam = make_camera(
        projection="orthographic", eye=[0, 0, 0], look_at=[0, 0, -1], eye_close=[0, 0, 0],
        look_at_close=[0, 0, -1], ortho_height=4.0, near=1.0, far=11.0,
    )
    m = cam.projection_matrix(aspect=1.5)
    np.testing.assert_allclose(eye_to_ndc(m, [3.0, 2.0, -1.0]), [1, 1, -1], atol=1e-12)
    np.testing.assert_allclose(eye_to_ndc(m, [-3.0, -2.0, -11.0]), [-1, -1, 1], atol=1e-12)
    np.testing.assert_allclose(m[3], [0, 0, 0, 1])
    boxed = make_camera(
        projection="orthographic", eye=[0, 0, 0], look_at=[0, 0, -1], eye_close=[0, 0, 0],
        look_at_close=[0, 0, -1], frustum=(-1.0, 3.0, 0.5, 2.5), near=1.0, far=11.0,
    )
    mb = boxed.projection_matrix(aspect=1.0)
    np.testing.assert_allclose(eye_to_ndc(mb, [-1.0, 0.5, -6.0]), [-1, -1, 0], atol=1e-12)
    np.testing.assert_allclose(eye_to_ndc(mb, [3.0, 2.5, -6.0]), [1, 1, 0], atol=1e-12)


def test_camera_motion_interpolates_eye_and_look_at():
    cam = make_camera(eye=[0, 0, 5], look_at=[0, 0, 0], eye_close=[2, 0, 5], look_at_close=[2, 0, 0])
    assert cam.moving
    for t, x in ((0.0, 0.0), (0.5, 1.0), (1.0, 2.0)):
        v = cam.view_matrix(t)
        np.testing.assert_allclose(v @ [x, 0, 5, 1], [0, 0, 0, 1], atol=1e-12)
        np.testing.assert_allclose(v @ [x, 0, 0, 1], [0, 0, -5, 1], atol=1e-12)
    assert not make_camera().moving


@settings(max_examples=60, deadline=None)
@given(
    eye=st.lists(st.floats(-50, 50), min_size=3, max_size=3),
    off=st.lists(st.floats(-10, 10), min_size=3, max_size=3),
    fov=st.floats(5.0, 170.0),
    aspect=st.floats(0.2, 5.0),
    u=st.floats(-0.99, 0.99),
    v=st.floats(-0.99, 0.99),
    depth=st.floats(0.0, 1.0),
)
def test_points_inside_frustum_map_inside_ndc_cube(eye, off, fov, aspect, u, v, depth):
    off = np.array(off)
    if np.linalg.norm(off) < 1e-3 or np.linalg.norm(np.cross(off / np.linalg.norm(off), [0, 1, 0])) < 1e-3:
        return
    look_at = np.add(eye, off)
    cam = make_camera(eye=eye, look_at=look_at, eye_close=eye, look_at_close=look_at, fov_y=fov, near=0.5, far=100.0)
    # Build the point from an independently derived camera basis.
    f = off / np.linalg.norm(off)
    s = np.cross(f, [0, 1, 0])
    s /= np.linalg.norm(s)
    up = np.cross(s, f)
    dist = 0.5 + depth * 99.5
    h = dist * math.tan(math.radians(fov) / 2.0)
    p = np.array(eye) + dist * f + u * h * aspect * s + v * h * up
    ndc = project(cam, aspect, p)
    np.testing.assert_allclose(ndc[:2], [u, v], atol=1e-7)
    assert -1.0 - 1e-9 <= ndc[2] <= 1.0 + 1e-9


# --------------------------------------------------------------------------
# Object transforms


def object_from(tmp_path: Path, body: str, index: int = 0):
    return load_text(tmp_path, MINIMAL + body).objects[index]


def test_rotate_y_90_maps_x_to_minus_z(tmp_path):
    obj = object_from(tmp_path, SPHERE + "[objects.open]\nrotate = [0.0, 90.0, 0.0]\n")
    m = obj.transform_open
    np.testing.assert_allclose(m[:3, :3] @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [0, 1, 0], atol=1e-12)


def test_rotation_axes_and_order(tmp_path):
    rx = object_from(tmp_path, SPHERE + "[objects.open]\nrotate = [90.0, 0.0, 0.0]\n").transform_open
    rz = object_from(tmp_path, SPHERE + "[objects.open]\nrotate = [0.0, 0.0, 90.0]\n").transform_open
    np.testing.assert_allclose(rx[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(rz[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # x first, then y: +y -> (x 90) +z -> (y 90) +x.  (y first would give +y.)
    rxy = object_from(tmp_path, SPHERE + "[objects.open]\nrotate = [90.0, 90.0, 0.0]\n").transform_open
    np.testing.assert_allclose(rxy[:3, :3] @ [0, 1, 0], [1, 0, 0], atol=1e-12)


def test_scale_then_rotate_then_translate(tmp_path):
    obj = object_from(
        tmp_path,
        SPHERE + "[objects.open]\nscale = [2.0, 1.0, 1.0]\nrotate = [0.0, 0.0, 90.0]\ntranslate = [0.0, 0.0, 5.0]\n",
    )
    np.testing.assert_allclose(obj.transform_open @ [1, 0, 0, 1], [0, 2, 5, 1], atol=1e-12)
    assert not obj.moving
    np.testing.assert_array_equal(obj.transform_open, obj.transform_close)


def test_close_defaults_per_key_to_open_and_linear_motion(tmp_path):
    obj = object_from(
        tmp_path,
        SPHERE
        + "[objects.open]\ntranslate = [1.0, 0.0, 0.0]\nscale = 2.0\n"
        + "[objects.close]\ntranslate = [3.0, 0.0, 0.0]\n",
    )
    assert obj.moving
    np.testing.assert_allclose(obj.transform_close[:3, :3], 2.0 * np.eye(3))
    p0, p1 = obj.world_positions(0), obj.world_positions(1)
    np.testing.assert_allclose(p0, 2.0 * obj.positions + [1, 0, 0])
    np.testing.assert_allclose(p1, 2.0 * obj.positions + [3, 0, 0])
    np.testing.assert_allclose(obj.world_positions(0.25), 0.75 * p0 + 0.25 * p1)


def test_world_normals_use_inverse_transpose(tmp_path):
    obj = object_from(tmp_path, SPHERE + "[objects.open]\nscale = [2.0, 1.0, 0.5]\nrotate = [0.0, 30.0, 0.0]\n")
    p = obj.positions  # unit sphere
    # Ellipsoid x^2/4 + y^2 + z^2/0.25 = 1: gradient (x/4, y, 4 z) at the scaled point (2x, y, z/2)
    # is (x/2, y, 2z); then rotate by the same rotation.
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    expected = np.stack([p[:, 0] / 2.0, p[:, 1], 2.0 * p[:, 2]], axis=1) @ ry.T
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(obj.world_normals(0), expected, atol=1e-9)


def test_arrays_are_read_only_and_replace(tmp_path):
    scene = load_text(tmp_path, MINIMAL + SPHERE)
    with pytest.raises(ValueError):
        scene.objects[0].positions[0, 0] = 1.0
    with pytest.raises(ValueError):
        scene.camera.eye[0] = 1.0
    import dataclasses

    bigger = scene.replace(image=dataclasses.replace(scene.image, spp=64))
    assert bigger.image.spp == 64 and scene.image.spp == 4
    assert bigger.objects is scene.objects and bigger.digest == scene.digest


# --------------------------------------------------------------------------
# Primitives


def signed_volume(p: np.ndarray, f: np.ndarray) -> float:
    a, b, c = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def face_normals(p: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def assert_closed_by_position(p: np.ndarray, f: np.ndarray) -> None:
    """Every directed edge (by vertex position) is matched by its reverse exactly once."""
    key = {tuple(np.round(x, 9)): i for i, x in enumerate(p)}
    ids = np.array([key[tuple(np.round(x, 9))] for x in p])
    edges = {}
    for tri in ids[f]:
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            edges[(a, b)] = edges.get((a, b), 0) + 1
    for (a, b), count in edges.items():
        assert count == 1 and edges.get((b, a)) == 1, (a, b)


CLOSED_PRIMITIVES = {
    "sphere": ("radius = 0.7\nsubdivisions = 3", 4.0 / 3.0 * math.pi * 0.7**3, 0.02),
    "box": ("size = [1.0, 2.0, 3.0]", 6.0, 1e-12),
    "torus": ("major_radius = 1.0\nminor_radius = 0.3\nmajor_sections = 64\nminor_sections = 32", 2 * math.pi**2 * 1.0 * 0.3**2, 0.012),
    "cylinder": ("radius = 0.5\nheight = 2.0\nsections = 48", math.pi * 0.25 * 2.0, 0.01),
}


@pytest.mark.parametrize("primitive", sorted(CLOSED_PRIMITIVES))
def test_closed_primitives_are_outward_and_watertight(tmp_path, primitive):
    params, volume, rel = CLOSED_PRIMITIVES[primitive]
    obj = object_from(tmp_path, f'[[objects]]\nprimitive = "{primitive}"\n{params}\n')
    p, f, n = obj.positions, obj.faces, obj.normals
    assert p.dtype == np.float64 and f.dtype == np.int32 and obj.colors.dtype == np.float32
    assert signed_volume(p, f) > 0
    assert signed_volume(p, f) == pytest.approx(volume, rel=rel)
    assert_closed_by_position(p, f)
    fn = face_normals(p, f)
    centres = p[f].mean(axis=1)
    if primitive == "torus":  # away from the nearest point of the tube's centre circle (ring in xz)
        radial = centres * [1, 0, 1]
        ring = radial / np.linalg.norm(radial, axis=1, keepdims=True) * 1.0
        away = centres - ring
    else:
        away = centres - p.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", fn, away) > 0)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    # vertex normals agree with the faces using them
    assert np.all(np.einsum("ij,ij->i", n[f].mean(axis=1), fn) > 0.5)


def test_primitive_defaults(tmp_path):
    objs = load_text(
        tmp_path,
        MINIMAL + "".join(f'[[objects]]\nprimitive = "{k}"\n' for k in ("sphere", "box", "plane", "torus", "cylinder")),
    ).objects
    sphere, box, plane, torus, cylinder = objs
    assert [o.name for o in objs] == [f"object{i}" for i in range(5)]
    assert len(sphere.faces) == 20 * 4**3
    np.testing.assert_allclose(np.linalg.norm(sphere.positions, axis=1), 1.0)
    np.testing.assert_allclose(box.positions.max(axis=0), [0.5, 0.5, 0.5])
    assert len(plane.faces) == 2
    assert len(torus.faces) == 2 * 32 * 16
    np.testing.assert_allclose(np.abs(torus.positions[:, 1]).max(), 0.25, rtol=1e-3)  # axis y
    np.testing.assert_allclose(np.hypot(torus.positions[:, 0], torus.positions[:, 2]).max(), 1.25, rtol=1e-6)
    np.testing.assert_allclose(cylinder.positions.min(axis=0)[1], -0.5)
    np.testing.assert_allclose(cylinder.positions.max(axis=0)[1], 0.5)
    np.testing.assert_allclose(np.hypot(cylinder.positions[:, 0], cylinder.positions[:, 2]).max(), 0.5)
    assert sphere.material == "lambert"
    np.testing.assert_allclose(sphere.colors, np.full((len(sphere.positions), 3), 0.8), rtol=1e-6)


@pytest.mark.parametrize("n", [0, 1, 4])
def test_plane_grid_faces_up(tmp_path, n):
    obj = object_from(tmp_path, f'[[objects]]\nprimitive = "plane"\nsize = [2.0, 3.0]\nsubdivisions = {n}\n')
    p, f = obj.positions, obj.faces
    assert len(f) == 2 * (n + 1) ** 2
    assert len(p) == (n + 2) ** 2
    np.testing.assert_allclose(face_normals(p, f), np.tile([0, 1, 0], (len(f), 1)), atol=1e-12)
    np.testing.assert_allclose(obj.normals, np.tile([0, 1, 0], (len(p), 1)))
    np.testing.assert_allclose(p.min(axis=0), [-1, 0, -1.5])
    np.testing.assert_allclose(p.max(axis=0), [1, 0, 1.5])
    areas = np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1) / 2
    assert areas.sum() == pytest.approx(6.0)


# --------------------------------------------------------------------------
# Example scenes


@pytest.mark.parametrize("name", EXAMPLE_SCENES)
def test_example_scene_loads(name):
    scene = load_scene(SCENES / f"{name}.toml")
    assert scene.path == SCENES / f"{name}.toml"
    assert len(scene.digest) == 64
    assert (scene.image.width, scene.image.height, scene.image.spp) == (320, 180, 16)
    assert 0 < scene.triangle_count < 10_000
    for obj in scene.objects:
        for t in (0, 1):
            assert np.all(np.isfinite(obj.world_positions(t)))
            assert np.all(np.isfinite(obj.world_normals(t)))
    aspect = scene.image.aspect
    # every object's centre is in front of the camera and inside the frustum at t=0
    for obj in scene.objects:
        if obj.name in ("ground",):
            continue
        centre = obj.world_positions(0).mean(axis=0)
        ndc = project(scene.camera, aspect, centre)
        assert ndc[3] > 0 and np.all(np.abs(ndc[:3]) < 1.0), (name, obj.name, ndc)


def test_example_scenes_use_the_intended_features():
    s = {n: load_scene(SCENES / f"{n}.toml") for n in EXAMPLE_SCENES}
    features = {n: (sc.moving, sc.has_lens, sc.camera.moving) for n, sc in s.items()}
    assert features["default"] == (True, True, False)
    assert features["static"] == (False, False, False)
    assert features["motion"] == (True, False, False)
    assert features["defocus"] == (False, True, False)
    assert features["camera_motion"] == (True, False, True)
    assert not any(o.moving for o in s["camera_motion"].objects)
    assert s["ortho"].camera.projection == "orthographic"
    l, r, b, t = s["offcentre"].camera.frustum
    assert l + r != 0 and b + t != 0
    assert s["meshes"].triangle_count > 0

    default = s["default"]
    assert 2000 <= default.triangle_count <= 5000
    by_name = {o.name: o for o in default.objects}
    assert set(by_name) >= {"ground", "sphere", "torus", "box", "cylinder"}
    cam = default.camera
    forward = (cam.look_at - cam.eye) / np.linalg.norm(cam.look_at - cam.eye)

    def depth(o):
        return float((o.world_positions(0).mean(axis=0) - cam.eye) @ forward)

    # the sphere is in focus; the torus is in front and moves; the box is behind and moves
    assert depth(by_name["sphere"]) == pytest.approx(cam.lens.focus_distance, rel=0.01)
    assert depth(by_name["torus"]) < depth(by_name["sphere"]) < depth(by_name["box"])
    assert by_name["torus"].moving and by_name["box"].moving and not by_name["sphere"].moving
    # circle of confusion (pixels) of the foreground torus and the background box
    px_per_unit_at_focus = default.image.height / (2 * cam.lens.focus_distance * math.tan(math.radians(cam.fov_y) / 2))
    for name in ("torus", "box"):
        z = depth(by_name[name])
        coc = 2 * cam.lens.radius * abs(z - cam.lens.focus_distance) / z * px_per_unit_at_focus
        assert coc > 3.0, (name, coc)


def test_digest_covers_scene_and_mesh_bytes(tmp_path):
    scenes = tmp_path / "scenes"
    meshes = tmp_path / "meshes"
    shutil.copytree(SCENES, scenes)
    shutil.copytree(MESHES, meshes)
    original = load_scene(SCENES / "meshes.toml").digest
    assert load_scene(scenes / "meshes.toml").digest == original  # location independent
    stl = meshes / "cylinder.stl"
    data = bytearray(stl.read_bytes())
    data[0] ^= 0xFF  # the 80-byte STL header; geometry unchanged
    stl.write_bytes(bytes(data))
    assert load_scene(scenes / "meshes.toml").digest != original
    assert load_scene(scenes / "static.toml").digest != load_scene(scenes / "motion.toml").digest


def test_parse_scene_from_dict():
    import tomllib

    data = tomllib.loads(MINIMAL + SPHERE)
    scene = parse_scene(data)
    assert scene.path is None and len(scene.digest) == 64
    assert len(scene.objects) == 1
    data["camera"]["fov"] = 1.0
    with pytest.raises(UserError, match=r"^<scene>: \[camera\]: unknown key 'fov'"):
        parse_scene(data)


def test_defaults(tmp_path):
    scene = load_text(tmp_path, MINIMAL)
    assert scene.image.seed == 0
    assert scene.objects == ()
    np.testing.assert_array_equal(scene.background, [0, 0, 0])
    assert scene.background.dtype == np.float32
    cam = scene.camera
    assert cam.projection == "perspective" and cam.lens is None and cam.frustum is None
    np.testing.assert_array_equal(cam.up, [0, 1, 0])
    np.testing.assert_array_equal(cam.eye_close, cam.eye)
    assert scene.light.kind == "directional"
    assert np.linalg.norm(scene.light.direction) == pytest.approx(1.0)
    assert scene.light.direction[1] < 0  # shining downwards


def test_light_and_lens_parsing(tmp_path):
    scene = load_text(
        tmp_path,
        MINIMAL
        + "[camera.lens]\nradius = 0.1\n"
        + '[light]\ntype = "point"\nposition = [1.0, 2.0, 3.0]\nintensity = 2.0\nambient = 0.0\n',
    )
    assert scene.camera.lens == Lens(radius=0.1, focus_distance=pytest.approx(5.0))
    assert scene.light.kind == "point"
    np.testing.assert_array_equal(scene.light.position, [1, 2, 3])
    directional = load_text(tmp_path, MINIMAL + "[light]\ndirection = [0.0, -2.0, 0.0]\n").light
    np.testing.assert_allclose(directional.direction, [0, -1, 0])


def test_frustum_overrides_fov_y(tmp_path):
    cam = load_text(tmp_path, MINIMAL + "frustum = [-0.5, 0.5, -0.1, 0.4]\n").camera
    assert cam.frustum == (-0.5, 0.5, -0.1, 0.4)
    # near = 0.5: vertical angle atan(0.4/0.5) + atan(0.1/0.5)
    assert cam.fov_y == pytest.approx(math.degrees(math.atan(0.8) + math.atan(0.2)))


# --------------------------------------------------------------------------
# Mesh files


def mesh_scene(tmp_path: Path, mesh: str, extra: str = "") -> Scene:
    return load_text(tmp_path, MINIMAL + f'[[objects]]\nmesh = "{mesh}"\n{extra}')


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    v, vn = [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if parts and parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts and parts[0] == "vn":
            vn.append([float(x) for x in parts[1:4]])
    return np.array(v), np.array(vn)


def test_obj_mesh_uses_file_normals(tmp_path):
    obj = mesh_scene(tmp_path, str(MESHES / "icosphere.obj")).objects[0]
    v, vn = read_obj(MESHES / "icosphere.obj")
    assert len(obj.positions) == len(v)
    # match loaded vertices to file vertices by position and compare normals
    for p, n in zip(obj.positions, obj.normals):
        i = int(np.argmin(np.linalg.norm(v - p, axis=1)))
        np.testing.assert_allclose(p, v[i], atol=1e-6)
        np.testing.assert_allclose(n, vn[i] / np.linalg.norm(vn[i]), atol=1e-5)
    assert signed_volume(obj.positions, obj.faces) > 0


def test_obj_normals_from_file_are_kept_even_when_not_geometric(tmp_path):
    (tmp_path / "tri.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 2 0\nvn 1 0 0\nvn 0 0 1\nf 1//1 2//2 3//3\n"
    )
    obj = mesh_scene(tmp_path, "tri.obj").objects[0]
    by_pos = {tuple(p): n for p, n in zip(obj.positions, obj.normals)}
    np.testing.assert_allclose(by_pos[(0.0, 0.0, 0.0)], [0, 1, 0])
    np.testing.assert_allclose(by_pos[(1.0, 0.0, 0.0)], [1, 0, 0])
    np.testing.assert_allclose(by_pos[(0.0, 1.0, 0.0)], [0, 0, 1])
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    flat = mesh_scene(tmp_path, "flat.obj").objects[0]
    np.testing.assert_allclose(flat.normals, np.tile([0, 0, 1], (3, 1)), atol=1e-12)  # computed


def read_binary_ply_vertices(path: Path) -> tuple[np.ndarray, np.ndarray]:
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    assert "format binary_little_endian 1.0" in header
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    props = []
    for line in header[header.index(next(h for h in header if h.startswith("element vertex"))) + 1 :]:
        if not line.startswith("property"):
            break
        props.append(tuple(line.split()[1:]))
    assert props == [("float", "x"), ("float", "y"), ("float", "z"), ("uchar", "red"),
                     ("uchar", "green"), ("uchar", "blue"), ("uchar", "alpha")]
    rows = [struct.unpack_from("<fffBBBB", data, end + 16 * i) for i in range(count)]
    arr = np.array(rows, dtype=np.float64)
    return arr[:, :3], arr[:, 3:6] / 255.0


def test_ply_mesh_vertex_colors(tmp_path):
    path = MESHES / "torus_colors.ply"
    obj = mesh_scene(tmp_path, str(path), "use_vertex_colors = true\n").objects[0]
    v, rgb = read_binary_ply_vertices(path)
    assert len(obj.positions) == len(v)
    assert np.unique(np.round(rgb, 3), axis=0).shape[0] > 10  # genuinely per-vertex colours
    for p, c in zip(obj.positions, obj.colors):
        i = int(np.argmin(np.linalg.norm(v - p, axis=1)))
        np.testing.assert_allclose(c, rgb[i], atol=1e-6)
    plain = mesh_scene(tmp_path, str(path), "color = [0.1, 0.2, 0.3]\n").objects[0]
    np.testing.assert_allclose(plain.colors, np.tile([0.1, 0.2, 0.3], (len(plain.positions), 1)), rtol=1e-6)
    assert signed_volume(obj.positions, obj.faces) > 0


def test_stl_mesh_smooth_normals(tmp_path):
    path = MESHES / "cylinder.stl"
    obj = mesh_scene(tmp_path, str(path)).objects[0]
    data = path.read_bytes()
    (n_tris,) = struct.unpack_from("<I", data, 80)
    assert len(obj.faces) == n_tris
    raw = np.array([struct.unpack_from("<12f", data, 84 + 50 * i)[3:] for i in range(n_tris)]).reshape(-1, 3)
    unique = np.unique(np.round(raw, 6), axis=0)
    assert len(obj.positions) == len(unique)  # shared vertices merged
    np.testing.assert_allclose(np.linalg.norm(obj.normals, axis=1), 1.0)
    # smooth normals point away from the axis (z) on the side; cap-edge vertices lean outward too
    radial = obj.positions * [1, 1, 0]
    on_rim = np.linalg.norm(radial, axis=1) > 0.3
    assert np.all(np.einsum("ij,ij->i", obj.normals[on_rim], radial[on_rim]) > 0)
    assert signed_volume(obj.positions, obj.faces) > 0


def test_glb_scene_flattened_with_node_transforms(tmp_path):
    import pygltflib

    path = MESHES / "cone_capsule.glb"
    obj = mesh_scene(tmp_path, str(path)).objects[0]
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    expected = []
    for node in gltf.nodes:
        if node.mesh is None:
            continue
        m = np.eye(4)
        if node.matrix:
            m = np.array(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major
        else:
            assert not node.rotation or node.rotation == [0, 0, 0, 1]
            if node.translation:
                m[:3, 3] = node.translation
        assert not np.allclose(m, np.eye(4))  # the file really has node transforms
        for prim in gltf.meshes[node.mesh].primitives:
            acc = gltf.accessors[prim.attributes.POSITION]
            view = gltf.bufferViews[acc.bufferView]
            start = (view.byteOffset or 0) + (acc.byteOffset or 0)
            pts = np.frombuffer(blob, dtype="<f4", count=acc.count * 3, offset=start).reshape(-1, 3)
            expected.append(pts.astype(np.float64) @ m[:3, :3].T + m[:3, 3])
    expected = np.concatenate(expected)
    np.testing.assert_allclose(obj.positions.min(axis=0), expected.min(axis=0), atol=1e-5)
    np.testing.assert_allclose(obj.positions.max(axis=0), expected.max(axis=0), atol=1e-5)
    assert signed_volume(obj.positions, obj.faces) > 0


def test_meshes_scene_has_one_object_per_format():
    scene = load_scene(SCENES / "meshes.toml")
    names = {o.name for o in scene.objects}
    assert {"obj_sphere", "ply_torus", "stl_cylinder", "glb_cone_capsule"} <= names
    ply = next(o for o in scene.objects if o.name == "ply_torus")
    assert np.ptp(ply.colors, axis=0).max() > 0.2  # vertex colours used


def test_mesh_loaded_once_per_file(tmp_path):
    mesh = str(MESHES / "icosphere.obj")
    scene = load_text(tmp_path, MINIMAL + f'[[objects]]\nmesh = "{mesh}"\n[[objects]]\nmesh = "{mesh}"\n')
    a, b = scene.objects
    assert a.positions is b.positions or np.array_equal(a.positions, b.positions)


# --------------------------------------------------------------------------
# Errors: each must be a single line naming the file and the key


ERROR_CASES = {
    # malformed TOML
    "toml_syntax": (MINIMAL.replace("spp = 4", "spp = = 4"), ["line 5, column", "invalid TOML"]),
    "toml_unclosed": (MINIMAL + "x = [1, 2", ["invalid TOML", "line"]),
    # unknown keys at every level
    "unknown_key_newline": (MINIMAL + '"we\\nird" = 1\n', ["unknown key 'we\\nird'"]),
    "unknown_top": (MINIMAL + "[imagee]\nwidth = 1\n", ["unknown key 'imagee'", "did you mean 'image'"]),
    "unknown_image": (MINIMAL.replace("spp = 4", "spp = 4\nsamples = 3"), ["[image]: unknown key 'samples'"]),
    "unknown_camera": (MINIMAL.replace("fov_y = 60.0", "fov = 60.0"), ["[camera]: unknown key 'fov'", "did you mean 'fov_y'"]),
    "unknown_lens": (MINIMAL + "[camera.lens]\nradius = 0.1\nfocus = 2.0\n", ["[camera.lens]: unknown key 'focus'", "focus_distance"]),
    "unknown_background": (MINIMAL + "[background]\ncolour = [0, 0, 0]\n", ["[background]: unknown key 'colour'", "did you mean 'color'"]),
    "unknown_light": (MINIMAL + "[light]\nintensty = 1.0\n", ["[light]: unknown key 'intensty'", "did you mean 'intensity'"]),
    "unknown_object": (MINIMAL + SPHERE + "colr = [1, 0, 0]\n", ["[objects[0]]: unknown key 'colr'", "did you mean 'color'"]),
    "unknown_transform": (MINIMAL + SPHERE + "[objects.open]\ntranslation = [0, 0, 0]\n", ["[objects[0].open]: unknown key 'translation'", "did you mean 'translate'"]),
    "unknown_close": (MINIMAL + SPHERE + "[objects.close]\nrotation = [0, 0, 0]\n", ["[objects[0].close]: unknown key 'rotation'", "did you mean 'rotate'"]),
    "primitive_param_typo": (MINIMAL + SPHERE + "radus = 2.0\n", ["[objects[0]]: unknown key 'radus'", "did you mean 'radius'"]),
    "param_of_other_primitive": (MINIMAL + SPHERE + "size = 2.0\n", ["[objects[0]]: unknown key 'size'", "box, plane", "sphere takes: radius, subdivisions"]),
    "mesh_with_param": (MINIMAL + f'[[objects]]\nmesh = "{MESHES / "icosphere.obj"}"\nradius = 1.0\n', ["[objects[0]]: unknown key 'radius'", "a mesh object takes none"]),
    # wrong types
    "width_string": (MINIMAL.replace("width = 64", 'width = "64"'), ["image.width: expected an integer, got '64'"]),
    "width_float": (MINIMAL.replace("width = 64", "width = 64.0"), ["image.width: expected an integer, got 64.0"]),
    "eye_string": (MINIMAL.replace("eye = [0.0, 0.0, 5.0]", 'eye = "here"'), ["camera.eye: expected 3 numbers"]),
    "eye_two": (MINIMAL.replace("eye = [0.0, 0.0, 5.0]", "eye = [0.0, 5.0]"), ["camera.eye: expected 3 numbers, got 2"]),
    "eye_element_bool": (MINIMAL.replace("eye = [0.0, 0.0, 5.0]", "eye = [0.0, true, 5.0]"), ["camera.eye[1]: expected a number, got true"]),
    "rotate_two": (
        MINIMAL + SPHERE + SPHERE + '[[objects]]\nprimitive = "box"\n[objects.open]\nrotate = [0.0, 0.0]\n',
        ["scene.toml: objects[2].open.rotate: expected 3 numbers, got 2"],
    ),
    "camera_not_table": ("camera = 5\n" + MINIMAL.split("[camera]")[0], ["[camera] must be a table, got 5"]),
    "objects_table": (MINIMAL + "[objects]\nprimitive = 'sphere'\n", ["objects: expected an array of tables"]),
    "scale_string": (MINIMAL + SPHERE + "[objects.open]\nscale = 'big'\n", ["objects[0].open.scale: expected a number or 3 numbers"]),
    "bool_type": (MINIMAL + SPHERE + "use_vertex_colors = 1\n", ["objects[0].use_vertex_colors: expected true or false"]),
    "material_type": (MINIMAL + SPHERE + "material = 3\n", ["objects[0].material: 3 is not one of flat, lambert"]),
    "subdivisions_float": (MINIMAL + SPHERE + "subdivisions = 2.5\n", ["objects[0].subdivisions: expected an integer"]),
    "name_type": (MINIMAL + SPHERE + "name = 3\n", ["objects[0].name: expected a string"]),
    # missing required keys
    "missing_image_table": ("\n".join(MINIMAL.splitlines()[6:]), ["image: missing required table [image]"]),
    "missing_camera": (MINIMAL.split("[camera]")[0], ["camera: missing required table [camera]"]),
    "missing_width": (MINIMAL.replace("width = 64\n", ""), ["image.width: missing required key"]),
    "missing_eye": (MINIMAL.replace("eye = [0.0, 0.0, 5.0]\n", ""), ["camera.eye: missing required key"]),
    "missing_look_at": (MINIMAL.replace("look_at = [0.0, 0.0, 0.0]\n", ""), ["camera.look_at: missing required key"]),
    "missing_near": (MINIMAL.replace("near = 0.5\n", ""), ["camera.near: missing required key"]),
    "missing_far": (MINIMAL.replace("far = 20.0\n", ""), ["camera.far: missing required key"]),
    "missing_fov": (MINIMAL.replace("fov_y = 60.0\n", ""), ["camera.fov_y: missing required key"]),
    "missing_shape": (MINIMAL + "[[objects]]\ncolor = [1, 1, 1]\n", ["objects[0]: missing required key 'primitive'", "'mesh'"]),
    "both_shapes": (MINIMAL + f'[[objects]]\nprimitive = "box"\nmesh = "{MESHES / "icosphere.obj"}"\n', ["objects[0]: give either 'primitive' or 'mesh'"]),
    "point_light_no_position": (MINIMAL + '[light]\ntype = "point"\n', ["light.position: missing required key"]),
    "missing_lens_radius": (MINIMAL + "[camera.lens]\nfocus_distance = 2.0\n", ["camera.lens.radius: missing required key"]),
    # missing / bad mesh files
    "missing_mesh": (MINIMAL + '[[objects]]\nmesh = "nothere/x.obj"\n', ["objects[0].mesh: mesh file not found: 'nothere/x.obj'", "resolved to", "nothere/x.obj'"]),
    "mesh_format": (MINIMAL + f'[[objects]]\nmesh = "{ROOT / "pipeline_sim" / "errors.py"}"\n', ["objects[0].mesh: unsupported mesh format '.py'"]),
    "mesh_is_dir": (MINIMAL + f'[[objects]]\nmesh = "{MESHES}"\n', ["objects[0].mesh: mesh path is not a file"]),
    # non-finite numbers
    "nan_eye": (MINIMAL.replace("eye = [0.0, 0.0, 5.0]", "eye = [nan, 0.0, 5.0]"), ["camera.eye[0]: expected a finite number, got nan"]),
    "inf_near": (MINIMAL.replace("near = 0.5", "near = inf"), ["camera.near: expected a finite number, got inf"]),
    "nan_color": (MINIMAL + SPHERE + "color = [0.5, nan, 0.5]\n", ["objects[0].color[1]: expected a finite number"]),
    "inf_translate": (MINIMAL + SPHERE + "[objects.open]\ntranslate = [0, -inf, 0]\n", ["objects[0].open.translate[1]: expected a finite number, got -inf"]),
    "nan_radius": (MINIMAL + SPHERE + "radius = nan\n", ["objects[0].radius: expected a finite number"]),
    "nan_light": (MINIMAL + "[light]\nintensity = nan\n", ["light.intensity: expected a finite number"]),
    "nan_fov": (MINIMAL.replace("fov_y = 60.0", "fov_y = nan"), ["camera.fov_y: expected a finite number"]),
    # non-positive image settings
    "width_zero": (MINIMAL.replace("width = 64", "width = 0"), ["image.width: must be from 1 to 16384, got 0"]),
    "height_negative": (MINIMAL.replace("height = 32", "height = -3"), ["image.height: must be from 1 to 16384, got -3"]),
    "spp_zero": (MINIMAL.replace("spp = 4", "spp = 0"), ["image.spp: must be from 1 to 16384, got 0"]),
    "seed_negative": (MINIMAL.replace("spp = 4", "spp = 4\nseed = -1"), ["image.seed: must be from 0 to"]),
    # clip planes and field of view
    "near_zero": (MINIMAL.replace("near = 0.5", "near = 0.0"), ["camera.near: must be > 0"]),
    "near_negative": (MINIMAL.replace("near = 0.5", "near = -1.0"), ["camera.near: must be > 0"]),
    "far_equal": (MINIMAL.replace("far = 20.0", "far = 0.5"), ["camera.far: must be > near"]),
    "far_less": (MINIMAL.replace("far = 20.0", "far = 0.1"), ["camera.far: must be > near"]),
    "fov_zero": (MINIMAL.replace("fov_y = 60.0", "fov_y = 0.0"), ["camera.fov_y: must be in (0, 180)"]),
    "fov_180": (MINIMAL.replace("fov_y = 60.0", "fov_y = 180"), ["camera.fov_y: must be in (0, 180)"]),
    "fov_negative": (MINIMAL.replace("fov_y = 60.0", "fov_y = -10.0"), ["camera.fov_y: must be in (0, 180)"]),
    "frustum_lr": (MINIMAL + "frustum = [0.1, -0.1, -0.1, 0.1]\n", ["camera.frustum: left must be < right"]),
    "frustum_bt": (MINIMAL + "frustum = [-0.1, 0.1, 0.1, 0.1]\n", ["camera.frustum: bottom must be < top"]),
    "frustum_three": (MINIMAL + "frustum = [-0.1, 0.1, 0.1]\n", ["camera.frustum: expected 4 numbers, got 3"]),
    "projection_unknown": (MINIMAL + 'projection = "orthogonal"\n', ["camera.projection: 'orthogonal' is not one of perspective, orthographic", "did you mean 'orthographic'"]),
    # lens
    "lens_negative": (MINIMAL + "[camera.lens]\nradius = -0.1\n", ["camera.lens.radius: must be >= 0"]),
    "focus_zero": (MINIMAL + "[camera.lens]\nradius = 0.1\nfocus_distance = 0.0\n", ["camera.lens.focus_distance: must be > 0"]),
    "focus_negative": (MINIMAL + "[camera.lens]\nradius = 0.1\nfocus_distance = -2.0\n", ["camera.lens.focus_distance: must be > 0"]),
    "lens_ortho": (
        MINIMAL.replace("fov_y = 60.0\n", 'projection = "orthographic"\n') + "[camera.lens]\nradius = 0.1\n",
        ["camera.lens: a thin lens needs a perspective camera"],
    ),
    "fov_on_ortho": (MINIMAL + 'projection = "orthographic"\n', ["camera.fov_y: applies only to perspective"]),
    "ortho_height_on_perspective": (MINIMAL + "ortho_height = 3.0\n", ["camera.ortho_height: applies only to orthographic"]),
    "ortho_height_zero": (MINIMAL.replace("fov_y = 60.0\n", 'projection = "orthographic"\northo_height = 0.0\n'), ["camera.ortho_height: must be > 0"]),
    # degenerate camera
    "eye_is_look_at": (MINIMAL.replace("look_at = [0.0, 0.0, 0.0]", "look_at = [0.0, 0.0, 5.0]"), ["camera: degenerate view: look_at equals eye"]),
    "up_parallel": (MINIMAL + "up = [0.0, 0.0, -3.0]\n", ["camera.up: up [0, 0, -3] is parallel to the view direction"]),
    "up_zero": (MINIMAL + "up = [0.0, 0.0, 0.0]\n", ["camera.up: must not be the zero vector"]),
    "close_degenerate": (MINIMAL + "eye_close = [1.0, 1.0, 1.0]\nlook_at_close = [1.0, 1.0, 1.0]\n", ["camera: degenerate view: look_at equals eye at shutter close"]),
    "close_up_parallel": (MINIMAL + "eye_close = [0.0, 5.0, 0.0]\n", ["camera.up: ", "parallel to the view direction", "at shutter close"]),
    "motion_through_eye": (MINIMAL + "eye_close = [0.0, 0.0, -5.0]\nlook_at_close = [0.0, 0.0, 0.0]\n", ["camera: degenerate view: eye and look_at coincide during the shutter"]),
    "motion_up_parallel": (
        MINIMAL.replace("eye = [0.0, 0.0, 5.0]", "eye = [0.0, -1.0, 5.0]") + "eye_close = [0.0, -1.0, -5.0]\nlook_at_close = [0.0, 0.0, 0.0]\n",
        ["camera"],
    ),
    # unknown types
    "primitive_unknown": (MINIMAL + '[[objects]]\nprimitive = "sphre"\n', ["objects[0].primitive: 'sphre' is not one of sphere, box, plane, torus, cylinder", "did you mean 'sphere'"]),
    "material_unknown": (MINIMAL + SPHERE + 'material = "phong"\n', ["objects[0].material: 'phong' is not one of flat, lambert"]),
    "light_unknown": (MINIMAL + '[light]\ntype = "spot"\n', ["light.type: 'spot' is not one of directional, point"]),
    "light_direction_on_point": (MINIMAL + '[light]\ntype = "point"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\n', ["light.direction: applies only to directional"]),
    "light_zero_direction": (MINIMAL + "[light]\ndirection = [0, 0, 0]\n", ["light.direction: must not be the zero vector"]),
    "light_negative_ambient": (MINIMAL + "[light]\nambient = -0.5\n", ["light.ambient: must be from 0 to 1e+08, got -0.5"]),
    "negative_color": (MINIMAL + "[background]\ncolor = [0, -1, 0]\n", ["background.color[1]: must be from 0 to 1e+08, got -1"]),
    # primitive parameters and transforms
    "radius_zero": (MINIMAL + SPHERE + "radius = 0.0\n", ["objects[0].radius: must be > 0"]),
    "box_size_negative": (MINIMAL + '[[objects]]\nprimitive = "box"\nsize = [1, -1, 1]\n', ["objects[0].size: must be > 0"]),
    "plane_size_three": (MINIMAL + '[[objects]]\nprimitive = "plane"\nsize = [1, 1, 1]\n', ["objects[0].size: expected 2 numbers, got 3"]),
    "sphere_subdivisions_big": (MINIMAL + SPHERE + "subdivisions = 12\n", ["objects[0].subdivisions: must be from 0 to 7, got 12"]),
    "torus_fat": (MINIMAL + '[[objects]]\nprimitive = "torus"\nmajor_radius = 0.5\nminor_radius = 0.5\n', ["objects[0].minor_radius: must be < major_radius"]),
    "cylinder_sections": (MINIMAL + '[[objects]]\nprimitive = "cylinder"\nsections = 2\n', ["objects[0].sections: must be from 3 to 65536, got 2"]),
    "scale_zero": (MINIMAL + SPHERE + "[objects.open]\nscale = 0.0\n", ["objects[0].open.scale: must be > 0"]),
    "scale_mirror": (MINIMAL + SPHERE + "[objects.close]\nscale = [1, -1, 1]\n", ["objects[0].close.scale: must be > 0"]),
    "duplicate_names": (MINIMAL + SPHERE + 'name = "a"\n' + SPHERE + 'name = "a"\n', ["objects[1].name: duplicate name 'a'"]),
}


def check_error(exc: UserError, expected: list[str], filename: str = "scene.toml") -> None:
    message = str(exc)
    assert "\n" not in message and "\r" not in message, message
    assert filename in message, message
    for part in expected:
        assert part in message, f"{part!r} not in {message!r}"


@pytest.mark.parametrize("case", sorted(ERROR_CASES))
def test_error_messages(tmp_path, case):
    text, expected = ERROR_CASES[case]
    path = tmp_path / "scene.toml"
    path.write_text(text)
    with pytest.raises(UserError) as info:
        load_scene(path)
    check_error(info.value, expected)


def write_bad_mesh(tmp_path: Path, name: str, content: bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(content)
    return path


BAD_MESHES = {
    "nan.obj": (b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "non-finite vertex coordinates"),
    "inf.obj": (b"v 0 0 0\nv 1 inf 0\nv 0 1 0\nf 1 2 3\n", "non-finite vertex coordinates"),
    "points.obj": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "mesh file has no triangles"),
    "empty.obj": (b"", "mesh file has no triangles"),
    "empty.stl": (b"solid x\nendsolid x\n", "mesh file has no triangles"),
    "garbage.glb": (b"\x00\x01not a glb file at all" * 10, "not a valid GLB file"),
    "badindex.obj": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "not a valid OBJ file"),
}


@pytest.mark.parametrize("name", sorted(BAD_MESHES))
def test_bad_mesh_files(tmp_path, name):
    content, expected = BAD_MESHES[name]
    write_bad_mesh(tmp_path, name, content)
    path = write_scene(tmp_path, MINIMAL + f'[[objects]]\nmesh = "{name}"\n')
    with pytest.raises(UserError) as info:
        load_scene(path)
    check_error(info.value, ["objects[0].mesh: ", expected, f"'{name}'", str(tmp_path / name)])


def test_nan_in_ply_vertices(tmp_path):
    header = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = struct.pack("<9f", 0, 0, 0, 1, float("nan"), 0, 0, 1, 0) + struct.pack("<B3i", 3, 0, 1, 2)
    write_bad_mesh(tmp_path, "nan.ply", header + body)
    path = write_scene(tmp_path, MINIMAL + '[[objects]]\nmesh = "nan.ply"\n')
    with pytest.raises(UserError) as info:
        load_scene(path)
    check_error(info.value, ["objects[0].mesh", "non-finite"])


def test_missing_mesh_reports_written_and_resolved_path(tmp_path):
    (tmp_path / "sub").mkdir()
    path = write_scene(tmp_path / "sub", MINIMAL + '[[objects]]\nmesh = "../meshes/gone.ply"\n')
    with pytest.raises(UserError) as info:
        load_scene(path)
    check_error(info.value, ["'../meshes/gone.ply'", str(tmp_path / "meshes" / "gone.ply")])


def test_scene_file_problems(tmp_path):
    with pytest.raises(UserError) as info:
        load_scene(tmp_path / "absent.toml")
    check_error(info.value, ["scene file not found"], "absent.toml")
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(b"# caf\xe9\n")
    with pytest.raises(UserError) as info:
        load_scene(bad)
    check_error(info.value, ["UTF-8"], "latin1.toml")
    with pytest.raises(UserError) as info:
        load_scene(tmp_path)
    assert "\n" not in str(info.value)


def test_toml_error_reports_line_and_column(tmp_path):
    path = write_scene(tmp_path, "[image]\nwidth = 3\nheight = ]\n")
    with pytest.raises(UserError) as info:
        load_scene(path)
    check_error(info.value, ["scene.toml: line 3, column 10: invalid TOML"])


def test_glb_mirroring_node_transform_keeps_triangles_outward(tmp_path):
    import trimesh

    scene = trimesh.Scene()
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = [5.0, 0.0, 0.0]
    scene.add_geometry(trimesh.creation.box(extents=[1.0, 2.0, 3.0]), node_name="m", transform=mirror)
    (tmp_path / "mirror.glb").write_bytes(scene.export(file_type="glb"))
    obj = mesh_scene(tmp_path, "mirror.glb").objects[0]
    assert signed_volume(obj.positions, obj.faces) == pytest.approx(6.0)
    np.testing.assert_allclose(obj.positions.mean(axis=0), [5.0, 0.0, 0.0], atol=1e-6)
    fn = face_normals(obj.positions, obj.faces)
    away = obj.positions[obj.faces].mean(axis=1) - [5.0, 0.0, 0.0]
    assert np.all(np.einsum("ij,ij->i", fn, away) > 0)


def test_unreferenced_vertices_dropped_and_normals_stay_aligned(tmp_path):
    (tmp_path / "extra.obj").write_text(
        "v 9 9 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 1 0 0\nvn 0 1 0\nvn 0 0 1\nvn 0 0 -1\n"
        "f 2//2 3//3 4//4\n"
    )
    obj = mesh_scene(tmp_path, "extra.obj").objects[0]
    assert len(obj.positions) == 3
    by_pos = {tuple(p): tuple(n) for p, n in zip(obj.positions, obj.normals)}
    assert by_pos == {(0.0, 0.0, 0.0): (0.0, 1.0, 0.0), (1.0, 0.0, 0.0): (0.0, 0.0, 1.0), (0.0, 1.0, 0.0): (0.0, 0.0, -1.0)}


def test_documented_example_loads(tmp_path):
    import pipeline_sim.scene as scene_module

    doc = scene_module.__doc__
    block = doc.split(".. code-block:: toml", 1)[1].split("\nExactly one of", 1)[0]
    text = textwrap.dedent(block.strip("\n"))
    scene = load_text(tmp_path, text)
    assert scene.has_lens and scene.moving
    assert scene.objects[0].name == "ball"
    np.testing.assert_allclose(scene.objects[0].transform_close[:3, 3], [0.6, 0.5, 0.0])


def test_a_number_beyond_any_float_and_a_subnormal_light_direction(tmp_path):
    """A 400-digit integer is one line naming the key (float() overflowed, a traceback); a light direction of
    subnormal components is a direction like any other (scaling it by a power of two overflowed)."""
    from scenes import moving_sphere, scene_toml

    path = tmp_path / "s.toml"
    path.write_text(scene_toml(moving_sphere().replace("radius = 0.7", "radius = 1" + "0" * 400)))
    with pytest.raises(UserError, match=r"radius.*401 digits") as info:
        load_scene(path)
    assert "\n" not in str(info.value)
    path.write_text(scene_toml(moving_sphere()) + "[light]\ndirection = [1e-320, -1e-320, 0.0]\n")
    direction = load_scene(path).light.direction
    np.testing.assert_allclose(direction, [2**-0.5, -(2**-0.5), 0.0], rtol=1e-12)


def test_a_scene_path_that_is_a_fifo_is_refused_not_read_forever(tmp_path):
    import os

    fifo = tmp_path / "scene.toml"
    os.mkfifo(fifo)
    with pytest.raises(UserError, match="not a regular file"):
        load_scene(fifo)   # reading a FIFO with no writer would block
