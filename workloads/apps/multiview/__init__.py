"""Stereo and multi-view rendering in one 5D pass (Nilsson12 §8; docs/multiview.md).

Cameras on a horizontal camera line become one oblong lens: lens coordinate u runs along the line
(u * half_width world units from its centre), v across it (v * aperture_height). Each view is a lens
region (``LensRegion``) along u, a box window of ``window`` camera spacings centred on its camera:
``window = 1`` splits the lens into disjoint, adjacent sub-lenses (stereo), ``window = 2`` overlaps
each window with its neighbours' halves (the overlapping box filters of Nilsson12 Fig. 17 against
inter-perspective aliasing). The lens's focus distance is the zero-parallax plane. One pass with
motion blur and defocus samples the whole lens from a sample table whose u is stratified, so every
view gets ``samples_per_view`` samples per pixel; the ROP resolves one image per view.

The shading cache (docs/pipeline.md §2.6) keys each sample by the surface point it sees, projected by
a reference camera on the line (``reference_x``) at mid-shutter, and reuses a shading point across
views, time and lens. ``results.json`` gives the shader executions of 1, 2 and 7 views (``view_counts``)
with no cache, with caches of ``cache_sizes`` entries and with an unbounded one, each count's increase
over one view, and each view's error against a ray-cast reference from its own camera
(``reference_view_images``: numpy, independent of the 5D path).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Annotated

import numpy as np
import pandas as pd
from pydantic import Field

from pipeline_sim.config import ArchConfig, apply_overrides
from pipeline_sim.errors import UserError
from pipeline_sim.output import finite_or_none
from pipeline_sim.scene import Camera
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, count, number
from pipeline_sim.workload import Workload, WorkloadResult
from workloads.apps.raycast import ray_triangles

# the camera line's centre camera: at the origin looking down -z, vertical field of view 45 degrees
CAMERA = Camera("perspective", np.zeros(3), np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0]), np.zeros(3),
                np.array([0.0, 0.0, -1.0]), 45.0, 0.5, 40.0)
CLEAR = (0.0, 0.0, 0.0, 1.0)
# the standard shader's directional light (pipeline_sim.shaders.STANDARD_PARAMS): direction, colour, ambient
LIGHT_DIRECTION = np.array([-0.4, -1.0, -0.6]) / np.linalg.norm([-0.4, -1.0, -0.6])
LIGHT = np.array([0.0, *LIGHT_DIRECTION, 0.9, 0.9, 0.9, 0.25], np.float32)
# shading-cache entries of the "unbounded" cache: at least this many times the pass's samples (doubled
# until nothing is evicted)
UNBOUNDED_FACTOR = 4

Counts = Annotated[list[count(1, 64)], Field(max_length=8)]
Sizes = Annotated[list[count(0, 1 << 22)], Field(max_length=8)]


@dataclass
class Settings:
    """The keys of a `multiview` file besides `kind`."""

    __pydantic_config__ = FORBID
    width: count(8, 1024) = key("image width of every view, pixels", default=64)
    height: count(8, 1024) = key("image height of every view, pixels", default=48)
    views: count(1, 64) = key("views rendered and written (cameras on the camera line)", default=2)
    samples_per_view: count(1, 256) = key("samples per pixel in each view's lens region", default=8)
    window: number(1.0, 4.0) = key("width of each view's box window along the camera line, in camera spacings "
                                   "(1: disjoint sub-lenses, stereo; 2: overlapping, multi-view)", default=1.0)
    spacing: number(0.0, 2.0) = key("distance between adjacent cameras, world units", default=0.3)
    aperture_height: number(0.0, 1.0) = key("half height of the lens across the camera line, world units",
                                            default=0.1)
    focus_distance: number(1.0, 40.0) = key("distance of the plane in focus (zero parallax), world units",
                                            default=8.0)
    motion: number(0.0, 10.0) = key("how far the moving boxes travel over the shutter, world units", default=1.0)
    seed: count(0) = key("seed of the sample table and the per-pixel scrambling", default=0)
    reference_x: number(-10.0, 10.0) = key("position on the camera line of the shading cache's reference camera, "
                                           "world units from its centre", default=0.0)
    view_counts: Counts = key("view counts whose shader executions results.json compares (each its own camera "
                              "line of the same spacing, window and samples per view; empty: none)",
                              default_factory=lambda: [1, 2, 7])
    cache_sizes: Sizes = key("shading-cache entries compared (0: no cache, one shader execution per covered "
                             "sample); an unbounded cache is added (with any view count)",
                             default_factory=lambda: [0, 1024])
    reference_spp: count(1, 4096) = key("rays per pixel of each view's ray-cast reference (the error figures)",
                                        default=64)


@dataclass(frozen=True)
class Layout:
    """The camera line of ``views`` cameras: the oblong lens and each view's window on it.

    Camera k sits at x_k = (k - (views - 1) / 2) * spacing; its window spans x_k +- window * spacing / 2;
    the lens spans the union, half_width = ((views - 1) / 2 + window / 2) * spacing, and lens coordinate
    u maps to x = u * half_width."""

    views: int
    spacing: float
    window: float
    samples_per_view: int

    @property
    def half_width(self) -> float:
        return ((self.views - 1) / 2 + self.window / 2) * self.spacing

    @property
    def spp(self) -> int:
        """Samples per pixel over the whole lens: the lens is (views - 1 + window) / window windows wide."""
        return round(self.samples_per_view * (self.views - 1 + self.window) / self.window)

    def windows(self) -> list[tuple[float, float]]:
        """Each view's window [u_lo, u_hi] in lens coordinates, left to right."""
        step = 2.0 / (self.views - 1 + self.window)  # one spacing in lens coordinates
        return [(-1.0 + k * step, -1.0 + (k + self.window) * step) for k in range(self.views)]


