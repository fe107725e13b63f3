"""The SimPy layer (pipeline_sim/pipeline.py) and timing-independence of the pipeline.

Timing semantics of ``simulate`` as read from the code, written here as a
recurrence (no SimPy) that the tests compare against. For stage j, batch k
(one output per input), depth D of every channel, latency L_j, cost c_j(k):

* G_j(k)  time stage j takes batch k from its input channel
          = max(P_{j-1}(k), P_j(k-1))       (P_{-1} = the source's put)
* S_j(k)  start = max(G_j(k), R_j(k)), R_j(k) = F_{j-1}(k) + L_{j-1}
          (the ready stamp is taken when the upstream *issues* its put)
* F_j(k)  = S_j(k) + c_j(k)
* P_j(k)  put completes = max(F_j(k), G_{j+1}(k - D)): room once batch k-D
          has been taken downstream; the last stage has no output, P = F.
* the end marker is batch n with no cost and no ready time.
Frame = G_last(n). Accounting: busy = sum c, blocked = sum (P - F) plus
the wait to put the end marker, P_j(n) - G_j(n); starved = sum (S_j(k) -
P_j(k-1)) + (G_j(n) - P_j(n-1)) plus the idle tail after the stage is done,
frame - P_j(n); so busy + starved + blocked = frame for every stage.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pandas as pd
import pytest

from pipeline_sim import render as render_module
from pipeline_sim.config import load_arch, pass_settings
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.pipeline import Stage, chunks, cycles_for, run_in_order, simulate
from pipeline_sim.render import UNIT_ORDER, RenderPass, run_pass

NEG = float("-inf")


def model(costs, lats, depth):
    """Recurrence above. costs[j][k], lats[j]. Returns dict of per-stage arrays."""
    m = len(costs)
    n = len(costs[0])
    G = np.zeros((m, n + 1))
    S = np.zeros((m, n))
    F = np.zeros((m, n))
    P = np.zeros((m, n + 1))
    src = np.zeros(n + 1)  # completion of the source's puts (item n: the end marker)
    for k in range(n + 1):
        src[k] = max(src[k - 1] if k else 0.0, G[0][k - depth] if k - depth >= 0 else NEG)
        for j in range(m):
            arrive = src[k] if j == 0 else P[j - 1][k]
            prev = P[j][k - 1] if k else 0.0
            G[j][k] = max(arrive, prev)
            last = j == m - 1
            if k == n:  # end marker: forward it
                P[j][k] = G[j][k] if last else max(G[j][k], G[j + 1][k - depth] if k - depth >= 0 else NEG)
                continue
            ready = 0.0 if j == 0 else F[j - 1][k] + lats[j - 1]
            S[j][k] = max(G[j][k], ready)
            F[j][k] = S[j][k] + costs[j][k]
            P[j][k] = F[j][k] if last else max(F[j][k], G[j + 1][k - depth] if k - depth >= 0 else NEG)
    busy = np.array([sum(c) for c in costs], float)
    frame = float(G[m - 1][n])
    blocked = (P[:, :n] - F).sum(axis=1) + (P[:, n] - G[:, n])
    prevP = np.concatenate([np.zeros((m, 1)), P[:, :n]], axis=1)  # P_j(k-1), k = 0..n
    starved = (S - prevP[:, :n]).sum(axis=1) + (G[:, n] - P[:, n - 1]) + (frame - P[:, n])
    # true time-weighted occupancy of each channel (input, then between stages)
    enter = [src] + [P[j] for j in range(m - 1)]
    occ = [float((G[j] - enter[j]).sum()) for j in range(m)]
    return dict(frame=frame, G=G, F=F, busy=busy, blocked=blocked, starved=starved, occ=occ)


def make_stages(costs, lats, log=None):
    stages = []
    for j, (cs, lat) in enumerate(zip(costs, lats)):
        def step(payload, j=j, cs=cs):
            if log is not None:
                log.append((j, payload))
            return [payload], cs[payload]
        stages.append(Stage(f"s{j}", step, lat))
    return stages


def run(costs, lats, depth, log=None):
    n = len(costs[0])
    return simulate(make_stages(costs, lats, log), list(range(n)), depth)


def unit_rows(res):
    return res.units.set_index("unit")


# --------------------------------------------------------------------------- #
# closed forms
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("n,c,lat,depth", [(1, 5, 0, 1), (7, 3, 10, 1), (10, 4, 25, 4), (3, 0, 5, 2)])
def test_single_stage_constant_cost(n, c, lat, depth):
    """One stage, constant cost: frame = n * c; the last stage's latency is never paid."""
    res = run([[c] * n], [lat], depth)
    assert res.frame_cycles == n * c
    row = unit_rows(res).loc["s0"]
    assert row.busy == n * c and row.starved == 0 and row.blocked == 0 and row.batches == n


