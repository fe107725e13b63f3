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
    """One screen for a workload's run (a :class:`~pipeline_sim.workload.WorkloadResult`): per-unit
    cycles and utilization, STE, shader executions, frame cycles, over all its passes; with several
    passes, one line per pass first."""
    total = result.total()
    hd = headline(total)
    dims = "".join(n for n, on in (("xy", True), ("uv", total.dimensions["lens"]),
                                    ("t", total.dimensions["motion"])) if on)
    lines = []
    if title:
        lines.append(title)
    if len(result.passes) > 1:
        lines += [f"pass {name}: {_headline_text(headline(r))}" for name, r in result.passes.items()]
    regions = total.region_info
    where = (f"   screen regions: {regions['count']} of {regions['rows']} rows" if regions["count"] > 1 else "")
    lines.append(f"dimensions: {dims}   units: {' -> '.join(total.units_used)}{where}")
    lines.append(unit_table(total).to_string(index=False))
    lines.append(_headline_text(hd))
    return "\n".join(lines)


def _headline_text(hd: dict) -> str:
    return (f"frame cycles {hd['frame_cycles']:,.0f} | STE {percent(hd['ste'], 1)} "
            f"({hd['samples_covered']:,} of {hd['samples_tested']:,} samples) | "
            f"shader executions {hd['shader_executions']:,} ({hd['shader_executions_per_pixel']:.2f}/pixel) | "
            f"wall {hd['wall_time_s']:.2f} s")


def _png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(linear_to_srgb8(image), mode="RGB").save(buf, format="PNG")
    return buf.getvalue()


#: The most passes a run report draws unit figures for (those with the most frame cycles): drawing them
#: for every pass of a workload of many passes took minutes; every pass keeps its tables.
MAX_PASS_FIGURES = 4

Figures = list[tuple[str, str, str, bytes]]


def run_figures(result) -> Figures:
    """The figures of a workload's run as ``(slug, title, caption, PNG bytes)``: the cycle breakdown,
    pipeline diagram and timeline of each pass, for the :data:`MAX_PASS_FIGURES` passes with the most
    frame cycles (in run order; slugs prefixed with the pass name when there are several passes)."""
    from reports import figures as F

    ranked = set(sorted(result.passes, key=lambda n: -result.passes[n].timing.frame_cycles)[:MAX_PASS_FIGURES])
    out = []
    for name, r in result.passes.items():
        if name not in ranked:
            continue
        t = r.timing
        unit = F.queue_columns(t.queues)[0]
        prefix, of = ("", "") if len(result.passes) == 1 else (f"{name}_", f" of pass {name}")
        figures = [
            (f"{prefix}cycle_breakdown", f"Per-unit cycle breakdown{of}",
             "Busy, starved (waiting for input) and blocked (waiting for room downstream) cycles of each unit.",
             F.cycle_breakdown(t.units, frame_cycles=t.frame_cycles)),
            (f"{prefix}pipeline", f"Pipeline{of}",
             "Units colored by utilization (the busiest unit has the colormap's top color); queues labelled with "
             f"their mean and peak occupancy and their capacity, in {unit} (red: the queue was full at some time).",
             F.pipeline_diagram(t.units, t.queues)),
            (f"{prefix}timeline", f"Timeline{of}",
             f"Each unit's state over simulated cycles and each queue's occupancy in {unit} (dotted line: its "
             "capacity).",
             F.timeline(t.traces, t.queue_series, t.frame_cycles, queue_capacities=F.queue_capacities(t.queues),
                        queue_unit=unit)),
        ]
        out += [(slug, title, caption, F.figure_png(fig)) for slug, title, caption, fig in figures]
    return out


def _figures_note(result) -> str:
    """What the figures leave out, for a run of more passes than :data:`MAX_PASS_FIGURES`."""
    n = len(result.passes)
    return (f"Figures of the {MAX_PASS_FIGURES} passes with the most frame cycles, of {n}; the tables above "
            "cover every pass." if n > MAX_PASS_FIGURES else "")


def _passes_table(result) -> pd.DataFrame:
    rows = []
    for name, r in result.passes.items():
        hd = headline(r)
        h, w = r.image.shape[:2]
        rows.append({"pass": name, "size": f"{w}x{h}", "frame cycles": f"{hd['frame_cycles']:,.0f}",
                     "STE": percent(hd["ste"], 2), "shader executions": f"{hd['shader_executions']:,}",
                     "wall (s)": f"{hd['wall_time_s']:.2f}"})
    return pd.DataFrame(rows)


