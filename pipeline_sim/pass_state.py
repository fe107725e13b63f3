"""Pass state: what one render pass asks of the pipeline, apart from the hardware that runs it.

The architecture (``pipeline_sim.config.ArchConfig``) describes the machine:
units' throughputs, latencies and instances, tile size, cache geometry,
z-cull boxes, bandwidth. A pass's state describes the work: its mode, depth
function and write, blending, user clip planes, backface culling, sample
pattern and shading mode. A workload of several passes gives each its own
state on one architecture (as Timeloop keeps architecture, workload and
mapping apart). A scene file sets it in its ``[pass]`` table (the clip
planes in ``[pass.clip]``), ``--set pass.KEY=VALUE`` on top of that.

Every field declares what it can change (``pipeline_sim.settings``), so
that a sweep's accuracy reference and ``compare`` derive what they keep and
what they reset from the declarations.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from pipeline_sim.definitions import BLEND_MODES, DEPTH_FUNCS
from pipeline_sim.errors import UserError
from pipeline_sim.sampling import DEFAULT_PATTERN, PATTERNS
from pipeline_sim.settings import FORBID, ACCURACY, IMAGE, Flag, count, number, setting

# a pass names a generated pattern; a sample table comes with the pass itself (RenderPass.sample_table)
SAMPLE_PATTERNS = tuple(p for p in PATTERNS if p != "table")
Time = number(0.0, 1.0)
Lens = number(-1.0, 1.0)


@dataclass(frozen=True)
class ClipPlanes:
    """Axis-aligned user clip planes on t, u and v (Nilsson12 §2): samples outside are never covered."""

    __pydantic_config__ = FORBID

    t_lo: Time = setting(0.0, IMAGE, "lowest shutter time t a sample may have to be covered")
    t_hi: Time = setting(1.0, IMAGE, "highest shutter time t")
    u_lo: Lens = setting(-1.0, IMAGE, "lowest lens coordinate u")
    u_hi: Lens = setting(1.0, IMAGE, "highest lens coordinate u")
    v_lo: Lens = setting(-1.0, IMAGE, "lowest lens coordinate v")
    v_hi: Lens = setting(1.0, IMAGE, "highest lens coordinate v")

    def check(self, where: str) -> None:
        for axis in "tuv":
            lo, hi = getattr(self, f"{axis}_lo"), getattr(self, f"{axis}_hi")
            if lo > hi:
                raise UserError(f"{where}.{axis}_lo/{axis}_hi: need {axis}_lo <= {axis}_hi, got [{lo}, {hi}]")

    @property
    def cuts_time(self) -> bool:
        """Whether the planes cut the shutter (then a pass samples t even with nothing moving)."""
        return self.t_lo > 0.0 or self.t_hi < 1.0

    @property
    def cuts_lens(self) -> bool:
        """Whether the planes cut the lens (then a pass samples u, v even with nothing defocused)."""
        return self.u_lo > -1.0 or self.u_hi < 1.0 or self.v_lo > -1.0 or self.v_hi < 1.0

    def as_array(self) -> np.ndarray:
        """(t_lo, t_hi, u_lo, u_hi, v_lo, v_hi), as the tile test reads them."""
        return np.array([self.t_lo, self.t_hi, self.u_lo, self.u_hi, self.v_lo, self.v_hi])


@dataclass(frozen=True)
class PassState:
    """The state of one render pass (docs/pipeline.md §2): everything but the hardware."""

    __pydantic_config__ = FORBID

    mode: Literal["standard", "conservative"] = setting(
        "standard", ACCURACY, "`conservative`: 1x1 tiles, one sample and one shader execution per covered pixel "
        "(Nilsson12 §2)", reference="standard")
    time_intervals: Literal["tile", "exact"] = setting(
        "tile", ACCURACY, "conservative mode, motion-only triangles: `tile`: the tile test's t^ per pixel; "
        "`exact`: the hull of the times the triangle meets the closed pixel, from the roots of its edge "
        "functions (Gribel10 §4.1), and no shader execution where there are none", reference="exact")
    depth_test: Literal[DEPTH_FUNCS] = setting(
        "less", IMAGE, "the ROP's depth function")
    depth_write: Flag = setting(True, IMAGE, "the ROP writes the depth of a sample that passes")
    blend: Literal[BLEND_MODES] = setting("replace", IMAGE, "how the ROP combines a "
                                                             "passing sample's colour with the stored one")
    backface_culling: Flag = setting(False, IMAGE, "drop triangles facing away at every (t, u, v) "
                                     "(conservative for moving and defocused triangles)")
    clip: ClipPlanes = field(default_factory=ClipPlanes)
    sample_pattern: Literal[SAMPLE_PATTERNS] = setting(
        DEFAULT_PATTERN, ACCURACY, "`net5`: a t-ordered (t, m, 5)-net, "
        "stratified in all five dimensions (docs/pipeline.md §3); `net`: the t-ordered (0, m, 3)-net of "
        "Munkberg11 §5 with a separately padded lens; `sobol`, `stratified`, `random`; "
        "all scrambled per pixel; `interleave`: each pixel takes spp of a fixed set of (u, v, t) tuples",
        reference="net")
    interleave_tuples: count(1, 64) = setting(64, ACCURACY, "size of that fixed set (one bit each in a tile's "
                                              "mask), a multiple of spp")
    shading_mode: Literal["cache", "per_sample"] = setting(
        "cache", ACCURACY, "`cache`: memoized, decoupled shading; `per_sample`: one shader execution per "
        "covered sample", reference="per_sample")
    # a shading-grid cell from 1/64 of a pixel to 1024 pixels: the grid's cell index stays an int64
    shading_rate: number(1 / 64, 1024.0) = setting(1.0, ACCURACY, "shading-grid cell size in pixels")
    # the reference camera of the shading cache (stereo and multi-view: one chosen view keys the shading)
    shading_u: Lens = setting(0.0, ACCURACY, "lens coordinate u of the reference camera whose view keys the "
                              "shading cache and where a cached shader runs (a chosen eye of a stereo pair)")
    shading_v: Lens = setting(0.0, ACCURACY, "lens coordinate v of that reference camera")
    shading_t: Time = setting(0.5, ACCURACY, "shutter time t of that reference camera")

    @property
    def conservative(self) -> bool:
        return self.mode == "conservative"

    @property
    def shading_view(self) -> tuple[float, float, float]:
        """(u, v, t) of the shading cache's reference camera."""
        return (self.shading_u, self.shading_v, self.shading_t)

    def replace(self, **changes: Any) -> "PassState":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
