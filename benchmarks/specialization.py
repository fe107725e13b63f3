"""Section 5: what the optional dimensions (lens u, v; shutter t) cost when a scene does not use them.

The four example scenes static.toml (xy), motion.toml (xyt), defocus.toml
(xyuv) and default.toml (xyuvt) share one geometry (the same objects at the
same shutter-open pose; 2,732 triangles), so their passes differ only in the
dimensions that are live.

There is no configuration switch that disables a dimension. The static scene
is run as is: ``scene_pass`` builds its draw with ``build_draw``, and for a
static pinhole scene that draw already has no motion and no lens
(``draw.has_motion`` / ``draw.has_lens`` are reported), so ``run_pass``
generates 2D samples (t = 0.5, u = v = 0) and the sample tester takes its 2D
path (edge functions once per tile). "As is" and "dimensions disabled" are the
same run here. To show what the specialization saves, one more row runs the
same static geometry forced through the general 5D path: the draw's t=1
vertices get a depth drift of ``FORCE_DZ`` * w (x, y and w unchanged, so the
coverage is the same; only z/w moves by at most FORCE_DZ), which makes
``has_motion`` true, every triangle "moving" in the sample tester, the samples
3D and z-cull time-sliced. Its image is compared with the static one.

When the architecture has the switch ``pipeline.specialize`` (false: every
triangle is tested as 5D, z-cull keeps all its boxes), the static and motion
scenes are also run with it off, by configuration.

Per scene: samples tested (sample_tester/samples_tested), the arithmetic the
sample tester's counters charge per tested sample (madd, mul), the frame
cycles (simulated), the wall and CPU time of ``run_pass`` (median of repeats,
scenes interleaved) and the wall time of the sample tester's numba kernel per
tested sample and per visited sample (instrumented runs). The arithmetic is
given as the tester's counters charge it per tested sample (madd and mul
minus those of the covered samples' barycentrics and depth) next to what the
tester's cost model needs for the scene's dimensions: the per-dimension
constants of units/sample_tester.py when it has them (TEST_OPS_MADD as a
tuple 2D, xyt, xyuv, xyuvt), else derived from its single 5D figure by its
breakdown (9 vertex lerp + 6 lens + 9 edges + 6 edge functions + 2
orientation madd; 9 + 3 mul): no lerp without motion, no lens terms without a
lens, only the edge functions for a static pinhole triangle (its edges are
set up once per tile). The lens arithmetic charged to motion.toml is its
charged madd per test minus the xyt figure, times the tests.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

FORCE_DZ = 1e-6
SCENES = (("static", "static.toml"), ("motion", "motion.toml"), ("defocus", "defocus.toml"),
          ("default", "default.toml"))
FORCED = "static, forced 5D path"

# the breakdown behind a single (5D) TEST_OPS_MADD / TEST_OPS_MUL in units/sample_tester.py
MADD_PARTS = {"lerp": 9, "lens": 6, "edges": 9, "edge_functions": 6, "orientation": 2}
MUL_PARTS = {"edges": 9, "edge_functions": 3}
DIMS = ("xy", "xyt", "xyuv", "xyuvt")
PATH_EVENTS = ("tests_2d", "tests_3d_xyt", "tests_4d_xyuv", "tests_5d")


def dims(draw) -> str:
    return "xy" + ("uv" if draw.has_lens else "") + ("t" if draw.has_motion else "")


def specialized_ops(motion: bool, lens: bool) -> tuple[int, int]:
    """(madd, mul) per tested sample a tester specialized for these dimensions
    would need, by the counters' own breakdown."""
    if not motion and not lens:
        # static pinhole: edges once per tile, per sample only e_k = a x + b y + c
        return MADD_PARTS["edge_functions"], MUL_PARTS["edge_functions"]
    madd = sum(MADD_PARTS.values()) - (0 if motion else MADD_PARTS["lerp"]) - (0 if lens else MADD_PARTS["lens"])
    return madd, sum(MUL_PARTS.values())


def ops_model() -> tuple[dict[str, tuple[int, int]], str]:
    """(madd, mul) per tested sample by dimensions, and where the figures come from."""
    from units import sample_tester as st_mod

    m, u = st_mod.TEST_OPS_MADD, st_mod.TEST_OPS_MUL
    if isinstance(m, (tuple, list)):
        return {d: (int(m[i]), int(u[i])) for i, d in enumerate(DIMS)}, "the tester's per-dimension constants"
    derived = {d: specialized_ops("t" in d, "uv" in d) for d in DIMS}
    ok = sum(MADD_PARTS.values()) == m and sum(MUL_PARTS.values()) == u
    return derived, "derived from the tester's 5D constant" + ("" if ok else " (breakdown out of date!)")