@pytest.mark.parametrize("a,b,lat", [(2, 5, 7), (5, 2, 7), (3, 3, 0), (1, 10, 30)])
def test_two_stages_unbounded_queue_closed_form(a, b, lat):
    """Enough queue for no blocking: frame = max_k ((k+1) a + L + (n-k) b)
    = a + L + n b if b >= a, else n a + L + b."""
    n = 12
    res = run([[a] * n, [b] * n], [lat, 0], depth=n + 1)
    expect = a + lat + n * b if b >= a else n * a + lat + b
    assert res.frame_cycles == expect
    rows = unit_rows(res)
    assert rows.loc["s1"].starved == expect - n * b
    assert rows.loc["s0"].blocked == 0


@pytest.mark.parametrize("depth", [1, 2, 3])
def test_slow_downstream_blocks_upstream_and_fills_queue(depth):
    n, a, b, lat = 20, 1, 10, 2
    res = run([[a] * n, [b] * n], [lat, 0], depth)
    rows = unit_rows(res)
    q = res.queues.set_index("channel")
    assert q.loc["s0->s1"].peak_batches == depth
    assert rows.loc["s0"].blocked > 0
    # closed form: the slow stage never waits after its first batch (a + L <= b)
    assert res.frame_cycles == a + lat + n * b
    # upstream: batches 0..D go straight in; batch D+1 waits until the slow
    # stage takes batch 1 at a + L + b = 13 (finished at D+2); every later batch
    # finishes 1 cycle after the previous put and waits for the next take, 10
    # cycles later: blocked = (13 - (D + 2)) + 9 (n - D - 2); the end marker then
    # waits one more slow batch, b, for room
    assert rows.loc["s0"].blocked == (13 - (depth + 2)) + 9 * (n - depth - 2) + b
    assert rows.loc["s0"].blocked == model([[a] * n, [b] * n], [lat, 0], depth)["blocked"][0]
    assert rows.loc["s1"].starved == a + lat


def test_model_matches_simulation_random():
    """Random stages, costs, latencies and depths against the recurrence."""
    rng = np.random.default_rng(0)
    for trial in range(150):
        m = int(rng.integers(1, 5))
        n = int(rng.integers(1, 12))
        depth = int(rng.integers(1, 5))
        costs = [[int(c) for c in rng.integers(0, 10, n)] for _ in range(m)]
        lats = [int(x) for x in rng.integers(0, 15, m)]
        res = run(costs, lats, depth)
        ref = model(costs, lats, depth)
        ctx = (costs, lats, depth)
        assert res.frame_cycles == ref["frame"], ctx
        rows = res.units
        np.testing.assert_array_equal(rows.busy.to_numpy(), ref["busy"], err_msg=str(ctx))
        np.testing.assert_array_equal(rows.blocked.to_numpy(), ref["blocked"], err_msg=str(ctx))
        np.testing.assert_array_equal(rows.starved.to_numpy(), ref["starved"], err_msg=str(ctx))
        assert (res.queues.peak_batches <= depth).all()
        np.testing.assert_allclose(rows.utilization, ref["busy"] / ref["frame"] if ref["frame"] else 0.0)


def model_records(costs, lats, weights, capacity):
    """The recurrence with FIFOs bounded in records: batch k of weight
    w_k = min(max(records, 1), capacity) enters once the batches still held
    ahead of it and itself fit, i.e. once batch m - 1 has been taken, m the
    first index with w_m + ... + w_k <= capacity; the end marker weighs
    nothing. Returns frame cycles and per-stage busy, blocked, starved."""
    m = len(costs)
    n = len(costs[0])
    w = [min(max(x, 1), capacity) for x in weights]

    def first_fitting(k):
        total, i = 0, k
        while i >= 0 and total + w[i] <= capacity:
            total += w[i]
            i -= 1
        return i  # the batch that must have been taken; -1: none

    G = np.zeros((m, n + 1))
    S = np.zeros((m, n))
    F = np.zeros((m, n))
    P = np.zeros((m, n + 1))
    src = np.zeros(n + 1)
    for k in range(n + 1):
        room = lambda j: (NEG if k == n or first_fitting(k) < 0 else G[j][first_fitting(k)])  # noqa: E731
        src[k] = max(src[k - 1] if k else 0.0, room(0))
        for j in range(m):
            arrive = src[k] if j == 0 else P[j - 1][k]
            G[j][k] = max(arrive, P[j][k - 1] if k else 0.0)
            last = j == m - 1
            if k == n:
                P[j][k] = G[j][k]
                continue
            ready = 0.0 if j == 0 else F[j - 1][k] + lats[j - 1]
            S[j][k] = max(G[j][k], ready)
            F[j][k] = S[j][k] + costs[j][k]
            P[j][k] = F[j][k] if last else max(F[j][k], room(j + 1))
    frame = float(G[m - 1][n])
    blocked = (P[:, :n] - F).sum(axis=1) + (P[:, n] - G[:, n])
    prevP = np.concatenate([np.zeros((m, 1)), P[:, :n]], axis=1)
    starved = (S - prevP[:, :n]).sum(axis=1) + (G[:, n] - P[:, n - 1]) + (frame - P[:, n])
    return dict(frame=frame, busy=np.array([sum(c) for c in costs], float), blocked=blocked, starved=starved)


