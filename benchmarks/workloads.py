"""Workloads for the benchmarks: the default scene at other sizes, and random triangles."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pipeline_sim.config import load_arch
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.render import RenderPass, scene_pass
from pipeline_sim.scene import load_scene

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SCENE = ROOT / "workloads" / "scenes" / "default.toml"


def default_pass(width: int | None = None, height: int | None = None, spp: int | None = None,
                 scene_path: Path = DEFAULT_SCENE) -> RenderPass:
    """The standard pass of a scene file, optionally at another image size or spp."""
    scene = load_scene(scene_path)
    img = scene.image
    changes = {k: v for k, v in (("width", width), ("height", height), ("spp", spp)) if v is not None}
    if changes:
        scene = scene.replace(image=dataclasses.replace(img, **changes))
    return scene_pass(scene, load_arch())


def random_triangles_pass(n: int, width: int, height: int, spp: int, seed: int = 7,
                          size_px: float = 4.0, motion_px: float = 8.0, coc_px: float = 3.0,
                          back_to_front: bool = False) -> RenderPass:
    """``n`` random small triangles (vertices within ``size_px`` of a centre), each
    moving by up to ``motion_px`` pixels over the shutter and defocused by a
    circle of confusion of up to ``coc_px`` pixels, at random depths and w in [1, 4].

    In submission order by default; ``back_to_front`` submits the farthest
    first, so no triangle is hidden by an earlier one: z-cull culls
    nothing and each triangle does the same expected work at any ``n``."""
    rng = np.random.default_rng(seed)
    cx = rng.uniform(0, width, (n, 1))
    cy = rng.uniform(0, height, (n, 1))
    px = cx + rng.uniform(-size_px, size_px, (n, 3))
    py = cy + rng.uniform(-size_px, size_px, (n, 3))
    mx = rng.uniform(-motion_px, motion_px, (n, 1))
    my = rng.uniform(-motion_px, motion_px, (n, 1))
    z = rng.uniform(0.05, 0.95, (n, 1)) + rng.uniform(-0.01, 0.01, (n, 3))
    w = rng.uniform(1.0, 4.0, (n, 1)) * rng.uniform(0.95, 1.05, (n, 3))

    def clip(sx, sy):
        ndc_x = 2.0 * sx / width - 1.0
        ndc_y = 1.0 - 2.0 * sy / height
        return np.stack([ndc_x * w, ndc_y * w, z * w, w], axis=-1)

    q = clip(px, py)
    r = clip(px + mx, py + my)
    coc = rng.uniform(0.0, coc_px, (n, 1)) * np.ones((n, 3))
    lens_x = np.repeat((coc * 2.0 / width * w)[:, :, None], 2, axis=2)
    lens_y = np.repeat((coc * 2.0 / height * w)[:, :, None], 2, axis=2)
    color = rng.uniform(0.2, 1.0, (n, 3)).astype(np.float32)
    if back_to_front:
        order = np.argsort(-z.max(axis=1), kind="stable")
        q, r, lens_x, lens_y, color = q[order], r[order], lens_x[order], lens_y[order], color[order]
    draw = draw_from_clip(q, r, lens_x, lens_y, color, width=width, height=height)
    return RenderPass(draw=draw, arch=load_arch(), spp=spp, seed=1)
