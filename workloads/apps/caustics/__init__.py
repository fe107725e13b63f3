"""Caustics on a pool floor from beams rasterized as moving triangles (Nilsson12 §4), checked against photons.

A water surface, a height field of summed sine waves over a square pool of side ``size`` (``cells`` x
``cells`` cells, two triangles a cell), refracts a directional light (Snell's law, index ``ior``). Each
vertex refracts along the height field's analytic normal and its ray meets the floor (z = 0) at its end
point; a surface triangle (the generator) and the triangle of its vertices' end points bound one caustic
beam. A point of the generator with barycentrics l travels to the point of the end triangle with the
same barycentrics, so the beam's section at time t, T(t) = sum_i l_i (p_i + t (q_i - p_i)), is one
moving triangle: the generator at t=0, the end triangle at t=1 (Nilsson12 §4). Its moving edges sweep
the beam's bilinear sides exactly.

Every beam carries the flux of the light crossing its generator, E0 * (the generator's area projected
across the light) * the Fresnel transmittance at the generator's face normal, and spreads it evenly over
each of its sections (flux conservation): on the floor, which it meets in its end section only, its
irradiance is that flux over the end triangle's area.

The passes, for each of two views of the floor (``eye``, a perspective camera, and ``top``, an
orthographic view from above whose pixels are squares of the floor):

1. ``<view>.receivers``: the floor drawn at each pixel's centre; the shader writes the world position the
   eye ray meets (the receiver) into a target, the next pass's texture.
2. ``<view>.light``: the beams as moving triangles, time only, conservative mode (one shader execution per
   (beam, pixel)), backface culling off, the per-pixel time intervals ``intervals`` (``exact``: from the
   edge functions' roots, Gribel10 §4.1; ``tile``: the tile test's t^). The shader adds, with float ADD
   blending, the beam's irradiance times the share of the receiver's footprint the beam's end section
   covers, where the pixel's interval reaches t = 1 (the only section that meets the floor): the footprint
   is the pixel's square of floor in the top view and the receiver point alone in the eye view. The
   irradiance goes to the three colour channels; the fourth counts the shader executions per pixel.

With ``fill_rate`` the eye view's light pass also runs with the other interval method, and the pixels the
bounding volumes of each beam would cover are counted in numpy, both touched in the closed-pixel sense of
conservative mode: the bounding prism of Ernst et al. 2005 (planes through the generator's edges, each
tilted to hold the beam's side, capped by the generator and the floor) and the convex hull of the six
projected vertices. The top view's irradiance is compared with an independent photon trace through the same
surface (:func:`reference_photon_irradiance`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any, Literal

import numba as nb
import numpy as np
import pandas as pd

from pipeline_sim.errors import UserError
from pipeline_sim.output import finite_or_none
from pipeline_sim.pass_state import PassState
from pipeline_sim.scene import Camera, Positive, Vec3
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, Flag, count, number
from pipeline_sim.shaders import IN_PX, IN_PY, IN_PZ, IN_T_HI, IN_TRIANGLE, IN_X, IN_Y, fetch
from pipeline_sim.workload import Workload, WorkloadResult
from workloads.apps.raycast import ray_triangles, refract

METHODS = ("exact", "tile", "prism", "hull")
VIEWS = ("eye", "top")
#: A pixel's interval reaches the beam's end section (t = 1, float32 inputs) from here.
END_T = 1.0 - 1e-6
#: Floats of one beam in the light shader's parameters: its end triangle (x, y) x 3 and its irradiance.
BEAM_PARAMS = 7
#: Pixels a volume may miss a pixel by and still count as touching it (rounding; as ``units.tile_test_exact``).
TOUCH = 1e-7
CENTRE = np.array([[0.5, 0.5, 0.0, 0.0, 0.5]])  # one sample at each pixel's centre
LIGHT_STATE = PassState(mode="conservative", depth_test="always", depth_write=False, blend="add")


@dataclass
class Wave:
    """One ``[[waves]]`` entry: h += amplitude * sin(2 pi (d . (x, y)) / wavelength + phase)."""

    __pydantic_config__ = FORBID
    amplitude: number(0.0, 10.0) = key("height of the crest above the mean, world units")
    wavelength: Positive = key("distance between crests, world units")
    direction: number(-360.0, 360.0) = key("direction the crests travel, degrees from +x toward +y", default=0.0)
    phase: number(-360.0, 360.0) = key("phase at the origin, degrees", default=0.0)


@dataclass
class Settings:
    """The keys of a `caustics` file besides `kind`."""

    __pydantic_config__ = FORBID
    cells: count(1, 512) = key("surface cells along each side of the pool (two generator triangles a cell)",
                               default=64)
    size: Positive = key("side of the square pool, world units (the floor is [0, size]^2 at z = 0)", default=1.0)
    depth: Positive = key("mean water depth, world units", default=0.5)
    waves: list[Wave] = key("the summed waves of the height field (none: flat water)", default_factory=list)
    light: Vec3 = key("direction the light travels (normalized; it must point down)",
                      default_factory=lambda: [0.25, 0.15, -1.0])
    ior: number(1.0, 3.0) = key("index of refraction of the water", default=1.33)
    resolution: count(8, 2048) = key("pixels along each side of the top view", default=128)
    width: count(8, 4096) = key("eye view width, pixels", default=160)
    height: count(8, 4096) = key("eye view height, pixels", default=120)
    eye: Vec3 = key("eye view's camera position", default_factory=lambda: [0.5, -0.45, 1.1])
    look_at: Vec3 = key("eye view's look-at point", default_factory=lambda: [0.5, 0.45, 0.0])
    fov: number(1.0, 170.0) = key("eye view's vertical field of view, degrees", default=60.0)
    intervals: Literal["exact", "tile"] = key("the light passes' per-pixel time intervals: `exact` (edge-function "
                                              "roots) or `tile` (the tile test's t^)", default="exact")
    fill_rate: Flag = key("also run the eye view's light pass with the other interval method and count the "
                          "prism's and the hull's pixels", default=True)
    photons: count(0, 100_000_000) = key("photons of the reference trace (0: none)", default=1_000_000)
    seed: count(0) = key("seed of the photon trace", default=0)
    reference_cells: count(1, 2048) = key("cells of the finer surface whose photon trace (each photon refracted "
                                          "at its interpolated normal) measures what the surface resolution "
                                          "costs", default=256)


@dataclass
class Surface:
    """The triangulated water surface: vertices (V, 3), unit vertex normals (V, 3), faces (F, 3)."""

    vertices: np.ndarray
    normals: np.ndarray
    faces: np.ndarray


@dataclass
class Beams:
    """The caustic beams: generators ``p`` and end triangles ``q`` (B, 3, 3), each beam's flux, Fresnel
    transmittance and irradiance on the floor (B,)."""

    p: np.ndarray
    q: np.ndarray
    flux: np.ndarray
    transmittance: np.ndarray
    irradiance: np.ndarray


def height_field(s: Settings, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The surface height at (x, y) and its two partial derivatives."""
    h = np.full(np.shape(x), float(s.depth))
    hx = np.zeros(np.shape(x))
    hy = np.zeros(np.shape(x))
    for w in s.waves:
        a = math.radians(w.direction)
        k = 2.0 * math.pi / w.wavelength
        arg = k * (math.cos(a) * x + math.sin(a) * y) + math.radians(w.phase)
        h += w.amplitude * np.sin(arg)
        hx += w.amplitude * k * math.cos(a) * np.cos(arg)
        hy += w.amplitude * k * math.sin(a) * np.cos(arg)
    return h, hx, hy


