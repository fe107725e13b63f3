"""Motion-blurred soft shadows from one 5D shadow-map pass (Nilsson12 §7; docs/shadows.md).

* ``light``: the area light is the lens of a shadow camera focused at infinity, so each lens point is
  the light camera translated parallel to the light (a constant lens shift per vertex in clip space);
  objects move in t. Its sample table holds the same K tuples (u_k, v_k, t_k) at every pixel's centre,
  one (u, v) per t, so sample k of every pixel is shadow map k: the pass's per-sample depth is the
  array of K shadow maps (texture ``light.depth``, one layer per tuple).
* ``camera``: motion blur (and optionally defocus) with the same K times, one sample per tuple at the
  pixel centre; a sample with tuple k (input ``tuple``) puts its surface point, at t_k, through
  projection k (the light camera moved to (u_k, v_k), among the shader's parameters) and compares it
  with map k: one lookup per sample, after a depth bias, optionally percentage-closer filtered.
* the accumulation buffer (``accumulation = true``): for each tuple k, a 2D shadow-map pass of the
  scene at t_k from light point k and a 2D camera pass at t_k, averaged; the same result in 2K passes.

``results.json``: shadow lookups, passes and simulated cycles of the one 5D pass pair against the
K-pass accumulation, the difference between the two, and the error of each against a ray-cast
reference of visibility averaged over the light and the shutter (``reference_visibility``); the table
``study`` (and top-level ``error_k<K>_r<R>``, ``cycles_k<K>_r<R>``) gives error and cycles over the
file's ``study_tuples`` x ``study_shadow_maps``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Annotated, Literal

import numba as nb
import numpy as np
import pandas as pd
from pydantic import Field

from pipeline_sim.errors import UserError
from pipeline_sim.output import finite_or_none
from pipeline_sim.sampling import concentric_disk, map_lens, t_ordered_net
from pipeline_sim.scene import Camera
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, Flag, count, number
from pipeline_sim.shaders import (IN_B, IN_G, IN_NX, IN_NY, IN_NZ, IN_PX, IN_PY, IN_PZ, IN_R, IN_TUPLE,
                                  compare_layer, project)
from pipeline_sim.workload import Workload, WorkloadResult
from workloads.apps.raycast import nearest_hit

SCENES = ("moving_object", "occluder_plane")
LIGHT_SHAPES = ("square", "disk")
#: The shadow camera's near plane (world units below the light) and how far below the ground its far
#: plane lies.
LIGHT_NEAR, LIGHT_FAR_MARGIN = 0.25, 1.0
#: Ground half size of each scene; the half size of the receiver the shadow maps cover in ``occluder_plane``
#: (the camera sees x in [-1, 1], z within as much).
GROUND = {"moving_object": 8.0, "occluder_plane": 4.0}
FOOTPRINT = 1.5
#: The shader's parameters before the K projections: depth bias (world units along the light's axis),
#: PCF radius (texels), the light's depth mapping z/w = c1 + c0 / w, the light's centre, ambient light,
#: normal offset (world units).
P_BIAS, P_PCF, P_C1, P_C0, P_LX, P_LY, P_LZ, P_AMBIENT, P_OFFSET = range(9)
HEADER = 9
AMBIENT = 0.2
BACKGROUND = (0.1, 0.1, 0.12, 1.0)
#: One sample at each pixel's centre, at t = 0.5 (the accumulation's 2D passes).
CENTRE = np.array([[0.5, 0.5, 0.0, 0.0, 0.5]])

Counts = Annotated[list[count(1, 4096)], Field(max_length=8)]


@dataclass
class Settings:
    """The keys of a `shadows` file besides `kind`."""

    __pydantic_config__ = FORBID
    scene: Literal[SCENES] = key("`moving_object`: a box moving over a ground plane beside a post; "
                                 "`occluder_plane`: a static plane with a straight edge over a receiver "
                                 "(closed-form penumbra)", default="moving_object")
    width: count(8, 4096) = key("image width, pixels", default=96)
    height: count(8, 4096) = key("image height, pixels", default=72)
    tuples: count(1, 4096) = key("K, the (u, v, t) tuples: shadow maps of the 5D pass and camera samples per "
                                 "pixel (a power of two: a (0, m, 3)-net)", default=64)
    shadow_map: count(8, 4096) = key("shadow-map resolution, texels along each side", default=128)
    light_shape: Literal[LIGHT_SHAPES] = key("shape of the area light", default="square")
    light_size: number(0.0, 10.0) = key("side of the square light / diameter of the disk light, world units",
                                        default=1.0)
    light_height: number(1.0, 100.0) = key("height of the light above the ground (it faces straight down)",
                                           default=8.0)
    occluder_height: number(0.1, 50.0) = key("height above the ground of the box's bottom / of the occluder "
                                             "plane", default=2.0)
    motion: number(0.0, 4.0) = key("distance the box moves along x over the shutter, world units",
                                    default=1.5)
    bias: number(0.0, 10.0) = key("depth bias: the receiver moves this far towards the light before the "
                                  "comparison, world units along the light's axis", default=0.03)
    normal_offset: number(0.0, 10.0) = key("the receiver's point moves this far along its normal before it is "
                                           "projected, world units (against acne on faces the light grazes)",
                                           default=0.0)
    pcf: count(0, 4) = key("percentage-closer filter radius, texels (0: one texel per lookup)", default=0)
    lens_radius: number(0.0, 1.0) = key("the camera's thin-lens radius, world units (0: pinhole)", default=0.0)
    focus_distance: number(1.0, 100.0) = key("the camera's focus distance, world units", default=10.0)
    accumulation: Flag = key("also run the K-pass accumulation buffer", default=True)
    reference_samples: count(0, 65536) = key("(u, v, t) samples per pixel of the ray-cast reference (a power "
                                             "of two; 0: none)", default=1024)
    study_tuples: Counts = key("K of the study table (each a power of two)", default_factory=list)
    study_shadow_maps: Counts = key("shadow-map resolutions of the study table", default_factory=list)
    seed: count(0) = key("seed of the camera's lens points and of the reference's per-pixel scrambles",
                         default=0)


@dataclass
class Mesh:
    """A moving triangle mesh: each triangle's world vertices at t=0 and t=1 (N, 3, 3), linear between."""

    name: str
    world0: np.ndarray
    world1: np.ndarray
    color: tuple[float, float, float]
    seen: bool = True  # drawn by the camera (False: it only casts shadows)

    def at(self, t: float) -> np.ndarray:
        return (1.0 - t) * self.world0 + t * self.world1


