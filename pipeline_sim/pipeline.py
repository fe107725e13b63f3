"""The SimPy plumbing: units as stage processes joined by bounded channels.

This is the only module that knows about SimPy. Each unit's functional model
(``units/``) is wrapped in a ``Stage`` that gets a batch from its input
channel, runs the unit's numba kernel on it, turns the work the kernel
reports into cycles with the unit's cost model (throughput per cycle per
instance, instances, latency), holds the unit busy for those cycles and then
puts its output batches into the next channel, waiting while that channel is
full. Per stage we account busy, starved (waiting for input) and blocked
(waiting for room downstream) cycles; per channel the time-weighted and
maximum occupancy.

Functional results never depend on timing: every unit processes its batches
in order, so changing a cost or a queue depth changes cycles, never the
image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pandas as pd
import simpy

from pipeline_sim.counters import CounterSet

END = None  # end-of-stream marker


class RecordStore(simpy.Store):
    """A FIFO of ``(ready, batch, records)`` items (and ``END``) bounded in records, not items.

    A put waits until its records fit (a batch of more records than the
    whole capacity counts as the whole capacity: it waits for an empty
    FIFO); a get frees its records at once. One event per put and per get,
    as for a plain store, so counting records costs no extra SimPy events.
    """

    def __init__(self, env: simpy.Environment, records: int):
        super().__init__(env)
        self.records = records
        self.level = 0  # records held

    def _do_put(self, event) -> None:
        n = event.item[2] if event.item is not END else 0
        if self.level + n <= self.records:
            self.level += n
            self.items.append(event.item)
            event.succeed()

    def _do_get(self, event) -> None:
        if self.items:
            item = self.items.pop(0)
            self.level -= item[2] if item is not END else 0
            event.succeed(item)


@dataclass
class Channel:
    """A bounded FIFO of batches between two stages, with occupancy statistics.

    Bounded either in batches (a plain store of ``depth`` items) or in records
    (a ``RecordStore``), so that the batch size sets the granularity of the
    timing without changing the size of the FIFO.
    """

    name: str
    store: simpy.Store
    depth: int
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
        level = len(self.store.items)
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
    busy: float = 0.0
    starved: float = 0.0
    blocked: float = 0.0
    batches: int = 0
    finished: float = 0.0
    trace: list[tuple[float, float, str]] = field(default_factory=list)

    def mark(self, start: float, end: float, state: str) -> None:
        if end > start:
            self.trace.append((start, end, state))


def _records(batch: Any) -> int:
    """Records in a batch: the length of a structure-of-arrays dict's arrays, or of an array."""
    if isinstance(batch, dict):
        return len(next(iter(batch.values()))) if batch else 0
    return len(batch) if hasattr(batch, "__len__") else 1


def _item(ch: Channel, ready: float, batch: Any) -> tuple[float, Any, int]:
    """The channel item of a batch: (ready time, batch, records it takes of a record-bounded channel).

    A batch of more records than the whole capacity counts as the whole
    capacity, so it waits for an empty FIFO rather than forever.
    """
    n = min(max(_records(batch), 1), ch.store.records) if isinstance(ch.store, RecordStore) else 0
    return ready, batch, n


def _stage_process(env: simpy.Environment, stage: Stage, inp: Channel, out: Channel | None):
    """Get a batch, wait until it is ready, step the unit, stay busy its cycles, put its outputs.

    ``env.now`` is read once after each yield (it only moves across yields).
    """
    get = inp.store.get
    trace = stage.trace
    while True:
        t0 = env.now
        item = yield get()
        now = env.now
        inp.record(now)
        if item is END:
            stage.starved += now - t0
            if now > t0:
                trace.append((t0, now, "starved"))
            if out is not None:
                yield out.store.put(END)
                t2 = env.now
                out.record(t2)
                stage.blocked += t2 - now
                if t2 > now:
                    trace.append((now, t2, "blocked"))
            stage.finished = env.now
            return
        ready, payload, _ = item
        if ready > now:
            yield env.timeout(ready - now)
            now = env.now
        stage.starved += now - t0
        if now > t0:
            trace.append((t0, now, "starved"))
        outputs, cycles = stage.step(payload)
        stage.batches += 1
        if cycles > 0:
            yield env.timeout(cycles)
            stage.busy += cycles
            trace.append((now, env.now, "busy"))
            now = env.now
        if out is None:
            continue
        put = out.store.put
        latency = stage.latency
        for batch in outputs:
            yield put(_item(out, now + latency, batch))
            t2 = env.now
            out.record(t2)
            stage.blocked += t2 - now
            if t2 > now:
                trace.append((now, t2, "blocked"))
            now = t2


def _source_process(env: simpy.Environment, batches: list[Any], out: Channel):
    for batch in batches:
        yield out.store.put(_item(out, env.now, batch))
        out.record(env.now)
    yield out.store.put(END)
    out.record(env.now)


@dataclass
class TimingResult:
    """Simulated timing of one pass."""

    frame_cycles: float
    units: pd.DataFrame  # unit, busy, starved, blocked, batches, utilization
    queues: pd.DataFrame  # channel, depth, mean_occupancy, peak_occupancy
    traces: dict[str, list[tuple[float, float, str]]]  # per unit: (start, end, busy|starved|blocked)
    queue_series: dict[str, list[tuple[float, int]]]  # per channel: (time, occupancy) at each change


def simulate(stages: list[Stage], source_batches: list[Any], queue_depth: int,
             capacities: list[int] | None = None) -> TimingResult:
    """Run the stages in order, fed with ``source_batches``, and time them.

    Each channel (the input of each stage) holds ``queue_depth`` batches, or,
    with ``capacities``, that many records (one number per stage input).
    """
    env = simpy.Environment()
    names = ["input"] + [f"{a.name}->{b.name}" for a, b in zip(stages, stages[1:])]
    if capacities is None:
        channels = [Channel(n, simpy.Store(env, capacity=queue_depth), queue_depth) for n in names]
    else:
        channels = [Channel(n, RecordStore(env, cap), queue_depth) for n, cap in zip(names, capacities)]
    env.process(_source_process(env, source_batches, channels[0]))
    for i, stage in enumerate(stages):
        out = channels[i + 1] if i + 1 < len(channels) else None
        env.process(_stage_process(env, stage, channels[i], out))
    env.run()
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
    queues = pd.DataFrame(
        [
            {"channel": c.name, "depth": c.depth, "mean_occupancy": (c.integral / frame) if frame > 0 else 0.0,
             "peak_occupancy": c.peak}
            for c in channels
        ]
    )
    return TimingResult(frame, units, queues, {s.name: s.trace for s in stages},
                        {c.name: c.series for c in channels})


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
