"""5D occlusion queries (Nilsson12 §3; docs/occlusion.md): an occluder, then a set of moving, defocused
proxies (boxes around objects behind it) queried two ways.

* sample-based: pass ``samples_<i>`` draws the occluder and proxy ``i``; the proxy's query counts its
  samples passing the depth test (visible when more than none). Its samples tested are those of the pass
  less those of pass ``occluder`` (the occluder alone, drawn first in both, with submission-order z-cull
  refresh, so it costs the same in both).
* interval-based: pass ``interval_ts<T>_t<N>_l<L>`` draws the occluder, then every proxy as a draw with
  ``query = "interval"`` (tile size T, N time slices, L x L lens boxes): z-cull compares each proxy's tile
  records with its boxes and answers at the first comparison that does not hide it.

``results.json`` lists each proxy's answers and work both ways at the architecture's own z-cull boxes
and tile size; the table ``occlusion_rate`` gives, per tile size and z-cull boxes, the share of the truly
occluded proxies (sample-based count 0) the interval method answers "occluded".
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Annotated

import numpy as np
import pandas as pd
from pydantic import Field

from pipeline_sim.config import ArchConfig, apply_overrides
from pipeline_sim.output import finite_or_none
from pipeline_sim.scene import Camera
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, count, number
from pipeline_sim.workload import Workload, WorkloadResult

# the camera: at the origin looking down -z, vertical field of view 50 degrees
CAMERA = Camera("perspective", np.zeros(3), np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0]), np.zeros(3),
                np.array([0.0, 0.0, -1.0]), 50.0, 1.0, 40.0)
OCCLUDER_DISTANCE = 6.0
OCCLUDER_HALF = (1.5, 1.0)  # half width and height of the occluding wall, world units
PROXY_DEPTHS = (8.0, 12.0)  # distances of the proxies' centres
PROXY_HALF = (0.15, 0.4)  # half sizes of the proxies' sides
# where a proxy's centre projects, as a multiple of the wall's half size: around its edges and within
SPREAD = 1.35
# a box's 12 triangles over its corners (bit 0: +x, bit 1: +y, bit 2: +z), counter-clockwise seen from outside
BOX_FACES = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                      [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])
BOX_CORNERS = np.array([[(i >> 0) & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], float) * 2.0 - 1.0

Sizes = Annotated[list[count(1, 128)], Field(min_length=1, max_length=8)]
Boxes = Annotated[list[count(1, 255)], Field(min_length=1, max_length=8)]


@dataclass
class Settings:
    """The keys of an `occlusion` file besides `kind`."""

    __pydantic_config__ = FORBID
    width: count(8, 4096) = key("image width, pixels", default=128)
    height: count(8, 4096) = key("image height, pixels", default=96)
    spp: count(1, 256) = key("samples per pixel of the passes (the sample-based queries' density)", default=16)
    seed: count(0) = key("seed of the sample pattern and of the proxies' placement", default=0)
    proxies: count(1, 1000) = key("number of proxies (boxes) behind the occluder", default=32)
    motion: number(0.0, 10.0) = key("largest distance a proxy moves over the shutter, world units", default=0.5)
    occluder_motion: number(0.0, 10.0) = key("distance the occluder moves along x over the shutter, world units",
                                             default=1.5)
    follow: number(0.0, 1.0) = key("share of the occluder's motion the proxies follow (matched on screen), so that "
                                   "hidden ones sweep past where the occluder stands at any one time", default=1.0)
    lens_radius: number(0.0, 1.0) = key("thin-lens radius, world units (0: pinhole)", default=0.1)
    focus_distance: number(1.0, 40.0) = key("distance of the plane in focus, world units", default=10.0)
    tile_sizes: Sizes = key("tile sizes of the occlusion-rate table (powers of two)",
                            default_factory=lambda: [4, 8, 16])
    time_slices: Boxes = key("z-cull time slices of the occlusion-rate table", default_factory=lambda: [1, 4, 8])
    lens_boxes: Boxes = key("z-cull lens boxes per axis of the occlusion-rate table",
                            default_factory=lambda: [1, 2, 4])


def proxy_boxes(s: Settings) -> tuple[np.ndarray, np.ndarray]:
    """Each proxy's box centre at shutter open and close and its half sizes, (N, 2, 3) and (N, 3): centres
    projecting around and within the occluder, at random depths behind it, each following ``follow`` of
    the occluder's motion (scaled by depth: the same motion on screen) and moving in a random direction
    over up to ``motion`` besides."""
    rng = np.random.default_rng(s.seed)
    n = s.proxies
    depth = rng.uniform(*PROXY_DEPTHS, n)
    scale = depth / OCCLUDER_DISTANCE
    centre = np.stack([rng.uniform(-SPREAD, SPREAD, n) * OCCLUDER_HALF[0] * scale,
                       rng.uniform(-SPREAD, SPREAD, n) * OCCLUDER_HALF[1] * scale, -depth], axis=1)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    move = direction * rng.uniform(0.0, s.motion, (n, 1))
    move[:, 0] += s.follow * s.occluder_motion * scale
    half = rng.uniform(*PROXY_HALF, (n, 3))
    return np.stack([centre, centre + move], axis=1), half


def _draw(world0: np.ndarray, world1: np.ndarray, s: Settings, proj: np.ndarray, query: str = "samples"):
    """A draw of world-space triangles (N, 3, 3) at shutter open and close, seen by the camera."""
    from pipeline_sim.draw import draw_from_world

    draw = draw_from_world(world0, world1, proj, width=s.width, height=s.height, lens_radius=s.lens_radius,
                           focus=s.focus_distance)
    return dataclasses.replace(draw, query=query)


class Occlusion(Workload):
    """The kind ``occlusion``: sample-based and interval-based queries of proxies behind an occluder."""

    file_schema = Settings

    def configurations(self) -> list[tuple[int, int, int]]:
        """The (tile size, time slices, lens boxes) of the occlusion-rate table, the architecture's own
        first."""
        s = self.settings_file
        own = (self.arch.tile_traverser.tile_size, self.arch.zcull.time_slices, self.arch.zcull.lens_boxes)
        swept = [(ts, nt, nl) for ts in s.tile_sizes for nt in s.time_slices for nl in s.lens_boxes]
        return [own] + [c for c in swept if c != own]

    def arch_for(self, config: tuple[int, int, int]) -> ArchConfig:
        """The architecture with tile size, time slices and lens boxes ``config`` and z-cull on."""
        ts, nt, nl = config
        return apply_overrides(self.arch, [f"tile_traverser.tile_size={ts}", f"zcull.time_slices={nt}",
                                           f"zcull.lens_boxes={nl}", "zcull.enabled=true"])

    def check(self, variants=None, *, reference_spp=None) -> str:
        for v in variants or [self]:
            for config in v.configurations():
                v.arch_for(config)  # refuses a tile size or box count the hardware cannot take
        s = self.settings_file
        return (f"{s.proxies} proxies behind an occluder, {s.width}x{s.height} at {s.spp} spp, "
                f"{len(self.configurations())} z-cull configurations")

    def run(self, progress=None) -> WorkloadResult:
        from pipeline_sim.pass_state import PassState
        from pipeline_sim.render import RenderPass

        s = self.settings_file
        proj = CAMERA.projection_matrix(s.width / s.height)
        hx, hy = OCCLUDER_HALF
        wall = np.array([[[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0]],
                         [[-hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]]]) + [0.0, 0.0, -OCCLUDER_DISTANCE]
        occluder = _draw(wall, wall + [s.occluder_motion, 0.0, 0.0], s, proj)
        centres, halves = proxy_boxes(s)
        boxes = [[(c + BOX_CORNERS * h)[BOX_FACES] for c in ends] for ends, h in zip(centres, halves)]
        state = PassState(depth_test="less", depth_write=True)

        def make(name, draws, arch=self.arch):
            return RenderPass(draw=draws, arch=arch, spp=s.spp, seed=s.seed, state=state, name=name,
                              zcull_refresh="ordered")

        configs = self.configurations()
        passes = [make("occluder", occluder)]
        passes += [make(f"samples_{i:03d}", [occluder, _draw(b0, b1, s, proj)]) for i, (b0, b1) in enumerate(boxes)]
        proxies = [_draw(b0, b1, s, proj, "interval") for b0, b1 in boxes]
        passes += [make(f"interval_ts{ts}_t{nt}_l{nl}", [occluder] + proxies, self.arch_for((ts, nt, nl)))
                   for ts, nt, nl in configs]
        results = self.run_passes(passes, progress)
        alone = results["occluder"].counter("sample_tester", "samples_tested")
        samples = []
        for i in range(s.proxies):
            r = results[f"samples_{i:03d}"]
            passed = int(r.queries[1])
            samples.append({"passed": passed, "visible": passed > 0,
                            "samples_tested": r.counter("sample_tester", "samples_tested") - alone})
        hidden = [not q["visible"] for q in samples]
        rows, per_config = [], {}
        for ts, nt, nl in configs:
            r = results[f"interval_ts{ts}_t{nt}_l{nl}"]
            answers = [r.interval_queries[i + 1] for i in range(s.proxies)]
            per_config[(ts, nt, nl)] = answers
            occluded = [not a["visible"] for a in answers]
            caught = sum(o and h for o, h in zip(occluded, hidden))
            rows.append({"tile_size": ts, "time_slices": nt, "lens_boxes": nl, "boxes_per_tile": nt * nl * nl,
                         "truly_occluded": sum(hidden), "answered_occluded": caught,
                         "occlusion_rate": finite_or_none(caught / sum(hidden) if any(hidden) else None),
                         "wrongly_occluded": sum(o and not h for o, h in zip(occluded, hidden)),
                         "mean_tiles": float(np.mean([a["tiles"] for a in answers])),
                         "mean_box_comparisons": float(np.mean([a["box_comparisons"] for a in answers])),
                         "frame_cycles": float(r.timing.frame_cycles)})
        table = pd.DataFrame(rows)
        own = configs[0]
        queries = [{"proxy": i, "samples": samples[i], "interval": per_config[own][i]} for i in range(s.proxies)]
        return WorkloadResult(results, results={
            "proxies": s.proxies, "truly_occluded": int(sum(hidden)),
            "configuration": dict(zip(("tile_size", "time_slices", "lens_boxes"), own)),
            "occlusion_rate": rows[0]["occlusion_rate"], "wrongly_occluded": rows[0]["wrongly_occluded"],
            # the cost of that configuration's queries: its pass's cycles, the tiles and box comparisons per query
            "interval_cycles": rows[0]["frame_cycles"], "mean_tiles": rows[0]["mean_tiles"],
            "mean_box_comparisons": rows[0]["mean_box_comparisons"],
            "queries": queries,
        }, tables={"occlusion_rate": table})

    def resolved(self) -> dict:
        return {**super().resolved(), "configurations": [list(c) for c in self.configurations()]}


WORKLOAD = Occlusion