def _title(run_info: dict) -> str:
    return str(run_info.get("workload", {}).get("file", ""))


def markdown_report(result, run_info: dict, files_dir: str | Path | None = None,
                    figures: Figures | None = None) -> str:
    """A short Markdown report of a workload's run (a :class:`~pipeline_sim.workload.WorkloadResult`)
    at the top of its run folder: the final pass's image, the totals, a table of the passes, the
    derived results, each pass's units and queues.

    With ``files_dir`` (a folder beside the Markdown file, created if needed)
    the figures are written there as PNG files and linked as
    ``<files_dir name>/<figure>.png``; without it the report is text only. ``figures``: those of
    :func:`run_figures`, when the caller has drawn them already (for the HTML twin too).
    """
    import json

    total = result.total()
    hd = headline(total)
    kind = run_info.get("kind", "scene")
    lines = [
        f"# pipeline-sim run: {_title(run_info)}",
        "",
        f"![image](passes/{result.final.name}/image.png)",
        "",
        f"- kind: {kind}, passes: {', '.join(result.passes)}",
        f"- dimensions: motion={total.dimensions['motion']}, lens={total.dimensions['lens']}",
        f"- frame cycles: {hd['frame_cycles']:,.0f}",
        f"- STE: {percent(hd['ste'], 2)} ({hd['samples_covered']:,} covered of {hd['samples_tested']:,} tested)",
        f"- shader executions: {hd['shader_executions']:,} ({hd['shader_executions_per_pixel']:.2f} per pixel)",
        f"- wall time: {hd['wall_time_s']:.2f} s",
        "",
    ]
    if len(result.passes) > 1:
        lines += ["## Passes", "", _table_md(_passes_table(result)), ""]
    if result.results:
        lines += ["## Results", "", "```json", json.dumps(result.results, indent=2, sort_keys=True, default=str),
                  "```", ""]
    for name, r in result.passes.items():
        of = "" if len(result.passes) == 1 else f" of pass {name}"
        lines += [f"## Units{of}", "", _table_md(unit_table(r)), "", f"## Queues{of}", "",
                  "```\n" + r.timing.queues.to_string(index=False) + "\n```", ""]
    if files_dir is not None:
        fdir = Path(files_dir)
        fdir.mkdir(parents=True, exist_ok=True)
        note = _figures_note(result)
        lines += ["## Figures", ""] + ([note, ""] if note else [])
        for slug, title, caption, png in run_figures(result) if figures is None else figures:
            atomic_write_bytes(fdir / f"{slug}.png", png)
            lines += [f"![{title}]({fdir.name}/{slug}.png)", "", f"*{title}.* {caption}", ""]
    return "\n".join(lines)


def _table_md(table: pd.DataFrame) -> str:
    return table.to_markdown(index=False) if _has_tabulate() else "```\n" + table.to_string(index=False) + "\n```"


