"""Every value that reaches a buffer is finite, over the most extreme inputs a scene may give.

The scene loader bounds what feeds shading (colours, light intensity and
ambient at most ``MAX_RADIANCE``, a light position within ``MAX_COORDINATE``)
and ``build_draw`` bounds what feeds geometry (world positions, clip
coordinates and lens shifts within ``MAX_COORDINATE``). Scenes at those
bounds, rendered through every shading path and the ROP's accumulating
blend, must leave the image, the per-sample depth, the counters and the
cycles finite; a value past a bound is refused in one line naming its key.
"""

import copy
import subprocess
import sys

import numpy as np
import pytest

import units.rop

from pipeline_sim.config import pass_settings
from pipeline_sim.draw import build_draw
from pipeline_sim.errors import UserError
from pipeline_sim.render import render_scene
from pipeline_sim.scene import MAX_COORDINATE, MAX_RADIANCE, parse_scene

R = MAX_RADIANCE
C = MAX_COORDINATE

CAMERA = {"eye": [0.0, 0.5, 4.0], "look_at": [0.0, 0.5, 0.0], "fov_y": 45.0, "near": 0.1, "far": 20.0,
          "lens": {"radius": 0.05, "focus_distance": 4.0}}

# every radiance at its bound; the point light sits on a vertex of the sphere
# (the top of an icosphere is a vertex), where the shader's attenuation is at
# its largest, 1e12; a moving lit sphere, a flat box and a lit plane behind
RADIANCE = {
    "image": {"width": 40, "height": 30, "spp": 4, "seed": 3},
    "camera": CAMERA,
    "background": {"color": [R, R, R]},
    "light": {"type": "point", "position": [0.0, 1.2, 0.0], "color": [R, R, R], "intensity": R, "ambient": R},
    "objects": [
        {"primitive": "sphere", "radius": 0.7, "subdivisions": 2, "color": [R, R, R],
         "open": {"translate": [0.0, 0.5, 0.0]}, "close": {"translate": [0.2, 0.5, 0.0]}},
        {"primitive": "box", "material": "flat", "color": [R, 0.0, R], "open": {"translate": [0.9, 0.0, -1.0]}},
        {"primitive": "plane", "size": [8.0, 8.0], "color": [R, R, R],
         "open": {"translate": [0.0, -0.5, -2.0], "rotate": [60.0, 0.0, 0.0]}},
    ],
}

# world coordinates near MAX_COORDINATE = 8.5e37: a sphere reaching 7e37,
# moving by 1e37, lit by a point light at the bound itself, seen by an
# orthographic camera that frames it (its clip coordinates are near 1)
HUGE_WORLD = {
    "image": {"width": 32, "height": 32, "spp": 4},
    "camera": {"projection": "orthographic", "eye": [0.0, 0.0, 0.0], "look_at": [0.0, 0.0, -1.0],
               "ortho_height": 6e37, "near": 1e37, "far": 8e37},
    "light": {"type": "point", "position": [C, C, C], "color": [R, R, R], "intensity": R, "ambient": R},
    "objects": [{"primitive": "sphere", "radius": 1.0, "subdivisions": 2, "color": [R, R, R],
                 "open": {"translate": [0.0, 0.0, -5e37], "scale": 2e37},
                 "close": {"translate": [1e37, 0.0, -5e37], "scale": 2e37}}],
}

# clip coordinates and lens shifts near the bound: the same sphere seen by a
# defocused perspective camera (w up to 7e37)
HUGE_CLIP = {
    "image": {"width": 32, "height": 32, "spp": 4},
    "camera": {"eye": [0.0, 0.0, 0.0], "look_at": [0.0, 0.0, -1.0], "fov_y": 90.0, "near": 1e30, "far": 8e37,
               "lens": {"radius": 1e37, "focus_distance": 5e37}},
    "light": HUGE_WORLD["light"],
    "objects": HUGE_WORLD["objects"],
}

# the other end: a sphere 2e-30 across, scaled by 1e-300 from a radius of
# 1e270, lit by a directional light given by a 1e-300 vector
TINY_WORLD = {
    "image": {"width": 32, "height": 32, "spp": 4},
    "camera": {"projection": "orthographic", "eye": [0.0, 0.0, 0.0], "look_at": [0.0, 0.0, -1.0],
               "ortho_height": 3e-30, "near": 1e-30, "far": 1e-29},
    "light": {"type": "directional", "direction": [1e-300, -1e-300, -1e-300], "color": [R, R, R], "intensity": R},
    "objects": [{"primitive": "sphere", "radius": 1e270, "subdivisions": 2, "color": [R, R, R],
                 "open": {"translate": [0.0, 0.0, -3e-30], "scale": 1e-300},
                 "close": {"translate": [1e-30, 0.0, -3e-30], "scale": 1e-300}}],
}

