"""benchmarks/instrument.py: the simulation thread's waits for run-ahead steps (and benchmarks/run.py's
medians of them)."""

from __future__ import annotations

import threading
import time

import pytest

from benchmarks import instrument as ins
from benchmarks.run import simulation_thread
from pipeline_sim import pipeline
from pipeline_sim.pipeline import Stage, simulate


def _stages(ran_on: dict[int, bool], refuse: set[int], fail_at: int | None = None) -> list[Stage]:
    """A source stage, a stage that may run ahead (except for the batches in ``refuse``; each step notes
    whether it ran on the thread that called ``simulate`` and sleeps a little, so that the simulation waits
    for some; the step of batch ``fail_at`` raises), and a sink."""
    caller = threading.current_thread()

    def first(it):
        return [it], 1.0

    def middle(it):
        ran_on[it] = threading.current_thread() is caller
        time.sleep(2e-4)
        if it == fail_at:
            raise RuntimeError("step failed")
        return [it], 3.0

    def last(it):
        return [], 1.0

    return [Stage("first", first, 1), Stage("middle", middle, 2, ahead=lambda it: it not in refuse),
            Stage("last", last, 1)]


@pytest.mark.parametrize("refuse", [set(), {0, 3, 4}, set(range(10))])
def test_simulation_waits_counts_each_step_once_where_it_ran(refuse):
    """Every step of the stage with run-ahead is counted once: as taken from its thread when it ran there, as
    the simulation's own when it ran on the simulation's thread; the seconds are at least those of the steps
    counted."""
    ran_on: dict[int, bool] = {}
    log: dict = {}
    with ins.simulation_waits(log):
        simulate(_stages(ran_on, refuse), list(range(10)), 2, run_ahead=2)
    assert set(log) == {"middle"}  # the only stage with a run-ahead thread
    d = log["middle"]
    own = sum(ran_on.values())
    assert (d["taken"], d["own"]) == (10 - own, own)
    assert own >= len(refuse)  # a refused batch runs on the simulation's thread
    assert d["own_s"] >= own * 2e-4  # each of those steps slept that long


def test_simulation_waits_sees_nothing_without_run_ahead():
    log: dict = {}
    with ins.simulation_waits(log):
        simulate(_stages({}, set()), list(range(5)), 2)
    assert log == {}


def test_simulation_waits_restores_the_step_after_an_error():
    real = pipeline._RunAhead.step
    log: dict = {}
    with pytest.raises(RuntimeError, match="step failed"), ins.simulation_waits(log):
        simulate(_stages({}, set(), fail_at=3), list(range(6)), 2, run_ahead=2)
    assert pipeline._RunAhead.step is real
    assert log["middle"]["taken"] + log["middle"]["own"] == 4  # the failed step counted where it was taken


def test_simulation_thread_takes_medians_field_by_field_with_missing_units_as_zeros():
    runs = [(0.5, {"a": {"taken": 4, "waited_s": 0.1, "own": 2, "own_s": 0.3}}),
            (0.7, {"a": {"taken": 6, "waited_s": 0.3, "own": 0, "own_s": 0.0},
                   "b": {"taken": 1, "waited_s": 0.2, "own": 1, "own_s": 0.1}}),
            (0.6, {})]
    got = simulation_thread(runs)
    assert got["cpu_s"] == pytest.approx(0.6)
    assert got["units"]["a"] == pytest.approx({"taken": 4, "waited_s": 0.1, "own": 0, "own_s": 0.0})
    assert got["units"]["b"] == pytest.approx({"taken": 0, "waited_s": 0.0, "own": 0, "own_s": 0.0})
    assert simulation_thread([]) == {"cpu_s": None, "units": {}}
