"""Comparing the culling algorithms on one workload, in the papers' own terms.

Runs a workload (a scene: its one pass) once per algorithm and tabulates what Wu13 and Munkberg11 compare:
tiles tested and rejected, samples tested and covered, sample test
efficiency (STE, Wu13 §1.1), arithmetic by stage (triangle setup, tile test,
sample test, interpolation setup; Munkberg11 §8 and Fig. 15), depth-buffer bytes,
shader executions, simulated cycles and wall time. Every culling algorithm
is conservative, so the covered samples, and therefore the images, must be
identical: the comparison checks it. Interleave UVT samples a different,
discrete set of (u, v, t); its image is checked against BBOX on that same
set (``bbox/interleave``) and its error against BBOX on the continuous
samples, or against a reference image, is reported.

The papers' own comparisons are checked where the algorithms they need are
in the run (``PAPER_CHECKS``); the figures are reported whatever they are.

Every algorithm is rendered with z-cull refreshed in submission order
(``zcull_refresh = "ordered"``, docs/pipeline.md §4): z-cull then sees, for
each triangle batch, the depth of every earlier one, whatever the queue
depths and throughputs, so algorithms are compared on equal footing, and a
faster tile test does not change what z-cull culls.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline_sim.config import ArchConfig
from pipeline_sim.definitions import ARITHMETIC
from pipeline_sim.errors import UserError, did_you_mean
from pipeline_sim.output_folder import OutputFolder

_HIER = "tile_test.algorithm='hierarchical'"
_INTERLEAVE = "pass.sample_pattern='interleave'"
# algorithm name -> its settings (hardware, and the pass state it needs); all are conservative
ALGORITHMS: dict[str, list[str]] = {
    "bbox": ["tile_test.algorithm='bbox'"],
    "hull": ["tile_test.algorithm='hull'"],
    "dual_space": ["tile_test.algorithm='dual_space'"],
    "two_stage": ["tile_test.algorithm='two_stage'"],
    "interleave_uvt": ["tile_test.algorithm='interleave_uvt'", _INTERLEAVE],
    "bbox/interleave": ["tile_test.algorithm='bbox'", _INTERLEAVE],
    "box": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=false", "tile_test.lens_bounds=false"],
    "box+edge": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=true", "tile_test.lens_bounds=false"],
    "box+edge/tile": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=true", "tile_test.gamma='tile'",
                      "tile_test.lens_bounds=false"],
    "box+lens": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=false", "tile_test.lens_bounds=true"],
    "box+quadratic": [_HIER, "tile_test.edge_test=true", "tile_test.edge_solver='quadratic'",
                      "tile_test.lens_bounds=false"],
    "hierarchical": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=true", "tile_test.lens_bounds=true"],
    "exact/pixel": [_HIER, "tile_test.edge_test=true", "tile_test.edge_solver='quadratic'",
                    "tile_test.lens_bounds=true", "tile_traverser.tile_size=1", "tile_traverser.coarse_factor=8"],
}
DESCRIPTIONS = {
    "bbox": "every sample in the moving, defocused bounds (Wu13/Munkberg11 baseline)",
    "box": "moving box vs tile frustum planes (Munkberg11 §4.1)",
    "box+edge": "moving box + linearized moving edges (Munkberg11 §4.1-4.2)",
    "box+edge/tile": "as box+edge, with the edge slope bound gamma recomputed per tile (Munkberg11 §4.2)",
    "box+lens": "moving box + lens intervals u^, v^",
    "hierarchical": "moving box + linearized edges + lens intervals (default)",
    "hull": "convex hull of the six projected vertices, motion only (McGuire10; Wu13 §3.2)",
    "dual_space": "lens bounds, then time bounds over the lens range (Laine11; Wu13 §2)",
    "two_stage": "lens bounds, then per-tile time bounds linear in u and v (Wu13 §3.3-3.4)",
    "interleave_uvt": "a fixed set of (u, v, t) tuples, one 2D raster each (Fatahalian09)",
    "bbox/interleave": "BBOX on Interleave UVT's discrete sample set (its image reference)",
    "box+quadratic": "moving box + the quadratic edge equations solved per tile (Munkberg11 §4.2; Gribel10 §4.1)",
    "exact/pixel": "hierarchical with exact quadratic time intervals per pixel (Gribel10 §4.1; 1x1 tiles)",
}
# the papers' comparisons: (name, claim, the scene's blur (motion, lens) it is
# about, algorithms needed, check(table) -> (measured text, met))
PAPER_CHECKS = (
    ("hierarchical_5x_bbox", "hierarchical tests reach >= 5x the STE of BBOX on motion blur (Munkberg11 §7)",
     (True, False), ("bbox", "hierarchical"),
     lambda t: _ratio_check(t.loc["hierarchical", "ste"], t.loc["bbox", "ste"], 5.0)),
    ("two_stage_beats_dual", "two-stage culling beats dual-space bounds in STE with both blurs "
     "(Wu13 Table 4.1: 19% vs 5%)", (True, True), ("dual_space", "two_stage"),
     lambda t: (f"{100 * t.loc['two_stage', 'ste']:.2f}% vs {100 * t.loc['dual_space', 'ste']:.2f}%",
                bool(t.loc["two_stage", "ste"] > t.loc["dual_space", "ste"]))),
    ("linearized_vs_quadratic", "the linearized edge test tests <= 10% more samples than the quadratic one "
     "and spends less arithmetic (Munkberg11 §7: +8% tests, -13% arithmetic)", (True, False),
     ("box+edge", "box+quadratic"),
     lambda t: _linear_vs_quadratic(t)),
)
STAGES = {  # Munkberg11 Fig. 15's stages and the units whose arithmetic they are
    "triangle_setup": ("triangle_setup",),
    "tile_test": ("tile_traverser", "tile_test"),
    "sample_test": ("sample_tester",),
    "interpolation_setup": ("shading",),
}


@dataclass
class Comparison:
    """The table (one row per algorithm), the images, and the identity check."""

    table: pd.DataFrame
    images: dict[str, np.ndarray]
    identical: bool
    differing: list[str]
    checks: list[dict]
    zcull_refresh: str = "ordered"


def _ratio_check(a: float, b: float, target: float) -> tuple[str, bool]:
    ratio = a / b if b else float("nan")
    return (f"{ratio:.2f}x" if np.isfinite(ratio) else "n/a (no sample tested)"), bool(ratio >= target)


def _linear_vs_quadratic(t: pd.DataFrame) -> tuple[str, bool]:
    lin, quad = t.loc["box+edge"], t.loc["box+quadratic"]
    more_tests = lin.samples_tested / max(quad.samples_tested, 1) - 1.0
    # Munkberg11 compares the total arithmetic of the four stages of its Fig. 15
    less_ops = 1.0 - lin.ops_total / max(quad.ops_total, 1)
    return (f"{100 * more_tests:+.1f}% tests, {-100 * less_ops:+.1f}% total arithmetic",
            bool(more_tests <= 0.10 and less_ops > 0))


def paper_checks(table: pd.DataFrame, dimensions: dict[str, bool]) -> list[dict]:
    """The papers' comparisons that this scene's blur and this run's algorithms
    allow, with measured figures."""
    t = table.set_index("algorithm")
    out = []
    for name, claim, blur, needs, check in PAPER_CHECKS:
        if (dimensions["motion"], dimensions["lens"]) == blur and all(n in t.index for n in needs):
            measured, met = check(t)
            out.append({"check": name, "claim": claim, "measured": measured, "met": met})
    return out


def parse_algorithms(names: list[str] | None) -> list[str]:
    """Validate algorithm names (default: all of them)."""
    if not names:
        return list(ALGORITHMS)
    for name in names:
        if name not in ALGORITHMS:
            raise UserError(f"--algorithms: unknown algorithm '{name}'{did_you_mean(name, ALGORITHMS)}; "
                            f"known: {', '.join(ALGORITHMS)}")
    return list(dict.fromkeys(names))


def _row(name: str, result) -> dict:
    c = result.counters
    get = result.counter
    row = {
        "algorithm": name,
        "tiles_tested": get("tile_test", "records_in"),
        "tiles_rejected": get("tile_test", "records_in") - get("tile_test", "records_out")
        + get("tile_traverser", "coarse_tiles_rejected"),
        "samples_tested": get("sample_tester", "samples_tested"),
        "samples_covered": get("sample_tester", "samples_covered"),
    }
    row["ste"] = row["samples_covered"] / row["samples_tested"] if row["samples_tested"] else float("nan")
    for stage, units in STAGES.items():
        row[f"ops_{stage}"] = int(c[c.unit.isin(units) & c.counter.isin(ARITHMETIC)].value.sum())
    row["ops_total"] = sum(row[f"ops_{s}"] for s in STAGES)
    row["depth_bytes"] = get("rop", "bytes_read") + get("rop", "bytes_written")
    row["shader_executions"] = get("shading", "shader_executions")
    row["frame_cycles"] = result.timing.frame_cycles
    row["wall_time_s"] = result.wall_time
    return row


def compare(workload, arch: ArchConfig, algorithms: list[str], progress=None,
            reference: np.ndarray | None = None, zcull_refresh: str = "ordered") -> Comparison:
    """Run ``workload`` (a :class:`~pipeline_sim.workload.Workload`, or a scene: its one standard
    pass) with each algorithm; tabulate and check the images are identical.

    A culling algorithm may change only settings declared not to change
    the image (``counters``, ``cycles``) and those declared to trade
    accuracy (the sample set); algorithms whose ``accuracy`` settings agree
    must give the same images, every pass's: those on the continuous samples
    the first one's, those on Interleave UVT's discrete sample set the first
    of theirs. A row holds the workload's totals over its passes; its image
    error (RMSE, PSNR) is the final pass's image measured against
    ``reference`` if given, else against the first final image whose accuracy
    settings are those of ``arch`` itself, else the first one.
    ``zcull_refresh``: when z-cull sees the ROP's refreshes, set on every pass
    (``pipeline_sim.render.ZCULL_REFRESH``); "ordered" (the default) makes
    every counter independent of timing, "timed" is the hardware-like order
    of ``pipeline-sim run``.
    """
    from pipeline_sim.accuracy import error_metrics
    from pipeline_sim.workload import SceneWorkload, Workload

    if not isinstance(workload, Workload):
        workload = SceneWorkload.of_scene(workload, arch)
    rows, images, passes, groups = [], {}, {}, {}
    for name in algorithms:
        run = workload.with_settings(ALGORITHMS[name])
        groups.setdefault(run.accuracy_settings(), []).append(name)
        run.pass_options["zcull_refresh"] = zcull_refresh
        out = run.run()
        result = out.total()
        dimensions = result.dimensions
        rows.append(_row(name, result))
        images[name] = result.image
        passes[name] = [r.image for r in out.passes.values()]
        if progress is not None:
            progress(name, rows[-1])
    differing = [n for group in groups.values() for n in group[1:]
                 if not all(np.array_equal(a, b) for a, b in zip(passes[n], passes[group[0]], strict=True))]
    table = pd.DataFrame(rows)
    own = groups.get(workload.accuracy_settings(), algorithms)
    against = reference if reference is not None else images[own[0]]
    errors = [error_metrics(images[n], against) for n in algorithms]
    table["rmse"] = [e["rmse"] for e in errors]
    table["psnr_db"] = [e["psnr"] for e in errors]
    base = table[table.algorithm == "bbox"]
    ref = base.iloc[0] if len(base) else table.iloc[0]
    table["ste_vs_baseline"] = table.ste / ref.ste if ref.ste else float("nan")
    table["samples_tested_vs_baseline"] = table.samples_tested / max(ref.samples_tested, 1)
    return Comparison(table, images, not differing, differing, paper_checks(table, dimensions), zcull_refresh)


def comparison_figure(table: pd.DataFrame):
    """Bar charts: STE, samples tested, arithmetic by stage, simulated cycles."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 3.6), layout="constrained")
    axes = fig.subplots(1, 4)
    names = list(table.algorithm)
    x = np.arange(len(names))
    axes[0].bar(x, 100 * table.ste, color="#2a7")
    axes[0].set_title("sample test efficiency (%)")
    axes[1].bar(x, table.samples_tested / 1e6, color="#57b")
    axes[1].set_title("samples tested (M)")
    bottom = np.zeros(len(names))
    for stage, color in zip(STAGES, ("#999", "#e93", "#57b", "#b5a")):
        vals = table[f"ops_{stage}"].to_numpy() / 1e6
        axes[2].bar(x, vals, bottom=bottom, color=color, label=stage.replace("_", " "))
        bottom += vals
    axes[2].set_title("arithmetic by stage (M ops)")
    axes[2].legend(fontsize=7)
    axes[3].bar(x, table.frame_cycles / 1e3, color="#c44")
    axes[3].set_title("simulated frame cycles (k)")
    for ax in axes:
        ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    return fig


