"""pipeline-sim benchmarks: ``python -m benchmarks.run --out bench-results [--quick]``.

Prints a table and writes ``results.json`` (every figure and raw timing, plus
machine information, package versions and the date), ``results.csv`` (one
row per headline figure), ``units.csv`` (wall time per unit) and
``scaling.csv`` (one row per scaling point) into ``--out``. Nothing is
asserted: the machine is shared and noisy, so each time is the median of a
few repeats, and the figures worth comparing are the ratios measured in the
same run. Next to each wall time the process CPU time (``time.process_time``)
is given too: everything measured is single-threaded, so on an idle machine
the two agree, and when other jobs compete for the two cores the CPU time is
the steadier of the two. ``--quick`` (about 2 minutes, a good part of it the
cold compile) uses fewer repeats, smaller sweeps and a tiny stand-in for the
1080p frame; the default (about 12 minutes on an idle 2-core machine, 7 of
them the 1080p frame of section 7, before section 11, which took 13 minutes
more on a machine with a load average of 6 to 12) is the full run.

The figures, all for the default workload (workloads/scenes/default.toml)
unless said otherwise:

0. Frame cycles and STE (sample test efficiency = samples_covered /
   samples_tested) of the default workload, and the wall time of one pass.

1. Sample tests per second. The pipeline's rate is the counter
   sample_tester/samples_tested divided by the wall time spent in
   ``SampleTester.run`` (its calls are wrapped with a timer; the rate of the
   numba kernel call alone, without the output allocation and copies, is
   shown too). It is compared with a bare numba micro-kernel
   (benchmarks/microkernel.py: float32 structure-of-arrays 5D inside test,
   one moving defocused triangle against 4,096 samples at a time) running
   the same number of tests in the same process; "gap" is micro / pipeline.

2. Share of wall time spent in the SimPy layer. The same pass runs (a)
   through ``run_pass`` as is and (b) through ``run_pass`` with SimPy's
   ``simulate`` replaced by a plain Python loop calling the very same stage
   steps (unit run + counters + cost model) on the same batches, in the
   stage order recorded from a SimPy run (so every unit also sees the same
   interleaving of z-cull tests and ROP refreshes). Share = (pipeline -
   direct) / pipeline, the median over 15 alternating pairs (each pair's
   two runs back to back; the ratio of the medians and of the minima are
   shown too). Because that
   difference is small next to run-to-run noise, the SimPy layer is also
   timed alone: ``simulate`` driven by do-nothing steps that return the
   recorded output counts and cycles (it reproduces the frame cycles
   exactly). Images, depth buffers and counters of (a) and (b) are compared
   for identity, and also those of a depth-first loop (each triangle batch
   all the way to the ROP before the next): the image must not change, the
   counters may, since z-cull then sees ROP refreshes earlier. A per-unit
   breakdown (wrapped unit ``run`` calls) shows where a pass spends its time.

3. Scaling. Each point runs in a fresh subprocess (benchmarks/child.py):
   wall time of ``run_pass`` (median of repeats; warm-up and scene building
   excluded); peak memory as the process's peak resident set size ("peak
   RSS"), read from VmHWM in /proc/self/status, the per-process high-water
   mark that ``getrusage(RUSAGE_SELF).ru_maxrss`` is built from. The mark is
   reset (/proc/self/clear_refs) after imports, warm-up and scene building,
   so it measures the runs rather than numba's compiler; "RSS growth" is the
   peak minus the RSS just before the runs. (ru_maxrss itself is recorded in
   the JSON but not used: after fork + exec Linux starts it at the parent's
   peak, so every child of this large process would report the parent's
   size.) Also the peak of tracemalloc-traced allocations during one extra
   run ("traced peak": Python objects and numpy buffers; arrays allocated
   inside numba kernels are not seen). Sweeps: triangle count (random small moving defocused
   triangles made with ``draw_from_clip``, fixed image size and spp,
   submitted back to front: in random order, more triangles on the same
   screen hide more of each other, z-cull rejects a growing share and time
   grows slower than the count for reasons of the workload, not of the
   simulator; back to front, every triangle does the same expected work at
   every count), pixel
   count (the default scene at 320x180 .. 1280x720) and spp (the default
   scene, 16 .. 256): 16x ranges, triangles from 8,000 up so that the
   frame's own work (samples, their layout, buffers, resolve: about 0.1 s
   at 320x180, 8 spp) is a small share. The log-log slope of time (and of
   memory) against the swept quantity is fitted with ``numpy.polyfit``: 1.0
   means linear, and issue 3 asks for 0.9 to 1.1. An affine fit time =
   fixed + c x splits off the work the swept quantity does not drive (per
   (triangle, tile) record work in the spp sweep: a tile is tested once
   whatever its spp) and gives the log-log slope of the rest.

4. First-run compile time. ``pipeline_sim.jit.warm_up()`` timed in a fresh
   subprocess with ``NUMBA_CACHE_DIR`` pointing at an empty temporary folder
   (cold: every kernel compiles), then in a second fresh subprocess with the
   same folder (the kernels load from numba's cache).

5. Specialization cost (benchmarks/specialization.py): static.toml (xy),
   motion.toml (xyt), defocus.toml (xyuv) and default.toml (xyuvt), one
   geometry, plus the static scene forced through the general 5D path:
   samples tested, sample-tester madd/mul per tested sample, frame cycles,
   wall time and ratios to static. Writes ``specialization.csv``.

6. Batch size as an accuracy knob (benchmarks/batching.py): the default
   workload at tiles_per_batch 16 .. 2048 (samples_per_batch = 64 x tiles)
   and triangles_per_batch 8 .. 256: frame cycles, their change against the
   smallest batch, wall time, and bit-identity of image and depth. Writes
   ``batch.csv``.

7. The 1080p frame (benchmarks/frame.py): 250,000 then 1,000,000 random
   small moving, defocused triangles at 1920x1080, 16 spp, each size in a
   fresh process limited to 480 s and a 12 GiB address space: wall time,
   peak RSS (VmHWM), frame cycles and how memory divides (the frame is
   rendered in screen regions of ``simulation.region_samples``, so samples
   and multisample buffers exist for one region at a time); a size that does
   not finish is reported with the reason. ``--quick`` runs a tiny stand-in
   (4,000 triangles at 480x270). Writes ``frame.csv``. This section alone
   takes about 2 minutes of the full run.
8. Sample patterns (benchmarks/patterns.py): the per-pixel discrepancy of
   every sample pattern (scipy.stats.qmc, centered L2) in (x, y), (x, y, t)
   and 5D, and how fast each is generated.
9. ("tester" section) The sample tester against bare micro-kernels of the
   same dimension on exactly the samples it tests, record by record
   (benchmarks/tester_speed.py): issue 3's like-for-like throughput ratio;
   and against a brute-force tester, the micro-kernel on every sample of
   each record's tile (the tester's whole input), in tile samples a second.
10. ("ab" section) What the pass layer costs (benchmarks/ab.py): the default
   pass in the working tree against earlier revisions extracted with
   ``git archive`` (before issue 12, before its pass layer, before the
   cost-per-sample work), each in fresh
   subprocesses in rotating order, in one run: wall and CPU time, their
   ratios, and whether image and counters are the same. Writes ``ab.csv``.
11. ("convergence" section) Error against samples per pixel, per sample
   pattern (benchmarks/convergence.py): RMSE against a converged reference
   on a motion-only, a defocus-only and a motion + defocus + camera-motion
   scene at 16 .. 1024 spp, its log-log slope and the error at 256 spp
   (deterministic figures); and the peer, Mesa's llvmpipe through moderngl
   on EGL as an accumulation buffer on the motion + defocus scene
   (benchmarks/peer.py; skipped with a note without moderngl or EGL): the
   passes it needs to reach the project's error at 64 and 256 spp and the
   time to equal error, project over peer, timed alternately in one run.
   Writes ``convergence.csv``.

12. ("per_sample" section) Cost per sample: the default scene at 256 spp,
   in nanoseconds per sample end to end, with the tile test, the sample
   tester, shading and the ROP on run-ahead threads (as shipped,
   ``simulation.run_ahead = 2``) and on one thread, timed alternately, with
   the machine's speed measured after each round (a bare 5D inside test's
   nanoseconds and a memory copy's bandwidth; the pass is also given in bare
   tests a sample, a figure less at the mercy of the machine's state than
   nanoseconds); then instrumented
   as in 2 (on one thread), per part
   (tile test, z-cull, tester, shading, ROP, the z-cull refresh, sample
   generation: in wall time the main thread's waits for a region's samples,
   which the next region's are made during, in CPU time also the generating
   threads; the cost model in the steps, the SimPy layer, the rest), and the tester's
   nanoseconds per tested sample including its outputs (``per_sample.csv``);
   and, in as many runs again (as shipped, with the main thread timed), the
   main thread's CPU, the simulation's waits for each unit's run-ahead steps
   and the steps it ran itself (in ``results.json`` and ``results.csv``).

``--only SECTION[,SECTION]`` runs some sections only (default, tester,
scaling, compile, specialization, batch, frame, patterns, ab, convergence,
per_sample; "default" is 0-2);
``--frame-triangles N[,N]`` changes the frame section's sizes.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import datetime as dt
import hashlib
import importlib.metadata
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline_sim.memory import keep_freed_memory

ROOT = Path(__file__).resolve().parent.parent

FULL = {
    "pairs": 15, "instrumented": 3, "simpy_only": 5, "micro_repeats": 7, "scaling_repeats": 5,
    # 16x ranges where the swept quantity's work dominates the per-pass and
    # per-tile fixed costs (issue 3 asks for log-log slopes of 0.9 to 1.1)
    "tris": {"n": [8000, 16000, 32000, 64000, 128000], "width": 320, "height": 180, "spp": 8},
    "pixels": {"sizes": [(320, 180), (640, 360), (960, 540), (1280, 720)], "spp": 16},
    "spp": {"spp": [16, 32, 64, 128, 256], "width": 320, "height": 180},
    "spec_repeats": 3, "spec_instrumented": 2,
    "batch_tiles": [16, 32, 64, 128, 256, 512, 2048], "batch_triangles": [8, 16, 32, 64, 128, 256],
    "batch_repeats": 2,
    "frame": {"n": [250_000, 1_000_000], "width": 1920, "height": 1080, "spp": 16,
              "time_limit_s": 480, "mem_limit_gib": 12},
    "patterns": {"width": 64, "height": 64, "spp": [16, 64], "pixels": 256, "t_value_m": list(range(1, 13))},
    "ab_rounds": 5, "ab_runs": 5,
    "convergence": {"width": 160, "height": 90, "spp": [16, 32, 64, 128, 256, 512, 1024], "ref_spp": 8192,
                    "peer_max_passes": 1024, "peer_rounds": 3},
    "per_sample": {"spp": 256, "plain": 5},
}
QUICK = {
    "pairs": 3, "instrumented": 1, "simpy_only": 3, "micro_repeats": 5, "scaling_repeats": 1,
    "tris": {"n": [500, 2000, 8000], "width": 160, "height": 90, "spp": 4},
    "pixels": {"sizes": [(80, 45), (160, 90), (320, 180)], "spp": 4},
    "spp": {"spp": [1, 4, 16], "width": 160, "height": 90},
    "spec_repeats": 1, "spec_instrumented": 1,
    "batch_tiles": [32, 2048], "batch_triangles": [8, 256],
    "batch_repeats": 1,
    # a tiny stand-in for the 1080p frame (same triangles, 1/16 of the pixels)
    "frame": {"n": [4_000], "width": 480, "height": 270, "spp": 16, "time_limit_s": 120, "mem_limit_gib": 12},
    "patterns": {"width": 32, "height": 32, "spp": [16], "pixels": 64, "t_value_m": [4, 6, 8]},
    "ab_rounds": 2, "ab_runs": 3,
    "convergence": {"width": 64, "height": 36, "spp": [16, 64, 256], "ref_spp": 2048, "peer_max_passes": 512,
                    "peer_rounds": 1},
    "per_sample": {"spp": 64, "plain": 2},
}
# sections in the order they run; --only picks some
SECTIONS = ("default", "tester", "scaling", "compile", "specialization", "batch", "frame", "patterns", "ab",
            "convergence", "per_sample")


def log(msg: str) -> None:
    print(f"  .. {msg}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------
# machine and environment


def source_digest() -> str:
    """sha256 over the simulator's sources (they may be edited while the benchmark runs)."""
    h = hashlib.sha256()
    for d in ("pipeline_sim", "units"):
        for p in sorted((ROOT / d).rglob("*.py")):
            h.update(p.relative_to(ROOT).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def machine_info() -> dict:
    info = {
        "platform": platform.platform(), "machine": platform.machine(), "python": platform.python_version(),
        "cpu_count": os.cpu_count(), "cpus_usable": len(os.sched_getaffinity(0)),
        "load_average_start": os.getloadavg(),
    }
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu_model"] = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                info["mem_total_gb"] = round(int(line.split()[1]) / 2**20, 1)
                break
    except OSError:
        pass
    import numba
    info["numba_num_threads"] = numba.config.NUMBA_NUM_THREADS
    return info


def package_versions() -> dict:
    out = {}
    for name in ("pipeline-sim", "numpy", "numba", "llvmlite", "simpy", "pandas", "scipy", "trimesh"):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    if out["pipeline-sim"] == "not installed":
        import tomllib
        out["pipeline-sim"] = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"] + " (source)"
    return out


# ---------------------------------------------------------------------------
# 0-2: the default workload in this process


def _clocks():
    return time.perf_counter(), time.process_time()


def _since(c):
    return time.perf_counter() - c[0], time.process_time() - c[1]


def _share(pipe: list[float], direct: list[float]) -> dict:
    mp, md = float(np.median(pipe)), float(np.median(direct))
    return {"medians": (mp - md) / mp, "minima": (min(pipe) - min(direct)) / min(pipe),
            "pairwise_median": float(np.median([(a - b) / a for a, b in zip(pipe, direct)]))}


def bench_default(cfg: dict) -> dict:
    from benchmarks import instrument as ins
    from benchmarks import microkernel
    from benchmarks.workloads import DEFAULT_SCENE, default_pass
    from pipeline_sim.render import run_pass

    p = default_pass()
    out: dict = {"scene": str(DEFAULT_SCENE.relative_to(ROOT)), "width": p.draw.width, "height": p.draw.height,
                 "spp": p.spp, "triangles": p.draw.n}

    # a recording SimPy run: stage order and step results, also warms every path
    log("default workload: recording run")
    script = ins.Script()
    with ins.recording(script):
        rec = run_pass(p)
    out["stage_visits"] = len(script.order)
    out["source_batches"] = script.n_source

    # (a) SimPy pipeline vs (b) direct loop, alternating which goes first
    log(f"default workload: {cfg['pairs']} pairs of pipeline / direct runs")
    t = {"pipe": [], "direct": []}
    c = {"pipe": [], "direct": []}
    res_pipe = res_direct = None
    for i in range(cfg["pairs"]):
        for which in (("pipe", "direct") if i % 2 == 0 else ("direct", "pipe")):
            ctx = ins.direct(script.order) if which == "direct" else contextlib.nullcontext()
            with ctx:
                c0 = _clocks()
                r = run_pass(p)
                wall, cpu = _since(c0)
            t[which].append(wall)
            c[which].append(cpu)
            if which == "pipe":
                res_pipe = r
            else:
                res_direct = r
    with ins.direct(None):
        res_depth = run_pass(p)

    tested = res_pipe.counter("sample_tester", "samples_tested")
    covered = res_pipe.counter("sample_tester", "samples_covered")
    out.update({
        "frame_cycles": res_pipe.timing.frame_cycles, "samples_tested": tested, "samples_covered": covered,
        "ste": covered / tested if tested else float("nan"),
        "recorded_frame_cycles": script.frame_cycles,
        "pipeline_times_s": t["pipe"], "direct_times_s": t["direct"],
        "pipeline_cpu_s": c["pipe"], "direct_cpu_s": c["direct"],
        "pipeline_median_s": float(np.median(t["pipe"])), "direct_median_s": float(np.median(t["direct"])),
        "pipeline_cpu_median_s": float(np.median(c["pipe"])), "direct_cpu_median_s": float(np.median(c["direct"])),
        "simpy_share_wall": _share(t["pipe"], t["direct"]),
        "simpy_share_cpu": _share(c["pipe"], c["direct"]),
    })

    def same(a, b):
        return bool(np.array_equal(a.image, b.image) and np.array_equal(a.depth, b.depth))

    def counter_diffs(a, b):
        m = a.counters.merge(b.counters, on=["unit", "counter"], suffixes=("_a", "_b"))
        m = m[m.value_a != m.value_b]
        return [f"{r.unit}/{r.counter}: {r.value_a} vs {r.value_b}" for r in m.itertuples()]

    out["identical_image_direct"] = same(res_pipe, res_direct)
    out["identical_counters_direct"] = not counter_diffs(res_pipe, res_direct)
    out["identical_image_depth_first"] = same(res_pipe, res_depth)
    out["counter_diffs_depth_first"] = counter_diffs(res_pipe, res_depth)
    out["identical_image_recording"] = same(res_pipe, rec)
    del rec, res_direct, res_depth, r

    # the SimPy layer alone
    log("default workload: SimPy layer alone")
    sw, sc = [], []
    for _ in range(cfg["simpy_only"]):
        wall, cpu, frame = ins.simpy_only(script)
        sw.append(wall)
        sc.append(cpu)
        out["simpy_only_frame_cycles"] = frame
    out["simpy_only_times_s"] = sw
    out["simpy_only_cpu_s"] = sc
    out["simpy_only_median_s"] = float(np.median(sw))
    out["simpy_only_cpu_median_s"] = float(np.median(sc))
    out["simpy_only_share"] = out["simpy_only_median_s"] / out["pipeline_median_s"]
    out["simpy_only_share_cpu"] = out["simpy_only_cpu_median_s"] / out["pipeline_cpu_median_s"]
    out["simpy_us_per_stage_visit"] = 1e6 * out["simpy_only_median_s"] / max(1, len(script.order))

    # per-unit wall time (SimPy pipeline with every unit's run wrapped)
    log(f"default workload: {cfg['instrumented']} instrumented runs")
    runs, r = instrumented_runs(p, cfg["instrumented"])
    out.update(unit_breakdown(runs, out["simpy_only_median_s"], out["simpy_only_cpu_median_s"]))

    # 1. sample tests per second: pipeline vs bare micro-kernel on the same number of tests
    st_tested = r.counter("sample_tester", "samples_tested")

    def med(key, cpu=False):
        return float(np.median([(tm.cpu if cpu else tm.seconds)[key] for _, _, tm in runs]))

    out["tester_run_s"] = med("sample_tester")
    out["tester_kernel_s"] = med("sample_test_kernel")
    out["tester_run_cpu_s"] = med("sample_tester", True)
    out["tester_rate"] = st_tested / out["tester_run_s"]
    out["tester_kernel_rate"] = st_tested / out["tester_kernel_s"]
    out["tester_rate_cpu"] = st_tested / out["tester_run_cpu_s"]
    log("micro-kernel")
    micro = microkernel.measure(st_tested, n_samples=4096, repeats=cfg["micro_repeats"])
    out["micro"] = micro
    out["micro_rate"] = micro["tests_per_s"]
    out["micro_rate_cpu"] = micro["tests_per_cpu_s"]
    out["micro_over_pipeline"] = micro["tests_per_s"] / out["tester_rate"]
    out["micro_over_pipeline_kernel"] = micro["tests_per_s"] / out["tester_kernel_rate"]
    out["micro_over_pipeline_cpu"] = micro["tests_per_cpu_s"] / out["tester_rate_cpu"]
    return out


def instrumented_runs(p, repeats: int) -> tuple[list, object]:
    """``repeats`` SimPy runs of pass ``p`` with every unit's run timed: [(wall, CPU, timers)] and the last result."""
    from benchmarks import instrument as ins
    from pipeline_sim.render import run_pass

    runs = []
    for _ in range(repeats):
        timers = ins.Timers()
        with ins.unit_timers(timers):
            c0, m0 = _clocks(), time.thread_time()
            r = run_pass(p)
            total, total_cpu = _since(c0)
            timers.other_threads_cpu = total_cpu - (time.thread_time() - m0)
        runs.append((total, total_cpu, timers))
    return runs, r


def unit_breakdown(runs: list, simpy_s: float, simpy_cpu_s: float) -> dict:
    """Where instrumented runs' time goes, part by part (medians; the SimPy layer as timed alone):
    ``instrumented_total_s``, ``instrumented_total_cpu_s`` and ``units`` (part, seconds, share, CPU, calls)."""
    from benchmarks import instrument as ins

    calls = runs[-1][2].calls
    unit_names = list(ins.UNIT_CLASSES)

    def parts(secs: dict, total: float, simpy: float, other_threads: float = 0.0) -> dict:
        """Each part's own time (``secs``: a run's self times, nested timed calls left out); sample
        generation is the main thread's wait for a region's samples plus ``other_threads`` (the CPU of the
        threads that make them; zero for wall time, where only the wait is on the critical path)."""
        d = {name: secs.get(name, 0.0) for name in unit_names}
        d["z-cull refresh (in the ROP's steps)"] = secs.get("zcull refresh", 0.0)
        d["sample generation"] = secs.get("samples wait", 0.0) + other_threads
        d["resolve"] = secs.get("resolve", 0.0)
        d["counters and cost model in the steps"] = sum(secs.get("step:" + n, 0.0) for n in unit_names)
        d["SimPy layer (timed alone)"] = simpy
        d["other (unit set-up, counters table, ...)"] = total - sum(d.values())
        return d

    wall_parts = [parts(tm.self_seconds, tot, simpy_s) for tot, _, tm in runs]
    cpu_parts = [parts(tm.self_cpu, tot, simpy_cpu_s, tm.other_threads_cpu) for _, tot, tm in runs]
    total = float(np.median([r_[0] for r_ in runs]))
    total_cpu = float(np.median([r_[1] for r_ in runs]))
    call_keys = {"sample generation": "make_samples", "resolve": "resolve"}
    units = []
    for key in wall_parts[0]:
        w = float(np.median([d[key] for d in wall_parts]))
        cp = float(np.median([d[key] for d in cpu_parts]))
        units.append({"part": key, "seconds": w, "share": w / total, "cpu_seconds": cp, "cpu_share": cp / total_cpu,
                      "calls": calls.get(call_keys.get(key, key), 0)})
    return {"instrumented_total_s": total, "instrumented_total_cpu_s": total_cpu, "units": units}


def simulation_thread(runs: list[tuple[float, dict]]) -> dict:
    """Medians over run-ahead runs, each (the main thread's CPU seconds over the pass, its
    ``instrument.simulation_waits`` log): ``cpu_s`` (None without runs) and, per unit in any run's log
    (``units``), each field of ``instrument.WAIT_FIELDS``, field by field (a unit missing from a run's log
    had no run-ahead steps there: zeros)."""
    from benchmarks import instrument as ins

    names = list(dict.fromkeys(name for _, steps in runs for name in steps))
    units = {name: {k: float(np.median([steps.get(name, {}).get(k, 0) for _, steps in runs])) for k in ins.WAIT_FIELDS}
             for name in names}
    return {"cpu_s": float(np.median([c for c, _ in runs])) if runs else None, "units": units}


def machine_reference() -> tuple[float, float]:
    """The machine's speed now, to read a run's times by: nanoseconds of one bare float32 5D inside test
    (``benchmarks.microkernel``, one core, 16 million tests, median of three) and the bandwidth of a
    copy of 64 MiB (GB/s counting the bytes read and the bytes written, median of three; source and
    destination together are four times the L3 of the machines this runs on, so it measures memory)."""
    from benchmarks.microkernel import measure

    bare_ns = 1e9 / measure(1 << 24, repeats=3)["tests_per_s"]
    src = np.ones(1 << 23)
    dst = np.empty_like(src)
    np.copyto(dst, src)  # first touch
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        np.copyto(dst, src)
        times.append(time.perf_counter() - t0)
    return bare_ns, 2 * src.nbytes / float(np.median(times)) / 1e9


def bench_per_sample(cfg: dict) -> dict:
    """Nanoseconds per sample end to end on the default scene at ``cfg["per_sample"]["spp"]``, split by part
    (issue 19's cost per sample), and the tester's nanoseconds per tested sample including its outputs."""
    from benchmarks import instrument as ins
    from benchmarks.workloads import default_pass
    from pipeline_sim.render import run_pass

    spp = cfg["per_sample"]["spp"]
    p = default_pass(spp=spp)
    samples = p.draw.width * p.draw.height * spp
    log(f"per sample: the default scene at {spp} spp, recording run")
    script = ins.Script()
    with ins.recording(script):
        run_pass(p)
    simpy = [ins.simpy_only(script)[:2] for _ in range(cfg["simpy_only"])]
    log(f"per sample: {cfg['instrumented']} instrumented runs")
    runs, r = instrumented_runs(p, cfg["instrumented"])
    out = {"spp": spp, "width": p.draw.width, "height": p.draw.height, "samples": samples,
           "samples_tested": r.counter("sample_tester", "samples_tested"),
           **unit_breakdown(runs, float(np.median([w for w, _ in simpy])), float(np.median([c for _, c in simpy])))}
    out["instrumented_ns_per_sample"] = 1e9 * out["instrumented_total_s"] / samples
    out["instrumented_ns_per_sample_cpu"] = 1e9 * out["instrumented_total_cpu_s"] / samples
    # uninstrumented passes on one thread (simulation.run_ahead = 0, as the instrumented runs) and as shipped,
    # with the tile test, the sample tester, shading and the ROP on run-ahead threads, alternately
    depth = p.simulation.run_ahead
    variants = {"one_thread": 0, "run_ahead": depth}
    log(f"per sample: {cfg['per_sample']['plain']} plain runs each, one thread and run-ahead, alternately")
    plain: dict[str, list] = {key: [] for key in variants}
    machine = []  # per round, after its passes: (ns of a bare 5D test, GB/s of a memory copy)
    for i in range(cfg["per_sample"]["plain"]):
        # which variant goes first alternates, so that neither always follows the machine's measure
        for key, value in (list(variants.items()) if i % 2 == 0 else list(variants.items())[::-1]):
            q = dataclasses.replace(p, simulation=p.simulation.replace(run_ahead=value))
            c0 = _clocks()
            run_pass(q)
            plain[key].append(_since(c0))
        machine.append(machine_reference())
    # then as shipped with the simulation's thread timed (instrument.simulation_waits): its CPU over the pass
    # and, per unit with run-ahead, its waits for the unit's steps and the steps it ran itself
    waits = []
    if depth:
        log(f"per sample: {cfg['instrumented']} run-ahead runs, the simulation's thread timed")
        for _ in range(cfg["instrumented"]):
            steps: dict = {}
            with ins.simulation_waits(steps):
                m0 = time.thread_time()
                run_pass(p)
                waits.append((time.thread_time() - m0, steps))
    out["simulation_thread"] = simulation_thread(waits)
    for key, times in plain.items():
        out[f"{key}_s"] = float(np.median([w for w, _ in times]))
        out[f"{key}_cpu_s"] = float(np.median([c for _, c in times]))
        out[f"{key}_ns_per_sample"] = 1e9 * out[f"{key}_s"] / samples
        out[f"{key}_ns_per_sample_range"] = [1e9 * f([w for w, _ in times]) / samples for f in (min, max)]
    out["run_ahead_depth"] = depth
    out["bare_test_ns"] = [b for b, _ in machine]
    out["copy_gb_per_s"] = [c for _, c in machine]
    out["ns_per_sample"] = out["run_ahead_ns_per_sample"]
    # the pass in units of the machine's own bare test, measured in the same rounds: a figure that moves
    # less than nanoseconds with the speed the machine happens to have
    out["bare_tests_per_sample"] = out["ns_per_sample"] / float(np.median(out["bare_test_ns"]))
    out["ns_per_sample_cpu"] = 1e9 * out["run_ahead_cpu_s"] / samples
    for u in out["units"]:
        u["ns_per_sample"] = 1e9 * u["seconds"] / samples
    tester = float(np.median([tm.seconds["sample_tester"] for _, _, tm in runs]))
    out["tester_ns_per_tested_sample"] = 1e9 * tester / max(1, out["samples_tested"])
    return out


# ---------------------------------------------------------------------------
# 3-4: subprocesses


def run_child(args: list[str], env: dict | None = None, timeout: float = 600) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "benchmarks.child", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        return {"error": (proc.stderr or proc.stdout).strip().splitlines()[-1:], "process_wall_s": wall}
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    res["process_wall_s"] = wall
    return res


def slope(xs, ys) -> float:
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    ok = (xs > 0) & (ys > 0) & np.isfinite(ys)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(xs[ok]), np.log(ys[ok]), 1)[0])


