"""The one-run report: a one-screen text summary and a short Markdown/HTML report.

The HTML report embeds the image and three figures (:mod:`reports.figures`):
the per-unit cycle breakdown, the pipeline diagram (units colored by
utilization, queues labelled with occupancy) and the timeline of unit states
and queue occupancy. The Markdown report links the same figures as PNG files
when it is given a folder to write them to (``files_dir``).
"""

from __future__ import annotations

import html
import io
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline_sim.output import atomic_write_bytes, linear_to_srgb8


def unit_table(result) -> pd.DataFrame:
    """Per-unit cycles, utilization and the unit's main work counters."""
    t = result.timing.units.set_index("unit")
    rows = []
    for unit in ("triangle_setup", "tile_traverser", "tile_test", "zcull", "sample_tester", "shading", "rop"):
        if unit in t.index:
            r = t.loc[unit]
            rows.append({"unit": unit, "busy": int(r.busy), "starved": int(r.starved), "blocked": int(r.blocked),
                         "util": f"{100 * r.utilization:5.1f}%", "in": result.counter(unit, "records_in"),
                         "out": result.counter(unit, "records_out")})
        else:
            rows.append({"unit": unit, "busy": 0, "starved": 0, "blocked": 0, "util": "bypass", "in": 0, "out": 0})
    return pd.DataFrame(rows)


def percent(value: float | None, digits: int) -> str:
    """``value`` (a fraction) as a percentage, or "n/a" when it has none (None or NaN)."""
    return "n/a" if value is None or value != value else f"{100 * value:.{digits}f}%"


def headline(result) -> dict[str, float | None]:
    """The figures every summary shows; ``ste`` is None when no sample was tested."""
    h, w = result.image.shape[:2]
    tested = result.counter("sample_tester", "samples_tested")
    covered = result.counter("sample_tester", "samples_covered")
    execs = result.counter("shading", "shader_executions")
    return {
        "frame_cycles": result.timing.frame_cycles,
        "samples_tested": tested,
        "samples_covered": covered,
        "ste": covered / tested if tested else None,
        "shader_executions": execs,
        "shader_executions_per_pixel": execs / (w * h),
        "depth_bytes_per_pixel": (result.counter("rop", "bytes_read") + result.counter("rop", "bytes_written")) / (w * h),
        "wall_time_s": result.wall_time,
    }


def summary_text(result, title: str = "") -> str:
    """One screen: per-unit cycles and utilization, STE, shader executions, frame cycles."""
    hd = headline(result)
    dims = "".join(n for n, on in (("xy", True), ("uv", result.dimensions["lens"]),
                                    ("t", result.dimensions["motion"])) if on)
    lines = []
    if title:
        lines.append(title)
    regions = result.region_info
    where = (f"   screen regions: {regions['count']} of {regions['rows']} rows" if regions["count"] > 1 else "")
    lines.append(f"dimensions: {dims}   units: {' -> '.join(result.units_used)}{where}")
    lines.append(unit_table(result).to_string(index=False))
    lines.append(
        f"frame cycles {hd['frame_cycles']:,.0f} | STE {percent(hd['ste'], 1)} "
        f"({hd['samples_covered']:,} of {hd['samples_tested']:,} samples) | "
        f"shader executions {hd['shader_executions']:,} ({hd['shader_executions_per_pixel']:.2f}/pixel) | "
        f"wall {hd['wall_time_s']:.2f} s"
    )
    return "\n".join(lines)


def _png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(linear_to_srgb8(image), mode="RGB").save(buf, format="PNG")
    return buf.getvalue()


def run_figures(result) -> list[tuple[str, str, str, object]]:
    """The run's figures: ``(slug, title, caption, Figure)`` for the cycle breakdown,
    the pipeline diagram and the timeline."""
    from reports import figures as F

    t = result.timing
    unit = F.queue_columns(t.queues)[0]
    return [
        ("cycle_breakdown", "Per-unit cycle breakdown",
         "Busy, starved (waiting for input) and blocked (waiting for room downstream) cycles of each unit.",
         F.cycle_breakdown(t.units, frame_cycles=t.frame_cycles)),
        ("pipeline", "Pipeline",
         "Units colored by utilization (the busiest unit has the colormap's top color); queues labelled with their "
         f"mean and peak occupancy and their capacity, in {unit} (red: the queue was full at some time).",
         F.pipeline_diagram(t.units, t.queues)),
        ("timeline", "Timeline",
         f"Each unit's state over simulated cycles and each queue's occupancy in {unit} (dotted line: its "
         "capacity).",
         F.timeline(t.traces, t.queue_series, t.frame_cycles, queue_capacities=F.queue_capacities(t.queues),
                    queue_unit=unit)),
    ]