def write_comparison(comp: Comparison, out: OutputFolder, info: dict) -> Path:
    """Write table.csv, comparison.json, comparison.png and one image per algorithm into the claimed
    output folder ``out`` (claim it before the algorithms run, so a bad destination fails first) and
    commit it; return its path.

    In comparison.json a figure with no finite value is null: STE and its
    ratio when no sample was tested, the PSNR of an image identical to the
    one it is measured against."""
    from pipeline_sim.output import finite_or_none, write_json, write_png
    from reports.figures import figure_png

    rows = [{k: finite_or_none(v) if isinstance(v, float) else v for k, v in row.items()}
            for row in comp.table.to_dict("records")]
    tmp = out.staging
    comp.table.to_csv(tmp / "table.csv", index=False)
    write_json(tmp / "comparison.json", {**info, "zcull_refresh": comp.zcull_refresh,
                                          "identical_images": comp.identical, "differing": comp.differing,
                                          "paper_checks": comp.checks, "rows": rows})
    (tmp / "comparison.png").write_bytes(figure_png(comparison_figure(comp.table)))
    for name, img in comp.images.items():
        stem = f"image_{name.replace('+', '_').replace('/', '_')}"
        write_png(tmp / f"{stem}.png", img)
        np.save(tmp / f"{stem}.npy", img)
    return out.commit()