def water_surface(s: Settings) -> Surface:
    """The height field sampled at the grid's vertices, with its analytic normals."""
    g = np.linspace(0.0, s.size, s.cells + 1)
    x, y = np.meshgrid(g, g, indexing="xy")
    h, hx, hy = height_field(s, x, y)
    verts = np.stack([x, y, h], axis=-1).reshape(-1, 3)
    nrm = np.stack([-hx, -hy, np.ones_like(h)], axis=-1).reshape(-1, 3)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    n = s.cells + 1
    i, j = np.meshgrid(np.arange(s.cells), np.arange(s.cells), indexing="xy")
    v = (j * n + i).ravel()
    faces = np.concatenate([np.stack([v, v + 1, v + n + 1], 1), np.stack([v, v + n + 1, v + n], 1)])
    return Surface(verts, nrm, faces)


def light_direction(s: Settings) -> np.ndarray:
    d = np.asarray(s.light, float)
    return d / np.linalg.norm(d)


def fresnel_transmittance(cos_i: np.ndarray, ior: float) -> np.ndarray:
    """Unpolarized Fresnel transmittance from air into index ``ior`` at incidence cosines ``cos_i``."""
    cos_t = np.sqrt(1.0 - (1.0 - cos_i * cos_i) / (ior * ior))
    rs = (cos_i - ior * cos_t) / (cos_i + ior * cos_t)
    rp = (ior * cos_i - cos_t) / (ior * cos_i + cos_t)
    return 1.0 - 0.5 * (rs * rs + rp * rp)