# and tiny clip coordinates: a perspective camera with a near plane at 1e-32
TINY_CLIP = {
    "image": {"width": 32, "height": 32, "spp": 4},
    "camera": {"eye": [0.0, 0.0, 0.0], "look_at": [0.0, 0.0, -1.0], "fov_y": 90.0, "near": 1e-32, "far": 1.0,
               "lens": {"radius": 1e-31, "focus_distance": 3e-30}},
    "light": TINY_WORLD["light"],
    "objects": TINY_WORLD["objects"],
}

# a point light 1e-6 in front of a face along its normal: n.l = 1 and the
# attenuation at its largest, 1e12, over the whole face the camera sees
GRAZING_LIGHT = {
    "image": {"width": 24, "height": 24, "spp": 4, "seed": 5},
    "camera": {"eye": [0.0, 0.0, 1.0], "look_at": [0.0, 0.0, 0.0], "fov_y": 1e-4, "near": 0.5, "far": 2.0},
    "light": {"type": "point", "position": [0.0, 0.0, 1e-6], "color": [R, R, R], "intensity": R, "ambient": R},
    "objects": [{"primitive": "plane", "size": [1.0, 1.0], "color": [R, R, R], "open": {"rotate": [90.0, 0.0, 0.0]}}],
}

SCENES = {"radiance": RADIANCE, "light_on_face": GRAZING_LIGHT, "huge_world": HUGE_WORLD, "huge_clip": HUGE_CLIP, "tiny_world": TINY_WORLD,
          "tiny_clip": TINY_CLIP}
# where the clip coordinates are themselves extreme, triangle setup's float32
# products leave the pipeline's working range: those frames must stay finite,
# but they need not show the sphere
SHOWN = ("radiance", "light_on_face", "huge_world", "tiny_world")

ARCHS = {
    "default": [],
    "per_sample": ["pass.shading_mode='per_sample'"],
    # every layer adds up: the blend must saturate, not overflow
    "add_always": ["pass.blend='add'", "pass.depth_test='always'", "pass.shading_mode='per_sample'"],
    "conservative": ["pass.mode='conservative'"],
}


def assert_finite(name: str, values) -> None:
    a = np.asarray(values, dtype=np.float64)
    bad = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
    assert bad == 0, f"{name}: {bad} non-finite values"


@pytest.fixture
def rop_batches(monkeypatch):
    """The number of non-finite colour and depth values of every batch entering
    the ROP: its saturating blend and depth test would hide them in the image."""
    bad = {"color": 0, "z": 0}
    run = units.rop.Rop.run

    def checked(self, batch):
        for key in bad:
            bad[key] += int(np.size(batch[key]) - np.count_nonzero(np.isfinite(batch[key])))
        return run(self, batch)

    monkeypatch.setattr(units.rop.Rop, "run", checked)
    return bad


@pytest.mark.parametrize("arch_name", sorted(ARCHS))
@pytest.mark.parametrize("scene_name", sorted(SCENES))
def test_extreme_accepted_scenes_leave_every_buffer_finite(scene_name, arch_name, rop_batches):
    data = SCENES[scene_name]
    scene = parse_scene(copy.deepcopy(data))  # accepted: every value is within its bound
    settings = pass_settings(ARCHS[arch_name])
    draw = build_draw(scene)
    for field in ("q", "r", "lens_x", "lens_y", "pos", "nrm", "color"):
        assert_finite(f"draw.{field} as float32", getattr(draw, field).astype(np.float32))
    res = render_scene(scene, **settings, keep_depth=True)
    assert rop_batches == {"color": 0, "z": 0}, f"non-finite values entering the ROP: {rop_batches}"
    assert_finite("image", res.image)
    if res.depth is not None:
        assert_finite("per-sample depth", res.depth)
    assert_finite("counters", res.counters.value.to_numpy())
    assert_finite("unit cycles", res.timing.units[["busy", "starved", "blocked"]].to_numpy())
    assert_finite("frame cycles", res.timing.frame_cycles)
    if scene_name in SHOWN:  # the extreme values were shaded, not just cleared
        assert res.counter("shading", "shader_executions") > 0


