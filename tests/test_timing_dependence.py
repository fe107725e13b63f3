"""Which counters timing can move (docs/pipeline.md §4), measured.

Each unit declares the counters timing can move (``timing_dependent``, next
to its event names); ``counters.csv`` carries the declaration. Here only
settings declared ``cycles`` change (queue depth, throughputs, latencies,
instances, batch sizes), on a blurred scene where z-cull culls: the image and
every counter declared timing-independent must stay bit-identical, every
counter that moved must be declared timing-dependent, and z-cull's culling
must really move. With z-cull refreshed in submission order (``ordered``,
what ``compare`` uses) nothing moves, and every culling algorithm sees the
same z-cull boxes for the same triangles.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

import units.zcull as zc
from pipeline_sim.compare import ALGORITHMS
from pipeline_sim.config import CYCLES, apply_overrides, load_arch, pass_settings, setting_effects
from pipeline_sim.simulation import SimOptions
from pipeline_sim.counters import COMMON
from pipeline_sim.render import render_scene
from pipeline_sim.scene import load_scene
from units.rop import Rop
from units.sample_tester import SampleTester
from units.shading_cache import Shading
from units.tile_test import TileTest
from units.tile_traverser import TileTraverser
from units.triangle_setup import TriangleSetup

SPP = 4  # z-cull culls hundreds of tiles of compare/both_1x at 4 spp, how many depends on the timing
# cycles settings only: every one of them moves what z-cull culls on this scene
VARIANTS = [
    ["pipeline.queue_depth=1"],
    ["pipeline.queue_depth=32"],
    ["tile_test.throughput=0.05"],
    ["sample_tester.throughput=2", "sample_tester.instances=1"],
    ["rop.bandwidth=8"],
    ["zcull.latency=2000"],
    ["simulation.triangles_per_batch=8"],
    ["simulation.tiles_per_batch=64"],
    ["simulation.samples_per_batch=4096"],
]


@pytest.fixture(scope="module")
def scene(root):
    return load_scene(root / "workloads/scenes/compare/both_1x.toml")


@pytest.fixture(scope="module")
def timed(scene):
    """The default (timed) refresh: the baseline and every variant."""
    return {tuple(v): render_scene(scene, **pass_settings(v), spp=SPP) for v in [[]] + VARIANTS}


def _values(result):
    return result.counters.set_index(["unit", "counter"]).value


def test_variants_change_cycles_settings_only():
    effects = setting_effects()
    for v in VARIANTS:
        for override in v:
            assert effects[override.split("=")[0]] == CYCLES, override


def test_timing_independent_counters_do_not_move(timed):
    base = timed[()]
    declared = base.counters.set_index(["unit", "counter"]).timing_dependent
    assert declared.any() and not declared.all()
    fixed = declared.index[~declared]
    for v, res in timed.items():
        np.testing.assert_array_equal(res.image, base.image)
        assert res.counters.timing_dependent.equals(base.counters.timing_dependent)
        a, b = _values(base)[fixed], _values(res)[fixed]
        assert a.equals(b), (v, {k: (int(a[k]), int(b[k])) for k in fixed if a[k] != b[k]})


def test_counters_that_move_are_declared_timing_dependent(timed):
    """The measured set of counters that moved against the declaration: a counter
    wrongly declared timing-independent shows up here by name."""
    base = timed[()]
    declared = base.counters.set_index(["unit", "counter"]).timing_dependent
    moved = set()
    for res in timed.values():
        diff = _values(res) != _values(base)
        moved |= set(diff.index[diff])
    assert moved - set(declared.index[declared]) == set()
    # the timing really moves z-cull's culling and the work after it ...
    assert {("zcull", "tiles_culled"), ("sample_tester", "samples_tested"),
            ("shading", "shader_executions"), ("rop", "depth_tests")} <= moved
    # ... and every unit that declares timing-dependent counters has one that moved
    units = {u for u, _ in declared.index[declared]}
    assert units == {u for u, _ in moved} == {"zcull", "sample_tester", "shading", "rop"}
    culled = {v: r.counter("zcull", "tiles_culled") for v, r in timed.items()}
    assert culled[("pipeline.queue_depth=1",)] != culled[("pipeline.queue_depth=32",)]


def test_ordered_refresh_moves_no_counter(scene, timed):
    base = render_scene(scene, load_arch(), spp=SPP, zcull_refresh="ordered")
    assert not base.counters.timing_dependent.any()
    assert base.counter("zcull", "tiles_culled") > 0
    cycles = {base.timing.frame_cycles}
    for v in VARIANTS:
        if any(o.startswith("simulation.triangles_per_batch") for o in v):
            continue  # the ordered refresh's step: it may move z-cull's counters
        res = render_scene(scene, **pass_settings(v), spp=SPP, zcull_refresh="ordered")
        np.testing.assert_array_equal(res.image, timed[()].image)
        assert res.counters.equals(base.counters), v
        cycles.add(res.timing.frame_cycles)
    assert len(cycles) > 5  # the timing did change


def test_ordered_refresh_over_screen_regions(scene, timed):
    """Region by region (each triangle batch belongs to one), the ordered refresh gives
    the same image and still no counter that moves with the timing."""
    regions = ["simulation.region_samples=40000"]
    a = render_scene(scene, **pass_settings(regions), spp=SPP, zcull_refresh="ordered")
    b = render_scene(scene, **pass_settings(regions + ["pipeline.queue_depth=32", "tile_test.throughput=0.05"]),
                     spp=SPP, zcull_refresh="ordered")
    assert a.region_info["count"] > 5
    np.testing.assert_array_equal(a.image, timed[()].image)
    assert a.counters.equals(b.counters) and a.counter("zcull", "tiles_culled") > 0


def _zmax_by_triangle_batch(scene, arch, refresh, monkeypatch):
    """Per triangle batch, z-cull's zmax boxes at each of its z-cull calls."""
    seen: dict[int, list[np.ndarray]] = {}
    run = zc.ZCull.run
    tpb = SimOptions().triangles_per_batch

    def spy(self, tiles, *query):
        if len(tiles["tri"]):
            batch = int(tiles["tri"][0]) // tpb  # one screen region: batches are consecutive ids
            assert int(tiles["tri"][-1]) // tpb == batch  # a z-cull batch holds one triangle batch's tiles
            seen.setdefault(batch, []).append(self.zmax.copy())
        return run(self, tiles, *query)

    monkeypatch.setattr(zc.ZCull, "run", spy)
    result = render_scene(scene, arch, zcull_refresh=refresh)
    monkeypatch.undo()
    assert result.region_info["count"] == 1
    return seen


