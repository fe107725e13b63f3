"""Screen regions: a frame rendered as horizontal bands of rows, one after another.

Samples and per-sample buffers scale with pixels x spp (a 1920x1080 frame at
16 spp holds 33 million samples), so a large frame is not materialized at
once. It is cut into regions of whole rows (``simulation.region_samples``
samples at most, rounded down to whole coarse-tile rows), and the pipeline
is fed region-major, as a binning (sort-middle) front end would feed it:
region 0's triangles in submission order, then region 1's, and so on. The
sample-level units (sample tester, shading, ROP) hold the samples and
buffers of the region they are working on only, and the ROP resolves a
region into the image as soon as it moves on.

Region boundaries lie on coarse-tile rows (and on shading-grid rows when the
shading cache is on), so every tile and coarse tile lies in exactly one
region, and each sample sees the same triangles in the same order: the
covered samples, their depths and the image are those of the whole frame.
What follows the order is the state units share across regions: the z-cull
boxes the ROP has refreshed by the time a tile arrives (z-cull's counters),
the shading cache's contents (its grid is in the reference view, where a
moving or defocused triangle's cell can take samples from two regions: hits
and misses, and, for a shader that reads the requesting sample's position
or depth, which sample's inputs a cell's color takes), and the cycles.

The region is bookkept here and nowhere else: every batch carries the region
it is bound for (``RegionBatch``), from the bins to the ROP, and each unit
that holds a region's samples or buffers follows its own batches with a
``RegionCursor``, which tells it when they move on to another region. The
units are handed that region's rows and samples; none of them works out a
region from the rows of its records.
"""

from __future__ import annotations

import bisect
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from pipeline_sim.sampling import SampleSet


def record_count(records: Any) -> int:
    """Records in a batch: the length of a structure-of-arrays dict's arrays, or of an array."""
    if isinstance(records, dict):
        return len(next(iter(records.values()))) if records else 0
    return len(records) if hasattr(records, "__len__") else 1


