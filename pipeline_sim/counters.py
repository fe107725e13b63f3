"""Counter declarations and the tidy counters table.

Every unit declares the counters it owns (ATTILA style): the common ones
(records in and out, arithmetic by class, bytes) followed by its own events.
Kernels fill an int64 vector laid out as the unit declares; ``CounterSet``
accumulates those vectors and renders one tidy row per (unit, counter).
Ratios such as STE are kept as numerator and denominator counters and
computed when reported. Each counter's meaning is declared with its name
(``COMMON_MEANINGS``, a unit's ``event_meanings``); the counter glossary
(docs/counters.md) is generated from them.

Each unit also declares which of its counters timing can move
(``timing_dependent``, next to its event names): z-cull tests against the
depth the ROP has refreshed by that simulated time, so what it culls, and
everything downstream of it, depends on queue depths, throughputs and
batch sizes as it would in hardware (docs/pipeline.md §4). The declaration is
checked by measurement in ``tests/test_timing_dependence.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

# the arithmetic classes and common counters are the units' (defined with what else they share)
from pipeline_sim.definitions import COMMON, COMMON_MEANINGS, N_OPS


@dataclass
class CounterSet:
    """Accumulated counters of one unit: common ones first, then ``events``;
    ``timing_dependent`` names those that timing can move."""

    unit: str
    events: tuple[str, ...]
    timing_dependent: tuple[str, ...] = ()
    values: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.values = np.zeros(len(COMMON) + len(self.events), dtype=np.int64)
        self._index = {name: i for i, name in enumerate(self.names)}
        unknown = set(self.timing_dependent) - set(self._index)
        assert not unknown, f"{self.unit}: timing_dependent names no counter {sorted(unknown)}"

    @property
    def names(self) -> tuple[str, ...]:
        return COMMON + self.events

    def add(self, name: str, amount: int) -> None:
        self.values[self._index[name]] += int(amount)

    def add_ops(self, ops: np.ndarray) -> None:
        """Add a kernel's arithmetic vector (length ``N_OPS``)."""
        self.values[2 : 2 + N_OPS] += ops[:N_OPS]

    def add_events(self, events: np.ndarray) -> None:
        """Add a kernel's event vector laid out as ``self.events``."""
        self.values[len(COMMON) :] += events[: len(self.events)]

    def __getitem__(self, name: str) -> int:
        return int(self.values[self._index[name]])

    def as_dict(self) -> dict[str, int]:
        return {n: int(v) for n, v in zip(self.names, self.values)}


def counter_meanings(unit: Any) -> dict[str, str]:
    """Each counter of ``unit`` (a unit class: ``name``, ``events``, ``event_meanings``), the common ones
    first, with what it counts as declared; a counter declared without a meaning is an error naming it."""
    meanings = {**COMMON_MEANINGS, **unit.event_meanings}
    missing = [c for c in COMMON + tuple(unit.events) if not meanings.get(c, "").strip()]
    if missing:
        raise ValueError(f"{unit.name}: counter(s) without a declared meaning: {', '.join(missing)}")
    return {c: meanings[c] for c in COMMON + tuple(unit.events)}


def counters_frame(sets: list[CounterSet], timing: bool = True) -> pd.DataFrame:
    """Tidy table: one row per unit and counter (columns unit, counter, value,
    timing_dependent). ``timing``: whether timing could move any counter in
    this pass (false when z-cull was bypassed or saw its refreshes in
    submission order); if not, every counter's ``timing_dependent`` is false."""
    rows = [(s.unit, n, int(v), timing and n in s.timing_dependent) for s in sets for n, v in zip(s.names, s.values)]
    return pd.DataFrame(rows, columns=["unit", "counter", "value", "timing_dependent"])