def affine_fit(xs, ys) -> dict:
    """time = fixed + per_unit * x by least squares: the fixed share of the
    smallest point's time, and the log-log slope of the part that grows
    (time - fixed), which is 1.0 when the marginal cost is linear."""
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    if len(xs) < 2:
        return {"fixed_s": float("nan"), "fixed_share": float("nan"), "slope_marginal": float("nan")}
    per_unit, fixed = np.polyfit(xs, ys, 1)
    return {"fixed_s": float(fixed), "per_unit_s": float(per_unit),
            "fixed_share": float(fixed / ys[np.argmin(xs)]), "slope_marginal": slope(xs, ys - fixed)}


def bench_scaling(cfg: dict) -> dict:
    reps = cfg["scaling_repeats"]
    sweeps = {"triangles": [], "pixels": [], "spp": []}
    c = cfg["tris"]
    for n in c["n"]:
        sweeps["triangles"].append({"kind": "tris", "n": n, "width": c["width"], "height": c["height"],
                                    "spp": c["spp"], "back_to_front": True, "repeats": reps})
    c = cfg["pixels"]
    for w, h in c["sizes"]:
        sweeps["pixels"].append({"kind": "scene", "width": w, "height": h, "spp": c["spp"], "repeats": reps})
    c = cfg["spp"]
    for s in c["spp"]:
        sweeps["spp"].append({"kind": "scene", "width": c["width"], "height": c["height"], "spp": s,
                              "repeats": reps})
    out = {}
    for name, specs in sweeps.items():
        points = []
        for spec in specs:
            log(f"scaling {name}: {spec}")
            res = run_child(["point", json.dumps(spec)])
            res.update({k: v for k, v in spec.items() if k not in res})
            res["x"] = {"triangles": res.get("triangles", spec.get("n")),
                        "pixels": spec["width"] * spec["height"], "spp": spec["spp"]}[name]
            points.append(res)
        good = [pt for pt in points if "error" not in pt]
        xs = [pt["x"] for pt in good]
        out[name] = {
            "points": points,
            "slope_time": slope(xs, [pt["median_s"] for pt in good]),
            "slope_cpu_time": slope(xs, [pt["cpu_median_s"] for pt in good]),
            "slope_traced_peak": slope(xs, [pt["traced_peak_mb"] for pt in good]),
            "slope_rss_growth": slope(xs, [pt["rss_growth_mb"] for pt in good]),
            "slope_samples_tested": slope(xs, [pt["samples_tested"] for pt in good]),
            "range": (max(xs) / min(xs)) if xs else float("nan"),
            "fit": affine_fit(xs, [pt["median_s"] for pt in good]),
        }
    return out


