"""Screen regions: the plan, the bins and region-by-region rendering against whole frames."""

import dataclasses
import itertools
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim import render
from pipeline_sim.config import literal as toml_literal
from pipeline_sim.config import pass_settings
from pipeline_sim.regions import (RegionBatch, RegionCursor, RegionPlan, RegionSamples, bin_triangles, plan_regions,
                                  region_step, row_step)
from pipeline_sim.render import render_scene
from pipeline_sim.sampling import make_samples
from pipeline_sim.scene import load_scene


@given(width=st.integers(1, 400), height=st.integers(1, 400), spp=st.integers(1, 64),
       budget=st.integers(0, 1 << 20), step=st.sampled_from([1, 4, 16, 48, 64]))
def test_plan_cuts_whole_steps_within_budget(width, height, spp, budget, step):
    plan = plan_regions(width, height, spp, budget, step)
    cover = [plan.bounds(r) for r in range(plan.count)]
    assert cover[0][0] == 0 and cover[-1][1] == height
    assert all(a[1] == b[0] for a, b in zip(cover, cover[1:]))  # contiguous, no overlap
    assert all(r1 > r0 for r0, r1 in cover)
    if plan.count > 1:
        assert budget > 0
        assert plan.rows % step == 0  # boundaries on whole steps
        # within the budget unless a single step is already larger
        assert plan.rows * width * spp <= budget or plan.rows == step
        # as large as the budget allows
        assert (plan.rows + step) * width * spp > budget


def test_row_step_meets_the_shading_grid():
    assert row_step(4, 4, None) == 16
    assert row_step(4, 4, 1.0) == 16
    assert row_step(4, 4, 3.0) == 48
    assert row_step(4, 4, 2.5) == 80  # grid rows at multiples of 2.5: 80 = 32 x 2.5
    assert row_step(1, 1, 1.0 / 3.0) == 1
    assert row_step(4, 4, np.pi) == 0  # no common row: one region


@settings(max_examples=60)
@given(st.data())
def test_bins_hold_exactly_the_triangles_that_reach_a_region(data):
    height = data.draw(st.integers(1, 300))
    rows = data.draw(st.integers(1, 64))
    plan = RegionPlan(50, height, rows)
    n = data.draw(st.integers(0, 40))
    y0 = np.array(data.draw(st.lists(st.integers(0, height), min_size=n, max_size=n)), np.int32)
    y1 = np.array(data.draw(st.lists(st.integers(0, height), min_size=n, max_size=n)), np.int32)
    bounds = np.zeros((n, 4), np.int32)
    bounds[:, 2], bounds[:, 3] = y0, y1
    ids = np.arange(n, dtype=np.int64)
    bins = bin_triangles(bounds, ids, plan)
    assert len(bins) == plan.count
    seen = np.zeros(n, int)
    for r, b in enumerate(bins):
        assert np.all(np.diff(b) > 0)  # submission order
        r0, r1 = plan.bounds(r)
        for tri in ids:
            reaches = y0[tri] < r1 and y1[tri] > r0  # brute force: the row ranges overlap
            if y1[tri] > y0[tri]:
                assert (tri in b) == reaches, (tri, r)
        seen[b] += 1
    assert np.all(seen >= 1)  # every triangle reaches setup, empty bounds too


def test_region_samples_are_slices_of_the_frame_and_come_back_identical():
    width, height, spp = 24, 40, 8
    whole = make_samples(width, height, spp, 5, lens=True, motion=True)
    plan = RegionPlan(width, height, 16)

    def make(rows):
        return make_samples(width, height, spp, 5, lens=True, motion=True, rows=rows)

    regions = RegionSamples(plan, make, keep=1)
    order = [0, 1, 2, 0, 2]  # with keep=1 each request after the first drops the previous set
    for r in order:
        s = regions.region(r)
        r0, r1 = plan.bounds(r)
        assert (s.row0, s.height) == (r0, r1 - r0)
        k = slice(r0 * width * spp, r1 * width * spp)
        for name in ("x", "y", "u", "v", "t"):
            np.testing.assert_array_equal(getattr(s, name), getattr(whole, name)[k])
    assert regions.made == len(order)