def check_layout(layout: Layout, where: str) -> None:
    """Refuse a camera line whose windows do not hold a whole number of the lens's strata each."""
    exact = layout.samples_per_view * (layout.views - 1 + layout.window) / layout.window
    if layout.spacing == 0 and layout.views > 1:
        raise UserError(f"{where}: spacing: {layout.views} views need cameras apart (spacing > 0)")
    if abs(exact - round(exact)) > 1e-9 or abs(layout.samples_per_view / layout.window
                                               - round(layout.samples_per_view / layout.window)) > 1e-9:
        raise UserError(f"{where}: samples_per_view = {layout.samples_per_view} with window = {layout.window:g} "
                        f"and {layout.views} views: samples_per_view / window and samples_per_view * "
                        "(views - 1 + window) / window must be whole numbers (each view's window holds whole "
                        "strata of the lens)")


def sample_table(layout: Layout, seed: int) -> np.ndarray:
    """The pass's (spp, 5) table (x, y, u, v, t): the project's stratified pattern on a square lens, one
    sample per 1/spp stratum of u, so each window (a whole number of strata) holds samples_per_view."""
    from pipeline_sim.sampling import make_samples

    s = make_samples(1, 1, layout.spp, seed, lens=True, motion=True, pattern="stratified", lens_shape="square")
    return np.column_stack([s.x, s.y, s.u, s.v, s.t]).astype(np.float64)


def _grid(corner: np.ndarray, a: np.ndarray, b: np.ndarray, n: int, colors) -> tuple[np.ndarray, ...]:
    """A parallelogram corner + [0, 1] a + [0, 1] b cut into n x n cells of two triangles each, each cell
    one of ``colors`` in a checker; (2 n^2, 3, 3) positions and colours, (2 n^2, 3) normals (a x b)."""
    tris, cols = [], []
    for i in range(n):
        for j in range(n):
            p = [corner + (i + di) / n * a + (j + dj) / n * b for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1))]
            tris += [[p[0], p[1], p[2]], [p[0], p[2], p[3]]]
            cols += [[colors[(i + j) % len(colors)]] * 3] * 2
    normal = np.cross(a, b) / np.linalg.norm(np.cross(a, b))
    return np.array(tris), np.array(cols, float), np.tile(normal, (2 * n * n, 1))


def _box(centre, half, color) -> tuple[np.ndarray, ...]:
    """An axis-aligned box as 12 triangles (each face two), their colours and outward normals."""
    tris, normals = [], []
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        for side in (-1.0, 1.0):
            face = []
            for da, db in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.array(centre, float)
                p[axis] += side * half[axis]
                p[a] += da * half[a]
                p[b] += db * half[b]
                face.append(p)
            tris += [[face[0], face[1], face[2]], [face[0], face[2], face[3]]]
            normals += [np.eye(3)[axis] * side] * 2
    return np.array(tris), np.full((12, 3, 3), color, float), np.array(normals)


