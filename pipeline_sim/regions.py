"""Screen regions: a frame rendered as horizontal bands of rows, one after another.

Samples and per-sample buffers scale with pixels x spp (a 1920x1080 frame at
16 spp holds 33 million samples), so a large frame is not materialized at
once. It is cut into regions of whole rows (``pipeline.region_samples``
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
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable

import numpy as np

from pipeline_sim.sampling import SampleSet


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

    def region_of_row(self, row: int) -> int:
        return int(row) // self.rows


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
class TriangleBatch:
    """A batch of triangle ids bound for one screen region."""

    region: int
    ids: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


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
    every generation, a repeat included).
    """

    def __init__(self, plan: RegionPlan, make: Callable[[tuple[int, int]], SampleSet], keep: int = 3):
        self.plan = plan
        self._make = make
        self._keep = keep
        self._sets: OrderedDict[int, SampleSet] = OrderedDict()
        self.made = 0

    @classmethod
    def of(cls, samples: SampleSet | RegionSamples, plan: RegionPlan | None = None) -> RegionSamples:
        """``samples`` itself when it is a ``RegionSamples``; a ready sample set
        as the only region (``plan``, if given, must then be a single region)."""
        if isinstance(samples, RegionSamples):
            return samples
        if plan is not None and plan.count > 1:
            raise ValueError("a ready sample set is one region; several regions need a RegionSamples")
        rows = samples.row0 + samples.height
        return cls(RegionPlan(samples.width, rows, max(rows, 1)), lambda bounds: samples)

    def region(self, region: int) -> SampleSet:
        s = self._sets.get(region)
        if s is None:
            s = self._make(self.plan.bounds(region))
            self.made += 1
            self._sets[region] = s
            while len(self._sets) > self._keep:
                self._sets.popitem(last=False)
        else:
            self._sets.move_to_end(region)
        return s

    def for_row(self, row: int) -> SampleSet:
        """The samples of the region holding image row ``row``."""
        return self.region(self.plan.region_of_row(row))


def samples_for_row(regions: RegionSamples, held: SampleSet | None, row: int | None) -> SampleSet:
    """``held`` if it holds image row ``row``, else the samples of the region
    that does; ``row`` None (an empty batch): ``held``, or region 0's samples."""
    if held is not None and (row is None or held.row0 <= row < held.row0 + held.height):
        return held
    return regions.for_row(0 if row is None else row)