def _lens_madd(paths: list[int], tested: int, model: dict) -> float:
    """madd charged for the lens terms: with per-path test counters, each xyuv test
    costs (xyuv - xy) more than a 2D one and each 5D test (xyuvt - xyt) more than
    an xyt one; without them every test is charged the 5D breakdown's 6 lens madd."""
    if any(paths):
        return (paths[2] * (model["xyuv"][0] - model["xy"][0]) + paths[3] * (model["xyuvt"][0] - model["xyt"][0]))
    return MADD_PARTS["lens"] * tested


def _lerp_madd(paths: list[int], tested: int, model: dict) -> float:
    """madd charged for the motion terms, as ``_lens_madd`` for t."""
    if any(paths):
        return (paths[1] * (model["xyt"][0] - model["xy"][0]) + paths[3] * (model["xyuvt"][0] - model["xyuv"][0]))
    return MADD_PARTS["lerp"] * tested


def specialize_switch() -> bool:
    from pipeline_sim.config import PipelineConfig

    return "specialize" in PipelineConfig.__dataclass_fields__


def forced_5d(p):
    """The same pass with a tiny depth drift over the shutter (x, y, w unchanged)."""
    d = p.draw
    r = d.r.copy()
    r[:, :, 2] += FORCE_DZ * r[:, :, 3]
    return dataclasses.replace(p, draw=dataclasses.replace(d, r=r))


