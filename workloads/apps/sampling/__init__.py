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

import dataclasses
import hashlib
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
from pipeline_sim.output import finite_or_none
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, Text, count, number
from pipeline_sim.shaders import append_record
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


@nb.njit
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