def test_record_bounded_fifos_match_the_recurrence():
    """FIFOs sized in records (what every pass uses): random batch sizes, some
    larger than the whole FIFO, against the weighted recurrence."""
    rng = np.random.default_rng(7)
    for trial in range(150):
        m = int(rng.integers(1, 5))
        n = int(rng.integers(1, 12))
        capacity = int(rng.integers(1, 9))
        weights = [int(x) for x in rng.integers(0, 12, n)]
        costs = [[int(c) for c in rng.integers(0, 10, n)] for _ in range(m)]
        lats = [int(x) for x in rng.integers(0, 15, m)]
        stages = [Stage(f"s{j}", lambda b, j=j: ([b], costs[j][b["k"]]), lats[j]) for j in range(m)]
        batches = [{"records": np.zeros(weights[k]), "k": k} for k in range(n)]
        res = simulate(stages, batches, queue_depth=1, capacities=[capacity] * m)
        ref = model_records(costs, lats, weights, capacity)
        ctx = (costs, lats, weights, capacity)
        assert res.frame_cycles == ref["frame"], ctx
        np.testing.assert_array_equal(res.units.busy.to_numpy(), ref["busy"], err_msg=str(ctx))
        np.testing.assert_array_equal(res.units.blocked.to_numpy(), ref["blocked"], err_msg=str(ctx))
        np.testing.assert_array_equal(res.units.starved.to_numpy(), ref["starved"], err_msg=str(ctx))


def test_accounting_covers_the_frame():
    """busy + starved + blocked = frame cycles for every stage."""
    rng = np.random.default_rng(1)
    for trial in range(60):
        m = int(rng.integers(2, 5))
        n = int(rng.integers(1, 10))
        depth = int(rng.integers(1, 4))
        costs = [[int(c) for c in rng.integers(0, 10, n)] for _ in range(m)]
        lats = [int(x) for x in rng.integers(0, 8, m)]
        res = run(costs, lats, depth)
        ref = model(costs, lats, depth)
        total = (res.units.busy + res.units.starved + res.units.blocked).to_numpy()
        np.testing.assert_array_equal(total, np.full(m, ref["frame"]))
        # the trace of each stage tiles [0, frame] without gaps or overlaps
        for j, s in enumerate(res.units.unit):
            tr = sorted(res.traces[s])
            end = 0.0
            for a, b, _ in tr:
                assert a == end
                end = b
            assert end == ref["frame"]


def test_accounting_covers_frame_for_every_stage():
    res = run([[1] * 5, [10] * 5], [0, 0], 1)
    total = res.units.busy + res.units.starved + res.units.blocked
    assert (total == res.frame_cycles).all(), total.tolist()


def test_mean_occupancy_is_time_weighted_level():
    # one stage, two batches of cost 10, deep queue: the source fills the input
    # channel with b0, b1, END at t=0; the stage takes b0 at 0, b1 at 10, END at
    # 20. Level: 2 on [0, 10), 1 on [10, 20): mean 1.5.
    res = run([[10, 10]], [0], 4)
    assert res.frame_cycles == 20
    assert res.queues.set_index("channel").loc["input"].mean_batches == pytest.approx(1.5)


def test_occupancy_counts_records_like_the_capacity():
    """FIFOs sized in records report capacity and occupancy in records: batches
    of 3 and 5 records into a FIFO of 8 both go in at 0 (level 8); the stage
    takes the first at 0 (level 5 until it takes the second at 10, then 0
    until the end at 20): mean 5 * 10 / 20 = 2.5 records, peak 8. END weighs
    nothing."""
    stages = [Stage("s0", lambda b: ([], 10.0), 0)]
    res = simulate(stages, [np.zeros(3), np.zeros(5)], queue_depth=1, capacities=[8])
    q = res.queues.set_index("channel").loc["input"]
    assert list(res.queues.columns) == ["channel", "capacity_records", "mean_records", "peak_records"]
    assert (q.capacity_records, q.mean_records, q.peak_records) == (8, 2.5, 8)
    assert res.queue_series["input"] == [(0.0, 3), (0.0, 8), (0.0, 5), (10.0, 0)]


def test_mean_occupancy_random_against_model():
    rng = np.random.default_rng(2)
    for trial in range(40):
        m = int(rng.integers(1, 4))
        n = int(rng.integers(1, 10))
        depth = int(rng.integers(1, 5))
        costs = [[int(c) for c in rng.integers(1, 10, n)] for _ in range(m)]
        lats = [int(x) for x in rng.integers(0, 8, m)]
        res = run(costs, lats, depth)
        ref = model(costs, lats, depth)
        np.testing.assert_allclose(res.queues.mean_batches.to_numpy(),
                                   np.array(ref["occ"]) / ref["frame"], err_msg=str((costs, lats, depth)))


