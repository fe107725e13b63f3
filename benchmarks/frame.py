"""Section 7: one 1080p frame of about a million small moving, defocused triangles.

Each size runs in a fresh process (``python -m benchmarks.child frame
'<json>'``) under limits set by the child itself: a wall-time alarm
(``signal.alarm``; the parent kills the process ``KILL_GRACE_S`` later as a
backstop) and an address-space limit (``resource.setrlimit(RLIMIT_AS)``), so
a frame that is too slow or too large stops with a report of why and how far
it got (triangles set up so far, from ``run_pass``'s progress callback)
instead of taking the machine down. Sizes are tried smallest first; once one
fails the larger ones are not attempted.

The scene is ``benchmarks.workloads.random_triangles_pass``: triangles with
vertices within 4 pixels of a random centre, each moving up to 8 pixels over
the shutter and defocused by a circle of confusion of up to 3 pixels.

Reported per size: the wall and CPU time of building the draw and of
``run_pass`` (one run: it is minutes long), the frame cycles, samples tested,
where the pass spent its time (unit ``run`` calls wrapped with timers; a few
microseconds per batch), and memory: peak RSS (VmHWM) of the whole process,
of the build and of the run (the mark is reset after the build, as in the
scaling section), the RSS growth measured across sample generation and the
ROP's buffer allocation, and an estimate of how the run's memory divides,
from array sizes: the sample arrays (x, y, u, v, t float32 per sample) and
the sample tester's tile-major copy, the multisample buffers (depth
float32 + RGBA float32 per sample), all of one screen region at a time
(``simulation.region_samples``), the resolved image, the per-triangle tables
(the draw and triangle setup's table) and the resolve's temporaries.
"""

from __future__ import annotations

import json
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
KILL_GRACE_S = 60
MB = 2.0 ** 20
SUMMED = ("sample_arrays", "tester_layout", "multisample_buffers", "image", "per_triangle_tables",
          "resolve_temporaries", "zcull")


# ---------------------------------------------------------------------------
# child side


class FrameTimeout(Exception):
    pass


