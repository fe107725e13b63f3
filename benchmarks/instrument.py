"""Running a pass with and without SimPy, and timing the units inside it.

Nothing here edits the project: ``run_pass`` looks up ``simulate``, the unit
classes and ``make_samples`` at call time, so the context managers below
swap them for the duration of one call and restore them afterwards.

* ``recording()``: the real SimPy ``simulate``, with every stage step wrapped
  to record the order in which the stages ran and what each step returned
  (number of output batches, cycles).
* ``direct(order)``: no SimPy at all. The same step functions (unit run +
  counters + cost model, exactly as ``run_pass`` builds them) are called in a
  plain Python loop with a FIFO per stage: either replaying the recorded stage
  order (so every unit sees the same batches in the same order *and* the same
  interleaving of z-cull tests and ROP refreshes as under SimPy) or, with
  ``order=None``, depth-first (each triangle batch all the way to the ROP
  before the next).
* ``simpy_only(script)``: the SimPy layer alone: ``pipeline.simulate`` with
  steps that do no work and return the recorded output counts and cycles.
* ``simulation_waits()``: per unit with run-ahead threads, the steps the
  simulation's thread took from the unit's thread and how long it waited for
  them, and the steps it ran itself: where a run-ahead pass's critical path
  goes through that thread.
* ``unit_timers()``: wall and main-thread CPU time of every unit's ``run``,
  the sample tester's numba kernel, the z-cull refresh, the waits for a
  screen region's samples (made on a background thread while the region
  before is processed) and the resolves. These runs step every unit on the
  main thread (``simulation.run_ahead = 0``): the split is of the work, not
  of a critical path that the run-ahead threads shorten.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
from collections import defaultdict, deque

import pandas as pd

import pipeline_sim.render as render
import units.sample_tester as sample_tester_mod
from pipeline_sim import pipeline
from pipeline_sim.pipeline import Stage, TimingResult
from pipeline_sim.regions import RegionSamples
from units.rop import Rop
from units.sample_tester import SampleTester
from units.shading_cache import Shading
from units.tile_test import TileTest
from units.tile_traverser import TileTraverser
from units.triangle_setup import TriangleSetup
from units.zcull import ZCull

UNIT_CLASSES = {
    "triangle_setup": TriangleSetup, "tile_traverser": TileTraverser, "tile_test": TileTest,
    "zcull": ZCull, "sample_tester": SampleTester, "shading": Shading, "rop": Rop,
}
_REAL_SIMULATE = pipeline.simulate


@contextlib.contextmanager
def patched(obj, name, value):
    old = getattr(obj, name)
    setattr(obj, name, value)
    try:
        yield
    finally:
        setattr(obj, name, old)


class Script:
    """What one SimPy run did: the stage order of every step call and its results."""

    def __init__(self):
        self.order: list[int] = []
        self.returns: dict[int, list[tuple[int, float]]] = defaultdict(list)
        self.stages: list[tuple[str, int]] = []
        self.n_source = 0
        self.queue_depth = 0
        self.capacities = None
        self.frame_cycles = 0.0


@contextlib.contextmanager
def recording(script: Script):
    def simulate(stages, source_batches, queue_depth, capacities=None, **_run_ahead):  # (one thread)
        script.stages = [(s.name, s.latency) for s in stages]
        script.n_source = len(source_batches)
        script.queue_depth = queue_depth
        script.capacities = capacities
        for i, s in enumerate(stages):
            def step(batch, _f=s.step, _i=i):
                script.order.append(_i)
                outs, cycles = _f(batch)
                script.returns[_i].append((len(outs), cycles))
                return outs, cycles
            s.step = step
        res = _REAL_SIMULATE(stages, source_batches, queue_depth, capacities, 0)  # (the order of one thread)
        script.frame_cycles = res.frame_cycles
        return res

    with patched(render, "simulate", simulate):
        yield


def _empty_timing() -> TimingResult:
    units = pd.DataFrame(columns=["unit", "busy", "starved", "blocked", "batches", "utilization"])
    queues = pd.DataFrame(columns=["channel", "capacity_records", "mean_records", "peak_records"])
    # the remaining fields (traces, queue_series, ...) are per-unit / per-channel dicts
    kw = {"frame_cycles": 0.0, "units": units, "queues": queues}
    for f in dataclasses.fields(TimingResult):
        kw.setdefault(f.name, {})
    return TimingResult(**kw)


@contextlib.contextmanager
def direct(order: list[int] | None):
    """Replace SimPy by a plain loop (replaying ``order``, or depth-first if None)."""

    def simulate(stages, source_batches, queue_depth, capacities=None, **_run_ahead):  # (one thread)
        n = len(stages)

        def step(i, batch):  # with its settle (the ROP's z-cull refresh published), as SimPy does
            return stages[i].step_and_settle(batch)[0]

        if order is None:
            def push(i, batch):
                outs = step(i, batch)
                if i + 1 < n:
                    for o in outs:
                        push(i + 1, o)
            for b in source_batches:
                push(0, b)
        else:
            queues = [deque() for _ in range(n)]
            queues[0].extend(source_batches)
            last = n - 1
            for i in order:
                outs = step(i, queues[i].popleft())
                if i < last:
                    queues[i + 1].extend(outs)
        return _empty_timing()

    with patched(render, "simulate", simulate):
        yield


def simpy_only(script: Script) -> tuple[float, float, float]:
    """Run ``pipeline.simulate`` with do-nothing steps replaying ``script``;
    (wall seconds, CPU seconds, frame cycles)."""
    stages = []
    for i, (name, latency) in enumerate(script.stages):
        rets = deque(script.returns[i])

        def step(_batch, _rets=rets):
            n_out, cycles = _rets.popleft()
            return [0] * n_out, cycles  # any non-None payload (None is the end marker)
        stages.append(Stage(name, step, latency))
    src = [0] * script.n_source
    t0 = time.perf_counter()
    c0 = time.process_time()
    res = _REAL_SIMULATE(stages, src, script.queue_depth, script.capacities)
    return time.perf_counter() - t0, time.process_time() - c0, res.frame_cycles


class Timers:
    """Accumulated wall (perf_counter) and CPU seconds of the calling thread (thread_time) and calls per key;
    ``self_seconds`` and ``self_cpu`` leave out the timed calls made inside (a screen region's samples
    waited for or resolved within a stage's step), except those of :data:`TRANSPARENT` keys, which their
    caller's time keeps. Every timed call is made on the main thread; the CPU of sample generation's
    threads is what the process used beyond it."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)
        self.cpu: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.self_seconds: dict[str, float] = defaultdict(float)
        self.self_cpu: dict[str, float] = defaultdict(float)
        self.stack: list[list[float]] = []  # per open timed call: its timed children's wall and CPU
        self.other_threads_cpu = 0.0  # CPU the process used beyond the main thread (set by the caller)
        self.lock = threading.Lock()  # for the sample sets counted on any thread


#: Keys timed inside a unit's run whose time stays that unit's (the tester's kernel).
TRANSPARENT = ("sample_test_kernel",)


def _timed(fn, timers: Timers, key: str):
    if key in TRANSPARENT:
        def transparent(*a, **k):
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
                timers.seconds[key] += wall
                timers.cpu[key] += cpu
                timers.calls[key] += 1
        return transparent

    def wrapper(*a, **k):
        children = [0.0, 0.0]
        timers.stack.append(children)
        t0 = time.perf_counter()
        c0 = time.thread_time()
        try:
            return fn(*a, **k)
        finally:
            wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
            timers.stack.pop()
            timers.cpu[key] += cpu
            timers.seconds[key] += wall
            timers.calls[key] += 1
            timers.self_seconds[key] += wall - children[0]
            timers.self_cpu[key] += cpu - children[1]
            if timers.stack:
                timers.stack[-1][0] += wall
                timers.stack[-1][1] += cpu
    return wrapper


#: what ``simulation_waits`` logs per unit
WAIT_FIELDS = ("taken", "waited_s", "own", "own_s")


@contextlib.contextmanager
def simulation_waits(log: dict):
    """Per unit whose steps may run ahead (``simulation.run_ahead``), in ``log[unit]``: ``taken``, the steps
    the simulation took from the unit's run-ahead thread, and ``waited_s``, the seconds its thread spent
    taking them (waiting for the ones not done yet); ``own``, the steps it ran on its own thread (batches not
    worth handing over, a unit's first step, the first batch of a screen region), and ``own_s``, their
    seconds. Each time also holds the starting of the unit's next batches on its thread that follows a step
    (``_RunAhead.step``). Every ``simulate`` during the context logs here, on whatever thread it runs."""
    real = pipeline._RunAhead.step

    def step(self, payload):
        taken = self.stepped in self.started
        t0 = time.perf_counter()
        try:
            return real(self, payload)
        finally:
            d = log.get(self.stage.name)
            if d is None:
                d = log[self.stage.name] = dict.fromkeys(WAIT_FIELDS, 0)
            if taken:
                d["taken"] += 1
                d["waited_s"] += time.perf_counter() - t0
            else:
                d["own"] += 1
                d["own_s"] += time.perf_counter() - t0

    with patched(pipeline._RunAhead, "step", step):
        yield


@contextlib.contextmanager
def unit_timers(timers: Timers):
    """Time each unit's ``run``, the sample test kernel, the z-cull refresh, the waits for a region's samples,
    the resolve and the stage steps; count the sample sets made (``calls["make_samples"]``, on any thread)."""
    with contextlib.ExitStack() as stack:
        for name, cls in UNIT_CLASSES.items():
            stack.enter_context(patched(cls, "run", _timed(cls.run, timers, name)))
        stack.enter_context(patched(Rop, "resolve", _timed(Rop.resolve, timers, "resolve")))
        # a frame in several screen regions resolves each one as the ROP moves on to the next
        stack.enter_context(patched(Rop, "open_region", _timed(Rop.open_region, timers, "resolve")))
        stack.enter_context(patched(sample_tester_mod, "sample_test_kernel",
                                    _timed(sample_tester_mod.sample_test_kernel, timers, "sample_test_kernel")))
        stack.enter_context(patched(Rop, "refresh_zcull", _timed(Rop.refresh_zcull, timers, "zcull refresh")))
        stack.enter_context(patched(RegionSamples, "region", _timed(RegionSamples.region, timers, "samples wait")))

        def make_samples(*a, _make=render.make_samples, **k):
            rows = k.get("rows")
            if rows is None or rows[1] > rows[0]:  # (a set of no rows carries only the pattern's tuples)
                with timers.lock:
                    timers.calls["make_samples"] += 1
            return _make(*a, **k)
        stack.enter_context(patched(render, "make_samples", make_samples))

        def simulate(stages, source_batches, queue_depth, capacities=None, **_run_ahead):  # (one thread)
            for s in stages:
                s.step = _timed(s.step, timers, "step:" + s.name)
            # every step on the main thread (the timers time one thread)
            return _timed(_REAL_SIMULATE, timers, "simulate")(stages, source_batches, queue_depth, capacities, 0)
        stack.enter_context(patched(render, "simulate", simulate))
        yield