# --------------------------------------------------------------------------- #
# random-stall harness: completeness and order
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("depth", [1, 2, 3, 4])
def test_random_stalls_outputs_complete_and_in_order(depth):
    """pymtl3-style: random per-batch costs from a seeded RNG in a source-side
    stage, a splitting/dropping middle stage and a random-cost sink."""
    rng = np.random.default_rng(depth)
    for trial in range(20):
        n = int(rng.integers(0, 25))
        items = [(trial, i) for i in range(n)]
        fanout = {it: int(rng.integers(0, 4)) for it in items}
        cost_a = {it: float(rng.integers(0, 6)) for it in items}
        cost_c = {}
        received = []

        def a(it):
            return [it], cost_a[it]

        def b(it):
            outs = [(it, part) for part in range(fanout[it])]
            for o in outs:
                cost_c[o] = float(rng.integers(0, 8))
            return outs, float(rng.integers(0, 3))

        def c(o):
            received.append(o)
            return [], cost_c[o]

        lats = rng.integers(0, 10, 3)
        stages = [Stage("a", a, int(lats[0])), Stage("b", b, int(lats[1])), Stage("c", c, int(lats[2]))]
        res = simulate(stages, items, depth)
        assert received == [(it, p) for it in items for p in range(fanout[it])]
        assert res.units.batches.tolist() == [n, n, len(received)]
        assert (res.queues.peak_batches <= depth).all()
        assert res.frame_cycles >= max(sum(cost_a.values()), sum(cost_c.values()))


@pytest.mark.parametrize("depth, min_seconds", [(1, 0.0), (2, 0.0), (5, 0.0), (2, 1e-4)])
def test_run_ahead_steps_in_order_one_at_a_time_and_times_the_same(depth, min_seconds):
    """A stage with ``ahead`` steps its batches on the run-ahead thread, ahead of the simulation: each
    step still starts after the one before it has ended (in FIFO order, never two at once), a batch
    ``ahead`` refuses is stepped by the stage itself, and the timing, counts and order of everything are
    those of the same stages without run-ahead. Its ``settle`` runs on the main thread, after the step,
    at the same point among the other stages' steps as without run-ahead. With ``min_seconds``, steps
    too short to hand over (random pauses of 0 to 0.2 ms against 0.1 ms) run on the main thread too."""
    rng = np.random.default_rng(100 + depth)
    on_worker = 0
    for trial in range(12):
        n = int(rng.integers(1, 30))
        items = list(range(n))
        cost = rng.integers(0, 8, (3, n)).astype(float)
        refuse = set(rng.choice(n, min(n, int(rng.integers(0, 4))), replace=False).tolist())
        pause = rng.uniform(0, 2e-4, n)  # sleeps that let the threads interleave
        lats = rng.integers(0, 6, 3)

        def stages(log, ahead):
            def a(it):
                return [it], cost[0][it]

            def b(it):
                log.append(("start", it, threading.current_thread() is threading.main_thread()))
                time.sleep(pause[it])
                log.append(("end", it, None))
                return [it, it], cost[1][it]

            def c(it):
                log.append(("c", it, None))
                return [], cost[2][it]

            def settle():
                log.append(("settle", settled[0], threading.current_thread() is threading.main_thread()))
                settled[0] += 1

            settled = [0]
            return [Stage("a", a, int(lats[0])), Stage("b", b, int(lats[1]), ahead=ahead, settle=settle),
                    Stage("c", c, int(lats[2]))]

        plain_log, log = [], []
        plain = simulate(stages(plain_log, None), items, 2)
        res = simulate(stages(log, lambda it: it not in refuse), items, 2, run_ahead=depth,
                       run_ahead_min_seconds=min_seconds)
        b_log = [e for e in log if e[0] in ("start", "end")]
        assert [(e[0], e[1]) for e in b_log] == [(k, it) for it in items for k in ("start", "end")]
        settles = [e for e in log if e[0] == "settle"]
        assert [e[1] for e in settles] == items and all(on_main for _, _, on_main in settles)
        assert [e for e in log if e[0] in ("settle", "c")] == [e for e in plain_log if e[0] in ("settle", "c")]
        assert all(log.index(("settle", it, True)) > log.index(("end", it, None)) for it in items)
        assert all(on_main for kind, it, on_main in b_log if kind == "start" and it in refuse)
        on_worker += sum(not on_main for kind, _, on_main in b_log if kind == "start")
        assert [e for e in log if e[0] == "c"] == [e for e in plain_log if e[0] == "c"]
        assert res.frame_cycles == plain.frame_cycles
        pd.testing.assert_frame_equal(res.units, plain.units)
        pd.testing.assert_frame_equal(res.queues, plain.queues)
        assert res.traces == plain.traces
    assert on_worker > (50 if min_seconds == 0 else 10)  # the run-ahead thread did step batches