@dataclass(frozen=True)
class RegionPlan:
    """Bands of ``rows`` image rows (the last one may be shorter) of a ``width x height`` frame."""

    width: int
    height: int
    rows: int

    @property
    def count(self) -> int:
        return -(-self.height // self.rows)

    def bounds(self, region: int) -> tuple[int, int]:
        """Rows ``[r0, r1)`` of ``region``."""
        r0 = region * self.rows
        return r0, min(self.height, r0 + self.rows)


def row_step(tile_size: int, coarse_factor: int, shading_rate: float | None) -> int:
    """The smallest band height whose boundaries lie on coarse-tile rows and,
    with a shading cache of ``shading_rate``, on shading-grid rows; 0 when no
    height up to 1024 coarse rows does (then the frame is one region)."""
    step = tile_size * coarse_factor
    for k in range(1, 1025):
        rows = k * step
        if shading_rate is None or abs(rows / shading_rate - round(rows / shading_rate)) < 1e-9:
            return rows
    return 0


def plan_regions(width: int, height: int, spp: int, region_samples: int, step: int) -> RegionPlan:
    """Bands of whole ``step``-row groups holding at most ``region_samples``
    samples (at least one group); ``region_samples = 0`` or ``step = 0``: one region."""
    if region_samples <= 0 or step <= 0:
        return RegionPlan(width, height, max(height, 1))
    per_row = max(width * spp, 1)
    rows = max(step, (region_samples // per_row) // step * step)
    return RegionPlan(width, height, rows if rows < height else max(height, 1))


@dataclass
class RegionBatch:
    """A batch bound for one screen region: triangle ids (an array), or tile
    or sample records (a structure-of-arrays dict)."""

    region: int
    records: Any

    def __len__(self) -> int:
        return record_count(self.records)


def bin_triangles(bounds: np.ndarray, ids: np.ndarray, plan: RegionPlan) -> list[np.ndarray]:
    """Triangle ids per region, in submission order: a triangle goes to every
    region its conservative row bounds ``[by0, by1)`` reach. A triangle whose
    bounds are empty (culled at setup) goes to the region of its ``by0``
    (clamped), so that setup still sees it once."""
    if plan.count == 1:
        return [ids]
    last = plan.count - 1
    by0 = bounds[ids, 2].astype(np.int64)
    by1 = bounds[ids, 3].astype(np.int64)
    first = np.clip(by0 // plan.rows, 0, last)
    final = np.maximum(first, np.clip((by1 - 1) // plan.rows, 0, last))
    return [ids[(first <= r) & (final >= r)] for r in range(plan.count)]


class RegionSamples:
    """The samples of each region, made on first request and kept for the
    ``keep`` most recently requested regions.

    Samples depend only on (seed, pixel, sample index), so a region that was
    dropped and is requested again comes back identical (``made`` counts
    every set handed out that had to be made, a repeat included).

    Once told which regions the pipeline will visit (``will_visit``), the
    first request of a region starts making the next region to be visited on
    a background thread, so that its samples are made while this region's
    batches run through the pipeline (sample generation's kernels run without
    the interpreter lock); a request for it then waits for the thread. A
    region the pipeline skips after all (its tiles were all culled) has its
    set dropped when a later one is requested. This holds up to ``keep + 1``
    regions' samples at once, and it changes no value: the same function
    makes the same set. ``prepare``, if given, runs on each set made ahead,
    on the same thread, before it is handed out (the sample tester lays its
    samples out there), and as ``prepare(set, True)`` on a set made on a
    request that asks for it (``region(r, prepared=True)``: the requester
    waits for both, so the next region is started only then); another set
    made on request is handed out as made.
    """

    def __init__(self, plan: RegionPlan, make: Callable[[tuple[int, int]], SampleSet], keep: int = 3,
                 prepare: Callable[..., SampleSet] | None = None):
        self.plan = plan
        self._make = make
        self._prepare = prepare
        self._keep = keep
        self._sets: OrderedDict[int, SampleSet] = OrderedDict()
        self._visits: list[int] = []  # sorted: regions are visited in increasing order
        self._pool: ThreadPoolExecutor | None = None
        self._pending: dict[int, Future] = {}
        self.made = 0

    def region(self, region: int, prepared: bool = False) -> SampleSet:
        s = self._sets.get(region)
        if s is not None:
            self._sets.move_to_end(region)
            return s
        for skipped in [r for r in self._pending if r < region]:  # made ahead for a region no batch reached
            self._pending.pop(skipped).cancel()
        pending = self._pending.pop(region, None)
        if pending is not None:
            s = pending.result()
        else:
            s = self._make(self.plan.bounds(region))
            if prepared and self._prepare is not None:
                s = self._prepare(s, True)
        self.made += 1
        self._sets[region] = s
        while len(self._sets) > self._keep:
            self._sets.popitem(last=False)
        self._prefetch_after(region)
        return s

    def will_visit(self, regions: Sequence[int]) -> None:
        """The regions the pipeline will visit; starts making the one after the latest request."""
        self._visits = sorted(regions)
        if self._sets:
            self._prefetch_after(next(reversed(self._sets)))

    def _prefetch_after(self, region: int) -> None:
        i = bisect.bisect_right(self._visits, region)
        if i == len(self._visits):
            return
        region = self._visits[i]
        if region in self._sets or region in self._pending:
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="region-samples")
        self._pending[region] = self._pool.submit(self._make_ahead, self.plan.bounds(region))

    def _make_ahead(self, rows: tuple[int, int]) -> SampleSet:
        s = self._make(rows)
        return s if self._prepare is None else self._prepare(s)

    def close(self) -> None:
        """Drop the sets and stop the background thread (waiting for a set it is making)."""
        self._sets.clear()
        self._pending.clear()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class RegionCursor:
    """Which screen region one unit is in: batches reach a unit region by
    region, and when the first batch of another region arrives, ``enter(region)``
    hands the unit what it needs of it (before the batch is run).

    ``region``: where the unit starts (-1: nowhere, it enters the region of
    its first batch)."""

    def __init__(self, enter: Callable[[int], None], region: int = -1):
        self.region = region
        self._enter = enter

    def move_to(self, region: int) -> None:
        """The next batch is bound for ``region``."""
        if region != self.region:
            self.region = region
            self._enter(region)


def region_step(step: Callable[[Any], tuple[list, float]], cursor: RegionCursor | None = None
                ) -> Callable[[RegionBatch], tuple[list[RegionBatch], float]]:
    """A stage step over ``RegionBatch``es made of ``step``, a step over records:
    the unit's ``cursor`` (if it has one) moves to each batch's region before
    ``step`` runs on its records, and the outputs go on bound for that region."""

    def run(batch: RegionBatch) -> tuple[list[RegionBatch], float]:
        if cursor is not None:
            cursor.move_to(batch.region)
        outputs, cycles = step(batch.records)
        return [RegionBatch(batch.region, o) for o in outputs], cycles

    return run