def markdown_report(result, run_info: dict, files_dir: str | Path | None = None) -> str:
    """A short Markdown report next to ``image.png``.

    With ``files_dir`` (a folder beside the Markdown file, created if needed)
    the cycle breakdown, pipeline diagram and timeline are written there as
    PNG files and linked as ``<files_dir name>/<figure>.png``; without it the
    report is text only.
    """
    hd = headline(result)
    lines = [
        f"# pipeline-sim run: {run_info.get('scene', '')}",
        "",
        "![image](image.png)",
        "",
        f"- dimensions: motion={result.dimensions['motion']}, lens={result.dimensions['lens']}",
        f"- frame cycles: {hd['frame_cycles']:,.0f}",
        f"- STE: {percent(hd['ste'], 2)} ({hd['samples_covered']:,} covered of {hd['samples_tested']:,} tested)",
        f"- shader executions: {hd['shader_executions']:,} ({hd['shader_executions_per_pixel']:.2f} per pixel)",
        f"- wall time: {hd['wall_time_s']:.2f} s",
        "",
        "## Units",
        "",
        unit_table(result).to_markdown(index=False) if _has_tabulate() else "```\n" + unit_table(result).to_string(index=False) + "\n```",
        "",
        "## Queues",
        "",
        "```\n" + result.timing.queues.to_string(index=False) + "\n```",
        "",
    ]
    if files_dir is not None:
        from reports.figures import figure_png

        fdir = Path(files_dir)
        fdir.mkdir(parents=True, exist_ok=True)
        lines += ["## Figures", ""]
        for slug, title, caption, fig in run_figures(result):
            atomic_write_bytes(fdir / f"{slug}.png", figure_png(fig))
            lines += [f"![{title}]({fdir.name}/{slug}.png)", "", f"*{title}.* {caption}", ""]
    return "\n".join(lines)


def html_report(result, run_info: dict) -> str:
    """The same report as self-contained HTML (image embedded, no network)."""
    hd = headline(result)
    from reports.figures import figure_png, png_data_uri

    img = png_data_uri(_png_bytes(result.image))
    units = unit_table(result).to_html(index=False, border=0)
    queues = result.timing.queues.to_html(index=False, border=0, float_format=lambda v: f"{v:.2f}")
    title = html.escape(str(run_info.get("scene", "")))
    figs = "\n".join(
        f'<figure id="fig-{slug}"><img id="img-{slug}" data-figure="{slug}" alt="{html.escape(ftitle)}" '
        f'src="{png_data_uri(figure_png(fig))}"><figcaption><strong>{html.escape(ftitle)}.</strong> '
        f"{html.escape(caption)}</figcaption></figure>"
        for slug, ftitle, caption, fig in run_figures(result))
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>pipeline-sim: {title}</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}} td,th{{padding:2px 8px;text-align:right}}
img.render{{image-rendering:pixelated;max-width:100%}}
figure{{margin:1em 0}} figure img{{max-width:100%;height:auto}} figcaption{{font-size:.9em;color:#555}}</style></head><body>
<h1>pipeline-sim run: {title}</h1>
<img alt="rendered image" class="render" src="{img}">
<ul><li>frame cycles: {hd['frame_cycles']:,.0f}</li>
<li>STE: {percent(hd['ste'], 2)} ({hd['samples_covered']:,} covered of {hd['samples_tested']:,} tested)</li>
<li>shader executions: {hd['shader_executions']:,} ({hd['shader_executions_per_pixel']:.2f} per pixel)</li>
<li>wall time: {hd['wall_time_s']:.2f} s</li></ul>
<h2>Units</h2>{units}<h2>Queues</h2>{queues}
<h2>Figures</h2>
{figs}
</body></html>
"""


def _has_tabulate() -> bool:
    try:
        import tabulate  # noqa: F401
    except ImportError:
        return False
    return True