def test_run_ahead_hands_over_only_steps_expected_to_take_long_enough(monkeypatch):
    """With ``run_ahead_min_seconds``, a stage's first step runs on the main thread (nothing measured
    yet); after that a batch goes to the run-ahead thread exactly when the seconds per record of the
    stage's steps so far (wherever they ran) times its records reach the minimum, the boundary included.
    The steps advance a fake clock by their cost, so the decisions are exact; the expected ones are
    worked out here in exact fractions. The timing is that of the plain simulation."""
    from fractions import Fraction
    from types import SimpleNamespace

    from pipeline_sim import pipeline as pipeline_module

    clock = [0.0]
    monkeypatch.setattr(pipeline_module, "time", SimpleNamespace(perf_counter=lambda: clock[0]))
    sizes = [2, 6, 3, 4, 1, 8, 2, 5, 3, 6, 1, 7, 4, 2]
    per_record = [1.0, 2.0, 2.0, 0.5, 4.0, 0.25, 1.0, 3.0, 1.0, 0.5, 2.0, 1.0, 1.5, 1.0]  # dyadic: exact sums
    min_seconds = 6.0
    where = []

    def b(it):
        where.append(threading.current_thread() is threading.main_thread())
        clock[0] += per_record[it] * sizes[it]
        return [it], float(sizes[it])

    def stages(ahead):
        return [Stage("a", lambda it: ([it], 1.0), 0),
                Stage("b", lambda it: b(it[0]), 0, ahead=ahead), Stage("c", lambda it: ([], 1.0), 0)]

    items = [[k] * size for k, size in enumerate(sizes)]  # batch k: ``sizes[k]`` records
    plain = simulate(stages(None), items, 2)
    where.clear()
    res = simulate(stages(lambda batch: True), items, 2, run_ahead=1, run_ahead_min_seconds=min_seconds)
    expected, seconds, records = [], Fraction(0), 0
    for k, size in enumerate(sizes):
        expected.append(not (records > 0 and seconds * size >= Fraction(min_seconds) * records))  # on main
        seconds += Fraction(per_record[k]) * size
        records += size
    assert expected.count(False) >= 4 and expected.count(True) >= 4
    assert not expected[1]  # on the boundary: 1 s a record so far, 6 records, 6 s
    assert where == expected
    assert res.frame_cycles == plain.frame_cycles
    pd.testing.assert_frame_equal(res.units, plain.units)
    pd.testing.assert_frame_equal(res.queues, plain.queues)
    assert res.traces == plain.traces


def test_run_in_order_settles_each_step_after_it():
    """``run_in_order`` steps every stage in submission order and settles each step right after it, as
    the simulation does when it takes a step's result."""
    log = []

    def stage(name, fan):
        return Stage(name, lambda it: (log.append((name, it)) or [it] * fan, 1.0), 0,
                     settle=lambda: log.append((name, "settled")))

    run_in_order([stage("a", 2), stage("b", 1)], [0, 1], lambda: 0.0)
    assert log == [("a", 0), ("a", "settled"), ("b", 0), ("b", "settled"), ("b", 0), ("b", "settled"),
                   ("a", 1), ("a", "settled"), ("b", 1), ("b", "settled"), ("b", 1), ("b", "settled")]


def test_run_ahead_passes_an_exception_on():
    def b(it):
        if it == 3:
            raise ValueError("bad batch 3")
        return [it], 1.0

    stages = [Stage("a", lambda it: ([it], 1.0), 0), Stage("b", b, 0, ahead=lambda it: True)]
    with pytest.raises(ValueError, match="bad batch 3"):
        simulate(stages, list(range(6)), 2, run_ahead=2)
    assert not [t for t in threading.enumerate() if t.name.startswith("run-ahead")]  # the thread is gone


def test_cycles_for_and_chunks():
    assert cycles_for(0, 2.0, 1) == 0
    assert cycles_for(1, 16.0, 2) == 1 / 32  # streamed: no partial cycle per batch
    assert cycles_for(33, 16.0, 2) == 33 / 32
    assert cycles_for(100, 0.5, 1) == 200
    # splitting work into batches does not change its cycles
    assert sum(cycles_for(w, 16.0, 2) for w in (7, 9, 16, 1)) == cycles_for(33, 16.0, 2)
    batch = {"a": np.arange(10), "b": np.arange(10) * 2}
    parts = chunks(batch, 4)
    assert [len(p["a"]) for p in parts] == [4, 4, 2]
    np.testing.assert_array_equal(np.concatenate([p["b"] for p in parts]), batch["b"])
    assert chunks({"a": np.arange(0)}, 4) == []