def bench_compile() -> dict:
    tmp = tempfile.mkdtemp(prefix="pipeline-sim-numba-cache-")
    try:
        env = dict(os.environ, NUMBA_CACHE_DIR=tmp)
        log("compile: cold warm_up() in a fresh process (empty NUMBA_CACHE_DIR)")
        cold = run_child(["compile"], env=env)
        log("compile: warm_up() again in a fresh process (same cache)")
        warm = run_child(["compile"], env=env)
        files = sum(1 for _ in Path(tmp).rglob("*") if _.is_file())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"cold": cold, "cached": warm, "cache_files": files}


# ---------------------------------------------------------------------------
# output


def fmt_rate(r: float) -> str:
    return f"{r / 1e6:,.1f} M/s"


def table(rows: list[tuple], headers: tuple) -> str:
    cells = [tuple(str(c) for c in headers)] + [tuple(str(c) for c in r) for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = []
    for j, r in enumerate(cells):
        lines.append("  " + "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
        if j == 0:
            lines.append("  " + "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def report(results: dict) -> tuple[str, list[dict]]:
    d = results.get("default")
    rows_csv: list[dict] = []

    def add(section, metric, value, unit="", note=""):
        rows_csv.append({"section": section, "metric": metric, "value": value, "unit": unit, "note": note})

    m = results["machine"]
    out = []
    out.append(f"pipeline-sim benchmarks ({results['mode']}), {results['date']}")
    out.append(f"machine: {m.get('cpu_model', '?')}, {m['cpus_usable']} CPUs, {m.get('mem_total_gb', '?')} GB, "
               f"Python {m['python']}, numba {results['packages']['numba']}, numpy {results['packages']['numpy']}, "
               f"simpy {results['packages']['simpy']}; load average {m['load_average_start'][0]:.2f} at start, "
               f"{m['load_average_end'][0]:.2f} at end")
    if results["source_digest_start"] != results["source_digest_end"]:
        out.append("WARNING: the simulator's sources changed while the benchmark ran; "
                   "points measured in different processes may not be comparable.")
    out.append("")
    if "default" in results:
        out.append(f"Default workload {d['scene']}: {d['width']}x{d['height']}, {d['spp']} spp, {d['triangles']:,} triangles")
        n = len(d["pipeline_times_s"])
        rows = [
            ("frame cycles", f"{d['frame_cycles']:,.0f}", "simulated"),
            ("STE", f"{100 * d['ste']:.2f} %", f"{d['samples_covered']:,} covered / {d['samples_tested']:,} tested"),
            ("wall time per pass", f"{d['pipeline_median_s']:.3f} s",
             f"median of {n}; CPU time {d['pipeline_cpu_median_s']:.3f} s"),
        ]
        out.append(table(rows, ("figure", "value", "note")))
        add("default", "frame_cycles", d["frame_cycles"], "cycles")
        add("default", "ste", d["ste"], "ratio", "samples_covered / samples_tested")
        add("default", "samples_tested", d["samples_tested"], "tests")
        add("default", "wall_time_per_pass", d["pipeline_median_s"], "s", f"median of {n}")
        add("default", "cpu_time_per_pass", d["pipeline_cpu_median_s"], "s", f"median of {n}")

        out.append("")
        out.append("1. Sample tests per second (same number of tests, same process; CPU-time rates in brackets)")
        mic = d["micro"]
        rows = [
            ("pipeline SampleTester.run", fmt_rate(d["tester_rate"]), f"({fmt_rate(d['tester_rate_cpu'])})",
             f"{d['samples_tested']:,} tests in {d['tester_run_s']:.3f} s"),
            ("pipeline kernel call only", fmt_rate(d["tester_kernel_rate"]), "", f"{d['tester_kernel_s']:.3f} s"),
            ("bare micro-kernel", fmt_rate(d["micro_rate"]), f"({fmt_rate(d['micro_rate_cpu'])})",
             f"{mic['tests']:,} tests in {mic['median_s']:.4f} s, {mic['samples_per_triangle']} samples/triangle"),
            ("gap micro / pipeline", f"{d['micro_over_pipeline']:.1f}x", f"({d['micro_over_pipeline_cpu']:.1f}x)",
             f"{d['micro_over_pipeline_kernel']:.1f}x against the kernel call alone"),
        ]
        out.append(table(rows, ("rate", "tests/s", "CPU", "note")))
        add("sample_tests", "pipeline_sample_tester_rate", d["tester_rate"], "tests/s", "samples_tested / SampleTester.run wall time")
        add("sample_tests", "pipeline_sample_tester_rate_cpu", d["tester_rate_cpu"], "tests/s", "samples_tested / SampleTester.run CPU time")
        add("sample_tests", "pipeline_kernel_rate", d["tester_kernel_rate"], "tests/s", "samples_tested / kernel call wall time")
        add("sample_tests", "micro_kernel_rate", d["micro_rate"], "tests/s", "bare float32 SoA 5D kernel, one core")
        add("sample_tests", "micro_kernel_rate_cpu", d["micro_rate_cpu"], "tests/s", "CPU time")
        add("sample_tests", "micro_over_pipeline", d["micro_over_pipeline"], "ratio", "wall-time rates")
        add("sample_tests", "micro_over_pipeline_cpu", d["micro_over_pipeline_cpu"], "ratio", "CPU-time rates")

        out.append("")
        out.append(f"2. SimPy layer share of a pass (target under 10%; {n} alternating pairs, wall and CPU time)")
        sw, sc = d["simpy_share_wall"], d["simpy_share_cpu"]
        rows = [
            ("pipeline (run_pass)", f"{d['pipeline_median_s']:.3f} s", f"{d['pipeline_cpu_median_s']:.3f} s", "median"),
            ("direct loop, same steps", f"{d['direct_median_s']:.3f} s", f"{d['direct_cpu_median_s']:.3f} s",
             f"median; {d['stage_visits']} stage visits replayed in SimPy's order"),
            ("(pipeline - direct) / pipeline", f"{100 * sw['pairwise_median']:.1f} %",
             f"{100 * sc['pairwise_median']:.1f} %",
             f"median over the pairs; from medians {100 * sw['medians']:.1f} % / {100 * sc['medians']:.1f} %, "
             f"from minima {100 * sw['minima']:.1f} % / {100 * sc['minima']:.1f} % (wall / CPU)"),
            ("SimPy layer timed alone", f"{1e3 * d['simpy_only_median_s']:.1f} ms", f"{1e3 * d['simpy_only_cpu_median_s']:.1f} ms",
             f"= {100 * d['simpy_only_share']:.2f} % of a pass; {d['simpy_us_per_stage_visit']:.1f} us per stage visit"),
        ]
        out.append(table(rows, ("figure", "wall", "CPU", "note")))
        rows = [
            ("identical image, direct loop", "yes" if d["identical_image_direct"] else "NO",
             "counters identical too" if d["identical_counters_direct"] else "counters differ"),
            ("identical image, depth-first loop", "yes" if d["identical_image_depth_first"] else "NO",
             f"{len(d['counter_diffs_depth_first'])} counters differ" if d["counter_diffs_depth_first"]
             else "counters identical too"),
        ]
        out.append(table(rows, ("check", "", "note")))
        if d["counter_diffs_depth_first"]:
            out.append("  SimPy vs depth-first order, e.g. " + "; ".join(d["counter_diffs_depth_first"][:3]))
        add("simpy", "pipeline_median", d["pipeline_median_s"], "s")
        add("simpy", "direct_median", d["direct_median_s"], "s")
        add("simpy", "share_wall_pairwise", sw["pairwise_median"], "ratio",
            "(pipeline - direct) / pipeline, median over alternating pairs (wall)")
        add("simpy", "share_cpu_pairwise", sc["pairwise_median"], "ratio", "same, CPU time")
        add("simpy", "share_wall_medians", sw["medians"], "ratio", "(pipeline - direct) / pipeline, wall-time medians")
        add("simpy", "share_wall_minima", sw["minima"], "ratio", "same, from minima")
        add("simpy", "share_cpu_medians", sc["medians"], "ratio", "same, CPU-time medians")
        add("simpy", "share_timed_alone", d["simpy_only_share"], "ratio", "simulate() with do-nothing steps / pipeline")
        add("simpy", "identical_image_direct", int(d["identical_image_direct"]), "bool")
        add("simpy", "identical_image_depth_first", int(d["identical_image_depth_first"]), "bool")

        out.append("")
        out.append(f"   Where a pass goes (instrumented SimPy runs, median of {results['config']['instrumented']}; "
                   f"pass {d['instrumented_total_s']:.3f} s wall, {d['instrumented_total_cpu_s']:.3f} s CPU)")
        rows = [(u["part"], f"{u['seconds']:.3f} s", f"{100 * u['share']:.1f} %", f"{100 * u['cpu_share']:.1f} %",
                 u["calls"] or "") for u in d["units"]]
        out.append(table(rows, ("part", "wall", "share", "CPU share", "calls")))
    if "scaling" in results:
        out.append("")
        out.append("3. Scaling (each point in a fresh process; time = median run_pass wall / CPU time; peak RSS = VmHWM,")
        out.append("   the kernel high-water mark behind ru_maxrss, reset after imports, warm-up and scene building; RSS growth")
        out.append("   = peak RSS - RSS before the runs; traced peak = tracemalloc peak (Python + numpy buffers) of one run)")
        sc = results["scaling"]
        labels = {"triangles": "triangles (random small moving defocused, back to front, {w}x{h}, {spp} spp)",
                  "pixels": "pixels (default scene, {spp} spp)", "spp": "spp (default scene, {w}x{h})"}
        for name, s in sc.items():
            pts = s["points"]
            p0 = pts[0]
            out.append("  " + labels[name].format(w=p0.get("width"), h=p0.get("height"), spp=p0.get("spp")))
            rows = []
            for pt in pts:
                xlab = {"triangles": f"{pt['x']:,}", "pixels": f"{pt['width']}x{pt['height']}", "spp": f"{pt['x']}"}[name]
                if "error" in pt:
                    rows.append((xlab, "error", "", "", "", "", "", str(pt["error"])[:60]))
                    continue
                rows.append((xlab, f"{pt['median_s']:.3f} s", f"{pt['cpu_median_s']:.3f} s",
                             f"{pt['rss_peak_mb']:.0f} MB", f"{pt['rss_growth_mb']:.0f} MB",
                             f"{pt['traced_peak_mb']:.1f} MB", f"{pt['samples_tested']:,}",
                             f"{1e9 * pt['median_s'] / max(1, pt['samples_tested']):.0f} ns"))
                add(f"scaling_{name}", f"time_s@{xlab}", pt["median_s"], "s")
                add(f"scaling_{name}", f"cpu_s@{xlab}", pt["cpu_median_s"], "s")
                add(f"scaling_{name}", f"rss_peak_mb@{xlab}", pt["rss_peak_mb"], "MB")
                add(f"scaling_{name}", f"traced_peak_mb@{xlab}", pt["traced_peak_mb"], "MB")
            out.append(table(rows, (name, "time", "CPU", "peak RSS", "RSS growth", "traced peak", "samples tested",
                                    "time/test")))
            ok = 0.9 <= s["slope_time"] <= 1.1
            out.append(f"  log-log slope over {s['range']:.0f}x: time {s['slope_time']:.2f} "
                       f"({'within' if ok else 'OUTSIDE'} the 0.9-1.1 target) (CPU {s['slope_cpu_time']:.2f}), "
                       f"traced peak {s['slope_traced_peak']:.2f}, RSS growth {s['slope_rss_growth']:.2f}, "
                       f"samples tested {s['slope_samples_tested']:.2f}")
            fit = s.get("fit")
            if fit:
                out.append(f"  affine fit time = fixed + c x: fixed {fit['fixed_s']:.3f} s "
                           f"({100 * fit['fixed_share']:.0f}% of the smallest point's time); "
                           f"log-log slope of time - fixed: {fit['slope_marginal']:.2f}")
                add(f"scaling_{name}", "fixed_s", fit["fixed_s"], "s", "affine fit intercept")
                add(f"scaling_{name}", "slope_marginal", fit["slope_marginal"], "log-log", "time - fixed")
            out.append("")
            add(f"scaling_{name}", "slope_time", s["slope_time"], "log-log")
            add(f"scaling_{name}", "slope_cpu_time", s["slope_cpu_time"], "log-log")
            add(f"scaling_{name}", "slope_traced_peak", s["slope_traced_peak"], "log-log")
            add(f"scaling_{name}", "slope_rss_growth", s["slope_rss_growth"], "log-log")
            add(f"scaling_{name}", "slope_samples_tested", s["slope_samples_tested"], "log-log")

    if "compile" in results:
        cp = results["compile"]
        out.append("4. First-run compile time of pipeline_sim.jit.warm_up() (fresh processes, temporary NUMBA_CACHE_DIR)")
        rows = []
        for key, label in (("cold", "cold (empty cache, compiles)"), ("cached", "second process (cache load)")):
            r = cp[key]
            if "error" in r:
                rows.append((label, "error", str(r["error"])[:60], "", ""))
            else:
                rows.append((label, f"{r['warm_up_s']:.2f} s", f"{r['import_s']:.2f} s", f"{r['process_wall_s']:.2f} s",
                             f"{r['peak_rss_mb']:.0f} MB"))
                add("compile", f"warm_up_{key}", r["warm_up_s"], "s")
                add("compile", f"process_wall_{key}", r["process_wall_s"], "s")
        out.append(table(rows, ("run", "warm_up()", "imports", "whole process", "peak RSS")))
        if "error" not in cp["cold"] and "error" not in cp["cached"]:
            out.append(f"  cold / cached warm_up: {cp['cold']['warm_up_s'] / max(1e-9, cp['cached']['warm_up_s']):.0f}x; "
                       f"{cp['cache_files']} cache files written")
        out.append("")
    if "tester" in results:
        from benchmarks import tester_speed
        tr = results["tester"]
        out.append("9. The sample tester against a bare micro-kernel of the same dimension on exactly the samples it "
                   "tests (benchmarks/tester_speed.py; issue 3 target: tester/micro >= 0.5)")
        out.extend("  " + line for line in tester_speed.format_table(tr).splitlines())
        out.append("")
        for name, r in list(tr["dims"].items()) + [("all", tr["all"])]:
            add("tester", f"tester_over_micro@{name}", r["ratio"], "ratio")
            add("tester", f"tester_over_brute_force@{name}", r["ratio_brute"], "ratio",
                "tile samples per second: the tester vs the micro-kernel on every sample of each record's tile")
            add("tester", f"tester_rate@{name}", r["tester_rate"], "tests/s")
    from benchmarks import ab, batching, convergence, frame, patterns, specialization
    for key, mod in (("specialization", specialization), ("batch", batching), ("frame", frame),
                     ("patterns", patterns), ("ab", ab), ("convergence", convergence)):
        if key in results:
            out.extend(mod.report(results[key], table, add))
            out.append("")
    if "per_sample" in results:
        ps = results["per_sample"]
        n_plain = results["config"]["per_sample"]["plain"]
        out.append(f"12. Cost per sample: the default scene at {ps['width']}x{ps['height']}, {ps['spp']} spp "
                   f"({ps['samples']:,} samples; issue 19 goal: under 50 ns a sample)")
        out.append(f"   {ps['ns_per_sample']:.1f} ns a sample wall ({ps['ns_per_sample_cpu']:.1f} CPU) as shipped; "
                   f"on one thread {ps['one_thread_ns_per_sample']:.1f} ns ({ps['one_thread_s']:.2f} s a pass), with "
                   f"the tile test, the sample tester, shading and the ROP up to {ps['run_ahead_depth']} batches ahead on "
                   f"threads of their own (simulation.run_ahead) {ps['run_ahead_ns_per_sample']:.1f} ns "
                   f"({ps['run_ahead_s']:.2f} s); "
                   f"medians of {n_plain} plain runs each, alternately (the runs as shipped "
                   f"{ps['run_ahead_ns_per_sample_range'][0]:.1f} to {ps['run_ahead_ns_per_sample_range'][1]:.1f} ns, "
                   f"on one thread {ps['one_thread_ns_per_sample_range'][0]:.1f} to "
                   f"{ps['one_thread_ns_per_sample_range'][1]:.1f} ns)")
        bare, copy = ps["bare_test_ns"], ps["copy_gb_per_s"]
        out.append(f"   the machine meanwhile, measured after each round of plain runs: a bare float32 5D inside test "
                   f"{np.median(bare):.2f} ns ({min(bare):.2f} to {max(bare):.2f}; benchmarks/microkernel.py, one "
                   f"core), a copy of 64 MiB {np.median(copy):.1f} GB/s read + written ({min(copy):.1f} to {max(copy):.1f}); as shipped "
                   f"the pass costs {ps['bare_tests_per_sample']:.0f} bare tests a sample")
        out.append(f"   where the work goes, one thread, median of {results['config']['instrumented']} instrumented "
                   f"runs: {ps['instrumented_ns_per_sample']:.1f} ns a sample wall "
                   f"({ps['instrumented_ns_per_sample_cpu']:.1f} CPU); the tester "
                   f"{ps['tester_ns_per_tested_sample']:.2f} ns per tested sample including its outputs "
                   f"({ps['samples_tested']:,} tested)")
        out.append(table([(u["part"], f"{u['ns_per_sample']:.2f}", f"{100 * u['share']:.1f} %") for u in ps["units"]],
                         ("part", "ns / sample", "share")))
        sim_thread = ps["simulation_thread"]
        if sim_thread["cpu_s"] is not None:
            out.append(f"   the main thread as shipped, medians of {results['config']['instrumented']} run-ahead runs "
                       f"with it timed: {sim_thread['cpu_s']:.2f} s of CPU over the pass; per unit, the steps the "
                       "simulation took from the unit's run-ahead thread and its wait for them, and the steps it ran "
                       "itself (not worth handing over, a unit's first, a screen region's first)")
            out.append(table([(name, f"{w['taken']:.0f}", f"{w['waited_s']:.3f} s", f"{w['own']:.0f}",
                               f"{w['own_s']:.3f} s") for name, w in sim_thread["units"].items()],
                             ("unit", "taken", "waited", "own steps", "their time")))
        out.append("")
        add("per_sample", "ns_per_sample", ps["ns_per_sample"], "ns", f"default scene, {ps['spp']} spp, wall")
        add("per_sample", "ns_per_sample_cpu", ps["ns_per_sample_cpu"], "ns", "CPU")
        add("per_sample", "one_thread_ns_per_sample", ps["one_thread_ns_per_sample"], "ns",
            "simulation.run_ahead = 0, wall")
        add("per_sample", "run_ahead_ns_per_sample", ps["run_ahead_ns_per_sample"], "ns",
            f"simulation.run_ahead = {ps['run_ahead_depth']}, wall")
        for bound, value in zip(("min", "max"), ps["run_ahead_ns_per_sample_range"]):
            add("per_sample", f"run_ahead_ns_per_sample_{bound}", value, "ns", f"the {bound} of the plain runs")
        add("per_sample", "bare_test_ns", float(np.median(ps["bare_test_ns"])), "ns",
            "one bare float32 5D inside test, one core, median over the rounds of plain runs")
        add("per_sample", "copy_gb_per_s", float(np.median(ps["copy_gb_per_s"])), "GB/s",
            "a copy of 64 MiB, bytes read plus written, median over the rounds")
        add("per_sample", "bare_tests_per_sample", ps["bare_tests_per_sample"], "",
            "ns_per_sample over bare_test_ns, measured in the same rounds")
        add("per_sample", "instrumented_ns_per_sample", ps["instrumented_ns_per_sample"], "ns",
            "one thread, every unit timed, wall")
        add("per_sample", "tester_ns_per_tested_sample", ps["tester_ns_per_tested_sample"], "ns",
            "the sample tester's run, outputs included")
        for u in ps["units"]:
            add("per_sample", f"ns_per_sample@{u['part']}", u["ns_per_sample"], "ns")
        if sim_thread["cpu_s"] is not None:
            add("per_sample", "main_thread_cpu_s", sim_thread["cpu_s"], "s", "as shipped, the main thread over the pass")
        for name, w in sim_thread["units"].items():
            add("per_sample", f"simulation_waited_s@{name}", w["waited_s"], "s",
                "as shipped: the simulation's thread waiting for the unit's run-ahead steps")
            add("per_sample", f"simulation_own_steps_s@{name}", w["own_s"], "s",
                "as shipped: the unit's steps run on the simulation's thread")
    out.append(f"total benchmark time {results['elapsed_s']:.0f} s"
               + (f" (sections: {', '.join(results['sections'])})" if results["sections"] != list(SECTIONS) else ""))
    return "\n".join(out), rows_csv


def to_jsonable(o):
    """Plain JSON values; a float with no finite value is null (strict JSON has no NaN)."""
    if isinstance(o, dict):
        return {str(k): to_jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [to_jsonable(v) for v in o]
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="bench-results", help="folder for results.json / *.csv (created)")
    ap.add_argument("--quick", action="store_true", help="about 2 minutes: fewer repeats, smaller sweeps")
    ap.add_argument("--only", metavar="SECTION[,SECTION]",
                    help=f"run only these sections ({', '.join(SECTIONS)}); default: all")
    ap.add_argument("--frame-triangles", metavar="N[,N]",
                    help="triangle counts of the frame section, tried in order (default 250000,1000000; quick 4000)")
    args = ap.parse_args(argv)
    keep_freed_memory()  # as the command line does
    cfg = json.loads(json.dumps(QUICK if args.quick else FULL))  # a copy
    sections = list(SECTIONS)
    if args.only:
        sections = [x.strip() for x in args.only.split(",") if x.strip()]
        bad = [x for x in sections if x not in SECTIONS]
        if bad:
            ap.error(f"--only: unknown section(s) {', '.join(bad)}; known: {', '.join(SECTIONS)}")
        sections = [x for x in SECTIONS if x in sections]
    if args.frame_triangles:
        cfg["frame"]["n"] = [int(x.replace("_", "")) for x in args.frame_triangles.split(",")]
    start = time.perf_counter()
    outdir = Path(args.out).resolve()
    os.chdir(ROOT)
    outdir.mkdir(parents=True, exist_ok=True)

    results: dict = {"mode": "quick" if args.quick else "full",
                     "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
                     "config": cfg, "sections": sections, "source_digest_start": source_digest()}
    results["machine"] = machine_info()
    results["packages"] = package_versions()

    # compile (or load) every kernel in this process first, so the cache is
    # written before any subprocess reads it
    log("warm-up in this process")
    from pipeline_sim.jit import warm_up
    results["parent_warm_up_s"] = warm_up()

    if "default" in sections:
        results["default"] = bench_default(cfg)
    if "tester" in sections:
        from benchmarks import tester_speed
        log("sample tester against same-dimension micro-kernels on the same tests")
        results["tester"] = tester_speed.measure(repeats=cfg["micro_repeats"], log=log)
    if "scaling" in sections:
        results["scaling"] = bench_scaling(cfg)
    if "compile" in sections:
        results["compile"] = bench_compile()
    if "specialization" in sections:
        from benchmarks import specialization
        results["specialization"] = specialization.bench(cfg, log)
    if "batch" in sections:
        from benchmarks import batching
        results["batch"] = batching.bench(cfg, log)
    if "frame" in sections:
        from benchmarks import frame
        results["frame"] = frame.bench(cfg, log)
    if "patterns" in sections:
        from benchmarks import patterns
        results["patterns"] = patterns.bench(cfg, log)
    if "ab" in sections:
        from benchmarks import ab
        results["ab"] = ab.bench(cfg, log)
    if "convergence" in sections:
        from benchmarks import convergence
        results["convergence"] = convergence.bench(cfg, log)
    if "per_sample" in sections:
        results["per_sample"] = bench_per_sample(cfg)
    results["machine"]["load_average_end"] = os.getloadavg()
    results["source_digest_end"] = source_digest()
    results["elapsed_s"] = time.perf_counter() - start

    text, rows = report(results)
    print(text)
    (outdir / "results.json").write_text(json.dumps(to_jsonable(results), indent=2, allow_nan=False))
    with open(outdir / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["section", "metric", "value", "unit", "note"])
        w.writeheader()
        w.writerows(rows)
    written = ["results.json", "results.csv"]
    if "default" in results:
        with open(outdir / "units.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["part", "seconds", "share", "cpu_seconds", "cpu_share", "calls"])
            w.writeheader()
            w.writerows(results["default"]["units"])
        written.append("units.csv")
    if "per_sample" in results:
        with open(outdir / "per_sample.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["part", "seconds", "share", "cpu_seconds", "cpu_share", "calls",
                                              "ns_per_sample"])
            w.writeheader()
            w.writerows(results["per_sample"]["units"])
        written.append("per_sample.csv")
    if "scaling" in results:
        with open(outdir / "scaling.csv", "w", newline="") as f:
            fields = ["sweep", "x", "kind", "n", "triangles", "width", "height", "spp", "repeats", "median_s",
                      "cpu_median_s", "rss_baseline_mb", "peak_reset", "rss_peak_mb", "rss_growth_mb", "traced_peak_mb",
                      "samples_tested", "samples_covered", "frame_cycles", "process_wall_s", "error"]
            w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
            w.writeheader()
            for name, s in results["scaling"].items():
                for pt in s["points"]:
                    w.writerow({"sweep": name, **pt})
        written.append("scaling.csv")
    from benchmarks import convergence
    tables = {
        "specialization": ("specialization.csv", lambda r: r["rows"],
                           ["scene", "dims", "specialize", "has_motion", "has_lens", "triangles", "samples_tested",
                            "samples_covered", "tests_by_path", "madd_per_test", "mul_per_test", "test_madd_per_test",
                            "test_mul_per_test", "specialized_madd_per_test", "specialized_mul_per_test",
                            "lens_madd_charged", "lerp_madd_charged", "frame_cycles", "wall_s", "cpu_s", "samples_visited", "kernel_s",
                            "kernel_ns_per_test", "kernel_ns_per_visited", "kernel_visited_over_static",
                            "tested_over_static", "cycles_over_static", "wall_over_static", "cpu_over_static",
                            "kernel_ns_over_static"]),
        "batch": ("batch.csv", lambda r: r["rows"],
                  ["sweep", "triangles", "tiles", "samples", "frame_cycles", "cycles_vs_smallest", "cycles_vs_previous",
                   "cycles_vs_all_smallest", "cycles_deterministic", "wall_s", "cpu_s", "image_identical",
                   "depth_identical", "samples_tested", "zcull_records_out", "zcull_tiles_culled", "source_batches"]),
        "convergence": ("convergence.csv", lambda r: convergence.csv_rows(r),
                        ["scene", "pattern", "spp", "rmse", "wall_s", "slope", "reference_error"]),
        "ab": ("ab.csv", lambda r: r["rows"],
               ["tree", "wall_median_s", "cpu_median_s", "current_over_this_wall", "current_over_this_cpu", "runs",
                "frame_cycles", "same_image", "same_counters"]),
        "frame": ("frame.csv", lambda r: r["points"],
                  ["n", "width", "height", "spp", "status", "reason", "triangles", "build_s", "run_s", "run_cpu_s",
                   "frame_cycles", "samples_tested", "samples_covered", "rss_after_warm_up_mb", "build_peak_mb",
                   "rss_before_run_mb", "run_peak_mb", "whole_peak_mb", "rss_after_run_mb", "samples_rss_growth_mb",
                   "rop_rss_growth_mb", "make_samples_s", "progress_triangles", "progress_elapsed_s",
                   "process_wall_s", "time_limit_s", "mem_limit_gib"]),
    }
    for key, (fname, get_rows, fields) in tables.items():
        if key in results:
            with open(outdir / fname, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
                w.writeheader()
                for row in get_rows(results[key]):
                    w.writerow(to_jsonable(row))
            written.append(fname)
    print(f"results written to {outdir}/ ({', '.join(written)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