def format_table(table: pd.DataFrame) -> str:
    """The table as printed by `pipeline-sim compare`."""
    from reports.run_report import percent

    show = table.copy()
    show["ste"] = show.ste.map(lambda v: percent(v, 2))
    for col in ("ste_vs_baseline", "samples_tested_vs_baseline"):
        show[col] = show[col].map(lambda v: "n/a" if v is None or v != v else f"{v:.2f}x")
    show["wall_time_s"] = show.wall_time_s.map("{:.2f}".format)
    cols = ["algorithm", "tiles_tested", "tiles_rejected", "samples_tested", "samples_covered", "ste",
            "ste_vs_baseline", "ops_triangle_setup", "ops_tile_test", "ops_sample_test", "ops_interpolation_setup",
            "depth_bytes", "shader_executions", "frame_cycles", "wall_time_s"]
    if "psnr_db" in show:
        show["psnr_db"] = show.psnr_db.map("{:.1f}".format)
        cols.append("psnr_db")
    return show[cols].to_string(index=False)


def format_checks(checks: list[dict]) -> str:
    """The paper checks as printed by `pipeline-sim compare` (empty if none apply)."""
    lines = [f"  [{'met' if c['met'] else 'MISSED'}] {c['claim']}: measured {c['measured']}" for c in checks]
    return ("paper checks:\n" + "\n".join(lines)) if lines else ""


__all__ = ["ALGORITHMS", "Comparison", "compare", "comparison_figure", "format_checks", "format_table",
           "paper_checks", "parse_algorithms", "write_comparison"]
