"""Comparing the culling algorithms on one scene, in the papers' own terms.

Renders a scene once per algorithm and tabulates what 001 and 002 compare:
tiles tested and rejected, samples tested and covered, sample test
efficiency (STE, 001 §1.1), arithmetic by stage (triangle setup, tile test,
sample test, interpolation setup; 002 §8 and Fig. 15), depth-buffer bytes,
shader executions, simulated cycles and wall time. Every culling algorithm
is conservative, so the covered samples, and therefore the images, must be
identical: the comparison checks it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline_sim.config import ArchConfig, apply_overrides
from pipeline_sim.errors import UserError, did_you_mean

# algorithm name -> architecture overrides; all are conservative
ALGORITHMS: dict[str, list[str]] = {
    "bbox": ["tile_test.algorithm='bbox'"],
    "box": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=false", "tile_test.lens_bounds=false"],
    "box+edge": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=true", "tile_test.lens_bounds=false"],
    "box+edge/tile": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=true", "tile_test.gamma='tile'",
                      "tile_test.lens_bounds=false"],
    "box+lens": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=false", "tile_test.lens_bounds=true"],
    "hierarchical": ["tile_test.algorithm='hierarchical'", "tile_test.edge_test=true", "tile_test.lens_bounds=true"],
}
DESCRIPTIONS = {
    "bbox": "every sample in the moving, defocused bounds (001/002 baseline)",
    "box": "moving box vs tile frustum planes (002 §4.1)",
    "box+edge": "moving box + linearized moving edges (002 §4.1-4.2)",
    "box+edge/tile": "as box+edge, with the edge slope bound gamma recomputed per tile (002 §4.2)",
    "box+lens": "moving box + lens intervals u^, v^",
    "hierarchical": "moving box + linearized edges + lens intervals (default)",
}
STAGES = {  # 002 Fig. 15's stages and the units whose arithmetic they are
    "triangle_setup": ("triangle_setup",),
    "tile_test": ("tile_traverser", "tile_test"),
    "sample_test": ("sample_tester",),
    "interpolation_setup": ("shading",),
}
ARITH = ("add", "mul", "madd", "rcp", "compare")


@dataclass
class Comparison:
    """The table (one row per algorithm), the images, and the identity check."""

    table: pd.DataFrame
    images: dict[str, np.ndarray]
    identical: bool
    differing: list[str]


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
        row[f"ops_{stage}"] = int(c[c.unit.isin(units) & c.counter.isin(ARITH)].value.sum())
    row["ops_total"] = sum(row[f"ops_{s}"] for s in STAGES)
    row["depth_bytes"] = get("rop", "bytes_read") + get("rop", "bytes_written")
    row["shader_executions"] = get("shading", "shader_executions")
    row["frame_cycles"] = result.timing.frame_cycles
    row["wall_time_s"] = result.wall_time
    return row


def compare(scene, arch: ArchConfig, algorithms: list[str], progress=None) -> Comparison:
    """Render ``scene`` with each algorithm; tabulate and check the images are identical."""
    from pipeline_sim.render import render_scene

    rows, images = [], {}
    for name in algorithms:
        result = render_scene(scene, apply_overrides(arch, ALGORITHMS[name]))
        rows.append(_row(name, result))
        images[name] = result.image
        if progress is not None:
            progress(name, rows[-1])
    first = algorithms[0]
    differing = [n for n in algorithms[1:] if not np.array_equal(images[n], images[first])]
    table = pd.DataFrame(rows)
    base = table[table.algorithm == "bbox"]
    ref = base.iloc[0] if len(base) else table.iloc[0]
    table["ste_vs_baseline"] = table.ste / ref.ste if ref.ste else float("nan")
    table["samples_tested_vs_baseline"] = table.samples_tested / max(ref.samples_tested, 1)
    return Comparison(table, images, not differing, differing)


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


def write_comparison(comp: Comparison, out_dir: Path, info: dict) -> None:
    """Write table.csv, comparison.json, comparison.png and one image per algorithm."""
    from pipeline_sim.output import atomic_directory, write_json, write_png
    from reports.figures import figure_png

    with atomic_directory(Path(out_dir)) as tmp:
        comp.table.to_csv(tmp / "table.csv", index=False)
        write_json(tmp / "comparison.json", {**info, "identical_images": comp.identical,
                                              "differing": comp.differing,
                                              "rows": comp.table.to_dict("records")})
        (tmp / "comparison.png").write_bytes(figure_png(comparison_figure(comp.table)))
        for name, img in comp.images.items():
            write_png(tmp / f"image_{name.replace('+', '_')}.png", img)
            np.save(tmp / f"image_{name.replace('+', '_')}.npy", img)


def format_table(table: pd.DataFrame) -> str:
    """The table as printed by `pipeline-sim compare`."""
    show = table.copy()
    show["ste"] = (100 * show.ste).map("{:.2f}%".format)
    for col in ("ste_vs_baseline", "samples_tested_vs_baseline"):
        show[col] = show[col].map("{:.2f}x".format)
    show["wall_time_s"] = show.wall_time_s.map("{:.2f}".format)
    cols = ["algorithm", "tiles_tested", "tiles_rejected", "samples_tested", "samples_covered", "ste",
            "ste_vs_baseline", "ops_triangle_setup", "ops_tile_test", "ops_sample_test", "ops_interpolation_setup",
            "depth_bytes", "shader_executions", "frame_cycles", "wall_time_s"]
    return show[cols].to_string(index=False)


__all__ = ["ALGORITHMS", "Comparison", "compare", "comparison_figure", "format_table", "parse_algorithms",
           "write_comparison"]
