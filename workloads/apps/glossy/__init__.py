"""Planar glossy reflections and refractions from a 4D lens pass (Nilsson12 §6; docs/glossy.md).

A planar object of a scene file (``surface``) is made glossy.

* Reflection: the main camera mirrored in the surface's plane is the centre of a thin lens parallel to
  the plane; an off-centre frustum encloses the surface exactly, with the surface as its near plane and
  its focus plane; the lens radius h tan(roughness) (h: the lens centre's distance from the plane)
  spreads each texel's samples over a cone of half-angle ``roughness``. One pass (xyuv; xyuvt when
  objects move) samples a fixed table of uniform, stratified points on the lens disc in every texel,
  with correct occlusion, into a multisampled target; its box resolve is a texture laid straight on the
  surface: texel (i, j) is the surface point the window maps it to.
* Refraction: the main camera's central ray refracted at the plane (Snell); the camera slid along the
  plane's normal onto the refracted ray's backward extension centres the same lens pass, looking into
  the medium (exact on the central ray only).
* The main pass renders the scene; the surface's shader reads the textures at its world position and
  mixes them by Fresnel (Schlick): the reflection over the surface's own shading, or the reflection
  over the refraction.

The references are ray casts written apart from the rasterizer (``reference_*``): the texture a lens
table should give (each sample's ray from its lens point through its point of the surface, nearest hit,
shaded by the standard shader, averaged per texel), and the exact per-texel refraction (Snell at every
texel against the moved camera's straight rays). ``results.json`` holds the samples per texel, each
pass's shader executions and simulated cycles, the textures' error against a ray-cast reference of
``reference_samples`` lens points per texel, the refraction's direction error, and an error study
over ``study`` (samples per texel, each its own lens passes) as top-level numbers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass
from typing import Annotated, Literal

import numba as nb
import numpy as np
import pandas as pd
from pydantic import Field

from pipeline_sim.errors import UserError, did_you_mean
from pipeline_sim.output import finite_results
from pipeline_sim.sampling import concentric_disk
from pipeline_sim.scene import Camera, ImageSettings, Lens, Scene, load_scene
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, Text, count, number
from pipeline_sim.shaders import (IN_B, IN_MATERIAL, IN_NX, IN_NZ, IN_OBJECT, IN_PX, IN_PY, IN_PZ,
                                  IN_R, N_INPUTS, sample_texture, standard_params, standard_shader)
from pipeline_sim.workload import Workload, WorkloadResult
from workloads.apps.raycast import nearest_hits, refract

EFFECTS = ("reflection", "refraction")
# the main shader's parameters after the standard shader's 8: the surface object's index, the main eye,
# the surface normal, F0; then per texture its lens camera's centre, x and y axes and window
SURFACE_AT, EYE_AT, NORMAL_AT, F0_AT, TEXTURE_AT, TEXTURE_PARAMS = 8, 9, 12, 15, 16, 13
# rings of the refraction error table, by distance from the central ray's hit over the largest distance
RINGS = 4

Study = Annotated[list[count(1, 256)], Field(max_length=8)]


@dataclass
class Settings:
    """The keys of a `glossy` file besides `kind`."""

    __pydantic_config__ = FORBID
    scene: Text = key("the scene file (camera, light, objects, main pass), relative to this file")
    surface: Text = key("name of the scene's planar object made glossy")
    effect: Literal[EFFECTS] = key("`reflection`: a glossy mirror; `refraction`: a rough transparent surface "
                                   "(refraction and reflection, mixed by Fresnel)", default="reflection")
    roughness: number(0.0, 45.0) = key("half-angle of the cone of directions a texel averages, degrees (lens "
                                       "radius = distance to the plane x tan)", default=5.0)
    samples_per_texel: count(1, 256) = key("lens samples per texel of the glossy passes (Nilsson12 Fig. 14: "
                                           "16 and 64)", default=16)
    texels: count(4, 1024) = key("texels along the surface's longer side", default=64)
    ior: number(1.0, 4.0) = key("index of refraction of the medium beyond the surface (refraction, and "
                                "its Fresnel term)", default=1.33)
    reflectance: number(0.0, 1.0) = key("reflectance at normal incidence (Schlick's F0) of a reflecting "
                                        "surface", default=0.04)
    seed: count(0) = key("seed of the lens sample tables", default=0)
    reference_samples: count(0, 4096) = key("lens samples per texel of the ray-cast reference the error is "
                                            "measured against (0: none)", default=256)
    study: Study = key("samples per texel of the error study (each its own lens passes)",
                       default_factory=list)


@dataclass(frozen=True)
class Surface:
    """The glossy surface: its object's index, a point of its plane, its unit normal (towards the main
    camera), a unit axis in the plane (the textures' horizontal) and its world vertices (V, 3)."""

    index: int
    point: np.ndarray
    normal: np.ndarray
    axis: np.ndarray
    vertices: np.ndarray


@dataclass(frozen=True)
class LensCamera:
    """A glossy pass's camera (Nilsson12 §6, Fig. 13): lens centre ``eye``, looking along ``forward`` (the
    plane's normal, into the plane); eye axes ``x``, ``y``; the near-plane ``window`` (left, right, bottom,
    top) enclosing the surface on its plane at distance ``distance`` (near plane = focus plane); lens
    ``radius``; ``far``; ``size``: texels (width, height)."""

    eye: np.ndarray
    forward: np.ndarray
    x: np.ndarray
    y: np.ndarray
    window: tuple[float, float, float, float]
    distance: float
    radius: float
    far: float
    size: tuple[int, int]

    def camera(self) -> Camera:
        """The scene camera: gluLookAt with up = ``y`` and the off-centre frustum ``window``."""
        l, r, b, t = self.window
        look = self.eye + self.forward
        fov = math.degrees(math.atan(t / self.distance) - math.atan(b / self.distance))
        lens = Lens(self.radius, self.distance) if self.radius > 0 else None
        return Camera("perspective", self.eye, look, self.y, self.eye, look, fov, self.distance, self.far,
                      frustum=self.window, lens=lens)

    def plane_points(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """World points of the surface's plane at texture pixel coordinates (px, py) (row 0 at the top)."""
        l, r, b, t = self.window
        w, h = self.size
        ex = l + px / w * (r - l)
        ey = t - py / h * (t - b)
        return self.eye + self.distance * self.forward + ex[..., None] * self.x + ey[..., None] * self.y

    def params(self) -> list[float]:
        """The main shader's parameters of this camera's texture: centre, axes, window."""
        return [*self.eye, *self.x, *self.y, *self.window]


def find_surface(scene: Scene, name: str, where: str) -> Surface:
    """The scene's object ``name``, which must be planar and static, with the main camera off its plane."""
    names = [o.name for o in scene.objects]
    if name not in names:
        raise UserError(f"{where}: surface '{name}' names no object of the scene{did_you_mean(name, names)}")
    index = names.index(name)
    obj = scene.objects[index]
    if obj.moving:
        raise UserError(f"{where}: surface '{name}' moves; a glossy surface must be static")
    vertices = obj.world_positions(0.0)
    centre = vertices.mean(axis=0)
    _, sv, vt = np.linalg.svd(vertices - centre)
    if len(vertices) < 3 or not sv[1] > 0 or sv[2] > 1e-9 * sv[0]:
        raise UserError(f"{where}: surface '{name}' is not planar")
    normal = vt[2]
    side = float(np.dot(scene.camera.eye - centre, normal))
    if abs(side) <= 1e-9 * sv[0]:
        raise UserError(f"{where}: the camera lies in the plane of surface '{name}'")
    normal = normal if side > 0 else -normal
    axis = obj.transform_open[:3, 0] - np.dot(obj.transform_open[:3, 0], normal) * normal
    if not np.linalg.norm(axis) > 1e-9 * np.linalg.norm(obj.transform_open[:3, 0]):
        axis = vt[0]
    return Surface(index, centre, normal, axis / np.linalg.norm(axis), vertices)


def lens_camera(surface: Surface, eye: np.ndarray, forward: np.ndarray, roughness: float, texels: int,
                others: list) -> LensCamera:
    """The lens camera centred at ``eye`` looking along ``forward`` (+-normal) whose window encloses
    ``surface`` exactly; lens radius distance x tan(``roughness``); far plane beyond every vertex of
    ``others`` (the objects drawn) at both shutter ends."""
    x = surface.axis
    y = np.cross(x, forward)
    distance = float(np.dot(surface.point - eye, forward))
    rel = surface.vertices - eye
    ex, ey = rel @ x, rel @ y
    window = (float(ex.min()), float(ex.max()), float(ey.min()), float(ey.max()))
    aspect = (window[1] - window[0]) / (window[3] - window[2])
    size = (texels, max(1, round(texels / aspect))) if aspect >= 1 else (max(1, round(texels * aspect)), texels)
    depths = [float(np.max((o.world_positions(t) - eye) @ forward)) for o in others for t in (0.0, 1.0)]
    far = max([2.0 * distance] + [1.01 * d for d in depths])
    return LensCamera(eye, forward, x, y, window, distance, distance * math.tan(math.radians(roughness)), far,
                      size)


def mirror_camera(surface: Surface, eye: np.ndarray, roughness: float, texels: int, others: list) -> LensCamera:
    """The reflection camera: ``eye`` mirrored in the surface's plane, looking along the normal."""
    height = float(np.dot(eye - surface.point, surface.normal))
    return lens_camera(surface, eye - 2.0 * height * surface.normal, surface.normal, roughness, texels, others)


def central_hit(surface: Surface, eye: np.ndarray, look_at: np.ndarray, where: str) -> np.ndarray:
    """Where the main camera's central ray meets the surface's plane."""
    d = (look_at - eye) / np.linalg.norm(look_at - eye)
    toward = float(np.dot(d, surface.normal))
    if not toward < -1e-9:
        raise UserError(f"{where}: the camera's central ray does not meet the plane of the refracting surface")
    return eye + d * float(np.dot(surface.point - eye, surface.normal)) / toward


def refraction_camera(surface: Surface, eye: np.ndarray, look_at: np.ndarray, ior: float, roughness: float,
                      texels: int, others: list, where: str = "") -> LensCamera:
    """The refraction camera (Nilsson12 §6, Fig. 13 right): the main camera slid along the plane's normal
    onto the backward extension of its central ray refracted at the plane, looking into the medium: at
    height h' = rho / tan(theta_t) over the plane (rho: the hit's distance from the camera's foot), h * ior
    at normal incidence."""
    hit = central_hit(surface, eye, look_at, where)
    height = float(np.dot(eye - surface.point, surface.normal))
    foot = eye - height * surface.normal
    rho = float(np.linalg.norm(hit - foot))
    t = refract((hit - eye) / np.linalg.norm(hit - eye), surface.normal, ior)
    sin_t = float(np.linalg.norm(t - np.dot(t, surface.normal) * surface.normal))
    moved = rho * -float(np.dot(t, surface.normal)) / sin_t if rho > 1e-12 * height else height * ior
    return lens_camera(surface, foot + moved * surface.normal, -surface.normal, roughness, texels, others)


def lens_table(n: int, seed: int) -> np.ndarray:
    """A texel's ``n`` samples (x, y, u, v, t), the same in every texel (Nilsson12 §6): (u, v) uniform and
    stratified on the unit disc (a jittered gx x gy grid, gx the largest divisor of n up to sqrt(n),
    mapped by the concentric map); x, y and t each jittered in n strata, paired at random."""
    gx = max(d for d in range(1, math.isqrt(n) + 1) if n % d == 0)
    rng = np.random.default_rng(seed)
    i = np.arange(n)
    u, v = concentric_disk((i % gx + rng.random(n)) / gx, (i // gx + rng.random(n)) / (n // gx))
    below_one = np.nextafter(1.0, 0.0)
    x, y, t = (np.minimum((rng.permutation(n) + rng.random(n)) / n, below_one) for _ in range(3))
    return np.stack([x, y, u, v, t], axis=1)


@nb.njit(cache=True)
def _texture_lookup(texture, params, at, px, py, pz):
    """The texture of the lens camera whose parameters start at ``at`` at world point (px, py, pz) of the
    surface: its eye coordinates over the window give the texture coordinates (Nilsson12 §6)."""
    rx, ry, rz = px - params[at], py - params[at + 1], pz - params[at + 2]
    ex = rx * params[at + 3] + ry * params[at + 4] + rz * params[at + 5]
    ey = rx * params[at + 6] + ry * params[at + 7] + rz * params[at + 8]
    s = (ex - params[at + 9]) / (params[at + 10] - params[at + 9])
    t = (params[at + 12] - ey) / (params[at + 12] - params[at + 11])
    return sample_texture(texture, s, t)


@nb.njit(cache=True)
def _fresnel(params, px, py, pz):
    """Schlick's reflectance at (px, py, pz) of the surface, seen from the main eye."""
    vx, vy, vz = params[EYE_AT] - px, params[EYE_AT + 1] - py, params[EYE_AT + 2] - pz
    length = np.sqrt(vx * vx + vy * vy + vz * vz)
    c = abs(vx * params[NORMAL_AT] + vy * params[NORMAL_AT + 1] + vz * params[NORMAL_AT + 2]) / max(length, 1e-30)
    f0 = params[F0_AT]
    return f0 + (1.0 - f0) * (1.0 - min(c, 1.0)) ** 5


@nb.njit(cache=True)
def _surface_shader(inputs, params, textures, reflection, below, out, append, refracts):
    """Main pass over the surface (Nilsson12 §6): the standard shader, then on the surface, by Schlick's
    Fresnel term, the ``reflection`` texture over the refraction texture ``below`` when it ``refracts``, else
    over its own shading."""
    standard_shader(inputs, params, textures, out, append)
    for i in range(inputs.shape[1]):
        if inputs[IN_OBJECT, i] != params[SURFACE_AT]:
            continue
        px, py, pz = inputs[IN_PX, i], inputs[IN_PY, i], inputs[IN_PZ, i]
        f = _fresnel(params, px, py, pz)
        reflected = _texture_lookup(reflection, params, TEXTURE_AT, px, py, pz)
        if refracts:
            refracted = _texture_lookup(below, params, TEXTURE_AT + TEXTURE_PARAMS, px, py, pz)
            for c in range(3):
                out[i, c] = f * reflected[c] + (1.0 - f) * refracted[c]
        else:
            for c in range(3):
                out[i, c] = f * reflected[c] + (1.0 - f) * out[i, c]


@nb.njit(cache=True, nogil=True)
def reflection_shader(inputs, params, textures, out, append):
    """A glossy reflector: its own shading under the reflection texture ``textures[0]``
    (:func:`_surface_shader`)."""
    _surface_shader(inputs, params, textures, textures[0], textures[0], out, append, False)


@nb.njit(cache=True, nogil=True)
def refraction_shader(inputs, params, textures, out, append):
    """A rough transparent surface: the reflection texture ``textures[0]`` over the refraction texture
    ``textures[1]`` (:func:`_surface_shader`)."""
    _surface_shader(inputs, params, textures, textures[0], textures[1], out, append, True)


# ---------------------------------------------------------------------------------------------------------
# references: ray casting, apart from the rasterizer


@dataclass(frozen=True)
class Triangles:
    """World triangles of some objects at shutter open and close, (N, 3, 3) each, with their vertex normals,
    colours, material ids and object indices (the scene's)."""

    p0: np.ndarray
    p1: np.ndarray
    n0: np.ndarray
    n1: np.ndarray
    color: np.ndarray
    material: np.ndarray
    object_id: np.ndarray


def reference_triangles(scene: Scene, skip: int) -> Triangles:
    """Every triangle of the scene's objects but object ``skip``, in float64."""
    from pipeline_sim.draw import MATERIAL_IDS

    parts = [(i, o) for i, o in enumerate(scene.objects) if i != skip]

    def cat(f):
        return np.concatenate([f(i, o) for i, o in parts])

    return Triangles(cat(lambda i, o: o.world_positions(0.0)[o.faces]),
                     cat(lambda i, o: o.world_positions(1.0)[o.faces]),
                     cat(lambda i, o: o.world_normals(0.0)[o.faces]), cat(lambda i, o: o.world_normals(1.0)[o.faces]),
                     cat(lambda i, o: np.asarray(o.colors, np.float64)[o.faces]),
                     cat(lambda i, o: np.full(len(o.faces), MATERIAL_IDS[o.material])),
                     cat(lambda i, o: np.full(len(o.faces), i)))


def reference_trace(tris: Triangles, origins: np.ndarray, dirs: np.ndarray, times: np.ndarray,
                    light: np.ndarray, background: np.ndarray) -> np.ndarray:
    """The colour (M, 3) each ray (origin, direction, shutter time) sees: its nearest hit shaded by the
    standard shader (position, normal and colour interpolated as the shading unit does), else
    ``background``."""
    m = len(origins)
    tri, _, bary = nearest_hits(tris.p0, tris.p1, origins, dirs, times)
    hit = tri >= 0
    k, t = tri[hit], times[hit][:, None, None]
    lam = np.stack([1.0 - bary[hit].sum(axis=1), bary[hit, 0], bary[hit, 1]], axis=1)[:, :, None]
    inputs = np.zeros((N_INPUTS, int(hit.sum())), np.float32)
    inputs[IN_PX:IN_PZ + 1] = (lam * (tris.p0[k] + t * (tris.p1[k] - tris.p0[k]))).sum(axis=1).T
    normal = (lam * (tris.n0[k] + t * (tris.n1[k] - tris.n0[k]))).sum(axis=1)
    inputs[IN_NX:IN_NZ + 1] = (normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)).T
    inputs[IN_R:IN_B + 1] = (lam * tris.color[k]).sum(axis=1).T
    inputs[IN_MATERIAL] = tris.material[k]
    out = np.zeros((inputs.shape[1], 4), np.float32)
    standard_shader(inputs, light, (), out, (np.zeros((0, 1), np.float32), np.zeros(1, np.int64)))
    colour = np.tile(np.asarray(background, np.float64), (m, 1))
    colour[hit] = out[:, :3]
    return colour


def reference_texture(cam: LensCamera, table: np.ndarray, tris: Triangles, moving: bool, light: np.ndarray,
                      background: np.ndarray) -> np.ndarray:
    """The texture (H, W, 3) a lens pass over ``table`` should resolve to (the accumulation of Nilsson12
    §6's pinhole renders): per texel the mean over the table's samples of the colour on the ray from the
    sample's lens point, eye + radius (u x + v y), through its point of the surface plane, cast from that
    point on (time t with motion, else 0.5)."""
    w, h = cam.size
    col, row = np.meshgrid(np.arange(w), np.arange(h))
    points = cam.plane_points(col[..., None] + table[:, 0], row[..., None] + table[:, 1])  # (h, w, n, 3)
    lens = cam.eye + cam.radius * (table[:, 2:3] * cam.x + table[:, 3:4] * cam.y)  # (n, 3)
    dirs = points - lens
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    times = np.broadcast_to(table[:, 4] if moving else 0.5, points.shape[:3])
    colour = reference_trace(tris, points.reshape(-1, 3), dirs.reshape(-1, 3), times.reshape(-1), light,
                             background)
    return colour.reshape(h, w, len(table), 3).mean(axis=2)


def refraction_angles(cam: LensCamera, surface: Surface, eye: np.ndarray, ior: float,
                      points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At surface points (M, 3): the refraction camera's straight ray directions, the main camera's rays
    refracted there (Snell), and the angle between them in degrees."""
    approx = points - cam.eye
    approx /= np.linalg.norm(approx, axis=1, keepdims=True)
    seen = (points - eye) / np.linalg.norm(points - eye, axis=1, keepdims=True)
    exact = refract(seen, surface.normal, ior)
    angle = np.arctan2(np.linalg.norm(np.cross(approx, exact), axis=1), (approx * exact).sum(axis=1))
    return approx, exact, np.degrees(angle)


def reference_refraction(cam: LensCamera, surface: Surface, eye: np.ndarray, hit: np.ndarray, ior: float,
                         tris: Triangles, light: np.ndarray, background: np.ndarray) -> pd.DataFrame:
    """The refraction camera against exact refraction at every texel centre: the angle between the moved
    camera's straight ray through the texel's surface point and the main camera's ray refracted there
    (Snell), and the colours the two rays see at mid-shutter, in ``RINGS`` rings by distance from the
    central ray's ``hit`` over the largest such distance."""
    w, h = cam.size
    col, row = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    points = cam.plane_points(col, row).reshape(-1, 3)
    approx, exact, angle = refraction_angles(cam, surface, eye, ior, points)
    half = np.full(len(points), 0.5)
    diff = np.abs(reference_trace(tris, points, approx, half, light, background)
                  - reference_trace(tris, points, exact, half, light, background)).mean(axis=1)
    r = np.linalg.norm(points - hit, axis=1)
    ring = np.minimum((r / max(r.max(), 1e-300) * RINGS).astype(int), RINGS - 1)
    rows = [{"ring": k, "distance_lo": k / RINGS, "distance_hi": (k + 1) / RINGS, "texels": int((ring == k).sum()),
             "angle_mean_deg": float(angle[ring == k].mean()), "angle_max_deg": float(angle[ring == k].max()),
             "colour_error": float(diff[ring == k].mean())} for k in range(RINGS) if (ring == k).any()]
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------------------------------------
# the workload


def _rmse(images: list[np.ndarray], references: list[np.ndarray]) -> float:
    """Root mean square difference of the images' RGB from their references, over all of them."""
    return float(np.sqrt(np.mean(np.concatenate([(i[..., :3] - r).ravel() ** 2 for i, r in zip(images, references)]))))


class Glossy(Workload):
    """The kind ``glossy``: lens passes into textures laid on a planar surface, then the main pass."""

    file_schema = Settings

    @classmethod
    def load(cls, path, data: Settings, arch, image: dict[str, int]) -> "Glossy":
        self = cls.from_settings(path, data, arch, {})
        scene = load_scene(self.path.parent / data.scene)
        self.scene = scene.replace(image=dataclasses.replace(scene.image, **image))
        return self

    def cameras(self) -> tuple[Surface, list, dict[str, LensCamera]]:
        """The surface, the objects the lens passes draw (all others) and the lens cameras by pass name."""
        s, scene, where = self.settings_file, self.scene, str(self.path)
        if scene.camera.moving:
            raise UserError(f"{where}: the scene's camera moves; the glossy kind needs a static main camera")
        surface = find_surface(scene, s.surface, where)
        others = [o for i, o in enumerate(scene.objects) if i != surface.index]
        if not others:
            raise UserError(f"{where}: the scene has no object besides the surface '{s.surface}'")
        cam = scene.camera
        cams = {"reflection": mirror_camera(surface, cam.eye, s.roughness, s.texels, others)}
        if s.effect == "refraction":
            cams["refraction"] = refraction_camera(surface, cam.eye, cam.look_at, s.ior, s.roughness, s.texels,
                                                   others, where)
        return surface, others, cams

    def lens_pass(self, name: str, cam: LensCamera, others: list, spp: int):
        """The glossy pass of camera ``cam`` (Nilsson12 §6): the other objects, ``spp`` samples per texel
        from the lens table, the scene's light, background and pass state, box resolve."""
        from pipeline_sim.render import scene_pass

        w, h = cam.size
        sub = self.scene.replace(camera=cam.camera(), objects=tuple(others),
                                 image=ImageSettings(w, h, spp, self.settings_file.seed))
        return scene_pass(sub, self.arch, name=name, sample_table=lens_table(spp, self.settings_file.seed))

    def main_params(self, surface: Surface, cams: dict[str, LensCamera]) -> np.ndarray:
        """The main shader's parameters: the standard shader's, then the surface's and each texture's."""
        s = self.settings_file
        f0 = s.reflectance if s.effect == "reflection" else ((s.ior - 1.0) / (s.ior + 1.0)) ** 2
        values = [*standard_params(self.scene.light), surface.index, *self.scene.camera.eye, *surface.normal, f0]
        for cam in cams.values():
            values += cam.params()
        return np.array(values, np.float32)

    def check(self, variants=None, *, reference_spp=None) -> str:
        from pipeline_sim.draw import build_draw
        from pipeline_sim.preflight import validate_run

        for v in variants or [self]:
            _, others, cams = v.cameras()
            validate_run([(v.scene, v.arch)], str(v.path))
            for cam in cams.values():
                build_draw(v.scene.replace(camera=cam.camera(), objects=tuple(others)))
        s = self.settings_file
        return (f"glossy {s.effect} of '{s.surface}': {s.samples_per_texel} samples per texel, roughness "
                f"{s.roughness:g} degrees, {len(s.study)} study points")

    def run(self, progress=None) -> WorkloadResult:
        from pipeline_sim.render import scene_pass

        s, scene = self.settings_file, self.scene
        surface, others, cams = self.cameras()
        shader = reflection_shader if s.effect == "reflection" else refraction_shader
        study = [n for n in dict.fromkeys(s.study) if n != s.samples_per_texel]
        passes = [self.lens_pass(name, cam, others, s.samples_per_texel) for name, cam in cams.items()]
        passes.append(scene_pass(scene, self.arch, name="main", shader=shader, textures=tuple(cams),
                                 params=self.main_params(surface, cams)))
        passes += [self.lens_pass(f"{name}_spt{n}", cam, others, n) for n in study for name, cam in cams.items()]
        ran = self.run_passes(passes, progress)

        def work(names):
            return (sum(ran[n].counter("shading", "shader_executions") for n in names),
                    float(sum(ran[n].timing.frame_cycles for n in names)))

        lens_names = list(cams)
        executions, cycles = work(lens_names)
        results = {
            "effect": s.effect, "samples_per_texel": s.samples_per_texel, "roughness_deg": s.roughness,
            "texels": list(cams["reflection"].size), "lens_radius": {n: c.radius for n, c in cams.items()},
            "shader_executions": executions, "cycles": cycles,
            "main_shader_executions": work(["main"])[0], "main_cycles": work(["main"])[1],
            "passes": {n: {"shader_executions": r.counter("shading", "shader_executions"),
                           "cycles": float(r.timing.frame_cycles)} for n, r in ran.items()},
        }
        tables, images = {}, {}
        tris = reference_triangles(scene, surface.index)
        light, background = standard_params(scene.light), np.asarray(scene.background, np.float64)
        moving = any(o.moving for o in others)
        if s.reference_samples:
            table = lens_table(s.reference_samples, s.seed + 1)
            refs = [reference_texture(c, table, tris, moving, light, background) for c in cams.values()]
            points = [(s.samples_per_texel, lens_names)] + [(n, [f"{m}_spt{n}" for m in lens_names]) for n in study]
            rows = []
            for n, names in sorted(points):
                err = _rmse([ran[m].image for m in names], refs)
                executions_n, cycles_n = work(names)
                rows.append({"samples_per_texel": n, "error": err, "shader_executions": executions_n,
                             "cycles": cycles_n})
                if s.study:
                    results.update({f"error_spt{n}": err, f"cycles_spt{n}": cycles_n,
                                    f"shader_executions_spt{n}": executions_n})
            results["error"] = _rmse([ran[m].image for m in lens_names], refs)
            for name, ref in zip(lens_names, refs):
                results[f"error_{name}"] = _rmse([ran[name].image], [ref])
            tables["error_vs_samples"] = pd.DataFrame(rows)
            images = {f"reference_{name}": np.concatenate([ref, np.ones(ref.shape[:2] + (1,))], axis=2)
                      for name, ref in zip(lens_names, refs)}
        if s.effect == "refraction":
            cam, eye = cams["refraction"], scene.camera.eye
            hit = central_hit(surface, eye, scene.camera.look_at, str(self.path))
            rings = reference_refraction(cam, surface, eye, hit, s.ior, tris, light, background)
            tables["refraction_error"] = rings
            results.update({
                "camera_height": float(np.dot(eye - surface.point, surface.normal)),
                "refraction_camera_height": cam.distance,
                "refraction_angle_centre_deg": float(refraction_angles(cam, surface, eye, s.ior, hit[None])[2][0]),
                "refraction_angle_mean_deg": float(np.average(rings.angle_mean_deg, weights=rings.texels)),
                "refraction_angle_max_deg": float(rings.angle_max_deg.max()),
                "refraction_colour_error": float(np.average(rings.colour_error, weights=rings.texels)),
            })
        return WorkloadResult(ran, results=finite_results(results), tables=tables, images=images)

    def resolved(self) -> dict:
        _, _, cams = self.cameras()
        return {**super().resolved(), "scene": str(self.scene.path), "image": dataclasses.asdict(self.scene.image),
                "cameras": {n: {"eye": c.eye.tolist(), "forward": c.forward.tolist(), "window": list(c.window),
                                "distance": c.distance, "radius": c.radius, "far": c.far, "size": list(c.size)}
                            for n, c in cams.items()}}

    @property
    def digest(self) -> str:
        return hashlib.sha256((super().digest + self.scene.digest).encode()).hexdigest()


WORKLOAD = Glossy
