"""The SimPy plumbing: units as stage processes joined by bounded channels.

This is the only module that knows about SimPy. Each unit's functional model
(``units/``) is wrapped in a ``Stage`` that gets a batch from its input
channel, runs the unit's numba kernel on it, turns the work the kernel
reports into cycles with the unit's cost model (throughput per cycle per
instance, instances, latency), holds the unit busy for those cycles and then
puts its output batches into the next channel, waiting while that channel is
full. Per stage we account busy, starved (waiting for input) and blocked
(waiting for room downstream) cycles; per channel the time-weighted and
maximum occupancy, in the unit its capacity counts (records, or batches).

Every unit processes its batches in order, so changing a cost or a queue
depth changes cycles, never the image. What a unit computes can still
depend on when it runs where one unit reads state another updates (z-cull
reads the depth the ROP has refreshed by that simulated time): such
counters are declared timing-dependent (docs/pipeline.md §4).
``run_in_order`` takes timing out of them: it runs the functional models
first, in submission order, and hands ``simulate`` stages that replay what
each step returned.

A stage whose step depends only on its batch and the steps before it
(``Stage.ahead``; the tile test, the sample tester, shading and the ROP) may
run its steps before the simulation reaches them: ``simulate`` starts the
step of each batch that enters the stage's FIFO on a thread of the stage's
own, in FIFO order and at most ``run_ahead`` batches ahead, and the stage
takes the result when it gets to the batch. What a step makes that other
units read waits for that moment: the stage's ``settle`` runs then, on the
simulation's thread (the ROP's publishes the z-cull refresh its step made).
The numba kernels release the interpreter lock, so one unit's kernel runs
beside the others' and the SimPy layer on another core. Handing a batch to
another thread has a cost of its own (a thread woken, results handed back),
so with ``run_ahead_min_seconds`` only a batch whose step is expected to take
at least that long goes: the stage's time per record over its steps so far
times the batch's records. The stage steps the same batches in the same
order either way, and settles them at the same simulated times: images,
counters and cycles do not change.
"""

from __future__ import annotations

import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pandas as pd
import simpy

from pipeline_sim.counters import CounterSet
from pipeline_sim.regions import record_count

END = None  # end-of-stream marker


class Fifo:
    """A bounded FIFO of ``(ready, batch)`` items (and ``END``) between two stage processes.

    Its capacity counts weights: one per item (a FIFO of ``depth`` batches)
    or the records of each batch (``by_records``; a batch of more records
    than the whole capacity weighs the whole capacity, so it waits for an
    empty FIFO; ``END`` weighs nothing). A put that fits and a get from a
    non-empty FIFO complete at once, without a SimPy event; only a process
    that must wait (for room, or for an item) yields one, which the other
    side triggers at the simulated time it frees room or brings an item. So
    the event layer schedules the waits, busy times and latencies, and no
    hand-off that happens at the same instant anyway.
    """

    def __init__(self, env: simpy.Environment, capacity: int, by_records: bool):
        self.env = env
        self.capacity = capacity
        self.by_records = by_records
        self.level = 0  # weight held
        self.items: deque = deque()
        self._waiting_get: simpy.Event | None = None  # the consumer, waiting for an item
        self._waiting_put: tuple[simpy.Event, Any, int] | None = None  # the producer, waiting for room
        self.on_admit: Callable[[], None] | None = None  # called after each item goes in

    @property
    def unit(self) -> str:
        """What the capacity and the level count."""
        return "records" if self.by_records else "batches"

    def weight(self, item: Any) -> int:
        if item is END:
            return 0 if self.by_records else 1
        return min(max(record_count(item[1]), 1), self.capacity) if self.by_records else 1

    def put(self, item: Any) -> simpy.Event | None:
        """Put ``item``: None when it went in now, else an event that fires when it does."""
        w = self.weight(item)
        if self._waiting_put is None and self.level + w <= self.capacity:
            self._admit(item, w)
            return None
        ev = self.env.event()
        self._waiting_put = (ev, item, w)
        return ev

    def get(self) -> tuple[bool, Any]:
        """(True, item) when an item was there, else (False, an event that fires when one comes)."""
        if self.items:
            return True, self.take()
        self._waiting_get = ev = self.env.event()
        return False, ev

    def _admit(self, item: Any, w: int) -> None:
        self.level += w
        self.items.append((item, w))
        if self.on_admit is not None:
            self.on_admit()
        if self._waiting_get is not None:
            ev, self._waiting_get = self._waiting_get, None
            ev.succeed()

    def take(self) -> Any:
        """The head item (after the event ``get`` returned has fired); room it frees admits a waiting put."""
        item, w = self.items.popleft()
        self.level -= w
        if self._waiting_put is not None and self.level + self._waiting_put[2] <= self.capacity:
            (ev, waiting, ww), self._waiting_put = self._waiting_put, None
            self._admit(waiting, ww)
            ev.succeed()
        return item


