"""Simulation options: how the simulator runs a pass, neither the machine nor the work.

Batch sizes set the granularity of the timing model (records per SimPy
batch between units), ``region_samples`` how much of a frame is held at
once and ``run_ahead`` how far the tile test, the sample tester, shading and
the ROP may work ahead, each on a thread of its own; none of them changes the image. A scene file sets
them in its ``[simulation]`` table, ``--set simulation.KEY=VALUE`` on top of
that.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from pipeline_sim.settings import FORBID, COUNTERS, CYCLES, SPEED, count, setting


@dataclass(frozen=True)
class SimOptions:
    """Batching and screen regions of a run."""

    __pydantic_config__ = FORBID

    triangles_per_batch: count(1) = setting(64, CYCLES, "triangles per SimPy batch into triangle setup")
    tiles_per_batch: count(1) = setting(512, CYCLES, "(triangle, tile) records per batch between tile units")
    samples_per_batch: count(1) = setting(65536, CYCLES, "covered-sample records per batch between sample units")
    region_samples: count(0) = setting(
        1 << 22, COUNTERS, "a frame of more samples is rendered in screen regions (bands of whole coarse-tile "
        "rows) of at most this many samples, to bound memory; 0: one region. Same image at every size; z-cull "
        "counters and cycles follow the order")
    run_ahead: count(0, 64) = setting(
        2, SPEED, "batches the tile test, the sample tester, shading and the ROP may each work ahead of the simulation, "
        "each on a thread of its own, while the other units run (0: off, every unit steps on one thread)")
    run_ahead_min_us: count(0) = setting(
        600, SPEED, "a batch goes to a unit's run-ahead thread only when its step is expected to take at least "
        "this many microseconds (the unit's time per record in its steps so far times the batch's records; its "
        "first step runs on the simulation's thread): handing a batch over has costs of its own (threads woken, "
        "the interpreter lock passed around). 0: every batch the unit may run ahead")

    def replace(self, **changes: Any) -> "SimOptions":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