def bench(cfg: dict, log) -> dict:
    from benchmarks import instrument as ins
    from benchmarks.workloads import ROOT, default_pass
    from pipeline_sim.render import run_pass
    from units import sample_tester as st_mod

    passes = {}
    for name, fname in SCENES:
        passes[name] = default_pass(scene_path=ROOT / "workloads" / "scenes" / fname)
    passes[FORCED] = forced_5d(passes["static"])
    if specialize_switch():
        for name in ("static", "motion"):
            arch = dataclasses.replace(passes[name].arch, pipeline=dataclasses.replace(passes[name].arch.pipeline,
                                                                                     specialize=False))
            passes[f"{name}, specialize=false"] = dataclasses.replace(passes[name], arch=arch)
    order = list(passes)
    reps = cfg["spec_repeats"]
    walls = {k: [] for k in order}
    cpus = {k: [] for k in order}
    results = {}
    log(f"specialization: {reps} interleaved repeats of {len(order)} passes")
    for i in range(reps):
        seq = order if i % 2 == 0 else order[::-1]
        for k in seq:
            c0, p0 = time.perf_counter(), time.process_time()
            res = run_pass(passes[k])
            walls[k].append(time.perf_counter() - c0)
            cpus[k].append(time.process_time() - p0)
            results[k] = res
    ireps = cfg["spec_instrumented"]
    log(f"specialization: {ireps} interleaved instrumented runs of each")
    kernel_runs = {k: [] for k in order}
    for i in range(ireps):
        for k in (order if i % 2 == 0 else order[::-1]):
            tm = ins.Timers()
            with ins.unit_timers(tm):
                run_pass(passes[k])
            kernel_runs[k].append(tm.seconds.get("sample_test_kernel", float("nan")))
    kernel_s = {k: float(np.median(v)) for k, v in kernel_runs.items()}

    ref = results["static"]
    model, model_source = ops_model()
    cover_madd, cover_mul = st_mod.COVER_OPS_MADD, st_mod.COVER_OPS_MUL
    rows = []
    for k in order:
        p, r = passes[k], results[k]
        tested = r.counter("sample_tester", "samples_tested")
        visited = r.counter("sample_tester", "pixels_visited") * p.spp
        covered = r.counter("sample_tester", "samples_covered")
        madd = r.counter("sample_tester", "madd")
        mul = r.counter("sample_tester", "mul")
        motion, lens = p.draw.has_motion, p.draw.has_lens
        smadd, smul = model[dims(p.draw)]
        test_madd = (madd - covered * cover_madd) / tested if tested else float("nan")
        test_mul = (mul - covered * cover_mul) / tested if tested else float("nan")
        paths = [r.counter("sample_tester", e) for e in PATH_EVENTS]
        row = {
            "scene": k, "dims": dims(p.draw) + (" (forced)" if k == FORCED else ""),
            "specialize": getattr(p.arch.pipeline, "specialize", None),
            "has_motion": motion, "has_lens": lens, "triangles": p.draw.n,
            "tests_by_path": paths if any(paths) else None,
            "test_madd_per_test": test_madd, "test_mul_per_test": test_mul,
            "samples_tested": tested, "samples_covered": covered, "samples_visited": visited,
            "madd_per_test": madd / tested if tested else float("nan"),
            "mul_per_test": mul / tested if tested else float("nan"),
            "lens_madd_charged": _lens_madd(paths, tested, model),
            "lerp_madd_charged": _lerp_madd(paths, tested, model),
            "specialized_madd_per_test": smadd, "specialized_mul_per_test": smul,
            "frame_cycles": r.timing.frame_cycles,
            "wall_s": float(np.median(walls[k])), "cpu_s": float(np.median(cpus[k])),
            "wall_times_s": walls[k], "cpu_times_s": cpus[k],
            "kernel_s": kernel_s[k], "kernel_times_s": kernel_runs[k],
            "kernel_ns_per_test": 1e9 * kernel_s[k] / tested if tested else float("nan"),
            "kernel_ns_per_visited": 1e9 * kernel_s[k] / visited if visited else float("nan"),
        }
        rows.append(row)
    by = {r["scene"]: r for r in rows}
    for row in rows:
        s = by["static"]
        row["wall_over_static"] = row["wall_s"] / s["wall_s"]
        row["cpu_over_static"] = row["cpu_s"] / s["cpu_s"]
        row["cycles_over_static"] = row["frame_cycles"] / s["frame_cycles"]
        row["tested_over_static"] = row["samples_tested"] / s["samples_tested"]
        row["kernel_ns_over_static"] = row["kernel_ns_per_test"] / s["kernel_ns_per_test"]
        row["kernel_visited_over_static"] = row["kernel_ns_per_visited"] / s["kernel_ns_per_visited"]
    forced = results[FORCED]
    diff = np.any(forced.image != ref.image, axis=2)
    return {
        "rows": rows, "repeats": reps, "instrumented": ireps, "force_dz": FORCE_DZ,
        "ops_model": model, "ops_model_source": model_source, "specialize_switch": specialize_switch(),
        "forced_image_identical": bool(not diff.any()),
        "forced_pixels_differing": int(diff.sum()),
        "forced_max_abs_diff": float(np.max(np.abs(forced.image - ref.image))),
        "forced_covered_identical": forced.counter("sample_tester", "samples_covered")
        == ref.counter("sample_tester", "samples_covered"),
        "same_geometry": len({r["triangles"] for r in rows}) == 1,
    }


def _mops(n: float) -> str:
    return f"{n / 1e6:,.1f} M"


