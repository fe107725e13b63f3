"""The rasterizer as a sampler (Nilsson12 §5; docs/sampling-app.md).

A triangle moving over the shutter carves a prism out of xyt (x, y in pixels, t the third axis); with a
thin lens, a shape out of xyuvt. In standard mode, with one shader call per covered sample and the depth
test off, every sample of the pass's pattern inside the prism reaches the shader: ``spp`` samples per
pixel per unit t (per unit t and lens disk area pi in xyuvt) is the density rho, and the expected count
is rho times the volume. Adjacent prisms that share vertex paths place a sample in at most one of them
(the sample tester's top-left rule); the slabs that clip planes in t cut are made half-open,
[t_lo, t_hi), by the shaders here (the clip planes themselves are closed): a sample at t = t_hi belongs
to the next slab, except at t_hi = 1.

Three methods, one per file of this kind:

* ``torus``: the integrals over a torus (axis along t) of 1, x^2 + y^2 and z^2, from prisms bounding it
  (tapered moving triangles per t slab, Nilsson12 Fig. 9); the shader rejects samples outside the torus
  and adds the integrands into a render target (ADD).
* ``poisson``: maximal Poisson-disk sets in 2D and 3D by accelerated dart throwing (Nilsson12 §5,
  Fig. 11): the active voids (axis-aligned cells) are scaled to set the expected candidates, displaced
  randomly into an atlas, rasterized with the depth test off into an append buffer; a compute step
  accepts the candidates that conflict with no point and splits the voids not yet covered, until none
  remains.
* ``density``: white noise following an image's luminance (Nilsson12 Fig. 12): samples under the height
  field (x, y, rho(x, y)) with the height as t, cells bounded by clip planes at their highest density,
  the shader rejecting samples above it; the points are the accepted samples' (x, y).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numba as nb
import numpy as np
import pandas as pd

from pipeline_sim.definitions import IN_OBJECT, IN_SAMPLE, IN_T, IN_U, IN_V, IN_X, IN_Y
from pipeline_sim.errors import UserError
from pipeline_sim.output import finite_results
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, Text, count, number
from pipeline_sim.shaders import append_record, fetch
from pipeline_sim.workload import Workload, WorkloadResult

PATTERNS = ("net", "sobol", "stratified", "random")
RECORD = ("x", "y", "t", "u", "v", "object", "sample")  # what append_shader appends per sample


@dataclass
class Settings:
    """The keys of a `sampling` file besides `kind`."""

    __pydantic_config__ = FORBID
    method: Literal["torus", "poisson", "density"] = key(
        "`torus`: integrals over a torus; `poisson`: a maximal Poisson-disk set; `density`: white noise "
        "following an image's luminance")
    spp: count(1, 256) = key("samples per pixel (per unit t): the sampling density rho", default=16)
    pattern: Literal[PATTERNS] = key("the sample pattern (scrambled per pixel and per seed)", default="random")
    seed: count(0) = key("seed of the sample pattern and of the random choices", default=0)
    resolution: count(8, 2048) = key("torus, density: pixels along each side of the screen", default=64)
    major: number(0.01, 100.0) = key("torus: major radius R", default=1.0)
    minor: number(0.001, 100.0) = key("torus: minor radius r (less than R)", default=0.4)
    slabs: count(1, 256) = key("torus: slabs in t, one draw of tapered prisms each", default=8)
    segments: count(3, 1024) = key("torus: sides of the polygons bounding each slab's annulus", default=24)
    dimension: count(2, 3) = key("poisson: dimension of the unit cube sampled", default=2)
    radius: number(0.01, 0.5) = key("poisson: the smallest distance between two points", default=0.05)
    candidates: number(0.05, 64.0) = key("poisson: expected candidates per void and round", default=1.0)
    layers: count(1, 64) = key("poisson: t layers of the void atlas in 3D (slabs of clip planes)", default=8)
    max_level: count(1, 24) = key("poisson: splits of a base cell before an uncovered void is dropped",
                                  default=14)
    image: Text = key("density: a scikit-image sample image's name (`camera`, `coins`, ...) or an image "
                      "file relative to this file, its luminance the density", default="camera")
    levels: count(1, 64) = key("density: clip-plane heights the cells' bounds are rounded up to", default=8)
    cell: count(1, 64) = key("density: cell side in pixels (two triangles each)", default=4)


# ------------------------------------------------------------------------------------------------------
# Prisms in pixel space


def slab_bounds(n: int) -> np.ndarray:
    """n + 1 slab bounds k/n in t, each a float32 value (clip planes and samples compare exactly)."""
    return (np.arange(n + 1) / n).astype(np.float32).astype(np.float64)


def prism_draw(p0: np.ndarray, p1: np.ndarray, width: int, height: int, *, lens0: np.ndarray | None = None,
               lens1: np.ndarray | None = None, t_lo: float = 0.0, t_hi: float = 1.0,
               objects: np.ndarray | None = None):
    """An orthographic draw (w = 1, z = 0) of triangles whose pixel-space vertices (N, 3, 2) move from
    ``p0`` at t = 0 to ``p1`` at t = 1 (x right, y down), shifted per unit lens coordinate by ``lens0``,
    ``lens1`` (N, 3, 2) pixels at t = 0, 1, clipped to [t_lo, t_hi]; ``objects``: each triangle's
    IN_OBJECT."""
    from pipeline_sim.draw import draw_from_clip
    from pipeline_sim.pass_state import ClipPlanes

    def clip(p):
        c = np.zeros(p.shape[:2] + (4,))
        c[..., 0] = 2.0 * p[..., 0] / width - 1.0
        c[..., 1] = 1.0 - 2.0 * p[..., 1] / height
        c[..., 3] = 1.0
        return c

    n = len(p0)
    lx = np.zeros((n, 3, 2))
    ly = np.zeros((n, 3, 2))
    if lens0 is not None:
        for s, lens in enumerate((lens0, lens1)):
            lx[:, :, s] = 2.0 * lens[..., 0] / width
            ly[:, :, s] = -2.0 * lens[..., 1] / height
    draw = draw_from_clip(clip(np.asarray(p0, float)), clip(np.asarray(p1, float)), lx, ly, width=width,
                          height=height)
    if objects is not None:
        draw.object_id = np.asarray(objects, np.int32)
    draw.clip = ClipPlanes(t_lo=float(t_lo), t_hi=float(t_hi))
    return draw


def reference_prism_volume(p0: np.ndarray, p1: np.ndarray, t_lo: float = 0.0, t_hi: float = 1.0,
                           lens0: np.ndarray | None = None, lens1: np.ndarray | None = None) -> np.ndarray:
    """Each triangle's volume in xyt (or, with lens shifts, in xyuvt over the unit lens disk) between t_lo
    and t_hi, by a quadrature exact for it: the signed area is quadratic in t (degree two in u and in v),
    so 3 Gauss-Legendre points in t, 4 in the disk's radius and 8 angles are exact. Assumes each
    triangle keeps its orientation over the range."""
    gt, wt = np.polynomial.legendre.leggauss(3)
    ts = t_lo + (t_hi - t_lo) * (gt + 1.0) / 2.0
    wt = wt * (t_hi - t_lo) / 2.0
    if lens0 is None:
        nodes = [(0.0, 0.0, 1.0)]
    else:
        gr, wr = np.polynomial.legendre.leggauss(4)
        rho, wr = (gr + 1.0) / 2.0, wr / 2.0
        angles = 2.0 * np.pi * np.arange(8) / 8
        nodes = [(r * np.cos(a), r * np.sin(a), w * r * 2.0 * np.pi / 8) for r, w in zip(rho, wr) for a in angles]
    total = np.zeros(len(p0))
    for t, w_t in zip(ts, wt):
        p = (1.0 - t) * p0 + t * p1
        if lens0 is not None:
            lens = (1.0 - t) * lens0 + t * lens1
        for u, v, w_uv in nodes:
            q = p if lens0 is None else p + np.stack([u * lens[..., 0], v * lens[..., 1]], axis=-1)
            e1, e2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
            total += w_t * w_uv * 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return np.abs(total)


@nb.njit(cache=True)
def _in_slab(t: float, hi: float) -> bool:
    """The half-open slab rule: a sample at the clip plane t = hi < 1 belongs to the next slab."""
    return t < hi or hi >= 1.0


@nb.njit(nogil=True)
def append_shader(inputs, params, textures, out, append):
    """Nilsson12 §5, the volumetric sampler: appends every covered sample (``RECORD``) of its slab
    (``params[object]``: the upper t bound of the triangle's slab) and counts it in ``out``."""
    record = np.empty(7, np.float32)
    for i in range(inputs.shape[1]):
        obj = inputs[IN_OBJECT, i]
        inside = _in_slab(inputs[IN_T, i], params[int(obj)])
        out[i, 0] = 1.0 if inside else 0.0
        if inside:
            record[0], record[1], record[2] = inputs[IN_X, i], inputs[IN_Y, i], inputs[IN_T, i]
            record[3], record[4], record[5], record[6] = inputs[IN_U, i], inputs[IN_V, i], obj, inputs[IN_SAMPLE, i]
            append_record(append, record)


def sampler_pass(draws, spp: int, seed: int, pattern: str, shader, params: np.ndarray, arch, name: str,
                 channels: int = 1, capacity: int = 0, textures: tuple = ()):
    """A pass of the sampler: 1:1 shading, depth test off, no depth writes, the shader's ``channels``
    added per sample (kept per sample), an append buffer of ``capacity`` ``RECORD``s when not 0."""
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.render import RenderPass
    from pipeline_sim.targets import AppendBuffer, ShaderOutput, Target

    state = PassState(depth_test="always", depth_write=False, blend="add", shading_mode="per_sample",
                      sample_pattern=pattern)
    return RenderPass(draw=draws, arch=arch, spp=spp, seed=seed, state=state, name=name, shader=shader,
                      params=np.asarray(params, np.float32), textures=textures,
                      outputs=(ShaderOutput("sum", channels),),
                      targets=(Target("sum", source="sum", clear=(0.0,) * channels, depth="always",
                                      resolve="none"),),
                      append=AppendBuffer(RECORD, capacity) if capacity else None)


def pass_work(result) -> dict[str, int]:
    """The samples a pass's sample tester tested and covered, and its simulated cycles."""
    return {"samples_tested": result.counter("sample_tester", "samples_tested"),
            "samples_covered": result.counter("sample_tester", "samples_covered"),
            "cycles": int(result.timing.frame_cycles)}

# ------------------------------------------------------------------------------------------------------
# Integration over a torus (Nilsson12 §5, Fig. 9)


def reference_torus(major: float, minor: float) -> dict[str, float]:
    """The torus's volume and the integrals of x^2 + y^2 and of z^2 over it (axis z), in closed form."""
    R, r = major, minor
    return {"volume": 2.0 * math.pi**2 * R * r**2, "xy2": 2.0 * math.pi**2 * R * r**2 * (R**2 + 0.75 * r**2),
            "z2": math.pi**2 * R * r**4 / 2.0}


def torus_slab_radii(major: float, minor: float, z0: float, z1: float) -> tuple[float, float, float, float]:
    """The radii at z0 and z1 of an outer and an inner circle varying linearly in z between them, such
    that for every z in [z0, z1] the torus's annulus R - h(z) <= |xy| <= R + h(z), h(z) = sqrt(r^2 - z^2),
    lies between them: h is concave, so its chord raised by the chord's largest gap (where h' equals the
    chord's slope) bounds it from above. Returns (outer0, outer1, inner0, inner1)."""
    r = minor

    def h(z):
        return math.sqrt(max(r * r - z * z, 0.0))

    m = (h(z1) - h(z0)) / (z1 - z0)
    z_star = min(max(-m * r / math.sqrt(1.0 + m * m), z0), z1)
    gap = max(h(z_star) - (h(z0) + m * (z_star - z0)), 0.0) + 1e-9 * r
    h0, h1 = h(z0) + gap, h(z1) + gap
    return major + h0, major + h1, major - h0, major - h1


def torus_prisms(s: Settings) -> tuple[list[tuple[np.ndarray, np.ndarray, float, float]], float, int]:
    """The tapered prisms bounding the torus, per slab (p0, p1, t_lo, t_hi): each slab's annulus bound is a
    ring between a regular polygon around its outer circle and one inside its inner circle, two moving
    triangles per side, whose vertices move radially so that at the slab's bounds they lie on the circles
    of :func:`torus_slab_radii` (extrapolated linearly to t = 0 and 1; shared vertex paths). Also the
    pixels per world unit and the screen side."""
    n, R, r = s.segments, s.major, s.minor
    bounds = slab_bounds(s.slabs)
    radii = [torus_slab_radii(R, r, -r + 2.0 * r * bounds[k], -r + 2.0 * r * bounds[k + 1]) for k in range(s.slabs)]
    if min(min(x[2], x[3]) for x in radii) <= 0.0:
        raise UserError(f"minor: a torus of minor radius {r} is too thick for major radius {R} at {s.slabs} slabs "
                        "(the bound's inner circle shrinks to its axis)")
    extent = max(max(x[0], x[1]) for x in radii) / math.cos(math.pi / n) * 1.01
    width = s.resolution
    scale = width / (2.0 * extent)
    angles = 2.0 * math.pi * np.arange(n + 1) / n
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    i = np.arange(n)
    prisms = []
    for k, (o0, o1, i0, i1) in enumerate(radii):
        ends = []
        for outer, inner in ((o0, i0), (o1, i1)):
            out = ring * outer / math.cos(math.pi / n)
            inn = ring * inner
            tri = np.concatenate([np.stack([out[i], out[i + 1], inn[i + 1]], axis=1),
                                  np.stack([out[i], inn[i + 1], inn[i]], axis=1)])
            ends.append(np.stack([tri[..., 0] * scale + width / 2.0, width / 2.0 - tri[..., 1] * scale], axis=-1))
        t0, t1 = bounds[k], bounds[k + 1]
        step = (ends[1] - ends[0]) / (t1 - t0)
        prisms.append((ends[0] - t0 * step, ends[0] + (1.0 - t0) * step, t0, t1))
    return prisms, scale, width


@nb.njit(nogil=True)
def torus_shader(inputs, params, textures, out, append):
    """Nilsson12 §5, Fig. 9: a sample of the bounding prisms inside the torus adds (1, x^2 + y^2, z^2,
    (x^2 + y^2)^2, z^4) (the integrands and their squares, for the standard errors), else zeros.
    params: pixels per unit, the screen centre, R, r, then each slab's upper t bound."""
    scale, centre, R, r = params[0], params[1], params[2], params[3]
    for i in range(inputs.shape[1]):
        for c in range(5):
            out[i, c] = 0.0
        t = inputs[IN_T, i]
        if not _in_slab(t, params[4 + int(inputs[IN_OBJECT, i])]):
            continue
        x = (np.float64(inputs[IN_X, i]) - centre) / scale
        y = (centre - np.float64(inputs[IN_Y, i])) / scale
        z = -r + 2.0 * r * np.float64(t)
        q = x * x + y * y
        if (math.sqrt(q) - R) ** 2 + z * z < r * r:
            out[i, 0] = 1.0
            out[i, 1] = q
            out[i, 2] = z * z
            out[i, 3] = q * q
            out[i, 4] = z**4


def integrate_torus(s: Settings, arch, run_passes) -> tuple[dict, dict]:
    """Run the torus pass; its estimates with standard errors, the closed forms and the work."""
    prisms, scale, width = torus_prisms(s)
    draws = [prism_draw(p0, p1, width, width, t_lo=lo, t_hi=hi, objects=np.full(len(p0), k))
             for k, (p0, p1, lo, hi) in enumerate(prisms)]
    params = np.concatenate([[scale, width / 2.0, s.major, s.minor], [hi for _, _, _, hi in prisms]])
    passes = run_passes([sampler_pass(draws, s.spp, s.seed, s.pattern, torus_shader, params, arch, "torus",
                                      channels=5)])
    result = passes["torus"]
    sums = result.sample_data["sum"].reshape(-1, 5).sum(axis=0, dtype=np.float64)
    density = s.spp * scale**2 / (2.0 * s.minor)  # samples per unit world volume
    in_box = s.spp * width * width  # samples of the screen over the whole shutter
    exact = reference_torus(s.major, s.minor)
    bound = sum(reference_prism_volume(p0, p1, lo, hi).sum() for p0, p1, lo, hi in prisms) / density * s.spp
    out = {"points_inside": int(sums[0]), "density": density, "bound_volume": bound, "triangles": sum(d.n for d in draws)}
    for name, total, square in (("volume", sums[0], sums[0]), ("xy2", sums[1], sums[3]), ("z2", sums[2], sums[4])):
        se = math.sqrt(max(square - total * total / in_box, 0.0)) / density
        estimate = total / density
        out.update({name: estimate, f"{name}_se": se, f"{name}_exact": exact[name],
                    f"{name}_rel_error": (estimate - exact[name]) / exact[name],
                    f"{name}_error": abs(estimate - exact[name]) / exact[name],
                    f"{name}_z": (estimate - exact[name]) / se if se > 0 else None})
    out.update(pass_work(result))
    return passes, out


# ------------------------------------------------------------------------------------------------------
# Maximal Poisson-disk sets by accelerated dart throwing (Nilsson12 §5, Fig. 11)


def base_grid(dimension: int, radius: float) -> int:
    """Cells per axis of the unit cube's base grid: the largest cells whose diagonal is at most r, so one
    point covers the cell it lies in and a cell holds at most one point."""
    return int(math.ceil(math.sqrt(dimension) / radius))


@nb.njit(cache=True)
def _cell(p: np.ndarray, n0: int, nz: int) -> tuple[int, int, int]:
    return min(int(p[0] * n0), n0 - 1), min(int(p[1] * n0), n0 - 1), min(int(p[2] * n0), nz - 1)


@nb.njit(cache=True)
def accept_candidates(candidates, points, count, grid, radius):
    """The compute step's conflict resolution (Nilsson12 §5): each candidate (rows of ``candidates``, in
    the order given) joins ``points`` (``count[0]`` of them so far) unless a point lies closer than
    ``radius`` (found through ``grid``, one point index per base cell, -1 for none). Returns the number
    accepted."""
    n0, nz = grid.shape[0], grid.shape[2]
    reach = int(math.ceil(radius * n0))
    r2 = radius * radius
    accepted = 0
    for j in range(candidates.shape[0]):
        p = candidates[j]
        cx, cy, cz = _cell(p, n0, nz)
        ok = grid[cx, cy, cz] < 0
        for x in range(max(cx - reach, 0), min(cx + reach + 1, n0)):
            for y in range(max(cy - reach, 0), min(cy + reach + 1, n0)):
                for z in range(max(cz - reach, 0), min(cz + reach + 1, nz)):
                    k = grid[x, y, z]
                    if ok and k >= 0:
                        d = points[k] - p
                        ok = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] >= r2
        if ok:
            points[count[0]] = p
            grid[cx, cy, cz] = count[0]
            count[0] += 1
            accepted += 1
    return accepted