def _quad(x0: float, x1: float, z0: float, z1: float, y: float) -> np.ndarray:
    """Two triangles over [x0, x1] x [z0, z1] at height y, facing up (+y)."""
    a, b, c, d = (x0, y, z0), (x0, y, z1), (x1, y, z1), (x1, y, z0)
    return np.array([[a, b, c], [a, c, d]], float)


def _box(extents, centre, turn_deg: float = 0.0) -> np.ndarray:
    """A box's 12 triangles (trimesh's, outward facing), turned about y and centred at ``centre``."""
    import trimesh

    box = trimesh.creation.box(extents=extents)
    a = np.radians(turn_deg)
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    return (box.vertices @ rot.T + centre)[box.faces]


def scene_meshes(s: Settings) -> list[Mesh]:
    """The meshes of the file's scene."""
    g = GROUND[s.scene]
    ground = _quad(-g, g, -g, g, 0.0)
    if s.scene == "occluder_plane":
        plane = _quad(-g, 0.0, -g, g, s.occluder_height)  # its straight edge along z at x = 0
        return [Mesh("receiver", ground, ground, (0.8, 0.8, 0.8)),
                Mesh("occluder", plane, plane, (0.8, 0.3, 0.2), seen=False)]
    half = 0.6
    box = _box([2 * half] * 3, [-0.5 * s.motion, s.occluder_height + half, 0.0], 30.0)
    post = _box([0.3, 2.0, 0.3], [2.2, 1.0, 1.2])
    return [Mesh("ground", ground, ground, (0.8, 0.8, 0.8)),
            Mesh("box", box, box + [s.motion, 0.0, 0.0], (0.9, 0.5, 0.2)),
            Mesh("post", post, post, (0.3, 0.5, 0.9))]