def test_accumulated_layers_saturate_at_the_largest_float32():
    """With additive blending every layer adds up: 400 coplanar layers of a
    lit colour near 1e36 exceed the float32 range; the buffer saturates."""
    layers = [{"primitive": "plane", "size": [1e-7, 1e-7], "color": [R, R, R], "name": f"layer{i}",
               "open": {"translate": [0.0, 1.2 - 1e-8, 0.0], "rotate": [90.0, 0.0, 0.0]}} for i in range(400)]
    data = copy.deepcopy(RADIANCE)
    data["image"]["spp"] = 1  # a pixel is its sample
    data["camera"] = {"eye": [0.0, 1.2 - 1e-8, 1e-6], "look_at": [0.0, 1.2 - 1e-8, 0.0], "fov_y": 10.0,
                      "near": 1e-7, "far": 1.0}
    data["light"]["position"] = [0.0, 1.2 - 1e-8, 1e-7]
    data["objects"] = layers
    res = render_scene(parse_scene(data), **pass_settings(ARCHS["add_always"]))
    assert_finite("image", res.image)
    assert res.image[..., 0].max() == np.finfo(np.float32).max  # the sum did exceed the range


TOO_BIG = [
    ("light.intensity", ("light", "intensity"), 1e308),
    ("light.ambient", ("light", "ambient"), 1e308),
    ("light.color", ("light", "color"), [1e308, 0.0, 0.0]),
    ("background.color", ("background", "color"), [0.0, 2 * R, 0.0]),
    ("objects[0].color", ("objects", 0, "color"), [0.0, 0.0, 1e9]),
    ("light.position", ("light", "position"), [0.0, 2 * C, 0.0]),
]


@pytest.mark.parametrize("key,path,value", TOO_BIG, ids=[t[0] for t in TOO_BIG])
def test_values_past_the_bound_are_refused_naming_the_key(key, path, value):
    data = copy.deepcopy(RADIANCE)
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    with pytest.raises(UserError) as info:
        parse_scene(data, where="s.toml")
    msg = str(info.value)
    assert msg.startswith((f"s.toml: {key}: ", f"s.toml: {key}[")) and "\n" not in msg, msg  # or its component


GEOMETRY_TOO_BIG = [
    ("translate", {"open": {"translate": [0.0, 0.0, -1e38]}}, "objects[0] ('big'): a world coordinate"),
    ("scale", {"open": {"scale": 1e300}}, "objects[0] ('big'): a world coordinate"),
    # within the bound in world space, 114x beyond it in clip space (fov_y of 1 degree)
    ("clip", {"open": {"translate": [0.0, 0.0, -6e37], "scale": 2e37}}, "objects[0] ('big'): a clip coordinate"),
]


@pytest.mark.parametrize("name,changes,needle", GEOMETRY_TOO_BIG, ids=[g[0] for g in GEOMETRY_TOO_BIG])
def test_geometry_past_the_bound_is_refused_naming_the_object(name, changes, needle):
    data = copy.deepcopy(HUGE_CLIP)
    data["camera"]["fov_y"] = 1.0
    data["objects"][0] = {"primitive": "sphere", "name": "big", "radius": 1.0, **changes}
    with pytest.raises(UserError) as info:
        build_draw(parse_scene(data, where="s.toml"))
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_issue_scene_through_the_cli(tmp_path):
    """The reported case: intensity 1e308 rendered with exit 0 and wrote NaN and
    inf into image.npy. Now: exit 2, one line naming light.intensity, nothing written."""
    scene = tmp_path / "s.toml"
    scene.write_text('[image]\nwidth = 16\nheight = 16\nspp = 1\n[camera]\neye = [0.0, 0.0, 4.0]\n'
                     'look_at = [0.0, 0.0, 0.0]\nfov_y = 45.0\nnear = 0.1\nfar = 20.0\n'
                     '[light]\nintensity = 1e308\n[[objects]]\nprimitive = "sphere"\n')
    res = subprocess.run([sys.executable, "-m", "pipeline_sim", "run", str(scene), "--out", str(tmp_path / "out"),
                          "-q"], capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and "light.intensity" in res.stderr
    assert not (tmp_path / "out").exists()