def test_the_next_region_to_visit_is_made_ahead_on_another_thread_with_the_same_values():
    width, height, spp = 24, 64, 8
    whole = make_samples(width, height, spp, 5, lens=True, motion=True)
    plan = RegionPlan(width, height, 16)  # regions 0-3
    made_on = {}

    def make(rows):
        made_on[rows[0] // 16] = threading.current_thread().name
        return make_samples(width, height, spp, 5, lens=True, motion=True, rows=rows)

    regions = RegionSamples(plan, make, keep=1)
    regions.region(0)
    regions.will_visit([0, 2, 3])  # region 1 gets no batches: the next one to visit is 2
    try:
        for r in (2, 3):
            s = regions.region(r)
            k = slice(r * 16 * width * spp, (r + 1) * 16 * width * spp)
            for name in ("x", "y", "u", "v", "t"):
                np.testing.assert_array_equal(getattr(s, name), getattr(whole, name)[k])
    finally:
        regions.close()
    assert made_on[0] == threading.current_thread().name
    assert 1 not in made_on
    assert made_on[2].startswith("region-samples") and made_on[3].startswith("region-samples")
    assert regions.made == 3


def test_a_request_for_a_prepared_set_prepares_it_before_the_next_region_is_started():
    """``region(r, prepared=True)`` on a set not made yet: it is made and prepared (``prepare(set, True)``:
    waited for) on the requesting thread, and only then is the next region started ahead (prepared
    there with ``prepare(set)``); a set already made is handed out as it is."""
    log = []

    def make(rows):
        log.append(("make", rows[0] // 16, threading.current_thread().name))
        return make_samples(8, 64, 4, 1, lens=False, motion=True, rows=rows)

    def prepare(s, waited_for=False):
        log.append(("prepare", s.row0 // 16, waited_for))
        return s

    regions = RegionSamples(RegionPlan(8, 64, 16), make, keep=1, prepare=prepare)
    regions.will_visit([0, 1, 2])
    try:
        first = regions.region(0, prepared=True)
        assert log[:2] == [("make", 0, threading.current_thread().name), ("prepare", 0, True)]
        assert regions.region(0, prepared=True) is first and len([e for e in log if e[1] == 0]) == 2
        assert regions.region(1, prepared=True).row0 == 16
    finally:
        regions.close()
    assert ("prepare", 1, False) in log and ("prepare", 1, True) not in log
    assert log[2][:2] == ("make", 1) and log[2][2].startswith("region-samples")


def test_no_region_is_made_before_the_first_request_and_only_those_made_ahead_are_prepared():
    """Regions with triangles may still get no batch (their tiles all culled): none is made on the
    word of ``will_visit`` alone, only once a unit asks for it; the next one to visit is then made
    ahead and ``prepare`` runs on it there, not on a set made on request."""
    made_on, prepared_on = {}, {}

    def make(rows):
        made_on[rows[0] // 16] = threading.current_thread().name
        return make_samples(8, 64, 4, 1, lens=False, motion=True, rows=rows)

    def prepare(s):
        prepared_on[s.row0 // 16] = threading.current_thread().name
        return s

    regions = RegionSamples(RegionPlan(8, 64, 16), make, keep=1, prepare=prepare)
    regions.will_visit([0, 1, 3])
    try:
        assert made_on == {}
        assert regions.region(1).row0 == 16 and regions.region(3).row0 == 48
    finally:
        regions.close()
    assert made_on == {1: threading.current_thread().name, 3: made_on[3]} and made_on[3].startswith("region-samples")
    assert prepared_on == {3: made_on[3]}
    assert regions.made == 2


def test_a_region_made_ahead_and_never_requested_is_dropped():
    plan = RegionPlan(8, 64, 16)
    regions = RegionSamples(plan, lambda rows: make_samples(8, 64, 4, 1, lens=False, motion=True, rows=rows), keep=1)
    regions.will_visit([0, 1, 2, 3])
    try:
        regions.region(0)  # makes 1 ahead
        regions.region(2)  # region 1 got no batch after all: its set is dropped, not held to the end
        assert set(regions._pending) <= {3} and set(regions._sets) == {2}
    finally:
        regions.close()


@given(start=st.integers(-1, 4), regions=st.lists(st.integers(0, 4), max_size=30))
def test_a_cursor_enters_each_run_of_a_region_once(start, regions):
    """``enter`` is called at each change of region, with the new one: the
    runs of equal regions after the starting one (brute force: groupby)."""
    entered = []
    cursor = RegionCursor(entered.append, region=start)
    for r in regions:
        cursor.move_to(r)
        assert cursor.region == r
    assert entered == [r for r, _ in itertools.groupby([start] + regions)][1:]


def test_a_region_step_moves_the_cursor_first_and_keeps_the_region():
    log = []
    cursor = RegionCursor(lambda r: log.append(("enter", r)))

    def step(records):
        log.append(("step", len(records["a"])))
        return [{"a": records["a"][:1]}, {"a": records["a"][1:]}], 7.0

    run = region_step(step, cursor)
    out, cycles = run(RegionBatch(3, {"a": np.arange(5)}))
    out2, _ = run(RegionBatch(3, {"a": np.arange(2)}))
    assert log == [("enter", 3), ("step", 5), ("step", 2)] and cycles == 7.0
    assert [(b.region, len(b)) for b in out + out2] == [(3, 1), (3, 4), (3, 1), (3, 1)]
    assert len(RegionBatch(0, np.arange(6))) == 6 and len(RegionBatch(0, {})) == 0


def _small(root, name, **image):
    scene = load_scene(root / f"workloads/scenes/{name}.toml")
    return scene.replace(image=dataclasses.replace(scene.image, **image))


CASES = {
    "hierarchical": {},
    "two_stage": {"tile_test.algorithm": "two_stage"},
    "interleave_uvt": {"tile_test.algorithm": "interleave_uvt", "pass.sample_pattern": "interleave"},
    "shading_rate_3": {"pass.shading_rate": 3.0, "tile_test.algorithm": "bbox"},
    "per_sample_quadratic": {"pass.shading_mode": "per_sample", "tile_test.edge_solver": "quadratic"},
    "conservative": {"pass.mode": "conservative"},
}


def _settings(overrides: dict, region_samples: int, zcull: bool) -> dict:
    values = {**overrides, "simulation.region_samples": region_samples, "zcull.enabled": zcull}
    return pass_settings([f"{key}={toml_literal(value)}" for key, value in values.items()])


@pytest.mark.parametrize("case", CASES)
def test_regions_render_the_whole_frames_image_and_counters(root, case):
    """Region by region gives the whole frame's image and per-sample depth.
    With z-cull off every counter matches too, but for the traverser's
    triangle records (a triangle enters it once per region it reaches) and the
    shading cache's: its grid lives in the reference view, where a moving or
    defocused triangle's cell can take samples from two regions, so hits and
    misses follow the order."""
    scene = _small(root, "default", width=120, height=72, spp=4)
    whole = render_scene(scene, **_settings(CASES[case], 0, zcull=False))
    assert whole.regions.count == 1
    budget = 120 * whole.depth.shape[2] * 20  # about 20 rows a region
    cut = render_scene(scene, **_settings(CASES[case], budget, zcull=False), keep_depth=True)
    assert cut.regions.count >= 2
    np.testing.assert_array_equal(cut.image, whole.image)
    np.testing.assert_array_equal(cut.depth, whole.depth)
    a = whole.counters.set_index(["unit", "counter"]).value
    b = cut.counters.set_index(["unit", "counter"]).value
    differ = set(a.index[a != b])
    allowed = {("tile_traverser", "records_in")}
    if cut.counter("shading", "lookups"):
        allowed |= {i for i in a.index if i[0] == "shading"}
    assert differ <= allowed, sorted(differ - allowed)
    assert cut.counter("tile_traverser", "records_in") >= whole.counter("tile_traverser", "records_in")
    assert cut.samples is None and whole.samples is not None


def test_regions_with_zcull_keep_the_image(root):
    """With z-cull the culled tiles depend on what the ROP has written when a
    tile arrives, so counters may change with the order; the image may not."""
    scene = _small(root, "default", width=160, height=90, spp=4)
    whole = render_scene(scene, **_settings({}, 0, zcull=True))
    for budget in (160 * 4 * 16, 160 * 4 * 40):
        cut = render_scene(scene, **_settings({}, budget, zcull=True), keep_depth=True)
        assert cut.regions.count > 1
        np.testing.assert_array_equal(cut.image, whole.image)
        np.testing.assert_array_equal(cut.depth, whole.depth)
        assert cut.counter("zcull", "tiles_tested") == whole.counter("zcull", "tiles_tested")
    assert cut.depth is not None
    assert render_scene(scene, **_settings({}, 160 * 4 * 16, zcull=True)).depth is None  # not kept by default


def test_region_size_is_checked(tmp_path):
    from pipeline_sim.errors import UserError

    with pytest.raises(UserError, match="simulation.region_samples"):
        pass_settings(["simulation.region_samples=-1"])


@pytest.mark.parametrize("case", ["hierarchical", "per_sample_quadratic", "conservative"])
@pytest.mark.parametrize("refresh", ["timed", "ordered"])
def test_units_hold_the_region_of_every_batch_they_run(root, monkeypatch, case, refresh):
    """The pipeline hands the sample tester, shading and the ROP the samples
    and buffers of each region as their batches move on: every record a unit
    runs lies in the rows it holds then (from the records themselves), and
    what it holds is a region of the plan."""
    held = {"sample_tester": [], "shading": [], "rop": []}  # (rows the unit holds, rows of the batch's records)

    def rows_of(s):
        return s.row0, s.row0 + s.height

    class Tester(render.SampleTester):
        def run(self, tiles):
            held["sample_tester"].append((rows_of(self.samples), tiles["ty"] * self.tile_size))
            return super().run(tiles)

    class Shading(render.Shading):
        def run(self, batch):
            if not self.conservative:
                held["shading"].append((rows_of(self.samples), batch["pix"] // self.draw.width))
            return super().run(batch)

    class Rop(render.Rop):
        def run(self, batch):
            if self.samples is not None:
                assert rows_of(self.samples) == self.rows
            held["rop"].append((self.rows, batch["pix"] // self.width))
            return super().run(batch)

    for name, cls in (("SampleTester", Tester), ("Shading", Shading), ("Rop", Rop)):
        monkeypatch.setattr(render, name, cls)
    made = []  # the rows of every sample set made
    make = render.make_samples
    monkeypatch.setattr(render, "make_samples", lambda *a, rows, **k: (made.append(rows), make(*a, rows=rows, **k))[1])
    scene = _small(root, "default", width=120, height=72, spp=4)
    res = render_scene(scene, **_settings(CASES[case], 120 * 20, zcull=True), zcull_refresh=refresh)  # 16-20 rows
    plan = res.regions
    bounds = [plan.bounds(r) for r in range(plan.count)]
    for unit, log in held.items():
        if case == "conservative" and unit != "rop":  # no sample tester, shading reads no samples
            assert not log
            continue
        for rows, record_rows in log:
            assert rows in bounds
            assert rows[0] <= record_rows.min() and record_rows.max() < rows[1], (unit, rows)
        assert len({rows for rows, _ in log}) > 1, unit  # regions without records are skipped
    # the samples of a region no unit ran a batch in are never made (the top region has triangles, no batch)
    used = {rows for log in held.values() for rows, _ in log}
    assert {rows for rows in made if rows[1] > rows[0]} <= used and bounds[0] not in used