def _status_mb(field: str) -> float:
    try:
        for line in open("/proc/self/status"):
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def estimate_bytes(draw, width: int, height: int, spp: int, tile_size: int, zcull_boxes: int,
                   region_rows: int, sets_kept: int) -> dict:
    """How the run's memory divides, from array sizes (bytes). Samples and
    multisample buffers exist for one screen region of ``region_rows`` rows at
    a time (the sample sets of up to ``sets_kept`` regions are cached)."""
    from pipeline_sim.records import TRIANGLE

    n = width * min(region_rows, height) * spp  # samples of one region
    table_per_tri = sum(a.nbytes for a in TRIANGLE.table(1))
    draw_bytes = sum(getattr(draw, f).nbytes for f in ("q", "r", "lens_x", "lens_y", "pos", "nrm", "color",
                                                       "material", "object_id"))
    tiles = -(-width // tile_size) * -(-height // tile_size)
    return {
        "sample_arrays": 5 * 4 * n * sets_kept,  # x, y, u, v, t float32 of the cached regions
        "tester_layout": 5 * 4 * n,  # the sample tester's tile-major copy of its region
        "multisample_buffers": (4 + 16) * n,  # depth float32 + RGBA float32 of the ROP's region
        "image": width * height * 4 * 4,  # resolved float32 RGBA
        "draw": draw_bytes,
        "triangle_table": table_per_tri * draw.n,
        "per_triangle_tables": draw_bytes + table_per_tri * draw.n,
        "table_bytes_per_triangle": table_per_tri,
        "draw_bytes_per_triangle": draw_bytes / max(1, draw.n),
        "resolve_temporaries": width * height * 4 * 4,  # the copy of the image resolve() returns
        "zcull": tiles * (2 * 4 * zcull_boxes + 1 + 8) + n,  # zmin, zmax, refresh state; a box number a sample
    }


def frame_point(spec: dict) -> dict:
    """Build and run one frame under a time and address-space limit; never raises."""
    t_start = time.perf_counter()
    limit_s = int(spec["time_limit_s"])
    mem_bytes = int(spec["mem_limit_gib"] * 2 ** 30)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        mem_bytes = min(mem_bytes, hard)
    resource.setrlimit(resource.RLIMIT_AS, (mem_bytes, hard))

    def on_alarm(signum, frame):
        raise FrameTimeout(f"wall-time limit of {limit_s} s reached")

    signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(limit_s)
    out: dict = {**spec, "status": "running", "phase": "imports", "as_limit_gib": mem_bytes / 2 ** 30}
    prog = {"done": 0, "n": spec["n"], "t": 0.0}
    mem_marks: dict = {}
    try:
        import numpy as np

        from benchmarks import instrument as ins
        from benchmarks.workloads import random_triangles_pass
        from pipeline_sim import render
        from pipeline_sim.jit import warm_up
        from pipeline_sim.render import run_pass

        out["phase"] = "warm-up"
        warm_up()
        out["rss_after_warm_up_mb"] = _status_mb("VmRSS")
        out["peak_before_build_mb"] = _status_mb("VmHWM")

        out["phase"] = "build"
        c0, p0 = time.perf_counter(), time.process_time()
        p = random_triangles_pass(spec["n"], spec["width"], spec["height"], spec["spp"])
        out["build_s"] = time.perf_counter() - c0
        out["build_cpu_s"] = time.process_time() - p0
        import gc
        gc.collect()
        out["build_peak_mb"] = _status_mb("VmHWM")
        out["rss_before_run_mb"] = _status_mb("VmRSS")
        out["triangles"] = p.draw.n
        arch = p.arch

        # sample generation (once per screen region) and the ROP's buffers
        real_make, real_rop = render.make_samples, render.Rop
        mem_marks["make_samples_s"] = 0.0
        mem_marks["sample_sets_made"] = 0

        def make_samples(*a, **k):
            r0 = _status_mb("VmRSS")
            t0 = time.perf_counter()
            s = real_make(*a, **k)
            mem_marks["make_samples_s"] += time.perf_counter() - t0
            mem_marks["sample_sets_made"] += 1
            mem_marks["samples_rss_growth_mb"] = max(mem_marks.get("samples_rss_growth_mb", 0.0),
                                                     _status_mb("VmRSS") - r0)
            mem_marks["samples_nbytes_mb"] = sum(getattr(s, f).nbytes for f in "xyuvt") / MB
            return s

        def rop(*a, **k):
            r0 = _status_mb("VmRSS")
            obj = real_rop(*a, **k)
            mem_marks["rop_rss_growth_mb"] = _status_mb("VmRSS") - r0
            mem_marks["rop_nbytes_mb"] = (obj.depth.nbytes + obj.color.nbytes + obj.image.nbytes) / MB
            return obj

        def progress(done, n):
            prog["done"], prog["t"] = done, time.perf_counter() - t_start
            step = max(1, n // 20)
            if done % step < p.simulation.triangles_per_batch or done == n:
                print(json.dumps({"progress": done, "of": n, "elapsed_s": prog["t"],
                                  "rss_mb": _status_mb("VmRSS")}), file=sys.stderr, flush=True)

        out["phase"] = "run"
        out["peak_reset"] = _reset_peak()
        timers = ins.Timers()
        with ins.patched(render, "make_samples", make_samples), ins.patched(render, "Rop", rop), \
                ins.unit_timers(timers):
            c0, p0 = time.perf_counter(), time.process_time()
            res = run_pass(p, progress=progress)
            out["run_s"] = time.perf_counter() - c0
            out["run_cpu_s"] = time.process_time() - p0
        out["run_peak_mb"] = _status_mb("VmHWM")
        out["regions"] = res.region_info
        est = estimate_bytes(p.draw, spec["width"], spec["height"], spec["spp"], arch.tile_traverser.tile_size,
                             arch.zcull.time_slices * arch.zcull.lens_boxes ** 2, res.regions.rows,
                             min(3, res.regions.count))
        out["estimate_mb"] = {k: (v / MB if not k.endswith("per_triangle") else v) for k, v in est.items()}
        out["rss_after_run_mb"] = _status_mb("VmRSS")
        out["frame_cycles"] = res.timing.frame_cycles
        out["samples_tested"] = res.counter("sample_tester", "samples_tested")
        out["samples_covered"] = res.counter("sample_tester", "samples_covered")
        out["tile_records"] = res.counter("tile_traverser", "records_out")
        out["coverage"] = float(np.mean(np.any(res.image[..., :3] != np.asarray(res.image[0, 0, :3]), axis=2)))
        parts = {k: v for k, v in timers.seconds.items() if not k.startswith("step:")}
        out["parts_s"] = dict(sorted(parts.items(), key=lambda kv: -kv[1]))
        out["status"], out["phase"] = "ok", "done"
    except FrameTimeout as e:
        out["status"], out["reason"] = "timeout", str(e)
    except MemoryError as e:
        out["status"] = "memory"
        out["reason"] = f"MemoryError under the {mem_bytes / 2 ** 30:.1f} GiB address-space limit: {e}"[:300]
    except Exception as e:  # report, do not crash: the parent wants the JSON
        out["status"], out["reason"] = "error", f"{type(e).__name__}: {e}"[:300]
    finally:
        signal.alarm(0)
    out.update(mem_marks)
    out["progress_triangles"] = prog["done"]
    out["progress_elapsed_s"] = prog["t"]
    out["peak_mb"] = _status_mb("VmHWM")  # after a reset: the larger of build and run peaks is kept below
    out["whole_peak_mb"] = max(out.get("build_peak_mb", 0.0), out["peak_mb"])
    out["child_elapsed_s"] = time.perf_counter() - t_start
    return out


# ---------------------------------------------------------------------------
# parent side


def run_size(spec: dict, log) -> dict:
    t0 = time.perf_counter()
    timeout = spec["time_limit_s"] + KILL_GRACE_S
    try:
        proc = subprocess.run([sys.executable, "-m", "benchmarks.child", "frame", json.dumps(spec)], cwd=ROOT,
                              capture_output=True, text=True, timeout=timeout)
        stdout, stderr, rc = proc.stdout, proc.stderr, proc.returncode
    except subprocess.TimeoutExpired as e:
        stdout = e.stdout.decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
        stderr = e.stderr.decode() if isinstance(e.stderr, bytes) else (e.stderr or "")
        rc = None
    wall = time.perf_counter() - t0
    res = None
    for line in reversed(stdout.strip().splitlines()):
        try:
            res = json.loads(line)
            break
        except ValueError:
            continue
    last_prog = None
    for line in reversed(stderr.strip().splitlines()):
        if line.startswith('{"progress"'):
            try:
                last_prog = json.loads(line)
            except ValueError:
                pass
            break
    if res is None:
        tail = [ln for ln in stderr.strip().splitlines() if not ln.startswith('{"progress"')][-1:]
        res = {**spec, "status": "killed" if rc is None else "crashed",
               "reason": (f"killed by the parent after {timeout} s" if rc is None
                          else f"exit code {rc}: {' '.join(tail)[:200]}"),
               "progress_triangles": last_prog["progress"] if last_prog else 0,
               "progress_elapsed_s": last_prog["elapsed_s"] if last_prog else float("nan")}
    res["process_wall_s"] = wall
    return res


def bench(cfg: dict, log) -> dict:
    c = cfg["frame"]
    points = []
    failed = None
    for n in c["n"]:
        spec = {"n": n, "width": c["width"], "height": c["height"], "spp": c["spp"],
                "time_limit_s": c["time_limit_s"], "mem_limit_gib": c["mem_limit_gib"]}
        if failed is not None:
            points.append({**spec, "status": "not attempted", "reason": f"{failed:,} triangles did not finish"})
            continue
        log(f"frame: {n:,} triangles at {c['width']}x{c['height']}, {c['spp']} spp "
            f"(limits {c['time_limit_s']} s, {c['mem_limit_gib']} GiB)")
        r = run_size(spec, log)
        log(f"frame: {r['status']} in {r['process_wall_s']:.0f} s")
        points.append(r)
        if r["status"] != "ok":
            failed = n
    ok = [p for p in points if p["status"] == "ok"]
    return {"points": points, "largest_ok": max((p["n"] for p in ok), default=None), "config": c}


def report(f: dict, table, add) -> list[str]:
    c = f["config"]
    out = [f"7. The 1080p frame: random small moving, defocused triangles at {c['width']}x{c['height']}, {c['spp']} spp "
           f"(fresh process each; limits {c['time_limit_s']} s wall, {c['mem_limit_gib']} GiB address space)"]
    rows = []
    for p in f["points"]:
        if p["status"] != "ok":
            prog = p.get("progress_triangles")
            rows.append((f"{p['n']:,}", p["status"], "", "", "", "", "",
                         (p.get("reason", "") + (f" (during {p['phase']})" if p.get("phase") else "")
                          + (f"; {prog:,} triangles set up after {p.get('progress_elapsed_s', 0):.0f} s" if prog else "")
                          + (f"; peak RSS {p['whole_peak_mb']:.0f} MB" if p.get("whole_peak_mb") else ""))[:160]))
            add("frame", f"status@{p['n']}", p["status"], "", p.get("reason", ""))
            continue
        rows.append((f"{p['n']:,}", "ok", f"{p['run_s']:.1f} s", f"{p['run_cpu_s']:.1f} s", f"{p['build_s']:.1f} s",
                     f"{p['whole_peak_mb'] / 1024:.2f} GiB", f"{p['frame_cycles']:,.0f}",
                     f"{p['samples_tested']:,} tests, {1e9 * p['run_s'] / max(1, p['samples_tested']):.0f} ns/test, "
                     f"{1e6 * p['run_s'] / p['n']:.0f} us/triangle"))
        add("frame", f"run_s@{p['n']}", p["run_s"], "s", "one run_pass")
        add("frame", f"run_cpu_s@{p['n']}", p["run_cpu_s"], "s")
        add("frame", f"peak_rss_mb@{p['n']}", p["whole_peak_mb"], "MB", "VmHWM, max of build and run")
        add("frame", f"run_peak_rss_mb@{p['n']}", p["run_peak_mb"], "MB", "VmHWM reset after build")
        add("frame", f"frame_cycles@{p['n']}", p["frame_cycles"], "cycles")
        add("frame", f"samples_tested@{p['n']}", p["samples_tested"], "tests")
    out.append(table(rows, ("triangles", "status", "run_pass", "CPU", "build", "peak RSS", "frame cycles", "note")))
    out.append(f"  largest size that finished: {f['largest_ok']:,} triangles" if f["largest_ok"]
               else "  no size finished")
    for p in f["points"]:
        if p["status"] != "ok":
            continue
        e = p["estimate_mb"]
        out.append(f"  {p['n']:,} triangles, memory: RSS {p['rss_after_warm_up_mb']:.0f} MB after imports and warm-up, "
                   f"{p['rss_before_run_mb']:.0f} MB after the build (build peak {p['build_peak_mb']:.0f} MB), "
                   f"run peak {p['run_peak_mb']:.0f} MB, {p['rss_after_run_mb']:.0f} MB after the run")
        reg = p["regions"]
        out.append(f"  screen regions: {reg['count']} of {reg['rows']} rows; {reg['sample_sets_made']} sample sets "
                   f"made in {p.get('make_samples_s', float('nan')):.1f} s")
        rows = [
            ("sample arrays (5 x float32 per sample, regions cached)", f"{e['sample_arrays']:.0f} MB",
             f"largest RSS growth in one make_samples: {p.get('samples_rss_growth_mb', float('nan')):.0f} MB"),
            ("sample tester's tile-major copy of its region", f"{e['tester_layout']:.0f} MB", ""),
            ("multisample buffers of a region (depth + RGBA float32)", f"{e['multisample_buffers']:.0f} MB",
             f"RSS grew {p.get('rop_rss_growth_mb', float('nan')):.0f} MB creating the ROP (with the image)"),
            ("resolved image (RGBA float32)", f"{e['image']:.0f} MB", ""),
            ("per-triangle: draw", f"{e['draw']:.0f} MB", f"{e['draw_bytes_per_triangle']:.0f} B per triangle"),
            ("per-triangle: setup table", f"{e['triangle_table']:.0f} MB",
             f"{e['table_bytes_per_triangle']:.0f} B per triangle"),
            ("resolve temporaries", f"{e['resolve_temporaries']:.0f} MB", "the image copy resolve() returns"),
            ("z-cull tile boxes and per-sample box numbers", f"{e['zcull']:.1f} MB", ""),
            ("sum of the above", f"{sum(v for k, v in e.items() if k in SUMMED):.0f} MB",
             f"vs run peak - RSS after warm-up = {p['run_peak_mb'] - p['rss_after_warm_up_mb']:.0f} MB"),
        ]
        out.append(table(rows, ("estimated from array sizes", "size", "measured")))
        add("frame", f"regions@{p['n']}", reg["count"], "regions", f"{reg['rows']} rows each")
        for k in ("sample_arrays", "tester_layout", "multisample_buffers", "per_triangle_tables"):
            add("frame", f"estimate_mb_{k}@{p['n']}", e[k], "MB", "from array sizes")
        parts = p.get("parts_s", {})
        top = [(k, v) for k, v in parts.items() if k not in ("simulate",)][:6]
        out.append("  where run_pass went: " + ", ".join(f"{k} {v:.1f} s" for k, v in top)
                   + f" (SimPy simulate incl. units {parts.get('simulate', 0):.1f} s)")
    return out