def camera_of(s: Settings) -> Camera:
    """The camera: looking at the box from above and in front, or straight down at the receiver."""
    if s.scene == "occluder_plane":  # from height 3, the receiver's x in [-1, 1] across the image
        eye, look, up = np.array([0.0, 3.0, 0.0]), np.zeros(3), np.array([0.0, 0.0, -1.0])
        a = 1.0 / 3.0
        return Camera("perspective", eye, look, up, eye, look, 0.0, 1.0, 40.0,
                      frustum=(-a, a, -a * s.height / s.width, a * s.height / s.width))
    eye, look = np.array([0.0, 6.5, 7.0]), np.array([0.5, 0.0, 0.3])
    return Camera("perspective", eye, look, np.array([0.0, 1.0, 0.0]), eye, look, 45.0, 1.0, 40.0)


def shadowed_extent(s: Settings) -> float:
    """Half size of the ground square the shadow maps must cover: in ``occluder_plane`` the receiver the
    camera sees; in ``moving_object`` every shadow of the casters (all but the ground): a point at height
    y and |x|, |z| <= e, lit from a light point at most R off the light's centre at height H, casts its
    shadow within (e H + R y) / (H - y)."""
    if s.scene == "occluder_plane":
        return FOOTPRINT
    casters = np.concatenate([np.concatenate([m.world0, m.world1]).reshape(-1, 3) for m in scene_meshes(s)[1:]])
    e, y = np.abs(casters[:, [0, 2]]).max(axis=1), casters[:, 1]
    h, r = s.light_height, 0.5 * s.light_size
    return float(((e * h + r * y) / (h - y)).max())


def light_camera(s: Settings) -> Camera:
    """The shadow camera at the light's centre, facing down: at every point of the light (translated by
    up to the light's half size R) its window covers the shadowed ground square and, at every height
    between, the casters (a caster's point at (x, y) lies within that window's |x| + R there)."""
    eye, look = np.array([0.0, s.light_height, 0.0]), np.zeros(3)
    a = LIGHT_NEAR * (shadowed_extent(s) + 0.5 * s.light_size) / s.light_height
    return Camera("perspective", eye, look, np.array([0.0, 0.0, -1.0]), eye, look, 0.0, LIGHT_NEAR,
                  s.light_height + LIGHT_FAR_MARGIN, frustum=(-a, a, -a, a))


def light_tuples(k: int, shape: str) -> np.ndarray:
    """The K tuples (u, v, t), (K, 3), sorted by t: the t-ordered (0, m, 3)-net (K = 2^m) at its strata's
    centres, (u, v) on [-1, 1]^2 or the unit disk (concentric map), t_k = (k + 0.5) / K; as float32 values
    (those the samples hold)."""
    net = t_ordered_net(k.bit_length() - 1) + 0.5 / k
    u, v = map_lens(net[:, 0], net[:, 1], shape)  # the light is the lens of the shadow camera
    return np.stack([u, v, net[:, 2]], axis=1).astype(np.float32).astype(np.float64)


def camera_lens_points(k: int, seed: int) -> np.ndarray:
    """The camera's lens point of each tuple, (K, 2) on the unit disk: the net's (u, v) in a seeded
    permutation, so that the camera's lens and the light's point are not paired."""
    net = t_ordered_net(k.bit_length() - 1) + 0.5 / k
    order = np.random.default_rng(seed).permutation(k)
    u, v = concentric_disk(net[order, 0], net[order, 1])
    return np.stack([u, v], axis=1).astype(np.float32).astype(np.float64)