def report(s: dict, table, add) -> list[str]:
    out = ["5. Specialization cost: the same geometry with 0, 1 or 2 optional dimensions live "
           f"(run_pass wall / CPU: median of {s['repeats']} interleaved runs; kernel: median of {s['instrumented']} "
           "instrumented runs; ratios to static in this run)"]
    rows = []
    for r in s["rows"]:
        paths = r["tests_by_path"]
        rows.append((r["scene"], r["dims"], f"{r['samples_tested']:,}",
                     " / ".join(f"{x / 1e6:.1f}" for x in paths) if paths else "n/a",
                     f"{r['test_madd_per_test']:.2f} / {r['test_mul_per_test']:.2f}",
                     f"{r['specialized_madd_per_test']} / {r['specialized_mul_per_test']}",
                     f"{r['frame_cycles']:,.0f}", f"{r['wall_s']:.3f} s", f"{r['cpu_s']:.3f} s",
                     f"{r['samples_visited']:,}", f"{r['kernel_ns_per_visited']:.1f} ns",
                     f"{r['tested_over_static']:.2f}", f"{r['cycles_over_static']:.2f}", f"{r['wall_over_static']:.2f}",
                     f"{r['cpu_over_static']:.2f}", f"{r['kernel_visited_over_static']:.2f}"))
        key = r["scene"].replace(", ", "_").replace(" ", "_").replace("=", "_")
        add("specialization", f"frame_cycles@{key}", r["frame_cycles"], "cycles", r["dims"])
        add("specialization", f"wall_s@{key}", r["wall_s"], "s", "median run_pass")
        add("specialization", f"cpu_s@{key}", r["cpu_s"], "s", "median run_pass")
        add("specialization", f"samples_tested@{key}", r["samples_tested"], "tests")
        add("specialization", f"test_madd_per_test@{key}", r["test_madd_per_test"], "ops",
            "sample_tester madd minus cover ops / samples_tested")
        add("specialization", f"test_mul_per_test@{key}", r["test_mul_per_test"], "ops",
            "sample_tester mul minus cover ops / samples_tested")
        add("specialization", f"kernel_ns_per_visited@{key}", r["kernel_ns_per_visited"], "ns",
            "kernel time / (pixels_visited x spp)")
        add("specialization", f"wall_over_static@{key}", r["wall_over_static"], "ratio")
        add("specialization", f"cycles_over_static@{key}", r["cycles_over_static"], "ratio")
    out.append(table(rows, ("scene", "dims", "samples tested", "tests 2D/xyt/xyuv/5D (M)",
                            "counted madd/mul per test", "model madd/mul at scene dims", "frame cycles", "wall", "CPU",
                            "samples visited", "kernel/visited", "tested/static", "cycles/static", "wall/static",
                            "CPU/static", "kernel/visited vs static")))
    out.append("  counted = the tester's madd / mul counters minus the covered samples' barycentrics and depth, per "
               f"tested sample; model = {s['ops_model_source']} for a triangle using all of the scene's dimensions; visited = every sample of every tile row the kernel "
               "loops over (pixels_visited x spp)")
    st = {r["scene"]: r for r in s["rows"]}
    out.append(f"  static.toml: build_draw gives has_motion={st['static']['has_motion']}, "
               f"has_lens={st['static']['has_lens']}, so the pipeline already runs it as 2D ('as is' = "
               "'dimensions disabled').")
    m = st["motion"]
    out.append(f"  motion.toml (no lens): lens arithmetic charged {_mops(m['lens_madd_charged'])} madd "
               f"({m['lens_madd_charged'] / max(1, m['samples_tested']):.1f} per tested sample)"
               + (f"; with specialize=false {_mops(st['motion, specialize=false']['lens_madd_charged'])}"
                  if "motion, specialize=false" in st else "")
               + f". defocus.toml (no motion): motion arithmetic charged {_mops(st['defocus']['lerp_madd_charged'])} madd."
               + (" (lens = the xyuv path's extra over 2D plus the 5D path's over xyt, from the per-path test counters)"
                  if m["tests_by_path"] else " (6 lens madd in every tested sample's 5D charge)"))
    fr = st[FORCED]
    out.append(f"  static forced through the 5D path (z drift {s['force_dz']:g} * w at t=1): kernel "
               f"{fr['kernel_ns_per_visited']:.1f} vs {st['static']['kernel_ns_per_visited']:.1f} ns per visited sample "
               f"({fr['kernel_visited_over_static']:.2f}x), run_pass {fr['wall_over_static']:.2f}x wall, "
               f"{fr['cpu_over_static']:.2f}x CPU, frame cycles "
               f"{fr['cycles_over_static']:.2f}x; image "
               + ("identical to static" if s["forced_image_identical"]
                  else f"differs from static in {s['forced_pixels_differing']} pixels (max {s['forced_max_abs_diff']:.3g})")
               + ("" if s["forced_covered_identical"] else "; covered samples differ"))
    if "static, specialize=false" in st:
        sf = st["static, specialize=false"]
        out.append(f"  static with pipeline.specialize=false: run_pass {sf['wall_over_static']:.2f}x wall, "
                   f"{sf['cpu_over_static']:.2f}x CPU, kernel {sf['kernel_visited_over_static']:.2f}x, frame cycles "
                   f"{sf['cycles_over_static']:.2f}x, {sf['test_madd_per_test']:.1f} madd per test "
                   f"(vs {st['static']['test_madd_per_test']:.1f} specialized)")
    elif not s["specialize_switch"]:
        out.append("  (no pipeline.specialize switch in this version: the forced row is the only unspecialized run)")
    add("specialization", "forced_5d_image_identical", int(s["forced_image_identical"]), "bool")
    add("specialization", "motion_lens_madd_charged", m["lens_madd_charged"], "ops", "charged madd - xyt model")
    return out
