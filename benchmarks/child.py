"""Subprocess entry points, so each measurement starts from a fresh process.

    python -m benchmarks.child point '<json spec>'   one scaling point
    python -m benchmarks.child compile                time warm_up() (set NUMBA_CACHE_DIR first)
    python -m benchmarks.child frame '<json spec>'    one 1080p frame under time / memory limits
                                                      (benchmarks/frame.py)

Each prints one JSON object as its last line of output.
"""

from __future__ import annotations

import json
import resource
import sys
import time

from pipeline_sim.memory import keep_freed_memory


def _maxrss_mb() -> float:
    # Linux reports ru_maxrss in kilobytes
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _status_mb(field: str) -> float:
    try:
        for line in open("/proc/self/status"):
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def _peak_mb() -> float:
    """Peak RSS of this process: VmHWM, the high-water mark ru_maxrss is made of.

    ru_maxrss itself is not used for the figure: after fork + exec it starts
    at the parent's RSS (Linux keeps the larger of the two), so a child of a
    large benchmark process reports the parent's size."""
    v = _status_mb("VmHWM")
    return v if v == v else _maxrss_mb()


def _reset_peak() -> bool:
    """Reset the peak RSS to the current RSS (Linux >= 4.0), so that ru_maxrss
    afterwards measures the runs, not importing numba or compiling kernels."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def compile_point() -> dict:
    t0 = time.perf_counter()
    import pipeline_sim.jit as jit
    from pipeline_sim import render  # noqa: F401  (the imports warm_up makes, timed apart)
    t1 = time.perf_counter()
    warm = jit.warm_up()
    t2 = time.perf_counter()
    return {"import_s": t1 - t0, "warm_up_s": warm, "warm_up_outer_s": t2 - t1, "peak_rss_mb": _peak_mb(),
            "ru_maxrss_mb": _maxrss_mb()}


def scaling_point(spec: dict) -> dict:
    import tracemalloc

    import numpy as np

    from benchmarks.workloads import default_pass, random_triangles_pass
    from pipeline_sim.jit import warm_up
    from pipeline_sim.render import run_pass

    warm_up()
    if spec["kind"] == "tris":
        p = random_triangles_pass(spec["n"], spec["width"], spec["height"], spec["spp"],
                                  back_to_front=spec.get("back_to_front", False))
    else:
        p = default_pass(spec["width"], spec["height"], spec["spp"])
    import gc
    gc.collect()
    peak_reset = _reset_peak()
    rss_base = _status_mb("VmRSS") if peak_reset else _peak_mb()
    times, cpu = [], []
    res = None
    for _ in range(spec["repeats"]):
        t0 = time.perf_counter()
        c0 = time.process_time()
        res = run_pass(p)
        cpu.append(time.process_time() - c0)
        times.append(time.perf_counter() - t0)
        del res.samples  # keep only what the report needs between repeats
    rss_peak = _peak_mb()
    ru_maxrss = _maxrss_mb()
    # one more run under tracemalloc: peak of Python and numpy allocations
    # (numpy registers its buffers with tracemalloc; arrays allocated inside
    # numba kernels are not seen)
    tracemalloc.start()
    res = run_pass(p)
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        **spec,
        "triangles": p.draw.n, "pixels": p.draw.width * p.draw.height,
        "times_s": times, "median_s": float(np.median(times)),
        "cpu_times_s": cpu, "cpu_median_s": float(np.median(cpu)), "ru_maxrss_mb": ru_maxrss,
        "rss_baseline_mb": rss_base, "peak_reset": peak_reset, "rss_peak_mb": rss_peak, "rss_growth_mb": rss_peak - rss_base,
        "traced_peak_mb": traced_peak / 2**20,
        "samples_tested": res.counter("sample_tester", "samples_tested"),
        "samples_covered": res.counter("sample_tester", "samples_covered"),
        "frame_cycles": res.timing.frame_cycles,
    }


def main(argv: list[str]) -> None:
    keep_freed_memory()  # as the command line does
    if argv[0] == "compile":
        out = compile_point()
    elif argv[0] == "point":
        out = scaling_point(json.loads(argv[1]))
    elif argv[0] == "frame":
        from benchmarks.frame import frame_point
        out = frame_point(json.loads(argv[1]))
    else:
        raise SystemExit(f"unknown command {argv[0]!r}")
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