# --------------------------------------------------------------------------- #
# the full pipeline: functional results independent of timing
# --------------------------------------------------------------------------- #
W, H, SPP = 64, 48, 4


def random_draw(seed=0, n=120):
    rng = np.random.default_rng(seed)
    q = np.zeros((n, 3, 4))
    q[:, :, :2] = rng.uniform(-1, 1, (n, 1, 2)) + rng.normal(0, 0.2, (n, 3, 2))
    q[:, :, 2] = rng.uniform(-0.8, 0.9, (n, 1)) + rng.normal(0, 0.05, (n, 3))
    q[:, :, 3] = rng.uniform(0.8, 1.5, (n, 1))
    q[:, :, :3] *= q[:, :, 3:]
    r = q.copy()
    r[:, :, :2] += rng.normal(0, 0.15, (n, 1, 2))
    r[:, :, 2] += rng.normal(0, 0.05, (n, 1))
    lx = np.zeros((n, 3, 2))
    lx[:, :, :] = rng.uniform(0, 0.03, (n, 1, 1))
    return draw_from_clip(q, r, lx, lx.copy(), rng.uniform(0, 1, (n, 3, 3)), W, H)


@pytest.fixture(scope="module")
def draw():
    return random_draw()


@pytest.fixture(scope="module")
def baseline(draw):
    return run_pass(RenderPass(draw=draw, arch=load_arch(), spp=SPP))


TIMING_VARIANTS = [
    ["pipeline.queue_depth=1"],
    ["pipeline.queue_depth=7"],
    ["simulation.triangles_per_batch=1"],
    ["simulation.triangles_per_batch=17", "simulation.tiles_per_batch=3"],
    ["simulation.tiles_per_batch=1", "pipeline.queue_depth=2"],
    ["simulation.samples_per_batch=2"],
    ["simulation.samples_per_batch=97", "simulation.tiles_per_batch=13"],
    ["triangle_setup.throughput=0.01", "rop.throughput=0.25", "rop.bandwidth=1.0"],
    ["tile_test.throughput=100", "sample_tester.throughput=0.5", "shading.throughput=0.1", "shading.cores=1"],
    ["triangle_setup.latency=0", "tile_traverser.latency=0", "tile_test.latency=0", "zcull.latency=0",
     "sample_tester.latency=0", "shading.latency=0", "rop.latency=0"],
    ["triangle_setup.latency=500", "zcull.latency=1000", "rop.latency=3", "shading.shader_cycles=1000"],
    ["tile_test.instances=7", "sample_tester.instances=1", "rop.instances=4", "zcull.instances=3",
     "pipeline.queue_depth=1", "simulation.triangles_per_batch=3"],
]


@pytest.fixture(scope="module")
def ordered_baseline(draw):
    return run_pass(RenderPass(draw=draw, arch=load_arch(), spp=SPP, zcull_refresh="ordered"))


@pytest.mark.parametrize("overrides", TIMING_VARIANTS, ids=lambda o: ",".join(o)[:60])
def test_image_independent_of_timing(draw, baseline, overrides):
    res = run_pass(RenderPass(draw=draw, **pass_settings(overrides), spp=SPP))
    np.testing.assert_array_equal(res.image, baseline.image)
    np.testing.assert_array_equal(res.depth, baseline.depth)
    # nor does any counter declared timing-independent (docs/pipeline.md §4)
    fixed = ~baseline.counters.timing_dependent
    assert res.counters.timing_dependent.equals(baseline.counters.timing_dependent)
    assert res.counters[fixed].equals(baseline.counters[fixed])


@pytest.mark.parametrize("overrides", TIMING_VARIANTS, ids=lambda o: ",".join(o)[:60])
def test_ordered_refresh_makes_every_counter_independent_of_timing(draw, ordered_baseline, baseline, overrides):
    """With z-cull refreshed in submission order no counter depends on queue
    depths, throughputs, latencies, instances or tile and sample batch sizes;
    the triangle batch is the refresh's step, so it may move z-cull's."""
    res = run_pass(RenderPass(draw=draw, **pass_settings(overrides), spp=SPP, zcull_refresh="ordered"))
    np.testing.assert_array_equal(res.image, baseline.image)
    np.testing.assert_array_equal(res.depth, baseline.depth)
    assert not res.counters.timing_dependent.any()
    if not any(o.startswith("simulation.triangles_per_batch") for o in overrides):
        assert res.counters.equals(ordered_baseline.counters)


def test_baseline_is_not_trivial(baseline):
    assert baseline.dimensions == {"motion": True, "lens": True}
    assert baseline.counter("rop", "samples_written") > 2000
    assert len(np.unique(baseline.image.reshape(-1, 4), axis=0)) > 100