@nb.njit(cache=True)
def _covered(origin, side, dimension, points, grid, radius):
    """Nilsson12 §5, a void's coverage test: whether one point lies within ``radius`` of every corner of
    the cell [origin, origin + side)^d (the ball being convex, it then covers the cell)."""
    n0, nz = grid.shape[0], grid.shape[2]
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for a in range(3):
        n = n0 if a < 2 else nz
        lo[a] = max(int((origin[a] - radius) * n0), 0)
        hi[a] = min(int((origin[a] + side + radius) * n0), n - 1)
    if dimension == 2:
        lo[2], hi[2] = 0, 0
    for x in range(lo[0], hi[0] + 1):
        for y in range(lo[1], hi[1] + 1):
            for z in range(lo[2], hi[2] + 1):
                k = grid[x, y, z]
                if k >= 0:
                    far = 0.0
                    for a in range(dimension):
                        e = max(abs(points[k, a] - origin[a]), abs(points[k, a] - origin[a] - side))
                        far += e * e
                    if far <= radius * radius:
                        return True
    return False


@nb.njit(cache=True)
def split_voids(levels, coords, dimension, points, grid, radius, max_level):
    """The compute step's void update (Nilsson12 §5): a void (level l, integer corner ``coords`` in cells
    of side 1 / (n0 2^l)) that one point covers is dropped; one that is not is split into its 2^d
    children, of which those not covered stay active; at ``max_level`` it is dropped instead and counted.
    Returns the new levels and coords, and the number and volume of voids dropped uncovered."""
    n0 = grid.shape[0]
    out_l = np.empty(levels.shape[0] * (1 << dimension), np.int64)
    out_c = np.empty((levels.shape[0] * (1 << dimension), 3), np.int64)
    m = 0
    dropped = 0
    dropped_volume = 0.0
    origin = np.zeros(3)
    for v in range(levels.shape[0]):
        side = 1.0 / (n0 * (1 << levels[v]))
        for a in range(dimension):
            origin[a] = coords[v, a] * side
        if _covered(origin, side, dimension, points, grid, radius):
            continue
        if levels[v] >= max_level:
            dropped += 1
            dropped_volume += side**dimension
            continue
        for child in range(1 << dimension):
            for a in range(dimension):
                out_c[m, a] = 2 * coords[v, a] + ((child >> a) & 1)
                origin[a] = out_c[m, a] * side / 2.0
            if not _covered(origin, side / 2.0, dimension, points, grid, radius):
                out_l[m] = levels[v] + 1
                if dimension == 2:
                    out_c[m, 2] = 0
                m += 1
    return out_l[:m].copy(), out_c[:m].copy(), dropped, dropped_volume


