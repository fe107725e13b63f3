"""Pass state: what one render pass asks of the pipeline, apart from the hardware that runs it.

The architecture (``pipeline_sim.config.ArchConfig``) describes the machine:
units' throughputs, latencies and instances, tile size, cache geometry,
z-cull boxes, bandwidth. A pass's state describes the work: its mode, depth
function and write, blending, user clip planes, backface culling, sample
pattern and shading mode. A workload of several passes gives each its own
state on one architecture (as Timeloop keeps architecture, workload and
mapping apart).

Every field declares what it can change (``pipeline_sim.config.EFFECTS``),
so that a sweep's accuracy reference and ``compare`` derive what they keep
and what they reset from the declarations.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline_sim.settings import ACCURACY, IMAGE, setting


@dataclass(frozen=True)
class ClipPlanes:
    """Axis-aligned user clip planes on t, u and v (Nilsson12 §2): samples outside are never covered."""

    t_lo: float = setting(0.0, IMAGE)
    t_hi: float = setting(1.0, IMAGE)
    u_lo: float = setting(-1.0, IMAGE)
    u_hi: float = setting(1.0, IMAGE)
    v_lo: float = setting(-1.0, IMAGE)
    v_hi: float = setting(1.0, IMAGE)

    def as_array(self) -> np.ndarray:
        """(t_lo, t_hi, u_lo, u_hi, v_lo, v_hi), as the tile test reads them."""
        return np.array([self.t_lo, self.t_hi, self.u_lo, self.u_hi, self.v_lo, self.v_hi])


@dataclass(frozen=True)
class PassState:
    """The state of one render pass (docs/pipeline.md §2): everything but the hardware."""

    mode: str = setting("standard", ACCURACY, reference="standard")
    depth_test: str = setting("less", IMAGE)
    depth_write: bool = setting(True, IMAGE)
    blend: str = setting("replace", IMAGE)
    backface_culling: bool = setting(False, IMAGE)
    clip: ClipPlanes = field(default_factory=ClipPlanes)
    sample_pattern: str = setting("net", ACCURACY, reference="net")
    interleave_tuples: int = setting(64, ACCURACY)
    shading_mode: str = setting("cache", ACCURACY, reference="per_sample")
    shading_rate: float = setting(1.0, ACCURACY)

    @property
    def conservative(self) -> bool:
        return self.mode == "conservative"

    def replace(self, **changes: Any) -> "PassState":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def pass_state_of(arch) -> PassState:
    """The pass state an architecture file still carries (its ``image`` and ``accuracy`` settings of a
    pass: mode, sample pattern, backface culling, clip planes, depth and blend, shading mode)."""
    tt = arch.tile_test
    return PassState(
        mode=arch.pipeline.mode, depth_test=arch.rop.depth_test, depth_write=arch.rop.depth_write,
        blend=arch.rop.blend, backface_culling=arch.triangle_setup.backface_culling,
        clip=ClipPlanes(tt.clip_t_lo, tt.clip_t_hi, tt.clip_u_lo, tt.clip_u_hi, tt.clip_v_lo, tt.clip_v_hi),
        sample_pattern=arch.pipeline.sample_pattern, interleave_tuples=arch.pipeline.interleave_tuples,
        shading_mode=arch.shading.mode, shading_rate=arch.shading.shading_rate,
    )