@dataclass
class Channel:
    """A bounded FIFO of batches between two stages, with occupancy statistics.

    Bounded either in batches or in records (``Fifo``'s ``by_records``), so
    that the batch size sets the granularity of the timing without changing
    the size of the FIFO; the occupancy is counted in the same unit as the
    capacity (the FIFO's level: a batch larger than the whole capacity
    counts as the capacity).
    """

    name: str
    store: Fifo
    _last: float = 0.0
    _level: int = 0
    integral: float = 0.0
    peak: int = 0
    series: list[tuple[float, int]] = field(default_factory=list)  # (time, level) after each change

    def record(self, now: float) -> None:
        """Note the level after a put or get at ``now``; the previous level held until then."""
        if now > self._last:
            self.integral += self._level * (now - self._last)
            self._last = now
        level = self.store.level
        if level != self._level or not self.series:
            self.series.append((now, level))
        self._level = level
        self.peak = max(self.peak, level)


@dataclass
class Stage:
    """A unit in the pipeline: functional model, counters, cost model, timing."""

    name: str
    step: Callable[[Any], tuple[list[Any], float]]  # batch -> (output batches, cycles)
    latency: int
    # whether the step of a batch in the stage's FIFO may start now, on the stage's run-ahead thread (None: never):
    # true only when the step then depends on nothing but the batch and the steps before it
    ahead: Callable[[Any], bool] | None = None
    # run when the simulation takes a step's result (after the step, at its simulated time, on the simulation's
    # thread): hands other units what the step made for them, whether the step ran then or ahead
    settle: Callable[[], None] | None = None
    busy: float = 0.0
    starved: float = 0.0
    blocked: float = 0.0
    batches: int = 0
    finished: float = 0.0
    trace: list[tuple[float, float, str]] = field(default_factory=list)

    def step_and_settle(self, payload: Any) -> tuple[list[Any], float]:
        """Step ``payload`` now and settle it: what a stage stepped in simulated order does."""
        result = self.step(payload)
        if self.settle is not None:
            self.settle()
        return result

    def mark(self, start: float, end: float, state: str) -> None:
        if end > start:
            self.trace.append((start, end, state))


def _put(env: simpy.Environment, stage: Stage, out: Channel, item: Any):
    """Put ``item`` into ``out``, waiting for room; the wait is ``stage``'s blocked time. Returns when it went in."""
    t1 = env.now
    ev = out.store.put(item)
    if ev is not None:
        yield ev
    t2 = env.now
    out.record(t2)
    stage.blocked += t2 - t1
    if t2 > t1:
        stage.trace.append((t1, t2, "blocked"))
    return t2