def light_matrices(s: Settings, tuples: np.ndarray) -> np.ndarray:
    """Projection k (K, 4, 4): the light camera moved to light point k (u_k, v_k) parallel to the light,
    world to clip."""
    light = light_camera(s)
    proj, view = light.projection_matrix(1.0), light.view_matrix()
    radius = 0.5 * s.light_size
    out = np.empty((len(tuples), 4, 4))
    for k, (u, v, _) in enumerate(tuples):
        move = np.eye(4)
        move[0, 3], move[1, 3] = -radius * u, -radius * v
        out[k] = proj @ move @ view
    return out


def _normals(world: np.ndarray) -> np.ndarray:
    n = np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.repeat(n[:, None, :], 3, axis=1)


def make_draw(meshes: list[Mesh], camera: Camera, width: int, height: int, *, lens_radius: float = 0.0,
              focus: float = np.inf, times: tuple[float, float] = (0.0, 1.0), lens: tuple[float, float] | None = None):
    """A draw of ``meshes`` seen by ``camera``: the vertices at ``times`` (shutter open and close), with
    a thin lens of ``lens_radius`` focused at ``focus`` (infinity: a constant clip shift, the light's
    parallel cameras). ``lens``: a fixed lens point, folded into the vertices (a 2D draw)."""
    from pipeline_sim.draw import draw_from_world

    proj = camera.projection_matrix(width / height)
    ends = [np.concatenate([m.at(t) for m in meshes]) for t in times]
    color = np.concatenate([np.tile(m.color, (len(m.world0), 1)) for m in meshes])
    draw = draw_from_world(ends[0], ends[1], proj, camera.view_matrix(), width=width, height=height,
                           lens_radius=lens_radius, focus=focus, lens_point=lens, color=color)
    pos = np.stack(ends).astype(np.float32)
    return dataclasses.replace(draw, pos=pos, nrm=np.stack([_normals(e) for e in ends]).astype(np.float32),
                               material=np.ones(draw.n, np.int32))


@nb.njit(cache=True, nogil=True)
def shadow_shader(inputs, params, textures, out, append):
    """Nilsson12 §7: a sample with tuple k puts its surface point (at its own time t_k, moved by the normal
    offset along its normal) through projection k (``params[HEADER + 16 k:]``, the light camera at light
    point k) and compares its depth, moved by the bias towards the light, with shadow map k (layer k of ``textures[0]``), over a PCF neighbourhood;
    outside the map it is lit. Outputs: colour (Lambert from the light's centre, the visibility on the
    direct part) and (visibility, 1)."""
    shadow = textures[0]
    bias, radius, c1, c0 = params[P_BIAS], int(params[P_PCF]), params[P_C1], params[P_C0]
    for i in range(inputs.shape[1]):
        k = int(inputs[IN_TUPLE, i])
        nx, ny, nz = inputs[IN_NX, i], inputs[IN_NY, i], inputs[IN_NZ, i]
        px, py, pz = inputs[IN_PX, i], inputs[IN_PY, i], inputs[IN_PZ, i]
        off = params[P_OFFSET]
        s, t, _, w = project(params, HEADER + 16 * k, px + off * nx, py + off * ny, pz + off * nz)
        vis = 1.0
        if w - bias > 0.0 and 0.0 <= s < 1.0 and 0.0 <= t < 1.0:
            vis = compare_layer(shadow, k, s, t, c1 + c0 / (w - bias), radius)
        lx, ly, lz = params[P_LX] - px, params[P_LY] - py, params[P_LZ] - pz
        ln = np.sqrt(lx * lx + ly * ly + lz * lz)
        ndl = max(0.0, (nx * lx + ny * ly + nz * lz) / ln)
        light = params[P_AMBIENT] + (1.0 - params[P_AMBIENT]) * vis * ndl
        out[i, 0] = inputs[IN_R, i] * light
        out[i, 1] = inputs[IN_G, i] * light
        out[i, 2] = inputs[IN_B, i] * light
        out[i, 3] = 1.0
        out[i, 4] = vis
        out[i, 5] = 1.0