def _check_records_chain(res):
    used = res.units_used
    assert used[0] == "triangle_setup" and used[-1] == "rop"
    assert [u for u in UNIT_ORDER if u in used] == used
    for a, b in zip(used, used[1:]):
        assert res.counter(a, "records_out") == res.counter(b, "records_in"), (a, b)
    for u in UNIT_ORDER:
        if u not in used:
            assert res.counter(u, "records_in") == 0
    rows = res.timing.units
    assert rows.unit.tolist() == used


def test_records_chain_between_used_units(draw, baseline):
    _check_records_chain(baseline)
    assert baseline.counter("triangle_setup", "records_in") == draw.n
    assert baseline.counter("rop", "records_out") == baseline.counter("rop", "samples_written")


def test_records_chain_conservative_mode(draw):
    res = run_pass(RenderPass(draw=draw, **pass_settings(["pass.mode=conservative"]), spp=SPP))
    assert "sample_tester" not in res.units_used
    _check_records_chain(res)


def test_records_chain_with_zcull_bypassed(draw):
    res = run_pass(RenderPass(draw=draw, **pass_settings(["zcull.enabled=false"]), spp=SPP))
    assert "zcull" not in res.units_used
    _check_records_chain(res)


def test_busy_cycles_closed_forms(draw):
    """With one item per cycle per unit the busy cycles are the work counters."""
    settings = pass_settings(["triangle_setup.throughput=0.5", "simulation.triangles_per_batch=10",
                                "sample_tester.throughput=1", "sample_tester.instances=1",
                                "tile_test.throughput=1", "tile_test.instances=1"])
    res = run_pass(RenderPass(draw=draw, **settings, spp=SPP))
    rows = res.timing.units.set_index("unit")
    assert rows.loc["triangle_setup"].busy == draw.n / 0.5  # batches of 10: 20 cycles each
    assert rows.loc["tile_test"].busy == res.counter("tile_test", "records_in")
    assert rows.loc["sample_tester"].busy == (res.counter("sample_tester", "samples_tested")
                                              + res.counter("sample_tester", "pixels_visited"))
    assert res.timing.frame_cycles >= rows.busy.max()
    assert rows.loc["triangle_setup"].batches == int(np.ceil(draw.n / 10))


def test_frame_cycles_change_with_throughput(draw, baseline):
    slow = run_pass(RenderPass(draw=draw, **pass_settings(["sample_tester.throughput=0.25"]), spp=SPP))
    fast = run_pass(RenderPass(draw=draw, **pass_settings(["sample_tester.throughput=1000"]), spp=SPP))
    assert slow.timing.frame_cycles > baseline.timing.frame_cycles >= fast.timing.frame_cycles
    # the slow tester alone needs (tested + pixels) * 4 cycles
    work = slow.counter("sample_tester", "samples_tested") + slow.counter("sample_tester", "pixels_visited")
    assert slow.timing.frame_cycles >= work / (0.25 * 2)
    np.testing.assert_array_equal(slow.image, baseline.image)


def test_determinism(draw, baseline):
    again = run_pass(RenderPass(draw=draw, arch=load_arch(), spp=SPP))
    np.testing.assert_array_equal(again.image, baseline.image)
    assert again.counters.equals(baseline.counters)
    assert again.timing.frame_cycles == baseline.timing.frame_cycles
    assert again.timing.units.equals(baseline.timing.units)
    assert again.timing.queues.equals(baseline.timing.queues)


def test_frame_cycles_converge_as_batches_shrink(draw):
    """Batch size is a fidelity knob (issue 3): FIFOs are sized in records, so
    smaller batches only refine the timing; the frame-cycle estimate moves
    less and less as they shrink, and the image never changes. Exactly so
    with z-cull refreshed in submission order, where the work (every
    counter) stays the same; with the timed refresh a smaller ROP batch
    also refreshes z-cull more often."""
    results = {}
    for tiles in (256, 64, 16, 4):
        settings = pass_settings([f"simulation.tiles_per_batch={tiles}", "simulation.triangles_per_batch=8",
                                    f"simulation.samples_per_batch={64 * tiles}"])
        results[tiles] = run_pass(RenderPass(draw=draw, **settings, spp=SPP, zcull_refresh="ordered"))
    cycles = [results[t].timing.frame_cycles for t in (256, 64, 16, 4)]
    steps = np.abs(np.diff(cycles))
    assert np.all(np.diff(steps) < 0) and steps[-1] <= 0.02 * cycles[-1], cycles
    for r in results.values():
        np.testing.assert_array_equal(r.image, results[4].image)
        assert r.counters.equals(results[4].counters)


def _threads_of(monkeypatch, units: dict) -> dict[str, list[str]]:
    """Record, per unit (name: class), the thread each of its ``run`` calls ran on."""
    names = {unit: [] for unit in units}
    for unit, cls in units.items():
        def run(self, batch, _run=cls.run, _log=names[unit]):
            _log.append(threading.current_thread().name)
            return _run(self, batch)
        monkeypatch.setattr(cls, "run", run)
    return names