def void_atlas(levels: np.ndarray, s: Settings, rng: np.random.Generator) -> dict:
    """The active voids as squares of one size (all voids scaled alike: ``candidates`` expected samples
    each, Nilsson12 §5), each at a random displacement within its slot of an atlas; in 3D, the atlas has
    ``layers`` slabs in t, one draw each. Returns the draws' geometry and what maps samples back."""
    n = len(levels)
    layers = s.layers if s.dimension == 3 else 1
    per_layer = -(-n // layers)
    cols = int(math.ceil(math.sqrt(per_layer)))
    rows = -(-per_layer // cols)
    side = math.sqrt(s.candidates * layers / s.spp)  # pixels: spp * side^2 / layers samples expected
    slot = side + 1.0
    j = np.arange(n)
    layer, jj = j // per_layer, j % per_layer
    corner = np.stack([jj % cols, jj // cols], axis=1) * slot + rng.random((n, 2))
    square = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float) * side
    bounds = slab_bounds(layers)
    return {"corner": corner, "side": side, "layer": layer, "bounds": bounds, "layers": layers,
            "width": max(int(math.ceil(cols * slot)), 1), "height": max(int(math.ceil(rows * slot)), 1),
            "triangles": (corner[:, None, None, :] + square[None]).reshape(-1, 3, 2)}


def poisson_disk(s: Settings, arch, run_passes) -> tuple[dict, dict, np.ndarray, pd.DataFrame]:
    """Dart throwing to a maximal Poisson-disk set of the unit cube (Nilsson12 §5): per round, the active
    voids rasterized as an atlas (depth test off, candidates appended), the candidates accepted greedily
    in a random order, the voids split; until no void remains. Returns the passes, the results, the
    points (N, d) and one row per round."""
    rng = np.random.default_rng(s.seed)
    d = s.dimension
    n0 = base_grid(d, s.radius)
    grid = np.full((n0, n0, n0 if d == 3 else 1), -1, np.int64)
    points = np.zeros((grid.size, 3))
    count = np.zeros(1, np.int64)
    idx = np.indices((n0,) * d).reshape(d, -1).T
    levels = np.zeros(len(idx), np.int64)
    coords = np.zeros((len(idx), 3), np.int64)
    coords[:, :d] = idx
    passes, rows = {}, []
    dropped, dropped_volume = 0, 0.0
    while len(levels):
        atlas = void_atlas(levels, s, rng)
        tri_void = np.repeat(np.arange(len(levels)), 2)
        draws = []
        for layer in range(atlas["layers"]):
            mine = atlas["layer"][tri_void] == layer
            if mine.any():
                tri = atlas["triangles"][mine]
                draws.append(prism_draw(tri, tri, atlas["width"], atlas["height"], t_lo=atlas["bounds"][layer],
                                        t_hi=atlas["bounds"][layer + 1], objects=tri_void[mine]))
        capacity = int(3 * s.candidates * len(levels)) + 1024
        name = f"round_{len(rows):02d}"
        params = atlas["bounds"][atlas["layer"] + 1]
        result = run_passes([sampler_pass(draws, s.spp, s.seed + len(rows), s.pattern, append_shader, params, arch,
                                          name, capacity=capacity)])[name]
        passes[name] = result
        records = result.append.records.astype(np.float64)
        void = records[:, 5].astype(np.int64)
        local = np.zeros((len(records), 3))
        local[:, :2] = (records[:, :2] - atlas["corner"][void]) / atlas["side"]
        if d == 3:
            lo, hi = atlas["bounds"][atlas["layer"][void]], atlas["bounds"][atlas["layer"][void] + 1]
            local[:, 2] = (records[:, 2] - lo) / (hi - lo)
        side = 1.0 / (n0 * (2.0 ** levels[void]))
        candidates = (coords[void] + np.clip(local, 0.0, 1.0 - 1e-12)) * side[:, None]
        candidates[:, d:] = 0.0
        accepted = accept_candidates(candidates[rng.permutation(len(candidates))], points, count, grid, s.radius)
        voids, level = len(levels), int(levels[0])  # every round splits all its voids: one level
        levels, coords, lost, lost_volume = split_voids(levels, coords, d, points, grid, s.radius, s.max_level)
        dropped += lost
        dropped_volume += lost_volume
        rows.append({"round": len(rows), "voids": voids, "level": level,
                     "candidates": len(records), "overflow": int(result.append.overflow), "accepted": accepted,
                     "points": int(count[0]), **pass_work(result)})
    table = pd.DataFrame(rows)
    pts = points[:count[0], :d].copy()
    ball = math.pi * (s.radius / 2.0) ** 2 if d == 2 else 4.0 / 3.0 * math.pi * (s.radius / 2.0) ** 3
    results = {"points": len(pts), "rounds": len(rows), "coverage": len(pts) * ball,
               "candidates_appended": int(table.candidates.sum()), "accepted": int(table.accepted.sum()),
               "overflow": int(table.overflow.sum()), "dropped_voids": dropped, "dropped_volume": dropped_volume,
               "samples_tested": int(table.samples_tested.sum()), "samples_covered": int(table.samples_covered.sum()),
               "cycles": int(table.cycles.sum())}
    return passes, results, pts, table


def reference_poisson(dimension: int, radius: float, seed: int) -> tuple[np.ndarray, float]:
    """scipy's Poisson-disk sampler (Bridson's algorithm, filled until no candidate fits) on the unit cube,
    and its wall time."""
    from scipy.stats import qmc

    start = time.perf_counter()
    pts = qmc.PoissonDisk(dimension, radius=radius, seed=seed).fill_space()
    return pts, time.perf_counter() - start


# ------------------------------------------------------------------------------------------------------
# Adaptive white noise under a density height field (Nilsson12 §5, Fig. 12)


def load_density(image: str, folder: Path, resolution: int) -> np.ndarray:
    """An image's luminance, ``resolution`` pixels high, scaled to a largest value of 1 (float32): a
    scikit-image sample image by name, or an image file relative to ``folder``."""
    import skimage.data
    from skimage.color import rgb2gray
    from skimage.transform import resize

    if "." in image:
        from PIL import Image

        path = folder / image
        if not path.is_file():
            raise UserError(f"image: no file {path}")
        pixels = np.asarray(Image.open(path).convert("RGB"))
    elif image in skimage.data.__all__ and image not in ("download_all", "lfw_subset", "stereo_motorcycle"):
        pixels = getattr(skimage.data, image)()
    else:
        raise UserError(f"image: '{image}' is neither an image file nor a scikit-image sample image")
    gray = rgb2gray(pixels[..., :3]) if pixels.ndim == 3 else pixels.astype(float)
    h, w = gray.shape
    rho = resize(gray.astype(float), (resolution, max(int(round(resolution * w / h)), 1)), anti_aliasing=True)
    if not rho.max() > 0.0:
        raise UserError(f"image: '{image}' is black: no density to follow")
    return (np.clip(rho, 0.0, None) / rho.max()).astype(np.float32)


def density_cells(rho: np.ndarray, cell: int, levels: int) -> dict[int, np.ndarray]:
    """The bound under the height field: per cell of ``cell`` x ``cell`` pixels, its highest density
    rounded up to one of ``levels`` clip-plane heights; per height (index into slab_bounds(levels)), the
    corners (N, 2) of its cells. Cells of zero density are left out."""
    h, w = rho.shape
    bounds = slab_bounds(levels)
    cells: dict[int, list] = {}
    for y in range(0, h, cell):
        for x in range(0, w, cell):
            top = rho[y:y + cell, x:x + cell].max()
            if top > 0.0:
                cells.setdefault(int(np.searchsorted(bounds, top)), []).append((x, y))
    return {k: np.array(v, float) for k, v in sorted(cells.items())}


@nb.njit(nogil=True)
def density_shader(inputs, params, textures, out, append):
    """Nilsson12 §5, Fig. 12: a sample (x, y, t) under the height field (t below the density of its pixel,
    ``textures[0]``) is appended (``RECORD``); the others are rejected."""
    rho = textures[0]
    record = np.empty(7, np.float32)
    for i in range(inputs.shape[1]):
        x, y, t = inputs[IN_X, i], inputs[IN_Y, i], inputs[IN_T, i]
        inside = t < fetch(rho, x, y, 0)
        out[i, 0] = 1.0 if inside else 0.0
        if inside:
            record[0], record[1], record[2], record[3], record[4] = x, y, t, inputs[IN_U, i], inputs[IN_V, i]
            record[5], record[6] = inputs[IN_OBJECT, i], inputs[IN_SAMPLE, i]
            append_record(append, record)


def adaptive_white_noise(s: Settings, rho: np.ndarray, arch, run_passes) -> tuple[dict, dict, np.ndarray]:
    """Samples under the height field (x, y, rho(x, y)), t the height, projected on (x, y): one draw per
    clip-plane height of the cells bounded by it (two static triangles per cell). Returns the passes, the
    results and the points (N, 2), in pixels."""
    from scipy import stats

    h, w = rho.shape
    bounds = slab_bounds(s.levels)
    square = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float) * s.cell
    draws = []
    cells = density_cells(rho, s.cell, s.levels)
    for level, corners in cells.items():
        tri = np.minimum((corners[:, None, None, :] + square[None]).reshape(-1, 3, 2), [w, h])
        draws.append(prism_draw(tri, tri, w, h, t_hi=bounds[level], objects=np.full(len(tri), level)))
    expected = s.spp * float(rho.sum(dtype=np.float64))
    capacity = int(expected + 6.0 * math.sqrt(expected)) + 1024
    passes = run_passes([sampler_pass(draws, s.spp, s.seed, s.pattern, density_shader, np.zeros(1), arch, "density",
                                      capacity=capacity, textures=(rho[..., None],))])
    result = passes["density"]
    pts = result.append.records[:, :2].astype(np.float64)
    observed = block_sums(np.histogram2d(pts[:, 1], pts[:, 0], bins=(h, w), range=((0, h), (0, w)))[0], 8)
    # per pixel, spp samples each under the height field with probability rho: binomial counts
    mean = block_sums(s.spp * rho.astype(np.float64), 8)
    var = block_sums(s.spp * rho.astype(np.float64) * (1.0 - rho), 8)
    keep = var > 0
    chi2 = float(((observed[keep] - mean[keep]) ** 2 / var[keep]).sum())
    bound = sum(len(c) * s.cell**2 * bounds[k] for k, c in cells.items())
    results = {"points": len(pts), "expected_points": expected, "points_z": (len(pts) - expected) / math.sqrt(expected),
               "overflow": int(result.append.overflow), "bound_volume": bound, "density_volume": float(rho.sum()),
               "chi2_blocks": int(keep.sum()), "chi2": chi2,
               "chi2_pvalue": float(stats.chi2.sf(chi2, int(keep.sum()))), **pass_work(result)}
    return passes, results, pts


def block_sums(a: np.ndarray, n: int) -> np.ndarray:
    """Sums of ``a`` over an n x n grid of blocks (rows and columns cut as evenly as they divide)."""
    rows = np.arange(a.shape[0]) * n // a.shape[0]
    cols = np.arange(a.shape[1]) * n // a.shape[1]
    out = np.zeros((n, n))
    np.add.at(out, (rows[:, None], cols[None, :]), a)
    return out.ravel()


# ------------------------------------------------------------------------------------------------------
# The workload kind


def plot_points(points: np.ndarray, extent: tuple[float, float], title: str, radius: float | None = None):
    """A figure of a point set (x right, y down as on screen; a 3D set seen along z, coloured by z)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 6 * extent[1] / extent[0]))
    ax = fig.add_subplot()
    size = 2.0 if radius is None else max((72.0 * 6.0 * radius / extent[0]) ** 2 / 4.0, 0.5)
    colour = {"c": points[:, 2], "cmap": "viridis"} if points.shape[1] == 3 else {"c": "k"}
    ax.scatter(points[:, 0], points[:, 1], s=size, linewidths=0, **colour)
    ax.set_xlim(0, extent[0])
    ax.set_ylim(extent[1], 0)
    ax.set_aspect("equal")
    ax.set_title(title)
    fig.tight_layout()
    return fig


class Sampling(Workload):
    """The kind ``sampling``: the rasterizer as a sampler (Nilsson12 §5), by ``method``."""

    file_schema = Settings

    def check(self, variants=None, *, reference_spp=None) -> str:
        from pipeline_sim.sampling import check_spp

        for v in variants or [self]:
            s = v.settings_file
            check_spp(s.pattern, s.spp, 64, str(v.path))
            if s.method == "torus" and s.minor >= s.major:
                raise UserError(f"{v.path}: minor: the minor radius {s.minor} must be less than the major "
                                f"radius {s.major}")
            try:
                if s.method == "torus":
                    torus_prisms(s)
                elif s.method == "density":
                    load_density(s.image, v.path.parent, s.resolution)
            except UserError as e:
                raise UserError(f"{v.path}: {e}") from None
        s = self.settings_file
        what = {"torus": f"a torus (R {s.major}, r {s.minor}) in {s.slabs} slabs of {2 * s.segments} prisms",
                "poisson": f"a maximal Poisson-disk set in {s.dimension}D, radius {s.radius}",
                "density": f"white noise following the luminance of {s.image}"}[s.method]
        return f"{what}, {s.spp} spp ({s.pattern})"

    def run(self, progress=None) -> WorkloadResult:
        s = self.settings_file

        def run_passes(passes):
            return self.run_passes(passes, progress)

        start = time.perf_counter()
        if s.method == "torus":
            passes, results = integrate_torus(s, self.arch, run_passes)
            return WorkloadResult(passes, results=finite_results(results))
        if s.method == "poisson":
            passes, results, pts, table = poisson_disk(s, self.arch, run_passes)
            results["wall_time_s"] = time.perf_counter() - start
            ref, ref_time = reference_poisson(s.dimension, s.radius, s.seed)
            results.update({"scipy_points": len(ref), "scipy_wall_time_s": ref_time,
                            "points_vs_scipy": len(pts) / len(ref)})
            fig = plot_points(pts, (1.0, 1.0), f"{len(pts)} points, radius {s.radius}", s.radius)
            return WorkloadResult(passes, results=finite_results(results),
                                  tables={"rounds": table}, arrays={"points": pts}, figures={"points": fig})
        rho = load_density(s.image, self.path.parent, s.resolution)
        passes, results, pts = adaptive_white_noise(s, rho, self.arch, run_passes)
        fig = plot_points(pts, (rho.shape[1], rho.shape[0]), f"{len(pts)} points following {s.image}")
        return WorkloadResult(passes, results=finite_results(results),
                              arrays={"points": pts, "density": rho}, figures={"points": fig})



WORKLOAD = Sampling