def shader_params(s: Settings, matrices: np.ndarray) -> np.ndarray:
    """The shadow shader's parameters: the header, then the K projections row-major."""
    light = light_camera(s)
    proj = light.projection_matrix(1.0)
    header = np.zeros(HEADER)
    header[[P_BIAS, P_PCF, P_C1, P_C0]] = s.bias, s.pcf, -proj[2, 2], proj[2, 3]
    header[[P_LX, P_LY, P_LZ]] = light.eye
    header[P_AMBIENT], header[P_OFFSET] = AMBIENT, s.normal_offset
    return np.concatenate([header, matrices.reshape(-1)]).astype(np.float32)


def light_pass(s: Settings, arch, tuples: np.ndarray, name: str = "light"):
    """The one 5D shadow-map pass: K samples per texel, sample k the tuple (u_k, v_k, t_k) at the centre."""
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.render import RenderPass
    from pipeline_sim.shaders import depth_shader

    draw = make_draw(scene_meshes(s), light_camera(s), s.shadow_map, s.shadow_map,
                     lens_radius=0.5 * s.light_size)
    table = np.concatenate([np.full((len(tuples), 2), 0.5), tuples], axis=1)
    return RenderPass(draw=draw, arch=arch, spp=len(tuples), name=name, shader=depth_shader,
                      state=PassState(), sample_table=table)


def _camera_targets(per_sample: bool):
    from pipeline_sim.targets import Target

    targets = (Target("color", clear=BACKGROUND), Target("visibility", source="visibility", clear=(0.0, 0.0)))
    return targets + ((Target("samples", source="visibility", clear=(0.0, 0.0), resolve="none"),)
                      if per_sample else ())


def camera_pass(s: Settings, arch, tuples: np.ndarray, lens_points: np.ndarray, light: str = "light",
                name: str = "camera", per_sample: bool = False):
    """The 5D camera pass: one sample per tuple at each pixel's centre, at t_k (and camera lens point k),
    looking up shadow map k of pass ``light``; ``per_sample``: also keep each sample's visibility."""
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.render import RenderPass
    from pipeline_sim.targets import ShaderOutput

    meshes = [m for m in scene_meshes(s) if m.seen]
    draw = make_draw(meshes, camera_of(s), s.width, s.height, lens_radius=s.lens_radius, focus=s.focus_distance)
    table = np.concatenate([np.full((len(tuples), 2), 0.5), lens_points, tuples[:, 2:]], axis=1)
    return RenderPass(draw=draw, arch=arch, spp=len(tuples), name=name, shader=shadow_shader,
                      params=shader_params(s, light_matrices(s, tuples)), textures=(f"{light}.depth",),
                      state=PassState(shading_mode="per_sample"), sample_table=table,
                      outputs=(ShaderOutput("color", 4), ShaderOutput("visibility", 2)),
                      targets=_camera_targets(per_sample), clear_color=BACKGROUND)