def scene_triangles(motion: float) -> tuple[np.ndarray, ...]:
    """The scene in the centre camera's eye space: world triangles at shutter open and close (N, 3, 3),
    vertex colours (N, 3, 3) and face normals (N, 3) (the boxes translate: one normal for the shutter).
    A checkered back wall and floor; a box in front of the focus plane moving right, one on it standing
    still, one behind it moving up and left."""
    parts = [
        _grid(np.array([-9.0, -1.5, -18.0]), np.array([18.0, 0.0, 0.0]), np.array([0.0, 12.0, 0.0]), 6,
              [(0.75, 0.7, 0.6), (0.35, 0.4, 0.55)]),
        _grid(np.array([-9.0, -1.5, -1.0]), np.array([18.0, 0.0, 0.0]), np.array([0.0, 0.0, -17.0]), 6,
              [(0.6, 0.6, 0.6), (0.2, 0.45, 0.25)]),
        _box((-0.9, -0.6, -5.0), (0.45, 0.45, 0.45), (0.9, 0.25, 0.2)),
        _box((0.4, -0.9, -8.0), (0.5, 0.6, 0.5), (0.25, 0.5, 0.9)),
        _box((1.6, 0.4, -11.0), (0.7, 0.7, 0.7), (0.95, 0.8, 0.2)),
    ]
    moves = [(0, 0, 0), (0, 0, 0), (1.0, 0.0, 0.0), (0, 0, 0), (-0.7, 0.5, 0.0)]
    world0 = np.concatenate([p[0] for p in parts])
    world1 = np.concatenate([p[0] + motion * np.array(m, float) for p, m in zip(parts, moves)])
    return world0, world1, np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])


def scene_draw(s: Settings, layout: Layout):
    """The scene as one draw on ``layout``'s oblong lens: clip-space triangles of the centre camera and
    lens shifts half_width (u) and aperture_height (v) world units per unit lens coordinate."""
    from pipeline_sim.draw import draw_from_world

    world0, world1, colors, normals = scene_triangles(s.motion)
    draw = draw_from_world(world0, world1, CAMERA.projection_matrix(s.width / s.height), width=s.width,
                           height=s.height, lens_radius=(layout.half_width, s.aperture_height),
                           focus=s.focus_distance, color=colors)
    normals = np.repeat(normals[:, None, :], 3, axis=1)
    return dataclasses.replace(draw, pos=np.stack([world0, world1]).astype(np.float32),
                               nrm=np.stack([normals, normals]).astype(np.float32),
                               material=np.ones(draw.n, np.int32))


def _screen_bounds(world0: np.ndarray, world1: np.ndarray, lens_box: tuple[float, float, float, float],
                   focus: float, proj: np.ndarray, w: int, h: int) -> np.ndarray:
    """Each triangle's pixel box (x0, x1, y0, y1), inclusive, over the shutter and a lens box (x_lo, x_hi,
    y_lo, y_hi world units): a vertex p seen from lens point L lies on the ray through the focus-plane
    point L + (p - L) F / -p_z, whose image position is monotonic in t (p linear in t, p_z < 0) and
    linear in L, so the corners of t and of the lens box bound it. Every vertex must lie in front of the
    lens plane (p_z < 0 at both shutter ends), as the scene's do; the bounds are padded by a pixel
    against rounding."""
    corners = np.array([(x, y) for x in lens_box[:2] for y in lens_box[2:]])
    pts = np.concatenate([world0, world1], axis=1)  # (N, 6, 3)
    scale = focus / -pts[:, :, 2]  # (N, 6)
    fx = corners[:, 0, None, None] + (pts[None, :, :, 0] - corners[:, 0, None, None]) * scale
    fy = corners[:, 1, None, None] + (pts[None, :, :, 1] - corners[:, 1, None, None]) * scale
    x = (fx * proj[0, 0] / focus + 1.0) * 0.5 * w
    y = (1.0 - fy * proj[1, 1] / focus) * 0.5 * h
    return np.stack([np.floor(x.min(axis=(0, 2))) - 1, np.floor(x.max(axis=(0, 2))) + 1,
                     np.floor(y.min(axis=(0, 2))) - 1, np.floor(y.max(axis=(0, 2))) + 1], axis=1)