class _RunAhead:
    """The steps of one stage (``Stage.ahead``) started early on its run-ahead thread (``pool``).

    The batches are numbered in the order they enter the stage's FIFO, which
    is the order the stage steps them. Steps start in that order, at most
    ``depth`` not yet taken up by the stage, each only when ``stage.ahead``
    allows it and it is worth handing over (``worth``); the first batch that
    may not start holds the run-ahead until it may (``worth`` is asked again
    as the stage's timing changes) or the stage has stepped it itself. So
    every step runs after all the steps before it and before all those after
    it, one at a time, as without run-ahead.

    The timing is of wall time wherever a step ran, so a step on the
    run-ahead thread counts the waits for the interpreter lock it met; one
    slow step (a band's buffers cleared, say) weighs in for the rest of the
    pass. Either only moves a step between threads.
    """

    def __init__(self, stage: Stage, fifo: Fifo, pool: ThreadPoolExecutor, depth: int, min_seconds: float = 0.0):
        self.stage = stage
        self.fifo = fifo
        self.pool = pool
        self.depth = depth
        self.min_seconds = min_seconds
        self.admitted = 0  # items that have entered the FIFO (the end marker included)
        self.stepped = 0  # batches the stage has stepped
        self.frontier = 0  # the first batch neither started nor stepped
        self.started: dict[int, Future] = {}  # by batch number
        # the stage's steps so far, wherever they ran (one at a time): seconds and records
        self.seconds = 0.0
        self.records = 0
        fifo.on_admit = self.admit

    def worth(self, payload: Any) -> bool:
        """Whether ``payload``'s step is expected to take at least ``min_seconds``: the stage's seconds per
        record so far times its records (none measured yet: no)."""
        if self.min_seconds <= 0:
            return True
        return self.records > 0 and self.seconds * record_count(payload) >= self.min_seconds * self.records

    def timed_step(self, payload: Any) -> tuple[list[Any], float]:
        """The stage's step of ``payload``, its time and records added to the stage's."""
        t0 = time.perf_counter()
        result = self.stage.step(payload)
        self.records += record_count(payload)
        self.seconds += time.perf_counter() - t0
        return result

    def admit(self) -> None:
        self.admitted += 1
        self.top_up()

    def top_up(self) -> None:
        """Start the steps of the next batches that may start."""
        items = self.fifo.items
        head = self.admitted - len(items)  # the number of the batch at the FIFO's head
        while len(self.started) < self.depth:
            k = self.frontier - head
            if k < 0 or k >= len(items):  # the stage holds it (taken, not yet stepped), or none is there
                return
            item = items[k][0]
            if item is END or not self.stage.ahead(item[1]) or not self.worth(item[1]):
                return
            self.started[self.frontier] = self.pool.submit(self.timed_step, item[1])
            self.frontier += 1

    def step(self, payload: Any) -> tuple[list[Any], float]:
        """The step of ``payload``, the next batch: its result when it was started, else run now; then
        start more."""
        future = self.started.pop(self.stepped, None)
        if future is not None:
            result = future.result()
        else:
            result = self.timed_step(payload)
            self.frontier = self.stepped + 1
        self.stepped += 1
        self.top_up()
        return result


def _stage_process(env: simpy.Environment, stage: Stage, inp: Channel, out: Channel | None,
                   ahead: _RunAhead | None = None):
    """Get a batch, wait until it is ready, step the unit, stay busy its cycles, put its outputs.

    ``env.now`` is read once after each yield (it only moves across yields).
    """
    fifo = inp.store
    step = stage.step if ahead is None else ahead.step
    trace = stage.trace
    while True:
        t0 = env.now
        got, item = fifo.get()
        if not got:
            yield item
            item = fifo.take()
        now = env.now
        inp.record(now)
        if item is END:
            stage.starved += now - t0
            if now > t0:
                trace.append((t0, now, "starved"))
            if out is not None:
                yield from _put(env, stage, out, END)
            stage.finished = env.now
            return
        ready, payload = item
        if ready > now:
            yield env.timeout(ready - now)
            now = env.now
        stage.starved += now - t0
        if now > t0:
            trace.append((t0, now, "starved"))
        outputs, cycles = step(payload)
        if stage.settle is not None:
            stage.settle()
        stage.batches += 1
        if cycles > 0:
            yield env.timeout(cycles)
            stage.busy += cycles
            trace.append((now, env.now, "busy"))
            now = env.now
        if out is None:
            continue
        for batch in outputs:  # each ready ``latency`` cycles after its put is issued
            now = yield from _put(env, stage, out, (now + stage.latency, batch))


def _source_process(env: simpy.Environment, batches: list[Any], out: Channel):
    for batch in batches + [END]:
        ev = out.store.put((env.now, batch) if batch is not END else END)
        if ev is not None:
            yield ev
        out.record(env.now)


@dataclass
class TimingResult:
    """Simulated timing of one pass."""

    frame_cycles: float
    units: pd.DataFrame  # unit, busy, starved, blocked, batches, utilization
    queues: pd.DataFrame  # channel, capacity_<unit>, mean_<unit>, peak_<unit> (unit: records or batches)
    traces: dict[str, list[tuple[float, float, str]]]  # per unit: (start, end, busy|starved|blocked)
    queue_series: dict[str, list[tuple[float, int]]]  # per channel: (time, occupancy) at each change