def accumulation_passes(s: Settings, arch, tuples: np.ndarray, lens_points: np.ndarray) -> list:
    """The accumulation buffer's 2K passes: per tuple k, a 2D shadow map of the scene at t_k from light
    point k (``light_k``), then a 2D camera pass at t_k and camera lens point k (``camera_k``) that looks it
    up through projection k."""
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.render import RenderPass
    from pipeline_sim.shaders import depth_shader
    from pipeline_sim.targets import ShaderOutput

    meshes = scene_meshes(s)
    light, camera = light_camera(s), camera_of(s)
    matrices = light_matrices(s, tuples)
    passes = []
    for k, (u, v, t) in enumerate(tuples):
        shadow = make_draw(meshes, light, s.shadow_map, s.shadow_map, lens_radius=0.5 * s.light_size,
                           times=(t, t), lens=(u, v))
        seen = make_draw([m for m in meshes if m.seen], camera, s.width, s.height, lens_radius=s.lens_radius,
                         focus=s.focus_distance, times=(t, t), lens=tuple(lens_points[k]))
        passes += [RenderPass(draw=shadow, arch=arch, spp=1, name=f"light_{k}", shader=depth_shader,
                              state=PassState(), sample_table=CENTRE),
                   RenderPass(draw=seen, arch=arch, spp=1, name=f"camera_{k}", shader=shadow_shader,
                              params=shader_params(s, matrices[k:k + 1]), textures=(f"light_{k}.depth",),
                              state=PassState(shading_mode="per_sample"), sample_table=CENTRE,
                              outputs=(ShaderOutput("color", 4), ShaderOutput("visibility", 2)),
                              targets=_camera_targets(False), clear_color=BACKGROUND)]
    return passes


def visibility(result) -> np.ndarray:
    """A camera pass's visibility per pixel, (H, W): the mean over the pixel's covered samples (1 where
    none is covered)."""
    vis = result.images["visibility"][0]
    return np.where(vis[..., 1] > 0, vis[..., 0] / np.maximum(vis[..., 1], 1e-30), 1.0)


# --------------------------------------------------------------------------- the ray-cast reference
@nb.njit(cache=True)
def _reference_kernel(origins, targets, times, lamps, seen0, seen1, w0, w1, vis):
    """Per ray i: the nearest hit of the camera ray from ``origins[i]`` towards ``targets[i]`` among the
    seen triangles (``seen0``, ``seen1``) at time ``times[i]``; there, whether the segment to ``lamps[i]``
    meets any triangle (``w0``, ``w1``). Hits closer than 1e-9 of either ray's length are not counted."""
    for r in range(len(times)):
        ox, oy, oz, t = origins[r, 0], origins[r, 1], origins[r, 2], times[r]
        dx, dy, dz = targets[r, 0] - ox, targets[r, 1] - oy, targets[r, 2] - oz
        tri, best, _, _ = nearest_hit(ox, oy, oz, dx, dy, dz, seen0, seen1, t, 1e-9, np.inf)
        vis[r] = 1.0
        if tri < 0:
            continue
        px, py, pz = ox + best * dx, oy + best * dy, oz + best * dz
        lx, ly, lz = lamps[r, 0] - px, lamps[r, 1] - py, lamps[r, 2] - pz
        if nearest_hit(px, py, pz, lx, ly, lz, w0, w1, t, 1e-9, 1.0 - 1e-9)[0] >= 0:
            vis[r] = 0.0