def make_beams(s: Settings, surf: Surface) -> Beams:
    """Each generator triangle and its end triangle on the floor, with its flux and floor irradiance
    (E0 = 1 across the light)."""
    d = light_direction(s)
    r = refract(d, surf.normals, s.ior)
    ends = surf.vertices - (surf.vertices[:, 2] / r[:, 2])[:, None] * r  # each vertex's ray to z = 0
    p, q = surf.vertices[surf.faces], ends[surf.faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # faces wind counter-clockwise seen from above
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / (2.0 * area)[:, None]
    cos_i = -(normal @ d)
    transmittance = fresnel_transmittance(cos_i, s.ior)
    flux = area * cos_i * transmittance
    qa = 0.5 * np.abs((q[:, 1, 0] - q[:, 0, 0]) * (q[:, 2, 1] - q[:, 0, 1])
                      - (q[:, 1, 1] - q[:, 0, 1]) * (q[:, 2, 0] - q[:, 0, 0]))
    return Beams(p, q, flux, transmittance, flux / qa)


def check_surface(s: Settings, where: str) -> None:
    """Refuse (one line) a surface the beam model does not describe: light not pointing down, water
    reaching the floor, a face turned from the light or shadowing another part of the surface."""
    d = np.asarray(s.light, float)
    if not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0.0 or d[2] >= 0.0:
        raise UserError(f"{where}: light: the light must point down (negative z), got {s.light}")
    d = d / np.linalg.norm(d)
    lowest = s.depth - sum(w.amplitude for w in s.waves)
    if lowest <= 0.0:
        raise UserError(f"{where}: waves: their amplitudes ({s.depth - lowest:g} in all) reach the floor "
                        f"below depth {s.depth:g}")
    horizontal = math.hypot(d[0], d[1])
    if horizontal > 0.0:
        # no self-shadowing: the surface must never rise along the light faster than the light falls
        g = np.linspace(0.0, s.size, 4 * s.cells + 1)
        _, hx, hy = height_field(s, *np.meshgrid(g, g))
        rise = float(np.max(hx * d[0] + hy * d[1])) / horizontal
        if rise >= -d[2] / horizontal:
            raise UserError(f"{where}: waves: too steep for the light: the surface rises {rise:.3g} per unit "
                            f"along it, the light falls {-d[2] / horizontal:.3g} (the surface would shadow itself)")


def check_beams(s: Settings, beams: Beams, where: str) -> None:
    """Refuse (one line) beams the passes cannot draw: one focused to a line or a point on the floor (no
    finite irradiance), or a vertex not in front of the eye view's camera."""
    if not np.all(np.isfinite(beams.irradiance)):
        raise UserError(f"{where}: waves: a beam focuses to a line or a point on the floor (infinite irradiance)")
    forward = np.asarray(s.look_at, float) - np.asarray(s.eye, float)
    if np.linalg.norm(np.cross(forward, [0.0, 0.0, 1.0])) <= 1e-9 * max(1.0, float(np.linalg.norm(forward))):
        raise UserError(f"{where}: look_at: the eye view must not look straight up or down (its up axis is +z), "
                        f"got eye {list(s.eye)} and look_at {list(s.look_at)}")
    cam, w, h = view_camera(s, "eye")
    if not np.all(to_clip(cam, w, h, np.concatenate([beams.p, beams.q], axis=1))[..., 3] > 0.0):
        raise UserError(f"{where}: eye: the eye view's camera must see the whole pool in front of it")


# ------------------------------------------------------------------ views


def view_camera(s: Settings, view: str) -> tuple[Camera, int, int]:
    """The camera of ``view`` and its image size."""
    far = 4.0 * (np.linalg.norm(s.eye) + s.size + s.depth)
    if view == "eye":
        return Camera("perspective", np.asarray(s.eye, float), np.asarray(s.look_at, float), np.array([0.0, 0.0, 1.0]),
                      np.asarray(s.eye, float), np.asarray(s.look_at, float), s.fov, 0.01, far), s.width, s.height
    top = 3.0 * s.depth + 1.0
    half = 0.5 * s.size
    eye = np.array([half, half, top])
    look = np.array([half, half, 0.0])
    return Camera("orthographic", eye, look, np.array([0.0, 1.0, 0.0]), eye, look, 0.0, 0.5, 2.0 * top + s.depth,
                  frustum=(-half, half, -half, half)), s.resolution, s.resolution


def to_clip(cam: Camera, width: int, height: int, pts: np.ndarray) -> np.ndarray:
    """World points (..., 3) to clip space (..., 4)."""
    m = cam.projection_matrix(width / height) @ cam.view_matrix(0.0)
    return np.concatenate([pts, np.ones(pts.shape[:-1] + (1,))], axis=-1) @ m.T


def to_pixels(clip: np.ndarray, width: int, height: int) -> np.ndarray:
    """Clip-space points (..., 4) to pixel positions (..., 2), row 0 at the top."""
    return np.stack([(clip[..., 0] / clip[..., 3] + 1.0) * 0.5 * width,
                     (1.0 - clip[..., 1] / clip[..., 3]) * 0.5 * height], axis=-1)


@nb.njit(cache=True, nogil=True)
def receiver_shader(inputs, params, textures, out, append):
    """The floor point each pixel's centre sees: its world position and a flag 1 (Nilsson12 §4's receiver)."""
    for i in range(inputs.shape[1]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = inputs[IN_PX, i], inputs[IN_PY, i], inputs[IN_PZ, i], 1.0


@nb.njit(cache=True)
def _clip_polygon(xs, ys, n, axis, bound, keep_below):
    """Sutherland-Hodgman: the polygon (xs, ys)[:n] cut to coordinate ``axis`` <= ``bound`` (or >=)."""
    ox = np.empty(n + 1)
    oy = np.empty(n + 1)
    m = 0
    for k in range(n):
        ax, ay = xs[k], ys[k]
        bx, by = xs[(k + 1) % n], ys[(k + 1) % n]
        va = (ax if axis == 0 else ay) - bound
        vb = (bx if axis == 0 else by) - bound
        if not keep_below:
            va, vb = -va, -vb
        if va <= 0.0:
            ox[m], oy[m] = ax, ay
            m += 1
        if (va < 0.0 < vb) or (vb < 0.0 < va):
            f = va / (va - vb)
            ox[m], oy[m] = ax + f * (bx - ax), ay + f * (by - ay)
            m += 1
    return ox, oy, m


@nb.njit(cache=True)
def triangle_square_area(ax, ay, bx, by, cx, cy, x0, x1, y0, y1):
    """Area of the triangle (a, b, c) inside the square [x0, x1] x [y0, y1] (clipped polygon, shoelace)."""
    xs = np.array([ax, bx, cx])
    ys = np.array([ay, by, cy])
    n = 3
    for axis, bound, below in ((0, x1, True), (0, x0, False), (1, y1, True), (1, y0, False)):
        xs, ys, n = _clip_polygon(xs, ys, n, axis, bound, below)
        if n == 0:
            return 0.0
    s = 0.0
    for k in range(n):
        s += xs[k] * ys[(k + 1) % n] - xs[(k + 1) % n] * ys[k]
    return 0.5 * abs(s)


@nb.njit(cache=True, nogil=True)
def light_shader(inputs, params, textures, out, append):
    """One (beam, pixel) of a conservative xyt pass (Nilsson12 §4): where the pixel's time interval reaches
    the beam's end section (t = 1, the only section on the floor), the beam's irradiance (``params``: per beam
    its end triangle and irradiance, after ``params[0]``, the receiver footprint's half side) times the share
    of the receiver's footprint it covers: a square of floor (top view) or the receiver point alone (half side
    0), in the three colour channels; channel 3 counts the executions."""
    receivers = textures[0]
    half = params[0]
    for i in range(inputs.shape[1]):
        out[i, 0] = out[i, 1] = out[i, 2] = 0.0
        out[i, 3] = 1.0
        x, y = inputs[IN_X, i], inputs[IN_Y, i]
        if inputs[IN_T_HI, i] < END_T or fetch(receivers, x, y, 3) < 0.5:
            continue
        rx, ry = np.float64(fetch(receivers, x, y, 0)), np.float64(fetch(receivers, x, y, 1))
        b = 1 + BEAM_PARAMS * int(inputs[IN_TRIANGLE, i])
        ax, ay, bx, by = np.float64(params[b]), np.float64(params[b + 1]), np.float64(params[b + 2]), \
            np.float64(params[b + 3])
        cx, cy = np.float64(params[b + 4]), np.float64(params[b + 5])
        if half > 0.0:
            share = triangle_square_area(ax, ay, bx, by, cx, cy, rx - half, rx + half, ry - half, ry + half) / (
                4.0 * half * half)
        else:
            d0 = (bx - ax) * (ry - ay) - (by - ay) * (rx - ax)
            d1 = (cx - bx) * (ry - by) - (cy - by) * (rx - bx)
            d2 = (ax - cx) * (ry - cy) - (ay - cy) * (rx - cx)
            share = 1.0 if (d0 >= 0 and d1 >= 0 and d2 >= 0) or (d0 <= 0 and d1 <= 0 and d2 <= 0) else 0.0
        out[i, 0] = out[i, 1] = out[i, 2] = params[b + 6] * share


# ------------------------------------------------------------------ bounding volumes


@nb.njit(cache=True)
def convex_pixel_counts(points, counts):
    """Add 1 to ``counts`` (H, W) at every pixel whose closed square the convex hull of each ``points[b]``
    (k, 2), in pixels, touches (within ``TOUCH`` pixels, as the exact intervals' margin). Separating axes:
    the square's two and the normal of every pair of points, which include the hull's edges."""
    height, width = counts.shape
    k = points.shape[1]
    for b in range(points.shape[0]):
        pts = points[b]
        x_min, x_max = pts[:, 0].min(), pts[:, 0].max()
        y_min, y_max = pts[:, 1].min(), pts[:, 1].max()
        for py in range(max(0, int(math.floor(y_min)) - 1), min(height - 1, int(math.floor(y_max))) + 1):
            for px in range(max(0, int(math.floor(x_min)) - 1), min(width - 1, int(math.floor(x_max))) + 1):
                if x_min > px + 1 + TOUCH or x_max < px - TOUCH or y_min > py + 1 + TOUCH or y_max < py - TOUCH:
                    continue
                apart = False
                for i in range(k):
                    for j in range(i + 1, k):
                        nx, ny = pts[i, 1] - pts[j, 1], pts[j, 0] - pts[i, 0]
                        lo, hi = np.inf, -np.inf
                        for m in range(k):
                            v = nx * pts[m, 0] + ny * pts[m, 1]
                            lo, hi = min(lo, v), max(hi, v)
                        c_lo, c_hi = np.inf, -np.inf
                        for cx in (px, px + 1):
                            for cy in (py, py + 1):
                                v = nx * cx + ny * cy
                                c_lo, c_hi = min(c_lo, v), max(c_hi, v)
                        slack = TOUCH * (abs(nx) + abs(ny))
                        if c_lo > hi + slack or c_hi < lo - slack:
                            apart = True
                            break
                    if apart:
                        break
                if not apart:
                    counts[py, px] += 1


def prism_vertices(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The bounding prism of each beam (Ernst et al. 2005): through each edge of the generator the plane
    tilted outward just enough to hold both end points of the beam's side, capped by the generator's plane
    and the floor (z = 0); its six vertices (B, 6, 3), where adjacent side planes meet the two caps. A beam
    that focuses through a caustic crosses its side planes before the floor, so they bound no prism there:
    the fill-rate count takes the hull of these vertices and the end triangle, which bounds every beam."""
    b = len(p)
    centre = p.mean(axis=1)
    planes_n = np.empty((b, 3, 3))
    planes_d = np.empty((b, 3))
    for k in range(3):
        i, j = k, (k + 1) % 3
        edge = p[:, j] - p[:, i]
        cand_n, cand_d, slack = [], [], []
        for through, other in ((i, j), (j, i)):  # the plane through the edge and one end point of the side
            n = np.cross(edge, q[:, through] - p[:, i])
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            n *= np.where(np.einsum("bc,bc->b", n, centre - p[:, i]) > 0, -1.0, 1.0)[:, None]  # outward
            d = -np.einsum("bc,bc->b", n, p[:, i])
            cand_n.append(n), cand_d.append(d), slack.append(np.einsum("bc,bc->b", n, q[:, other]) + d)
        second = slack[1] < slack[0]  # the plane that holds the side's other end point (its slack <= 0)
        planes_n[:, k] = np.where(second[:, None], cand_n[1], cand_n[0])
        planes_d[:, k] = np.where(second, cand_d[1], cand_d[0])
    top_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    top_d = -np.einsum("bc,bc->b", top_n, p[:, 0])
    out = np.empty((b, 6, 3))
    for k in range(3):
        a, c = (k - 1) % 3, k  # side planes meeting at generator vertex k
        for cap, (cn, cd) in enumerate(((top_n, top_d), (np.broadcast_to([0.0, 0.0, 1.0], top_n.shape), np.zeros(b)))):
            m = np.stack([planes_n[:, a], planes_n[:, c], cn], axis=1)
            rhs = -np.stack([planes_d[:, a], planes_d[:, c], cd], axis=1)
            out[:, 3 * cap + k] = np.linalg.solve(m, rhs[..., None])[..., 0]
    return out


def projected_volume_pixels(points: np.ndarray, cam: Camera, width: int, height: int) -> np.ndarray:
    """Per pixel, how many of the convex volumes with vertices ``points`` (B, k, 3) its closed square
    touches once projected (every vertex in front of the camera)."""
    counts = np.zeros((height, width), np.int64)
    convex_pixel_counts(to_pixels(to_clip(cam, width, height, points), width, height), counts)
    return counts


# ------------------------------------------------------------------ the photon reference


def reference_photon_irradiance(s: Settings, photons: int, seed: int, interpolated_normal: bool = False
                                ) -> np.ndarray:
    """The floor's irradiance on the top view's pixels (``resolution`` squared, row 0 at y = size) from a
    Monte-Carlo photon trace, written apart from the beams: photons start evenly spread across the light
    (E0 = 1) on a plane above the waves, each is ray cast (Moeller-Trumbore) against the surface's
    triangles near its path, weighted by the Fresnel transmittance at the hit face (sine and tangent
    forms), and lands where the beam model sends it: the point of the triangle of the vertices' floor hits
    with its barycentrics (each vertex refracted by Snell's law in angle form). With
    ``interpolated_normal`` it refracts instead at the hit point's interpolated normal and goes straight to
    the floor (the model error of interpolating the end points)."""
    d = np.asarray(s.light, float)
    d /= np.linalg.norm(d)
    n = s.cells + 1
    g = np.linspace(0.0, s.size, n)
    gx, gy = np.meshgrid(g, g, indexing="xy")
    h, hx, hy = height_field(s, gx, gy)
    verts = np.stack([gx, gy, h], -1).reshape(-1, 3)
    normals = np.stack([-hx, -hy, np.ones_like(h)], -1).reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)

    def snell(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Refracted directions, incidence and refraction angles at unit normals (N, 3)."""
        theta_i = np.arccos(np.clip(-(normal @ d), -1.0, 1.0))
        theta_t = np.arcsin(np.sin(theta_i) / s.ior)
        along = d[None, :] - (normal @ d)[:, None] * normal
        size = np.linalg.norm(along, axis=1, keepdims=True)
        tangent = np.divide(along, size, out=np.zeros_like(along), where=size > 0)
        return np.cos(theta_t)[:, None] * -normal + np.sin(theta_t)[:, None] * tangent, theta_i, theta_t

    out_dir, _, _ = snell(normals)
    ends = verts + (verts[:, 2] / -out_dir[:, 2])[:, None] * out_dir
    cell = s.size / s.cells
    top = s.depth + sum(w.amplitude for w in s.waves) + 1e-3 * s.size
    bottom = s.depth - sum(w.amplitude for w in s.waves)
    slide = -d[:2] / d[2]  # horizontal travel per unit of descent
    lo = -np.maximum(0.0, slide * (top - bottom)) - cell
    hi = s.size + np.maximum(0.0, -slide * (top - bottom)) + cell
    power = -d[2] * float(np.prod(hi - lo)) / photons  # each photon's share of E0 |d_z| over the start box
    span = int(np.ceil(np.max(np.abs(slide)) * (top - bottom) / cell)) + 1  # cells a path crosses per axis
    rng = np.random.default_rng(seed)
    res = s.resolution
    image = np.zeros(res * res)
    for start in range(0, photons, 1 << 18):
        m = min(1 << 18, photons - start)
        o = np.concatenate([rng.uniform(lo, hi, (m, 2)), np.full((m, 1), top)], axis=1)
        ends_xy = (o[:, :2], o[:, :2] + slide * (top - bottom))  # the path's xy at the top and the bottom
        c0 = np.floor(np.minimum(*ends_xy) / cell).astype(np.int64)
        c1 = np.floor(np.maximum(*ends_xy) / cell).astype(np.int64)
        best = np.full(m, np.inf)
        hit_face = np.full(m, -1)
        hit_uv = np.zeros((m, 2))
        for di in range(span):
            for dj in range(span):
                ci, cj = c0[:, 0] + di, c0[:, 1] + dj
                inside = (ci >= 0) & (ci < s.cells) & (cj >= 0) & (cj < s.cells) & (ci <= c1[:, 0]) & (cj <= c1[:, 1])
                v = cj * n + ci
                for second, tri in enumerate(((v, v + 1, v + n + 1), (v, v + n + 1, v + n))):
                    t, u, w, meets = ray_triangles(o, d, *(verts[np.where(inside, k, 0)] for k in tri))
                    ok = inside & meets & (t > 0) & (t < best)
                    best[ok] = t[ok]
                    face = (second * s.cells + cj) * s.cells + ci
                    hit_face[ok] = face[ok]
                    hit_uv[ok] = np.stack([u, w], 1)[ok]
        hit = hit_face >= 0
        f, uv, t = hit_face[hit], hit_uv[hit], best[hit]
        first = f < s.cells * s.cells
        ci = np.where(first, f, f - s.cells * s.cells) % s.cells
        cj = np.where(first, f, f - s.cells * s.cells) // s.cells
        v = cj * n + ci
        ids = np.stack([v, v + 1, v + n + 1], 1)
        ids[~first] = np.stack([v, v + n + 1, v + n], 1)[~first]
        lam = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
        tri_v = verts[ids]
        face_n = np.cross(tri_v[:, 1] - tri_v[:, 0], tri_v[:, 2] - tri_v[:, 0])
        face_n /= np.linalg.norm(face_n, axis=1, keepdims=True)
        _, ti, tt = snell(face_n)
        with np.errstate(divide="ignore", invalid="ignore"):
            rs = np.sin(ti - tt) ** 2 / np.sin(ti + tt) ** 2
            rp = np.tan(ti - tt) ** 2 / np.tan(ti + tt) ** 2
        normal_incidence = ((s.ior - 1.0) / (s.ior + 1.0)) ** 2
        weight = 1.0 - np.where(ti > 1e-6, 0.5 * (rs + rp), normal_incidence)
        if interpolated_normal:
            nrm = np.einsum("ik,ikc->ic", lam, normals[ids])
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
            p = o[hit] + t[:, None] * d
            r, _, _ = snell(nrm)
            land = p + (p[:, 2] / -r[:, 2])[:, None] * r
        else:
            land = np.einsum("ik,ikc->ic", lam, ends[ids])
        col = np.floor(land[:, 0] / s.size * res).astype(np.int64)
        row = np.floor((s.size - land[:, 1]) / s.size * res).astype(np.int64)
        keep = (col >= 0) & (col < res) & (row >= 0) & (row < res)
        np.add.at(image, row[keep] * res + col[keep], weight[keep] * power)
    return image.reshape(res, res) / (s.size / res) ** 2


# ------------------------------------------------------------------ the workload


def relative_errors(raster: np.ndarray, photons: np.ndarray) -> dict[str, float | None]:
    """Overall relative L1 error of ``raster`` against ``photons`` and the median and 95th percentile of the
    per-pixel relative error over the pixels the photons light."""
    lit = photons > 0
    per_pixel = np.abs(raster[lit] - photons[lit]) / photons[lit]
    total = float(np.abs(raster - photons).sum() / max(photons.sum(), np.finfo(float).tiny))
    return {"rel_l1": finite_or_none(total),
            "rel_median_pixel": finite_or_none(float(np.median(per_pixel))) if lit.any() else None,
            "rel_p95_pixel": finite_or_none(float(np.percentile(per_pixel, 95))) if lit.any() else None}


class Caustics(Workload):
    """The kind ``caustics``: beams through a water surface rasterized as moving triangles onto a pool floor."""

    file_schema = Settings

    @classmethod
    def load(cls, path, data: Settings, arch, image: dict[str, int]) -> "Caustics":
        if image:
            raise UserError(f"{path}: a caustics workload has no image settings ({', '.join(image)}); set "
                            "resolution, width and height in the file")
        check_surface(data, str(path))
        self = cls(path, arch)
        self.data = data
        return self

    def check(self, variants=None, *, reference_spp=None) -> str:
        for v in variants or [self]:
            check_surface(v.data, str(v.path))
            check_beams(v.data, make_beams(v.data, water_surface(v.data)), str(v.path))
        s = self.data
        return (f"{2 * s.cells * s.cells} beams, eye view {s.width}x{s.height}, top view "
                f"{s.resolution}x{s.resolution}, {s.photons} reference photons")

    def _passes(self, view: str, beams: Beams, methods: tuple[str, ...]) -> list:
        """The receiver pass and the light pass per interval method of ``view``."""
        from pipeline_sim.draw import draw_from_clip
        from pipeline_sim.render import RenderPass
        from pipeline_sim.targets import ShaderOutput, Target

        s = self.data
        cam, w, h = view_camera(s, view)
        floor = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], float) * s.size
        draw = draw_from_clip(to_clip(cam, w, h, floor), width=w, height=h)
        draw = dataclasses.replace(draw, pos=np.stack([floor, floor]).astype(np.float32))
        out = [RenderPass(draw=draw, arch=self.arch, spp=1, name=f"{view}.receivers", sample_table=CENTRE,
                          state=PassState(shading_mode="per_sample"), shader=receiver_shader,
                          outputs=(ShaderOutput("receivers", 4),),
                          targets=(Target("receivers", source="receivers", clear=(0.0, 0.0, 0.0, 0.0)),))]
        half = 0.5 * s.size / s.resolution if view == "top" else 0.0
        params = np.concatenate([[half], np.concatenate([beams.q[:, :, :2].reshape(-1, 6),
                                                         beams.irradiance[:, None]], axis=1).ravel()])
        beam_draw = draw_from_clip(to_clip(cam, w, h, beams.p), to_clip(cam, w, h, beams.q), width=w, height=h)
        for m in methods:
            out.append(RenderPass(draw=beam_draw, arch=self.arch, spp=1, name=f"{view}.light" + (
                "" if m == s.intervals else f".{m}"), state=LIGHT_STATE.replace(time_intervals=m),
                shader=light_shader, params=params, textures=(f"{view}.receivers.receivers",),
                outputs=(ShaderOutput("light", 4),),
                targets=(Target("light", source="light", clear=(0.0,) * 4, depth="always"),)))
        return out

    def run(self, progress=None) -> WorkloadResult:
        s = self.data
        beams = make_beams(s, water_surface(s))
        check_beams(s, beams, str(self.path))
        other = "tile" if s.intervals == "exact" else "exact"
        methods = {"eye": (s.intervals, other) if s.fill_rate else (s.intervals,), "top": (s.intervals,)}
        passes = self.run_passes([p for v in VIEWS for p in self._passes(v, beams, methods[v])], progress)
        light = {v: passes[f"{v}.light"].images["light"][0] for v in VIEWS}
        chosen = [f"{v}.{k}" for v in VIEWS for k in ("receivers", "light")]
        results: dict[str, Any] = {
            "beams": len(beams.p), "cells": s.cells, "intervals": s.intervals,
            "flux": finite_or_none(float(beams.flux.sum())),
            "cycles": finite_or_none(float(sum(passes[n].timing.frame_cycles for n in chosen))),
            "shader_executions": int(sum(passes[f"{v}.light"].counter("shading", "shader_executions") for v in VIEWS)),
        }
        tables: dict[str, pd.DataFrame] = {}
        if s.fill_rate:
            cam, w, h = view_camera(s, "eye")
            prism = np.concatenate([prism_vertices(beams.p, beams.q), beams.q], axis=1)
            heat = {s.intervals: light["eye"][..., 3].astype(np.int64),
                    other: passes[f"eye.light.{other}"].images["light"][0][..., 3].astype(np.int64),
                    "prism": projected_volume_pixels(prism, cam, w, h),
                    "hull": projected_volume_pixels(np.concatenate([beams.p, beams.q], axis=1), cam, w, h)}
            totals = {m: int(heat[m].sum()) for m in METHODS}
            results["executions"] = totals
            results["ratio_to_prism"] = {m: finite_or_none(totals[m] / totals["prism"]) if totals["prism"] else None
                                         for m in METHODS}
            results["max_executions_per_pixel"] = {m: int(heat[m].max()) for m in METHODS}
            ys, xs = np.nonzero(sum(heat.values()))
            tables["heat_eye"] = pd.DataFrame({"x": xs, "y": ys, **{m: heat[m][ys, xs] for m in METHODS}})
        top = light["top"][..., 0].astype(np.float64)
        results["irradiance_mean"] = finite_or_none(float(top.mean()))
        if not s.waves:
            results["flat"] = self._flat(beams, top)
        if s.photons:
            ref = reference_photon_irradiance(s, s.photons, s.seed)
            err = relative_errors(top, ref)
            results["photons"] = s.photons
            results.update({f"error_{k}": v for k, v in err.items()})
            results["error_rel_l1_by_photons"] = {
                str(n): relative_errors(top, reference_photon_irradiance(s, n, s.seed + 1))["rel_l1"]
                for n in (s.photons // 16, s.photons // 4) if n}
            results["model_error_rel_l1"] = relative_errors(
                top, reference_photon_irradiance(s, s.photons, s.seed, interpolated_normal=True))["rel_l1"]
            fine = dataclasses.replace(s, cells=s.reference_cells)
            results["error_fine_rel_l1"] = relative_errors(
                top, reference_photon_irradiance(fine, s.photons, s.seed + 2, interpolated_normal=True))["rel_l1"]
            ys, xs = np.nonzero((top > 0) | (ref > 0))
            tables["top_pixels"] = pd.DataFrame({"x": xs, "y": ys, "raster": top[ys, xs], "photons": ref[ys, xs]})
        return WorkloadResult(passes, results=results, tables=tables)

    def _flat(self, beams: Beams, top: np.ndarray) -> dict[str, Any]:
        """Flat water: the closed-form irradiance (E0 |L_z| T, every beam a translate of its generator) and
        the spread of the top view over the pixels wholly inside the lit square."""
        s = self.data
        shift = beams.q[0, 0, :2] - beams.p[0, 0, :2]
        res = s.resolution
        c = (np.arange(res) + 0.5) / res * s.size
        px = s.size / res
        x_in = (c - 0.5 * px >= shift[0]) & (c + 0.5 * px <= s.size + shift[0])
        y = s.size - c
        y_in = (y - 0.5 * px >= shift[1]) & (y + 0.5 * px <= s.size + shift[1])
        inner = top[np.ix_(y_in, x_in)]
        expected = float(-light_direction(s)[2] * beams.transmittance[0])
        if not inner.size:
            return {"expected": expected, "pixels": 0, "mean": None, "max_rel_deviation": None}
        return {"expected": expected, "pixels": int(inner.size), "mean": finite_or_none(float(inner.mean())),
                "max_rel_deviation": finite_or_none(float(np.abs(inner / expected - 1.0).max()))}

    def resolved(self) -> dict[str, Any]:
        return {**super().resolved(), **dataclasses.asdict(self.data)}

    @property
    def digest(self) -> str:
        return hashlib.sha256(json.dumps(dataclasses.asdict(self.data), sort_keys=True).encode()).hexdigest()


WORKLOAD = Caustics
