"""What a unit makes of a screen region's sample set ahead of its use, held until the unit takes it.

The sample tester's tile-major layouts (``units.sample_tester.TileMajorLayouts``) and z-cull's box groups
(``units.zcull.BoxGroups``) are made on the thread that makes a region's samples ahead
(``pipeline_sim.regions.RegionSamples``'s ``prepare``) and taken by the unit when its batches reach the
region; both hold them here.
"""

from __future__ import annotations

import threading
from typing import Any


class MadeAhead:
    """What a unit made ahead, by sample set (a set has rows from ``row0``), until the unit takes it. Taking
    a set's drops what is held for sets of earlier rows: regions the pipeline has passed. Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._held: dict[int, tuple[Any, Any]] = {}  # by id(samples)

    def hold(self, samples: Any, made: Any) -> None:
        with self._lock:
            self._held[id(samples)] = (samples, made)

    def take(self, samples: Any) -> tuple[Any, list, bool]:
        """(what is held for ``samples``, None if nothing; what was held for sets of earlier rows, now
        dropped; whether something is still held, for a later set)."""
        with self._lock:
            got = self._held.pop(id(samples), None)
            passed = [k for k, (s, _) in self._held.items() if s.row0 < samples.row0]
            dropped = [self._held.pop(k)[1] for k in passed]
            return (None if got is None else got[1]), dropped, bool(self._held)

    def __len__(self) -> int:
        with self._lock:
            return len(self._held)
