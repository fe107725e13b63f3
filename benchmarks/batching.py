"""Section 6: batch size as an accuracy knob of the simulated timing.

The pipeline's functional results never depend on batching (every unit
processes its batches in order), but the SimPy cost model sees batches: a unit
is busy for a whole batch before the next stage can start on it, so large
batches serialize the stages (pipeline fill and drain per batch) and small
batches approach a record-by-record pipeline. The FIFOs between units are
sized in records (``queue_depth`` batches of the default size) and a batch
costs its exact fractional cycles, so the batch size changes only the
granularity: the frame-cycle estimate converges as batches shrink. On the
default workload the section sweeps

* ``simulation.tiles_per_batch`` together with ``simulation.samples_per_batch``
  (samples = 64 x tiles), triangles per batch at the default;
* ``simulation.triangles_per_batch``, tiles and samples per batch at the default;
* all three at their smallest at once;

and reports the frame cycles (simulated), the relative change of frame cycles
against the smallest setting of each sweep, the wall time of ``run_pass``
(median of repeats, settings interleaved) and whether the image and depth
buffer are bit-identical to the default configuration's (and which counters
differ: z-cull sees ROP refreshes at other moments when batches change).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np


def settings(cfg: dict) -> list[dict]:
    from pipeline_sim.simulation import SimOptions

    d = SimOptions()
    out = [{"sweep": "default", "triangles": d.triangles_per_batch, "tiles": d.tiles_per_batch,
            "samples": d.samples_per_batch}]
    for t in cfg["batch_tiles"]:
        out.append({"sweep": "tiles", "triangles": d.triangles_per_batch, "tiles": t, "samples": 64 * t})
    for n in cfg["batch_triangles"]:
        out.append({"sweep": "triangles", "triangles": n, "tiles": d.tiles_per_batch, "samples": d.samples_per_batch})
    t0 = min(cfg["batch_tiles"])
    out.append({"sweep": "all smallest", "triangles": min(cfg["batch_triangles"]), "tiles": t0, "samples": 64 * t0})
    return out


def bench(cfg: dict, log) -> dict:
    from benchmarks.workloads import default_pass
    from pipeline_sim.render import run_pass
    from pipeline_sim.simulation import SimOptions

    base = default_pass()
    pts = settings(cfg)
    passes = []
    for s in pts:
        sim = SimOptions(triangles_per_batch=s["triangles"], tiles_per_batch=s["tiles"],
                         samples_per_batch=s["samples"])
        passes.append(dataclasses.replace(base, simulation=sim))
    reps = cfg["batch_repeats"]
    walls = [[] for _ in pts]
    cpus = [[] for _ in pts]
    cycles = [[] for _ in pts]
    res = [None] * len(pts)
    log(f"batch sizes: {len(pts)} settings x {reps} interleaved repeats")
    for i in range(reps):
        idx = list(range(len(pts))) if i % 2 == 0 else list(range(len(pts)))[::-1]
        for j in idx:
            c0, p0 = time.perf_counter(), time.process_time()
            r = run_pass(passes[j])
            walls[j].append(time.perf_counter() - c0)
            cpus[j].append(time.process_time() - p0)
            cycles[j].append(r.timing.frame_cycles)
            if res[j] is None:
                res[j] = r
                res[j].samples = None  # not needed; keeps memory down
    ref = res[0]

    def counter_diffs(a, b):
        m = a.counters.merge(b.counters, on=["unit", "counter"], suffixes=("_a", "_b"))
        m = m[m.value_a != m.value_b]
        return [f"{r.unit}/{r.counter}: {r.value_b} vs {r.value_a}" for r in m.itertuples()]

    rows = []
    for s, r, w, c, cy in zip(pts, res, walls, cpus, cycles):
        rows.append({
            **s, "frame_cycles": cy[0], "cycles_deterministic": len(set(cy)) == 1,
            "wall_s": float(np.median(w)), "cpu_s": float(np.median(c)), "wall_times_s": w, "cpu_times_s": c,
            "image_identical": bool(np.array_equal(r.image, ref.image)),
            "depth_identical": bool(np.array_equal(r.depth, ref.depth)),
            "counter_diffs": counter_diffs(ref, r),
            "samples_tested": r.counter("sample_tester", "samples_tested"),
            "zcull_records_out": r.counter("zcull", "records_out"),
            "zcull_tiles_culled": r.counter("zcull", "tiles_culled"),
            "source_batches": -(-base.draw.n // s["triangles"]),
        })
    for sweep in ("tiles", "triangles"):
        sw = [r for r in rows if r["sweep"] == sweep]
        key = "tiles" if sweep == "tiles" else "triangles"
        smallest = min(sw, key=lambda r: r[key])
        prev = None
        for r in sorted(sw, key=lambda r: r[key]):
            r["cycles_vs_smallest"] = r["frame_cycles"] / smallest["frame_cycles"] - 1.0
            r["cycles_vs_previous"] = (r["frame_cycles"] / prev["frame_cycles"] - 1.0) if prev else float("nan")
            prev = r
    small = next(r for r in rows if r["sweep"] == "all smallest")
    for r in rows:
        r["cycles_vs_all_smallest"] = r["frame_cycles"] / small["frame_cycles"] - 1.0
        if "cycles_vs_smallest" not in r:
            r["cycles_vs_smallest"] = r["cycles_vs_all_smallest"]
            r["cycles_vs_previous"] = float("nan")
    return {"rows": rows, "repeats": reps, "triangles": base.draw.n,
            "all_images_identical": all(r["image_identical"] and r["depth_identical"] for r in rows)}


def report(b: dict, table, add) -> list[str]:
    out = [f"6. Batch size as an accuracy knob (default workload, {b['triangles']:,} triangles; wall = median of "
           f"{b['repeats']} interleaved runs; change = frame cycles relative to the smallest batch of the sweep)"]
    rows = []
    for r in b["rows"]:
        label = {"default": "default arch", "tiles": "tiles (+samples)", "triangles": "triangles",
                 "all smallest": "all smallest"}[r["sweep"]]
        diffs = r["counter_diffs"]
        rows.append((label, r["triangles"], r["tiles"], f"{r['samples']:,}", f"{r['frame_cycles']:,.0f}",
                     f"{100 * r['cycles_vs_smallest']:+.2f} %",
                     "" if r["cycles_vs_previous"] != r["cycles_vs_previous"] else f"{100 * r['cycles_vs_previous']:+.2f} %",
                     f"{r['samples_tested']:,}", f"{r['zcull_tiles_culled']:,}",
                     f"{r['wall_s']:.3f} s", f"{r['cpu_s']:.3f} s",
                     "yes" if r["image_identical"] and r["depth_identical"] else "NO",
                     f"{len(diffs)}" + (f" ({diffs[0].split(':')[0]}, ...)" if diffs else "")))
        key = f"{r['sweep'].replace(' ', '_')}@{r['triangles']}/{r['tiles']}/{r['samples']}"
        add("batch", f"frame_cycles@{key}", r["frame_cycles"], "cycles", "triangles/tiles/samples per batch")
        add("batch", f"cycles_vs_smallest@{key}", r["cycles_vs_smallest"], "ratio")
        add("batch", f"wall_s@{key}", r["wall_s"], "s")
        add("batch", f"identical_image@{key}", int(r["image_identical"] and r["depth_identical"]), "bool")
    out.append(table(rows, ("sweep", "tris/batch", "tiles/batch", "samples/batch", "frame cycles", "vs smallest",
                            "vs previous", "samples tested", "z-cull tiles culled", "wall", "CPU",
                            "image bit-identical", "counters differing")))
    out.append("  image and depth bit-identical at every batch size: "
               + ("yes" if b["all_images_identical"] else "NO"))
    nondet = [r for r in b["rows"] if not r["cycles_deterministic"]]
    if nondet:
        out.append(f"  NOTE: frame cycles changed between repeats at {len(nondet)} settings")
    ex = [r for r in b["rows"] if r["counter_diffs"]]
    if ex:
        out.append(f"  counters (this setting vs default arch), e.g. ({ex[0]['sweep']} {ex[0]['triangles']}/{ex[0]['tiles']}): "
                   + "; ".join(ex[0]["counter_diffs"][:3]))
    add("batch", "all_images_identical", int(b["all_images_identical"]), "bool")
    return out
