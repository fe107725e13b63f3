"""benchmarks/instrument.py: the simulation thread's waits for run-ahead steps."""

from __future__ import annotations

import threading
import time

import pytest

from benchmarks import instrument as ins
from pipeline_sim.pipeline import Stage, simulate


def _stages(ran_on: dict[int, bool], refuse: set[int]) -> list[Stage]:
    """A source stage, a stage that may run ahead (except for the batches in ``refuse``; each step notes
    whether it ran on the main thread and sleeps a little so that the simulation waits for some), and a
    sink."""
    def first(it):
        return [it], 1.0

    def middle(it):
        ran_on[it] = threading.current_thread() is threading.main_thread()
        time.sleep(2e-4)
        return [it], 3.0

    def last(it):
        return [], 1.0

    return [Stage("first", first, 1), Stage("middle", middle, 2, ahead=lambda it: it not in refuse),
            Stage("last", last, 1)]


@pytest.mark.parametrize("refuse", [set(), {0, 3, 4}, set(range(10))])
def test_simulation_waits_counts_each_step_once_where_it_ran(refuse):
    """Every step of the stage with run-ahead is counted once: as taken from its thread when it ran there, as
    the simulation's own when it ran on the main thread; the seconds are those of the steps counted."""
    ran_on: dict[int, bool] = {}
    log: dict = {}
    with ins.simulation_waits(log):
        simulate(_stages(ran_on, refuse), list(range(10)), 2, run_ahead=2)
    assert set(log) == {"middle"}  # the only stage with a run-ahead thread
    d = log["middle"]
    own = sum(ran_on.values())
    assert (d["taken"], d["own"]) == (10 - own, own)
    assert own >= len(refuse)  # a refused batch runs on the main thread
    assert d["own_s"] >= own * 2e-4  # each of those steps slept that long
    assert d["waited_s"] >= 0.0


def test_simulation_waits_sees_nothing_without_run_ahead():
    log: dict = {}
    with ins.simulation_waits(log):
        simulate(_stages({}, set()), list(range(5)), 2)
    assert log == {}