def reference_visibility(s: Settings, samples: int) -> np.ndarray:
    """Visibility of each pixel centre's surface point averaged over the shutter and the light (and the
    camera's lens), (H, W), by float64 ray casting against the triangles: per pixel ``samples`` (u, v, t)
    points of the t-ordered (0, m, 3)-net, Cranley-Patterson rotated per pixel (the camera's lens from
    another rotation of the net). The camera ray at time t meets the nearest seen triangle; the shadow
    ray from there to the light point meets any triangle or none. Pixels whose ray meets nothing: 1."""
    meshes = scene_meshes(s)
    camera, light = camera_of(s), light_camera(s)
    proj = camera.projection_matrix(s.width / s.height)
    to_world = np.linalg.inv(camera.view_matrix())
    net = t_ordered_net(samples.bit_length() - 1)
    rng = np.random.default_rng(s.seed)
    npix = s.width * s.height
    pix = np.repeat(np.arange(npix), samples)
    pts = ((net[None, :, :] + rng.random((npix, 1, 3))) % 1.0).reshape(-1, 3)
    lens = ((net[None, :, 1::-1] + rng.random((npix, 1, 2))) % 1.0).reshape(-1, 2)
    # the camera ray: from lens point (u R, v R) through the pixel centre's point on the focus plane
    focus = s.focus_distance if s.lens_radius > 0 else 1.0
    xn = 2.0 * ((pix % s.width) + 0.5) / s.width - 1.0
    yn = 1.0 - 2.0 * ((pix // s.width) + 0.5) / s.height
    target = np.stack([xn * focus / proj[0, 0], yn * focus / proj[1, 1], np.full(len(pix), -focus)], axis=1)
    origin = np.zeros((len(pix), 3))
    origin[:, 0], origin[:, 1] = (s.lens_radius * c for c in concentric_disk(lens[:, 0], lens[:, 1]))
    lu, lv = map_lens(pts[:, 0], pts[:, 1], s.light_shape)
    axes = light.view_matrix()[:2, :3]  # the light's x and y axes in world space
    lamps = light.eye + 0.5 * s.light_size * (lu[:, None] * axes[0] + lv[:, None] * axes[1])
    vis = np.empty(len(pix))
    seen = [m for m in meshes if m.seen]
    _reference_kernel(origin @ to_world[:3, :3].T + to_world[:3, 3], target @ to_world[:3, :3].T + to_world[:3, 3],
                      pts[:, 2], lamps, *(np.concatenate([getattr(m, f) for m in group])
                                          for group in (seen, meshes) for f in ("world0", "world1")), vis)
    return vis.reshape(s.height, s.width, samples).mean(axis=2)


def penumbra_width(s: Settings) -> float:
    """The closed-form penumbra width on the receiver of the ``occluder_plane`` scene under a square light
    of side L: L (d_receiver - d_occluder) / d_occluder, distances from the light."""
    d_o = s.light_height - s.occluder_height
    return s.light_size * (s.light_height - d_o) / d_o


def _power_of_two(name: str, value: int, where: str) -> None:
    if value & (value - 1):
        raise UserError(f"{where}: {name} = {value} must be a power of two (the tuples are a (0, m, 3)-net)")


class Shadows(Workload):
    """The kind ``shadows``: soft, motion-blurred shadows from one 5D shadow-map pass, against the
    accumulation buffer and a ray-cast reference."""

    file_schema = Settings

    image_refusals = {"spp": "takes one camera sample per tuple; set `tuples` instead"}

    def check(self, variants=None, *, reference_spp=None) -> str:
        for v in variants or [self]:
            s = v.settings_file
            for name, value in [("tuples", s.tuples), ("reference_samples", s.reference_samples),
                                *(("study_tuples", k) for k in s.study_tuples)]:
                if value:
                    _power_of_two(name, value, str(v.path))
            top = max(float(np.concatenate([m.world0, m.world1])[..., 1].max()) for m in scene_meshes(s))
            if top > s.light_height - 2 * LIGHT_NEAR:
                raise UserError(f"{v.path}: occluder_height = {s.occluder_height:g}: the scene reaches {top:g}, "
                                f"above light_height - {2 * LIGHT_NEAR:g} = {s.light_height - 2 * LIGHT_NEAR:g} "
                                "(the shadow camera's near plane)")
        s = self.settings_file
        return (f"{s.scene}: K = {s.tuples} tuples, {s.shadow_map}^2 shadow maps, {s.width}x{s.height} "
                f"camera{', with the accumulation buffer' if s.accumulation else ''}")

    def run(self, progress=None) -> WorkloadResult:
        s = self.settings_file
        tuples = light_tuples(s.tuples, s.light_shape)
        lens = camera_lens_points(s.tuples, s.seed)
        passes = [light_pass(s, self.arch, tuples), camera_pass(s, self.arch, tuples, lens)]
        study = [(k, r) for k in s.study_tuples for r in s.study_shadow_maps]
        for k, r in study:
            sk = dataclasses.replace(s, tuples=k, shadow_map=r)
            tk = light_tuples(k, s.light_shape)
            passes += [light_pass(sk, self.arch, tk, f"study_light_k{k}_r{r}"),
                       camera_pass(sk, self.arch, tk, camera_lens_points(k, s.seed), f"study_light_k{k}_r{r}",
                                   f"study_camera_k{k}_r{r}")]
        if s.accumulation:
            passes += accumulation_passes(s, self.arch, tuples, lens)
        results = self.run_passes(passes, progress)
        five_d = visibility(results["camera"])
        cycles = {name: float(r.timing.frame_cycles) for name, r in results.items()}
        out = {
            "scene": s.scene, "tuples": s.tuples, "shadow_map": s.shadow_map,
            "shadow_lookups": results["camera"].counter("shading", "shader_executions"),
            "passes": 2, "light_cycles": cycles["light"], "camera_cycles": cycles["camera"],
            "cycles": cycles["light"] + cycles["camera"], "mean_visibility": float(five_d.mean()),
        }
        reference = reference_visibility(s, s.reference_samples) if s.reference_samples else None
        if reference is not None:
            out["error"] = float(np.abs(five_d - reference).mean())
        if s.accumulation:
            acc = np.mean([visibility(results[f"camera_{k}"]) for k in range(s.tuples)], axis=0)
            light_acc = sum(cycles[f"light_{k}"] for k in range(s.tuples))
            camera_acc = sum(cycles[f"camera_{k}"] for k in range(s.tuples))
            out.update({
                "accumulation_passes": 2 * s.tuples, "accumulation_light_cycles": light_acc,
                "accumulation_camera_cycles": camera_acc, "accumulation_cycles": light_acc + camera_acc,
                "accumulation_shadow_lookups": sum(results[f"camera_{k}"].counter("shading", "shader_executions")
                                                   for k in range(s.tuples)),
                "light_speedup": finite_or_none(light_acc / cycles["light"]),
                "speedup": finite_or_none((light_acc + camera_acc) / out["cycles"]),
                "accumulation_difference": float(np.abs(five_d - acc).mean()),
                "accumulation_max_difference": float(np.abs(five_d - acc).max()),
            })
            if reference is not None:
                out["accumulation_error"] = float(np.abs(acc - reference).mean())
        if s.scene == "occluder_plane":
            out["penumbra_width_closed_form"] = penumbra_width(s)
            out["penumbra_width"] = finite_or_none(measured_penumbra(s, five_d))
        rows = []
        for k, r in study:
            vis = visibility(results[f"study_camera_k{k}_r{r}"])
            row = {"tuples": k, "shadow_map": r, "light_cycles": cycles[f"study_light_k{k}_r{r}"],
                   "camera_cycles": cycles[f"study_camera_k{k}_r{r}"],
                   "error": finite_or_none(float(np.abs(vis - reference).mean()) if reference is not None else None)}
            row["cycles"] = row["light_cycles"] + row["camera_cycles"]
            out[f"error_k{k}_r{r}"], out[f"cycles_k{k}_r{r}"] = row["error"], row["cycles"]
            rows.append(row)
        tables = {"study": pd.DataFrame(rows)} if rows else {}
        return WorkloadResult(results, results=out, tables=tables)



def measured_penumbra(s: Settings, vis: np.ndarray) -> float:
    """The penumbra width on the receiver of the ``occluder_plane`` scene, measured from a visibility
    image: the straight line fitted to each row's visibility against x where it lies in (0.05, 0.95),
    its run from 0 to 1 (1 / slope); the mean over rows."""
    camera = camera_of(s)
    proj = camera.projection_matrix(s.width / s.height)
    # straight down from height h: a pixel centre's NDC x maps to world x = x_ndc * h / P00
    x = (2.0 * (np.arange(s.width) + 0.5) / s.width - 1.0) * camera.eye[1] / proj[0, 0]
    widths = []
    for row in vis:
        ramp = (row > 0.05) & (row < 0.95)
        if ramp.sum() >= 3:
            widths.append(1.0 / np.polyfit(x[ramp], row[ramp], 1)[0])
    return float(np.mean(widths)) if widths else float("nan")


WORKLOAD = Shadows