def simulate(stages: list[Stage], source_batches: list[Any], queue_depth: int,
             capacities: list[int] | None = None, run_ahead: int = 0,
             run_ahead_min_seconds: float = 0.0) -> TimingResult:
    """Run the stages in order, fed with ``source_batches``, and time them.

    Each channel (the input of each stage) holds ``queue_depth`` batches, or,
    with ``capacities``, that many records (one number per stage input); its
    capacity and occupancy are reported in that unit. ``run_ahead``: how many
    batches a stage with ``ahead`` may have started on its run-ahead thread
    (0: none, every step runs when the simulation reaches it);
    ``run_ahead_min_seconds``: only batches whose step is expected to take
    that long (``_RunAhead.worth``; 0: all).
    """
    env = simpy.Environment()
    names = ["input"] + [f"{a.name}->{b.name}" for a, b in zip(stages, stages[1:])]
    if capacities is None:
        channels = [Channel(n, Fifo(env, queue_depth, by_records=False)) for n in names]
    else:
        channels = [Channel(n, Fifo(env, cap, by_records=True)) for n, cap in zip(names, capacities)]
    env.process(_source_process(env, source_batches, channels[0]))
    # a thread of its own for each stage that may run ahead
    pools = [ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"run-ahead-{s.name}")
             if run_ahead and s.ahead is not None else None for s in stages]
    for i, stage in enumerate(stages):
        out = channels[i + 1] if i + 1 < len(channels) else None
        ahead = (_RunAhead(stage, channels[i].store, pools[i], run_ahead, run_ahead_min_seconds)
                 if pools[i] is not None else None)
        env.process(_stage_process(env, stage, channels[i], out, ahead))
    try:
        env.run()
    finally:
        for pool in pools:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
        for ch in channels:  # a FIFO and its run-ahead refer to each other: without this the pass's
            ch.store.on_admit = None  # units and buffers would live until a garbage collection
    frame = float(env.now)
    for ch in channels:
        ch.record(frame)
    for s in stages:  # after its last batch a unit waits for input that never comes
        s.starved += frame - s.finished
        s.mark(s.finished, frame, "starved")
    units = pd.DataFrame(
        [
            {
                "unit": s.name, "busy": s.busy, "starved": s.starved, "blocked": s.blocked,
                "batches": s.batches, "utilization": (s.busy / frame) if frame > 0 else 0.0,
            }
            for s in stages
        ]
    )
    unit = channels[0].store.unit
    queues = pd.DataFrame(
        [
            {"channel": c.name, f"capacity_{unit}": c.store.capacity,
             f"mean_{unit}": (c.integral / frame) if frame > 0 else 0.0, f"peak_{unit}": c.peak}
            for c in channels
        ]
    )
    return TimingResult(frame, units, queues, {s.name: s.trace for s in stages},
                        {c.name: c.series for c in channels})


def run_in_order(stages: list[Stage], source_batches: list[Any], after_batch: Callable[[], float]) -> list[Stage]:
    """Run the stages' functional models in submission order and return stages that replay them.

    Each source batch goes through every stage before the next one starts,
    so nothing a step computes depends on timing. Each stage still steps
    through the same batches in the same order as under ``simulate`` (a
    stage takes its inputs in the order the stage before it put them out),
    so the returned stages, which return the recorded output sizes and
    cycles of each step, give ``simulate`` the same work to time.
    ``after_batch`` runs once each source batch has gone through; the cycles
    it returns are charged to the last stage's last step of that batch.
    """
    logs: list[deque] = [deque() for _ in stages]
    last = len(stages) - 1

    def push(i: int, batch: Any) -> None:
        outputs, cycles = stages[i].step_and_settle(batch)
        logs[i].append([[record_count(o) for o in outputs], cycles])
        if i < last:
            for o in outputs:
                push(i + 1, o)

    for batch in source_batches:
        steps_before = len(logs[last])
        push(0, batch)
        extra = after_batch()
        if extra:
            assert len(logs[last]) > steps_before, "cycles after a batch that reached no last step"
            logs[last][-1][1] += extra
    return [Stage(s.name, _replay(log), s.latency) for s, log in zip(stages, logs)]


def _replay(log: deque) -> Callable[[Any], tuple[list[Any], float]]:
    """A step returning, call by call, the recorded output sizes (as stand-in batches) and cycles."""

    def step(_batch: Any) -> tuple[list[Any], float]:
        sizes, cycles = log.popleft()
        return [range(n) for n in sizes], cycles

    return step


def cycles_for(work: float, throughput: float, instances: int) -> float:
    """Busy cycles of a batch: its work at ``throughput`` items/cycle on each instance.

    Not rounded up per batch: a unit streams items, so a batch boundary costs
    no partial cycle, and the total over a frame does not depend on how the
    work is split into batches.
    """
    return float(work) / (throughput * instances) if work > 0 else 0.0


def chunks(batch: dict[str, np.ndarray], size: int) -> list[dict[str, np.ndarray]]:
    """Split a structure-of-arrays batch into batches of at most ``size`` records."""
    n = len(next(iter(batch.values()))) if batch else 0
    return [{k: v[i : i + size] for k, v in batch.items()} for i in range(0, n, size)]


def count_records(cs: CounterSet, n_in: int, n_out: int) -> None:
    cs.add("records_in", n_in)
    cs.add("records_out", n_out)