def html_report(result, run_info: dict, figures: Figures | None = None) -> str:
    """The same report as self-contained HTML (image embedded, no network); ``figures`` as for
    :func:`markdown_report`."""
    import json

    total = result.total()
    hd = headline(total)
    from reports.figures import png_data_uri

    img = png_data_uri(_png_bytes(result.final.image))
    passes = (f"<h2>Passes</h2>{_passes_table(result).to_html(index=False, border=0)}"
              if len(result.passes) > 1 else "")
    results = (f"<h2>Results</h2><pre>{html.escape(json.dumps(result.results, indent=2, sort_keys=True, default=str))}"
               "</pre>" if result.results else "")
    units = "".join(
        f"<h2>Units{'' if len(result.passes) == 1 else ' of pass ' + html.escape(name)}</h2>"
        f"{unit_table(r).to_html(index=False, border=0)}"
        f"<h2>Queues{'' if len(result.passes) == 1 else ' of pass ' + html.escape(name)}</h2>"
        f"{r.timing.queues.to_html(index=False, border=0, float_format=lambda v: f'{v:.2f}')}"
        for name, r in result.passes.items())
    title = html.escape(_title(run_info))
    figs = "\n".join(
        f'<figure id="fig-{slug}"><img id="img-{slug}" data-figure="{slug}" alt="{html.escape(ftitle)}" '
        f'src="{png_data_uri(png)}"><figcaption><strong>{html.escape(ftitle)}.</strong> '
        f"{html.escape(caption)}</figcaption></figure>"
        for slug, ftitle, caption, png in (run_figures(result) if figures is None else figures))
    note = _figures_note(result)
    note = f"<p>{html.escape(note)}</p>" if note else ""
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><meta name="generator" content="pipeline-sim"><title>pipeline-sim: {title}</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}} td,th{{padding:2px 8px;text-align:right}}
img.render{{image-rendering:pixelated;max-width:100%}}
figure{{margin:1em 0}} figure img{{max-width:100%;height:auto}} figcaption{{font-size:.9em;color:#555}}</style></head><body>
<h1>pipeline-sim run: {title}</h1>
<img alt="rendered image" class="render" src="{img}">
<ul><li>kind: {html.escape(str(run_info.get("kind", "scene")))}, passes: {html.escape(", ".join(result.passes))}</li>
<li>frame cycles: {hd['frame_cycles']:,.0f}</li>
<li>STE: {percent(hd['ste'], 2)} ({hd['samples_covered']:,} covered of {hd['samples_tested']:,} tested)</li>
<li>shader executions: {hd['shader_executions']:,} ({hd['shader_executions_per_pixel']:.2f} per pixel)</li>
<li>wall time: {hd['wall_time_s']:.2f} s</li></ul>
{passes}{results}{units}
<h2>Figures</h2>
{note}{figs}
</body></html>
"""


def _has_tabulate() -> bool:
    try:
        import tabulate  # noqa: F401
    except ImportError:
        return False
    return True


def read_run(folder: str | Path):
    """A run folder written by ``pipeline-sim run`` read back: its
    :class:`~pipeline_sim.workload.WorkloadResult` (images, counters, timing and traces of every
    pass, results and tables) and its run.json. A folder that is not one is a one-line error."""
    import json

    from pipeline_sim.errors import UserError
    from pipeline_sim.pipeline import TimingResult
    from pipeline_sim.render import PassResult
    from pipeline_sim.workload import WorkloadResult

    folder = Path(folder)
    try:
        info = json.loads((folder / "run.json").read_text(encoding="utf-8"))
        passes = {}
        for rec in info["passes"]:
            d = folder / "passes" / rec["name"]
            trace = json.loads((d / "trace.json").read_text(encoding="utf-8"))
            timing = TimingResult(
                trace["frame_cycles"], pd.read_csv(d / "timing.csv"), pd.read_csv(d / "queues.csv"),
                {u: [tuple(s) for s in states] for u, states in trace["units"].items()},
                {c: [tuple(s) for s in series] for c, series in trace["queues"].items()})
            passes[rec["name"]] = PassResult(
                name=rec["name"], image=np.load(d / "image.npy"), counters=pd.read_csv(d / "counters.csv"),
                timing=timing, wall_time=rec["wall_time_s"], dimensions=rec["dimensions"],
                units_used=rec["units_used"], depth=None, samples=None,
                region_samples_made=rec["screen_regions"]["sample_sets_made"])
        results = json.loads((folder / "results.json").read_text(encoding="utf-8"))
        tables = {Path(name).stem: pd.read_csv(folder / name) for name in info["tables"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserError(f"{folder}: not a run folder written by this version of pipeline-sim run "
                        f"({type(exc).__name__}: {exc})") from None
    return WorkloadResult(passes, results, tables), info


def build_run_report(run_dir: str | Path, out_html: str | Path, *, force: bool = False) -> Path:
    """The report of the run folder ``run_dir`` written again, as ``out_html``, its Markdown twin
    and the twin's figures in ``<out_html stem>_files/`` (refused where they exist and were not
    written by this tool, unless ``force``); return the HTML path."""
    import re

    from pipeline_sim.output_folder import OutputFolder, check_output_file
    from reports.sweep_report import HTML_SIGNATURES

    result, info = read_run(run_dir)
    out_html = Path(out_html)
    out_md = out_html.with_suffix(".md")
    check_output_file(out_html, HTML_SIGNATURES, force=force, option="-o")
    check_output_file(out_md, (re.compile(r"# pipeline-sim (run|sweep): [^\n]*\n"),), force=force, option="-o")
    with OutputFolder(out_html.parent / f"{out_html.stem}_files", "report figures", force=force,
                      option="-o") as figures:
        drawn = run_figures(result)
        markdown = markdown_report(result, info, files_dir=figures.staging, figures=drawn)
        figures.commit()
    atomic_write_bytes(out_md, markdown.replace(f"]({figures.staging.name}/", f"]({out_html.stem}_files/")
                       .encode("utf-8"))
    atomic_write_bytes(out_html, html_report(result, info, figures=drawn).encode("utf-8"))
    return out_html