@pytest.mark.parametrize("regions", [0, 2048])
def test_run_ahead_changes_nothing_but_the_thread(draw, regions, monkeypatch):
    """The tile test, the sample tester, shading and the ROP stepped ahead, each on a thread of its own (at
    depths 1, 2 (the default) and 8), or on the main thread: the same image, every counter (the
    timing-dependent ones too: z-cull sees each of the ROP's refreshes when the simulation reaches the ROP
    step that made it; the shading cache's follow the order of its lookups), cycles and timing, in one
    screen region or in several (the tester, shading and the ROP do not run ahead into the next region)."""
    from units.rop import Rop
    from units.sample_tester import SampleTester
    from units.shading_cache import Shading
    from units.zcull import ZCull

    threads = _threads_of(monkeypatch, {"sample_tester": SampleTester, "shading": Shading, "rop": Rop})
    seen = []  # the z-cull boxes each z-cull batch is tested against
    zcull_run = ZCull.run

    def spy(self, tiles, *query):
        seen.append(self.zmax.tobytes())
        return zcull_run(self, tiles, *query)

    monkeypatch.setattr(ZCull, "run", spy)

    def result(run_ahead):
        seen.clear()
        # (this draw's batches are far too small to be worth handing over: run_ahead_min_us=0 hands over
        # every one)
        settings = [f"simulation.run_ahead={run_ahead}", f"simulation.region_samples={regions}",
                    "simulation.tiles_per_batch=16", "simulation.samples_per_batch=256",
                    "simulation.run_ahead_min_us=0"]
        for log in threads.values():
            log.clear()
        res = run_pass(RenderPass(draw=draw, **pass_settings(settings), spp=SPP))
        for unit, names in threads.items():  # where each unit's batches ran
            ahead = sum(name.startswith(f"run-ahead-{unit}") for name in names)
            assert ahead > len(names) // 2 if run_ahead else ahead == 0, (unit, ahead, len(names))
        return res, list(seen)

    one_thread, boxes = result(0)
    assert len(set(boxes)) > 10  # the ROP's refreshes reached z-cull
    assert one_thread.regions.count == (1 if regions == 0 else 3)
    assert one_thread.timing.units.set_index("unit").loc["sample_tester"].batches > 40
    assert one_thread.timing.units.set_index("unit").loc["shading"].batches > 40
    for run_ahead in (1, 2, 8):
        res, seen_ahead = result(run_ahead)
        assert seen_ahead == boxes
        np.testing.assert_array_equal(res.image, one_thread.image)
        np.testing.assert_array_equal(res.depth, one_thread.depth)
        pd.testing.assert_frame_equal(res.counters, one_thread.counters)
        pd.testing.assert_frame_equal(res.timing.units, one_thread.timing.units)
        pd.testing.assert_frame_equal(res.timing.queues, one_thread.timing.queues)
        assert res.timing.traces == one_thread.timing.traces
        assert res.region_samples_made == one_thread.region_samples_made


def test_a_pass_hands_its_run_ahead_minimum_to_the_simulation(draw, monkeypatch):
    """``simulation.run_ahead_min_us`` reaches ``simulate`` in seconds (default 600 us)."""
    seen = []
    real = render_module.simulate

    def spy(*args, **kwargs):
        seen.append(kwargs.get("run_ahead_min_seconds"))
        return real(*args, **kwargs)

    monkeypatch.setattr(render_module, "simulate", spy)
    for settings, want in (([], 6e-4), (["simulation.run_ahead_min_us=250"], 250e-6)):
        run_pass(RenderPass(draw=draw, **pass_settings(settings), spp=SPP))
        assert seen[-1] == pytest.approx(want)


def test_conservative_shading_ahead_changes_nothing_but_the_thread(draw, monkeypatch):
    """Conservative rasterization (no sample tester; shading runs once per tile record, reading no
    samples) with shading stepped ahead on its own thread: the image, counters and timing of one thread."""
    from units.shading_cache import Shading

    names = _threads_of(monkeypatch, {"shading": Shading})["shading"]

    def result(run_ahead):
        names.clear()
        settings = pass_settings([f"simulation.run_ahead={run_ahead}", "pass.mode=conservative",
                                  "simulation.tiles_per_batch=16", "simulation.run_ahead_min_us=0"])
        return run_pass(RenderPass(draw=draw, **settings, spp=SPP)), list(names)

    (one, one_names), (ahead, ahead_names) = result(0), result(2)
    assert "sample_tester" not in one.units_used and len(one_names) > 20
    assert not any(n.startswith("run-ahead") for n in one_names)
    assert sum(n.startswith("run-ahead-shading") for n in ahead_names) > len(ahead_names) // 2
    np.testing.assert_array_equal(ahead.image, one.image)
    pd.testing.assert_frame_equal(ahead.counters, one.counters)
    pd.testing.assert_frame_equal(ahead.timing.units, one.timing.units)