def reference_view_images(s: Settings, layout: Layout, spp: int, seed: int = 1) -> list[np.ndarray]:
    """Each view rendered on its own by numpy ray casting (independent of the 5D path): per pixel,
    ``spp`` rays from uniform points of the view's own lens (its window along the camera line times the
    aperture's height) through uniform points of the pixel on the focus plane, at uniform shutter
    times; the nearest hit (``raycast.ray_triangles`` against the triangles moved to the ray's time)
    shaded as the standard shader's Lambert, the clear colour where none. Returns (H, W, 4) images, left
    to right."""
    proj = CAMERA.projection_matrix(s.width / s.height)
    world0, world1, colors, normals = scene_triangles(s.motion)
    shade = colors * (LIGHT[7] + LIGHT[4:7] * np.maximum(0.0, normals @ -LIGHT_DIRECTION)[:, None, None])
    rng = np.random.default_rng(seed)
    w, h = s.width, s.height
    row = w * spp  # rays are ordered by pixel, so an image row's rays are one slice
    py, px = np.divmod(np.repeat(np.arange(w * h), spp), w)
    images = []
    for u_lo, u_hi in layout.windows():
        n = len(px)
        ndc_x = (px + rng.random(n)) / w * 2.0 - 1.0
        ndc_y = 1.0 - (py + rng.random(n)) / h * 2.0
        lens = np.column_stack([rng.uniform(u_lo, u_hi, n) * layout.half_width,
                                rng.uniform(-1.0, 1.0, n) * s.aperture_height, np.zeros(n)])
        time = rng.random(n)
        focus = np.column_stack([ndc_x * s.focus_distance / proj[0, 0], ndc_y * s.focus_distance / proj[1, 1],
                                 np.full(n, -s.focus_distance)])
        d = focus - lens
        best = np.full(n, np.inf)
        rgb = np.tile(np.array(CLEAR[:3]), (n, 1))
        bounds = _screen_bounds(world0, world1, (u_lo * layout.half_width, u_hi * layout.half_width,
                                                 -s.aperture_height, s.aperture_height), s.focus_distance, proj, w, h)
        for k, (x0, x1, y0, y1) in enumerate(bounds):
            rows = slice(int(max(y0, 0)) * row, int(min(y1 + 1, h)) * row)
            sel = np.flatnonzero((px[rows] >= x0) & (px[rows] <= x1)) + rows.start
            tm = time[sel, None]
            dist, a, b, meets = ray_triangles(lens[sel], d[sel], *(world0[k, i] + tm * (world1[k, i] - world0[k, i])
                                                                    for i in range(3)))
            hit = meets & (dist > 0) & (dist < best[sel])
            a, b, at = a[hit, None], b[hit, None], sel[hit]
            best[at] = dist[hit]
            rgb[at] = (1 - a - b) * shade[k, 0] + a * shade[k, 1] + b * shade[k, 2]
        img = np.ones((h * w, 4))
        img[:, :3] = rgb.reshape(h * w, spp, 3).mean(axis=1)
        images.append(img.reshape(h, w, 4).astype(np.float32))
    return images


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean square error of the RGB channels."""
    return float(np.sqrt(np.mean((a[..., :3].astype(np.float64) - b[..., :3]) ** 2)))


def anaglyph(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """A red-cyan anaglyph: red from the left view, green and blue from the right."""
    out = right.copy()
    out[..., 0] = left[..., 0]
    return out


class Multiview(Workload):
    """The kind ``multiview``: views of a camera line as lens regions of one 5D pass."""

    file_schema = Settings

    image_refusals = {"spp": "sets samples_per_view (its pass's spp follows from it and the views)"}

    def layout(self, views: int | None = None) -> Layout:
        s = self.settings_file
        return Layout(s.views if views is None else views, s.spacing, s.window, s.samples_per_view)

    def cache_arch(self, entries: int) -> ArchConfig:
        """The architecture with a shading cache of ``entries`` (a multiple of its ways)."""
        ways = min(self.arch.shading.cache_ways, entries)
        return apply_overrides(self.arch, [f"shading.cache_entries={entries}", f"shading.cache_ways={ways}"])

    def check(self, variants=None, *, reference_spp=None) -> str:
        for v in variants or [self]:
            s = v.settings_file
            where = str(v.path)
            for n in sorted({s.views, *s.view_counts}):
                check_layout(v.layout(n), where)
            for size in s.cache_sizes:
                if size:
                    v.cache_arch(size)  # refuses a size that is no multiple of the ways
            if abs(s.reference_x) > v.layout().half_width:
                raise UserError(f"{where}: reference_x = {s.reference_x:g} lies off the camera line "
                                f"(half width {v.layout().half_width:g})")
        s = self.settings_file
        layout = self.layout()
        return (f"{s.views} views of {s.width}x{s.height}, {s.samples_per_view} samples per view "
                f"({layout.spp} spp over the lens), view counts {s.view_counts}, caches {s.cache_sizes} + unbounded")

    def make_pass(self, name: str, views: int, arch: ArchConfig, cached: bool):
        """The one pass rendering ``views`` views of the camera line, each resolved from its window."""
        from pipeline_sim.pass_state import PassState
        from pipeline_sim.render import RenderPass
        from pipeline_sim.targets import LensRegion, Target

        s = self.settings_file
        layout = self.layout(views)
        state = PassState(shading_mode="cache" if cached else "per_sample",
                          shading_u=float(np.clip(s.reference_x / layout.half_width, -1.0, 1.0))
                          if layout.half_width > 0 else 0.0)
        regions = tuple(LensRegion(u_lo=lo, u_hi=hi) for lo, hi in layout.windows())
        return RenderPass(draw=scene_draw(s, layout), arch=arch, spp=layout.spp, seed=s.seed, state=state,
                          name=name, params=LIGHT, clear_color=CLEAR, sample_table=sample_table(layout, s.seed),
                          scramble_table=True,
                          targets=(Target("views", clear=CLEAR, resolve="lens", views=regions),))

    def study_pass(self, views: int, size: int | None, progress=None):
        """Run ``views`` views with a cache of ``size`` entries (0: none, one shader execution per covered
        sample; None: unbounded, at least UNBOUNDED_FACTOR entries per sample of the pass and doubled until
        nothing is evicted). Returns the pass's result and the entries it had."""
        name = f"views{views}_cache{'unbounded' if size is None else size}"
        if size is not None:
            arch = self.cache_arch(size) if size else self.arch
            return self.run_passes([self.make_pass(name, views, arch, size > 0)], progress)[name], size
        entries = 1 << int(np.ceil(np.log2(UNBOUNDED_FACTOR * self.layout(views).spp * self.settings_file.width
                                           * self.settings_file.height)))
        while True:
            r = self.run_passes([self.make_pass(name, views, self.cache_arch(entries), True)], progress)[name]
            if r.counter("shading", "evictions") == 0:
                return r, entries
            self.states.pop()  # run.json records the pass that counts
            entries *= 2

    def run(self, progress=None) -> WorkloadResult:
        s = self.settings_file
        layout = self.layout()
        main = self.run_passes([self.make_pass("views", s.views, self.arch, True)], progress)["views"]
        images = main.images["views"]
        reference = reference_view_images(s, layout, s.reference_spp)
        errors = [rmse(img, ref) for img, ref in zip(images, reference)]
        passes = {"views": main}
        rows = []
        for views in dict.fromkeys(s.view_counts):
            for size in dict.fromkeys([*s.cache_sizes, None]):
                r, entries = self.study_pass(views, size, progress)
                passes[r.name] = r
                rows.append({"views": views, "cache": "unbounded" if size is None else str(size),
                             "cache_entries": entries, "spp": self.layout(views).spp,
                             "samples_covered": r.counter("sample_tester", "samples_covered"),
                             "shader_executions": r.counter("shading", "shader_executions"),
                             "cache_hits": r.counter("shading", "hits"), "frame_cycles": float(r.timing.frame_cycles)})
        table = pd.DataFrame(rows)
        one = {row["cache"]: row["shader_executions"] for row in rows if row["views"] == 1}
        table["increase_over_one_view"] = [finite_or_none(row["shader_executions"] / one[row["cache"]] - 1.0)
                                           if one.get(row["cache"]) else None for row in rows]
        results = {
            "views": s.views, "samples_per_view": s.samples_per_view, "spp": layout.spp,
            "shader_executions": main.counter("shading", "shader_executions"),
            "frame_cycles": float(main.timing.frame_cycles),
            "rmse_per_view": [finite_or_none(e) for e in errors],
            "rmse_mean": finite_or_none(float(np.mean(errors))), "rmse_max": finite_or_none(float(np.max(errors))),
        }
        for row, inc in zip(rows, table["increase_over_one_view"]):
            results[f"executions_views{row['views']}_cache{row['cache']}"] = row["shader_executions"]
            if row["views"] != 1 and inc is not None:
                results[f"increase_views{row['views']}_cache{row['cache']}"] = inc
        views = {f"view_{k}": img for k, img in enumerate(images)}
        combined = {"side_by_side": np.concatenate(images, axis=1)}
        if len(images) > 1:
            combined["anaglyph"] = anaglyph(images[0], images[-1])
        return WorkloadResult(passes, results=results, tables={"shader_executions": table} if rows else {},
                              images={**views, **combined})

    def resolved(self) -> dict:
        layout = self.layout()
        return {**super().resolved(), "spp": layout.spp, "half_width": layout.half_width, "windows": [list(w) for w in layout.windows()]}


WORKLOAD = Multiview