def test_ordered_refresh_gives_every_algorithm_the_same_zcull_boxes(scene, monkeypatch):
    """Same submitted triangles, same z-cull state: with the ordered refresh z-cull
    tests every tile of a triangle batch against the zmax of the depth of all
    earlier batches, whichever tiles the algorithm's tile test passed it; with
    the timed one it is whatever the ROP had got to."""
    small = scene.replace(image=dataclasses.replace(scene.image, width=160, height=90, spp=SPP))
    names = ("bbox", "hierarchical", "two_stage")
    for refresh in ("ordered", "timed"):
        boxes = {n: _zmax_by_triangle_batch(small, apply_overrides(load_arch(), ALGORITHMS[n]), refresh,
                                            monkeypatch) for n in names}
        same = True
        for n in names:
            for batch, states in boxes[n].items():
                first = boxes[names[0]].get(batch, [states[0]])[0]
                same &= all(np.array_equal(s, first) for s in states)
        shared = set.intersection(*(set(b) for b in boxes.values()))
        assert len(shared) > 5
        assert same == (refresh == "ordered"), refresh


def test_documented_counters_are_the_declared_ones(root):
    """docs/pipeline.md §4 lists each unit's events and the counters timing can move: the same as the code."""
    text = (root / "docs/pipeline.md").read_text()
    section = text[text.index("## 4. What is counted"):text.index("## 5.")]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = cells[1:]
    units = (TriangleSetup, TileTraverser, TileTest, zc.ZCull, SampleTester, Shading, Rop)
    assert set(rows) == {u.name for u in units}
    for u in units:
        events, moving = rows[u.name]
        assert tuple(re.findall(r"`([a-z0-9_]+)`", events)) == u.events, u.name
        declared = {"none": (), "all": COMMON + u.events}.get(moving) or tuple(re.findall(r"`([a-z0-9_]+)`", moving))
        assert declared == tuple(u.timing_dependent), u.name
