"""The sweep report: a static, self-contained HTML page and its Markdown twin.

    from reports.sweep_report import build_report
    build_report("sweeps/spp_tile", "sweeps/spp_tile/report.html", metric="flip", cost="frame_cycles")

reads a sweep results folder (written by ``pipeline_sim.sweep``)::

    DIR/sweep.json      scene, arch, fixed_set, metrics, reference, points [{id, params}]
    DIR/points.csv      one row per point: point_id, status, error, params, costs, counters, metrics
    DIR/results.csv     tidy: point_id, kind, unit, name, value            (optional)
    DIR/points/<id>/    image.npy, error_map.npy, timing.csv, queues.csv, trace.json, ...
    DIR/reference/*.npy the reference image(s)

and writes ``out_html`` (every figure embedded as a base64 PNG; no network
reference of any kind), ``out_html`` with the suffix ``.md`` and the PNG
files of the Markdown in ``<name>_files/`` beside it. Every file is written
to a temporary name first and renamed into place.

The report, in order: what the accuracy costs (error against cost with the
Pareto frontier, colored by spp when spp was swept: always the first
figure), the counters table per point, the per-unit cycle breakdown and the
bottleneck per point, swept parameters against the metrics, images with
their FLIP error maps, the pipeline diagram and timeline of one
representative point, the per-unit counters, and the failed points with
their errors.
"""

from __future__ import annotations

import html
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline_sim.errors import UserError, did_you_mean
from pipeline_sim.output import atomic_write_bytes
from pipeline_sim.output_folder import OutputFolder, check_output_file
from pipeline_sim.sweep import RESULT_PREFIX
from reports import figures as F

__all__ = ["Sweep", "load_sweep", "build_report", "select_images", "representative_point"]

#: How the reports this module writes begin: what marks an existing file as this tool's own
#: (the generator tag in the head; reports from before it had the tool's name first in the title).
GENERATOR_META = '<meta name="generator" content="pipeline-sim">'
_IN_HEAD = r"<!doctype html>\s*<html[^>]*><head>(?:(?!</head>).)*"
HTML_SIGNATURES = tuple(re.compile(_IN_HEAD + tail, re.IGNORECASE | re.DOTALL)
                        for tail in (re.escape(GENERATOR_META), re.escape("<title>pipeline-sim sweep: ")))
MARKDOWN_SIGNATURES = (re.compile(r"# pipeline-sim sweep: [^\n]*\n"),)

#: Columns of points.csv that are not parameters.
BASE_COLUMNS = ("point_id", "status", "error", "frame_cycles", "wall_time_s", "ops_total", "samples_tested",
                "samples_covered", "ste", "shader_executions", "shader_executions_per_pixel",
                "depth_bytes_per_pixel", "bottleneck_unit", "rmse", "psnr", "ssim", "flip")
METRIC_COLUMNS = ("rmse", "psnr", "ssim", "flip")
COST_COLUMNS = ("frame_cycles", "ops_total", "wall_time_s")
#: Metrics where higher is better (the Pareto frontier needs "lower is better").
HIGHER_IS_BETTER = ("psnr", "ssim")
MAX_IMAGES = 8
MAX_BREAKDOWN_ROWS = 40
MAX_COUNTER_COLUMNS = 12


# ---------------------------------------------------------------------------
# reading a results folder


@dataclass
class Sweep:
    """A sweep results folder, read."""

    dir: Path
    spec: dict[str, Any]
    points: pd.DataFrame  # points.csv, plus a "label" column
    results: pd.DataFrame | None
    params: list[str]  # every parameter path, in sweep order
    swept: list[str]  # the parameters that take more than one value
    references: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # (H, W) -> image

    @property
    def ok(self) -> pd.DataFrame:
        return self.points[self.points["status"].astype(str) == "ok"]

    @property
    def failed(self) -> pd.DataFrame:
        return self.points[self.points["status"].astype(str) != "ok"]

    def point_dir(self, pid: str) -> Path:
        return self.dir / "points" / str(pid)

    def higher(self, metric: str) -> bool:
        """Whether higher values of ``metric`` are better: PSNR, SSIM, and the workload results the
        sweep file lists under ``maximize``."""
        return metric in HIGHER_IS_BETTER or metric in {
            f"{RESULT_PREFIX}{m}" for m in self.spec.get("maximize") or [] if isinstance(m, str)}

    @property
    def default_metric(self) -> str:
        """The report's error metric when none is chosen: the first workload result the sweep file
        lists under ``results``, else FLIP."""
        listed = [m for m in self.spec.get("results") or [] if isinstance(m, str)]
        return f"{RESULT_PREFIX}{listed[0]}" if listed else "flip"


def _not_a_sweep(d: Path, why: str) -> UserError:
    return UserError(f"{d}: not a sweep results folder ({why}; expected sweep.json, points.csv and points/)")


def _normalize_spec(raw: dict[str, Any]) -> dict[str, Any]:
    """sweep.json in one shape: scene, arch (resolved dict or None), fixed_set, metrics, reference,
    points [{id, params}].

    Accepts the flat layout (``scene``, ``arch``, ``fixed_set``, ... at the top) and the nested one
    the sweep engine writes (``spec: {scene, arch: file, set, metrics, reference}``, points with
    ``point_id``); without a resolved ``arch`` the default architecture with the sweep's arch file
    and fixed settings is loaded, for finding the default-like point.
    """
    inner = raw.get("spec") if isinstance(raw.get("spec"), dict) else {}

    def pick(*names: str) -> Any:
        for src in (raw, inner):
            for n in names:
                if src.get(n) is not None:
                    return src[n]
        return None

    fixed = pick("fixed_set", "set") or []
    fixed = [str(x) for x in fixed] if isinstance(fixed, list) else [str(fixed)]
    arch = raw.get("arch") if isinstance(raw.get("arch"), dict) else None
    if arch is None:
        arch_file = pick("arch_file", "arch")
        try:
            from pipeline_sim.config import load_arch

            arch = load_arch(arch_file if isinstance(arch_file, str) else None, overrides=fixed).to_dict()
        except Exception:  # noqa: BLE001 - only a hint for choosing the representative point
            arch = None
    points = []
    for p in raw.get("points") or []:
        if isinstance(p, dict):
            pid = p.get("id", p.get("point_id"))
            params = p.get("params") if isinstance(p.get("params"), dict) else {}
            points.append({"id": None if pid is None else str(pid), "params": params})
    out = dict(raw)
    out.update({"scene": pick("scene"), "arch": arch, "fixed_set": fixed, "metrics": pick("metrics") or [],
                "reference": pick("reference") or {}, "points": points,
                "results": pick("results") or [], "maximize": pick("maximize") or []})
    return out


def load_sweep(sweep_dir: str | Path) -> Sweep:
    """Read a sweep results folder; :class:`UserError` (one line) if it is not one."""
    d = Path(sweep_dir)
    if not d.is_dir():
        raise _not_a_sweep(d, "no such folder")
    sj = d / "sweep.json"
    if not sj.is_file():
        raise _not_a_sweep(d, "no sweep.json")
    try:
        spec = json.loads(sj.read_text())
    except json.JSONDecodeError as e:
        raise UserError(f"{sj}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"{sj}: cannot read ({e})") from None
    if not isinstance(spec, dict) or not isinstance(spec.get("points"), list):
        raise _not_a_sweep(d, "sweep.json has no 'points' list")
    spec = _normalize_spec(spec)
    pc = d / "points.csv"
    if not pc.is_file():
        raise _not_a_sweep(d, "no points.csv")
    try:
        points = pd.read_csv(pc, dtype={"point_id": str, "status": str, "error": str, "bottleneck_unit": str},
                             keep_default_na=True)
    except (pd.errors.EmptyDataError, pd.errors.ParserError, UnicodeDecodeError) as e:
        raise UserError(f"{pc}: not a readable CSV ({str(e).splitlines()[0] if str(e) else type(e).__name__})") \
            from None
    missing = [c for c in ("point_id", "status") if c not in points.columns]
    if missing:
        raise UserError(f"{pc}: missing column(s) {', '.join(missing)}; not a sweep points table")
    results = None
    rc = d / "results.csv"
    if rc.is_file():
        try:
            results = pd.read_csv(rc, dtype={"point_id": str, "unit": str, "name": str, "kind": str},
                                  keep_default_na=False, na_values=[])
        except (pd.errors.EmptyDataError, pd.errors.ParserError):
            results = None
    # parameters: the spec's, in order, then any dotted column of points.csv
    params: list[str] = []
    spec_params: dict[str, dict[str, Any]] = {}
    for p in spec["points"]:
        if isinstance(p, dict):
            pp = p.get("params") or {}
            if isinstance(pp, dict):
                spec_params[str(p.get("id"))] = pp
                params += [k for k in pp if k not in params]
    params += [c for c in points.columns if "." in c and c not in params and c not in BASE_COLUMNS
               and not c.startswith(RESULT_PREFIX)]
    for k in params:  # a parameter only in sweep.json: fill its column from there
        if k not in points.columns:
            points[k] = [spec_params.get(pid, {}).get(k) for pid in points["point_id"]]
    swept = [k for k in params if points[k].astype(str).nunique(dropna=False) > 1]
    for c in [*BASE_COLUMNS[3:], *(c for c in points.columns if c.startswith(RESULT_PREFIX))]:
        if c in points.columns and c != "bottleneck_unit":
            points[c] = pd.to_numeric(points[c], errors="coerce")
    points["status"] = points["status"].fillna("error").astype(str)
    if "error" not in points.columns:
        points["error"] = ""
    points["error"] = points["error"].fillna("").astype(str)
    keys = swept or params[:2]
    labels = [F.point_label(r, keys) for r in points[keys].to_dict("records")] if keys else []
    points["label"] = [lbl or pid for lbl, pid in zip(labels, points["point_id"])] if keys \
        else points["point_id"].astype(str)
    refs: dict[tuple[int, int], np.ndarray] = {}
    rd = d / "reference"
    if rd.is_dir():
        for f in sorted(rd.glob("*.npy")):
            try:
                img = np.load(f, allow_pickle=False)
            except (OSError, ValueError, EOFError):
                continue
            if img.ndim == 3:
                refs.setdefault((img.shape[0], img.shape[1]), img)
    return Sweep(d, spec, points, results, params, swept, refs)


def _read_csv(path: Path) -> pd.DataFrame | None:
    try:
        return pd.read_csv(path) if path.is_file() else None
    except (pd.errors.EmptyDataError, pd.errors.ParserError, OSError):
        return None


def _load_npy(path: Path) -> np.ndarray | None:
    try:
        return np.load(path, allow_pickle=False) if path.is_file() else None
    except (OSError, ValueError, EOFError):
        return None


def _load_trace(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text()) if path.is_file() else None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return None
    return data if isinstance(data, dict) else None


# ---------------------------------------------------------------------------
# choices


def _order_by_cost(df: pd.DataFrame, cost: str) -> pd.DataFrame:
    return df.sort_values([cost, "point_id"], kind="stable", na_position="last") if cost in df else df


def _error_values(df: pd.DataFrame, metric: str, higher: bool) -> np.ndarray:
    """``metric``'s values as "lower is better" (negated when ``higher`` is better)."""
    v = pd.to_numeric(df[metric], errors="coerce").to_numpy(float) if metric in df else np.full(len(df), np.nan)
    return -v if higher else v


def _pareto(df: pd.DataFrame, metric: str, cost: str, higher: bool) -> pd.Series:
    if df.empty or cost not in df or metric not in df:
        return pd.Series(False, index=df.index)
    return pd.Series(F.pareto_front(pd.to_numeric(df[cost], errors="coerce"), _error_values(df, metric, higher)),
                     index=df.index)


def select_images(sweep: Sweep, metric: str, cost: str, max_images: int = MAX_IMAGES) -> list[str]:
    """Point ids whose images to show: all when few; else the best point of each spp
    (when spp was swept) or the Pareto frontier; in cost order."""
    ok = sweep.ok
    ok = ok[[(sweep.point_dir(p) / "image.npy").is_file() for p in ok["point_id"]]]
    if ok.empty:
        return []
    if len(ok) <= max_images:
        chosen = ok
    elif "image.spp" in sweep.swept and ok["image.spp"].nunique() > 1:
        err = pd.Series(_error_values(ok, metric, sweep.higher(metric)), index=ok.index).fillna(np.inf)
        chosen = ok.loc[[err.loc[g.index].idxmin() for _, g in ok.groupby("image.spp", sort=True)]]
    else:
        front = _pareto(ok, metric, cost, sweep.higher(metric))
        chosen = ok[front] if front.sum() >= 2 else ok
    chosen = _order_by_cost(chosen, cost)
    if len(chosen) > max_images:
        pick = np.unique(np.round(np.linspace(0, len(chosen) - 1, max_images)).astype(int))
        chosen = chosen.iloc[pick]
    return [str(p) for p in chosen["point_id"]]


def _scene_image(sweep: Sweep) -> dict | None:
    """The scene file's own [image] settings (its spp, size, seed), if the scene can be read."""
    scene = sweep.spec.get("scene")
    if not isinstance(scene, str) or not scene:
        return None
    try:
        import tomllib

        with open(scene, "rb") as fh:
            image = tomllib.load(fh).get("image")
    except (OSError, ValueError):  # a missing or changed scene only loses this hint
        return None
    return {"seed": 0, **image} if isinstance(image, dict) else None


def _default_of(sweep: Sweep, path: str, scene_image: dict | None = None) -> Any:
    """The default value of a parameter from the sweep's arch (or the scene's image settings), or None."""
    section, _, key = path.partition(".")
    for src in (sweep.spec.get("arch"), {"image": sweep.spec.get("image")}, {"image": scene_image}):
        if isinstance(src, dict) and isinstance(src.get(section), dict) and key in src[section]:
            return src[section][key]
    return None


def _same(a: Any, b: Any) -> bool:
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=0.0)
    except (TypeError, ValueError):
        return str(a).strip().lower() == str(b).strip().lower()


def representative_point(sweep: Sweep, cost: str) -> tuple[str | None, str]:
    """The point to draw the pipeline and timeline for, and why it was chosen.

    The successful point (with a trace) matching the default architecture in
    the most swept parameters; among equals, the one nearest the median cost.
    """
    ok = sweep.ok
    with_trace = ok[[(sweep.point_dir(p) / "timing.csv").is_file() or (sweep.point_dir(p) / "trace.json").is_file()
                     for p in ok["point_id"]]]
    cand = with_trace if len(with_trace) else ok
    if cand.empty:
        return None, "no successful point"
    scene_image = _scene_image(sweep) if any(p.startswith("image.") for p in sweep.swept) else None
    defaults = {p: _default_of(sweep, p, scene_image) for p in sweep.swept}
    known = {p: v for p, v in defaults.items() if v is not None}
    scores = pd.Series([sum(_same(r[p], v) for p, v in known.items()) for _, r in cand.iterrows()],
                       index=cand.index)
    costs = pd.to_numeric(cand[cost], errors="coerce") if cost in cand else pd.Series(0.0, index=cand.index)
    median = costs.median()
    if known and scores.max() > 0:
        best = cand[scores == scores.max()]
        dist = (costs.loc[best.index] - median).abs().fillna(np.inf)
        idx = dist.idxmin()
        pid = str(best.loc[idx, "point_id"])
        match = [F.short_param(p) for p in known if _same(cand.loc[idx, p], known[p])]
        why = (f"the point closest to the default architecture (default {', '.join(match)}"
               + (f"; nearest the median {cost} among those" if len(best) > 1 else "") + ")")
        return pid, why
    dist = (costs - median).abs().fillna(np.inf)
    return str(cand.loc[dist.idxmin(), "point_id"]), f"the point nearest the median {cost}"


# ---------------------------------------------------------------------------
# the document: blocks rendered both as HTML and as Markdown


@dataclass
class _Fig:
    slug: str
    title: str
    caption: str
    png: bytes
    filename: str = ""


@dataclass
class _Table:
    df: pd.DataFrame
    row_class: list[str] | None = None
    bold: set[tuple[int, str]] = field(default_factory=set)


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else ""
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if math.isnan(f):
            return ""
        if math.isinf(f):
            return "inf" if f > 0 else "-inf"
        if f.is_integer() and abs(f) >= 1:
            return f"{int(f):,}"
        if abs(f) >= 1000:
            return f"{f:,.0f}"
        return f"{f:.4g}"
    return str(v)


def _html_table(t: _Table) -> str:
    cols = list(t.df.columns)
    out = ['<div class="tw"><table>', "<thead><tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
           + "</tr></thead>", "<tbody>"]
    for i, row in enumerate(t.df.itertuples(index=False)):
        cls = t.row_class[i] if t.row_class else ""
        cells = []
        for c, v in zip(cols, row):
            s = html.escape(_fmt(v))
            if (i, c) in t.bold:
                s = f"<strong>{s}</strong>"
            num = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
            cells.append(f'<td class="n">{s}</td>' if num else f"<td>{s}</td>")
        out.append((f'<tr class="{cls}">' if cls else "<tr>") + "".join(cells) + "</tr>")
    out.append("</tbody></table></div>")
    return "\n".join(out)


def _md_escape(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def _md_table(t: _Table) -> str:
    cols = [str(c) for c in t.df.columns]
    lines = ["| " + " | ".join(_md_escape(c) for c in cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for i, row in enumerate(t.df.itertuples(index=False)):
        cells = []
        for c, v in zip(t.df.columns, row):
            s = _md_escape(_fmt(v))
            cells.append(f"**{s}**" if (i, c) in t.bold and s else s)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


class _Doc:
    def __init__(self, title: str):
        self.title = title
        self.blocks: list[tuple[str, Any]] = []
        self.figures: list[_Fig] = []
        self.sections: list[tuple[str, str]] = []

    def h2(self, text: str, anchor: str) -> None:
        self.sections.append((anchor, text))
        self.blocks.append(("h2", (text, anchor)))

    def h3(self, text: str) -> None:
        self.blocks.append(("h3", text))

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def items(self, items: list[str]) -> None:
        self.blocks.append(("ul", items))

    def table(self, t: _Table, collapsed: str | None = None) -> None:
        self.blocks.append(("table", (t, collapsed)))

    def fig(self, slug: str, title: str, caption: str, figure) -> None:
        png = F.figure_png(figure)
        f = _Fig(slug, title, caption, png, f"{len(self.figures) + 1:02d}_{slug}.png")
        self.figures.append(f)
        self.blocks.append(("fig", f))

    # -- rendering

    def html(self) -> str:
        css = ("body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:84em;margin:1.5em auto;"
               "padding:0 1em;color:#222;line-height:1.4}"
               "h1{font-size:1.6em}h2{margin-top:2em;border-bottom:1px solid #ddd;padding-bottom:.2em}"
               "figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}"
               "figcaption{font-size:.9em;color:#555;margin-top:.3em}"
               ".tw{overflow-x:auto}table{border-collapse:collapse;font-size:.82em;margin:.6em 0}"
               "th,td{padding:2px 7px;border-bottom:1px solid #eee;text-align:left;white-space:nowrap}"
               "td.n{text-align:right;font-variant-numeric:tabular-nums}th{background:#f5f5f5}"
               "tr.pareto td{background:#fff6cf}tr.failed td{background:#fde4e4}"
               "nav ul{columns:2;font-size:.92em}code{background:#f4f4f4;padding:0 3px}"
               ".err{font-family:monospace;color:#8a0010}")
        out = ["<!doctype html>", '<html lang="en"><head><meta charset="utf-8">',
               '<meta name="viewport" content="width=device-width, initial-scale=1">', GENERATOR_META,
               f"<title>{html.escape(self.title)}</title>", f"<style>{css}</style></head><body>",
               f"<h1>{html.escape(self.title)}</h1>"]
        if self.sections:
            out.append("<nav><ul>" + "".join(f'<li><a href="#{a}">{html.escape(t)}</a></li>'
                                             for a, t in self.sections) + "</ul></nav>")
        for kind, data in self.blocks:
            if kind == "h2":
                text, anchor = data
                out.append(f'<h2 id="{anchor}">{html.escape(text)}</h2>')
            elif kind == "h3":
                out.append(f"<h3>{html.escape(data)}</h3>")
            elif kind == "p":
                out.append(f"<p>{html.escape(data)}</p>")
            elif kind == "ul":
                out.append("<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in data) + "</ul>")
            elif kind == "table":
                t, collapsed = data
                body = _html_table(t)
                if collapsed:
                    body = f"<details><summary>{html.escape(collapsed)}</summary>{body}</details>"
                out.append(body)
            elif kind == "fig":
                f = data
                out.append(f'<figure id="fig-{f.slug}"><img id="img-{f.slug}" data-figure="{f.slug}" '
                           f'alt="{html.escape(f.title)}" src="{F.png_data_uri(f.png)}">'
                           f"<figcaption><strong>{html.escape(f.title)}.</strong> {html.escape(f.caption)}"
                           "</figcaption></figure>")
        out.append("</body></html>")
        return "\n".join(out) + "\n"

    def markdown(self, files_name: str) -> str:
        out = [f"# {self.title}", ""]
        for kind, data in self.blocks:
            if kind == "h2":
                out += [f"## {data[0]}", ""]
            elif kind == "h3":
                out += [f"### {data}", ""]
            elif kind == "p":
                out += [data, ""]
            elif kind == "ul":
                out += [f"- {i}" for i in data] + [""]
            elif kind == "table":
                t, collapsed = data
                if collapsed:
                    out += [f"*{collapsed}*", ""]
                out += [_md_table(t), ""]
            elif kind == "fig":
                out += [f"![{data.title}]({files_name}/{data.filename})", "", f"*{data.title}.* {data.caption}", ""]
        return "\n".join(out)


# ---------------------------------------------------------------------------
# the report


_COUNTER_COLUMNS = [("frame_cycles", "frame cycles"), ("ops_total", "ops"), ("wall_time_s", "wall s"),
                    ("samples_tested", "samples tested"), ("samples_covered", "samples covered"),
                    ("ste", "STE (covered / tested)"), ("shader_executions", "shader execs"),
                    ("shader_executions_per_pixel", "shader execs / px"),
                    ("depth_bytes_per_pixel", "depth bytes / px"), ("bottleneck_unit", "bottleneck"),
                    ("rmse", "rmse"), ("psnr", "psnr"), ("ssim", "ssim"), ("flip", "flip")]


def _check_choice(sweep: Sweep, name: str, value: str, known: tuple[str, ...]) -> None:
    numeric = [c for c in sweep.points.columns if c not in ("point_id", "status", "error", "label",
                                                            "bottleneck_unit") and c not in sweep.params]
    choices = sorted(set(known) | set(numeric))
    if value not in sweep.points.columns and value in known:
        sweep.points[value] = np.nan  # a known column no point wrote (e.g. every point failed)
    elif value not in sweep.points.columns:
        raise UserError(f"{sweep.dir / 'points.csv'}: no {name} column '{value}'{did_you_mean(value, choices)}; "
                        f"choose one of {', '.join(choices)}")


def _summary(doc: _Doc, sw: Sweep, metric: str, cost: str, front: pd.Series) -> None:
    spec = sw.spec
    ok, failed = sw.ok, sw.failed
    ref = spec.get("reference") or {}
    items = [f"scene: {spec.get('scene', '?')}",
             f"points: {len(sw.points)} ({len(ok)} ok, {len(failed)} failed)",
             "swept: " + ("; ".join(f"{p} = {', '.join(F._fmt_value(v) for v in _sorted_values(sw.points[p]))}"
                                    for p in sw.swept) or "nothing (a single configuration)")]
    fixed = spec.get("fixed_set")
    if fixed:
        items.append("fixed settings: " + ", ".join(str(x) for x in fixed))
    if isinstance(ref, dict) and ref:
        drop = {"pipeline": ("passes",), "accumulation": ("spp",)}.get(str(ref.get("kind")), ())
        items.append("reference: " + ", ".join(f"{k}={v}" for k, v in ref.items() if k not in drop))
    higher = sw.higher(metric)
    items.append(f"error metric: {metric} ({'higher' if higher else 'lower'} is better); "
                 f"cost: {cost}")
    doc.items(items)
    finite_cost = np.isfinite(pd.to_numeric(ok.get(cost), errors="coerce"))
    good = ok[np.isfinite(_error_values(ok, metric, higher)) & finite_cost] if cost in ok and metric in ok else ok[:0]
    if len(good) >= 2:
        err = pd.Series(_error_values(good, metric, higher), index=good.index)
        c = pd.to_numeric(good[cost], errors="coerce")
        best, cheap = err.idxmin(), c.idxmin()
        ratio = c[best] / c[cheap] if c[cheap] > 0 else float("nan")
        doc.p(f"The most accurate point ({good.loc[best, 'label']}: {metric} {F._fmt_value(good.loc[best, metric])}) "
              f"costs {ratio:.2f}x the {cost} of the cheapest ({good.loc[cheap, 'label']}: {metric} "
              f"{F._fmt_value(good.loc[cheap, metric])}); {int(front.sum())} of {len(good)} points are on the "
              "Pareto frontier (no other point is both cheaper and more accurate).")


def _sorted_values(s: pd.Series) -> list:
    vals = list(pd.unique(s.dropna()))
    try:
        return sorted(vals)
    except TypeError:
        return sorted(vals, key=str)


def build_report(sweep_dir: str | Path, out_html: str | Path, *, metric: str | None = None,
                 cost: str = "frame_cycles", force: bool = False) -> Path:
    """Write the sweep report (HTML, its Markdown twin and the twin's PNGs); return the HTML path.

    The three outputs (``X.html``, ``X.md``, the folder ``X_files/``) are
    checked before anything is built: one that exists and was not written
    by this tool is refused unless ``force`` (see
    :mod:`pipeline_sim.output_folder`).
    """
    sw = load_sweep(sweep_dir)
    metric = metric or sw.default_metric
    _check_choice(sw, "metric", metric, METRIC_COLUMNS)
    _check_choice(sw, "cost", cost, COST_COLUMNS)
    out_html = Path(out_html)
    out_md = out_html.with_suffix(".md")
    files_dir = out_html.parent / f"{out_html.stem}_files"
    check_output_file(out_html, HTML_SIGNATURES, force=force, option="-o")
    check_output_file(out_md, MARKDOWN_SIGNATURES, force=force, option="-o")
    with OutputFolder(files_dir, "report figures", force=force, option="-o") as figures:
        doc = _document(sw, metric, cost)
        for f in doc.figures:
            (figures.staging / f.filename).write_bytes(f.png)
        figures.commit()
    atomic_write_bytes(out_md, doc.markdown(files_dir.name).encode("utf-8"))
    atomic_write_bytes(out_html, doc.html().encode("utf-8"))
    return out_html


def _document(sw: Sweep, metric: str, cost: str) -> _Doc:
    """The report of ``sw``, figures and tables, ready to render as HTML or Markdown."""
    ok = _order_by_cost(sw.ok, cost)
    front = _pareto(ok, metric, cost, sw.higher(metric))
    color_by = "image.spp" if "image.spp" in sw.swept else (
        sw.swept[0] if sw.swept and sw.points[sw.swept[0]].nunique() <= 10 else None)
    label_params = [p for p in sw.swept if p != color_by] or sw.swept

    scene = Path(str(sw.spec.get("scene", "sweep"))).stem
    doc = _Doc(f"pipeline-sim sweep: {scene}")
    _summary(doc, sw, metric, cost, front)

    # 1. what does accuracy cost
    doc.h2("What does accuracy cost?", "accuracy-cost")
    costs = [cost] + [c for c in COST_COLUMNS if c != cost and c in ok.columns]
    acc = ok.copy()
    if sw.higher(metric):
        doc.p(f"{metric} is higher-is-better: the frontier here is higher {metric} at lower cost.")
    acc["label"] = [F.point_label(r, label_params) if label_params else pid
                    for r, pid in zip(acc[label_params].to_dict("records") if label_params else [{}] * len(acc),
                                      acc["point_id"])]
    doc.fig("accuracy_cost", f"Error ({metric}) against cost",
            "Each point is one configuration; circled points form the Pareto frontier (more accurate and "
            "cheaper; the dashed staircase is the best error reachable at each cost). "
            + (f"Colored by {color_by}. " if color_by else "")
            + f"Panels: {', '.join(costs)}; axes are logarithmic where values span 10x or more.",
            _accuracy_figure(acc, metric, costs, color_by, sw.higher(metric)))
    if front.any():
        cols = ["label", "point_id", metric, *costs]
        doc.table(_Table(ok[front][[c for c in cols if c in ok.columns]].rename(columns={"label": "point"})))

    # 2. counters per point
    doc.h2("Counters per point", "counters")
    doc.p(f"Sorted by {cost}. STE is the sample test efficiency (covered / tested samples). Highlighted rows are on "
          "the Pareto frontier; failed points are listed at the end.")
    table_pts = pd.concat([ok, _order_by_cost(sw.failed, cost)])
    cols = ["label", "point_id", "status"] + [c for c, _ in _COUNTER_COLUMNS if c in table_pts.columns]
    table_pts = table_pts.copy()
    if "ste" in table_pts:
        table_pts["ste"] = [f"{100 * v:.2f}%" if pd.notna(v) else "" for v in table_pts["ste"]]
    ct = table_pts[cols].rename(columns={"label": "point", "point_id": "id", **dict(_COUNTER_COLUMNS)})
    row_class = ["pareto" if (idx in front.index and front.loc[idx]) else ("failed" if st != "ok" else "")
                 for idx, st in zip(table_pts.index, table_pts["status"])]
    doc.table(_Table(ct.reset_index(drop=True), row_class))

    # 3. per-unit cycle breakdown and bottleneck
    doc.h2("Where the cycles go: per-unit breakdown and bottleneck", "cycles")
    timings = {}
    for pid in ok["point_id"]:
        t = _read_csv(sw.point_dir(pid) / "timing.csv")
        if t is not None and {"unit", "busy", "starved", "blocked"} <= set(t.columns):
            timings[str(pid)] = t
    if timings:
        shown = list(timings)
        if len(shown) > MAX_BREAKDOWN_ROWS:
            pick = np.unique(np.round(np.linspace(0, len(shown) - 1, MAX_BREAKDOWN_ROWS)).astype(int))
            shown = [shown[i] for i in pick]
            doc.p(f"{MAX_BREAKDOWN_ROWS} of {len(timings)} points shown, evenly spaced in {cost}.")
        lab = dict(zip(ok["point_id"].astype(str), ok["label"].astype(str)))
        bn = dict(zip(ok["point_id"].astype(str), ok["bottleneck_unit"])) if "bottleneck_unit" in ok else {}
        doc.fig("cycle_breakdown", "Per-unit cycle breakdown per point",
                f"Rows are points in {cost} order; each panel is one unit; bars split the frame into busy, starved "
                "(waiting for input) and blocked (waiting for room downstream). The framed, starred cell is the "
                "point's bottleneck unit.",
                F.sweep_cycle_breakdown({p: timings[p] for p in shown}, bottleneck=bn,
                                        labels={p: f"{lab.get(p, p)}" for p in shown}))
        ut_rows, bold = [], set()
        for i, pid in enumerate(timings):
            t = timings[pid].set_index("unit")
            row = {"point": lab.get(pid, pid), "id": pid}
            b = bn.get(pid) if isinstance(bn.get(pid), str) and bn.get(pid) else (
                str(t["busy"].idxmax()) if len(t) else "")
            for u in F.UNIT_ORDER:
                col = F.UNIT_LABELS[u]
                if u in t.index:
                    util = t.loc[u, "utilization"] if "utilization" in t.columns else np.nan
                    row[col] = f"{100 * float(util):.1f}%" if pd.notna(util) else ""
                else:
                    row[col] = "bypass"
                if u == b:
                    bold.add((i, col))
            row["bottleneck"] = b
            ut_rows.append(row)
        doc.p("Utilization (busy / frame cycles) per unit; the bottleneck unit of each point in bold.")
        doc.table(_Table(pd.DataFrame(ut_rows), bold=bold))
    else:
        doc.p("No point has a timing.csv: no per-unit breakdown.")

    # 4. swept parameters against metrics
    doc.h2("Swept parameters against metrics", "params")
    spec_metrics = [m for m in (sw.spec.get("metrics") or []) if isinstance(m, str)]
    chosen = []
    for m in [metric, *spec_metrics, cost]:
        if m in ok.columns and m not in chosen and pd.to_numeric(ok[m], errors="coerce").notna().any():
            chosen.append(m)
    chosen = chosen[:5]
    if sw.swept and len(ok):
        doc.fig("params_metrics", "Swept parameters against metrics",
                "Columns are swept parameters, rows are metrics; each line holds the other swept parameters fixed.",
                F.params_vs_metrics(ok, sw.swept, chosen))
    else:
        doc.p("Nothing was swept (or no point succeeded).")

    # 5. images
    doc.h2("Images and error maps", "images")
    sel = select_images(sw, metric, cost)
    if sel:
        n_img = sum((sw.point_dir(p) / "image.npy").is_file() for p in ok["point_id"])
        if len(sel) < n_img:
            doc.p(("The best point (lowest " + metric + ") of each spp" if "image.spp" in sw.swept
                   else "Points on the Pareto frontier") + f": {len(sel)} of {n_img} images, in {cost} order.")
        entries = []
        lab = dict(zip(ok["point_id"].astype(str), ok["label"].astype(str)))
        met = dict(zip(ok["point_id"].astype(str), ok[metric])) if metric in ok else {}
        for pid in sel:
            img = _load_npy(sw.point_dir(pid) / "image.npy")
            if img is None:
                continue
            emap = _load_npy(sw.point_dir(pid) / "error_map.npy")
            m = met.get(pid)
            entries.append((f"{lab.get(pid, pid)}\n{metric} {F._fmt_value(m)}" if m is not None and pd.notna(m)
                            else lab.get(pid, pid), img, emap))
        ref = sw.references.get(entries[0][1].shape[:2]) if entries else None
        if ref is None and sw.references:
            ref = next(iter(sw.references.values()))
            if entries and ref.shape[:2] != entries[0][1].shape[:2]:
                ref = None
        rs = sw.spec.get("reference") or {}
        if rs.get("kind") == "accumulation":
            rlabel = f"reference\naccumulation, {rs.get('passes', '?')} passes"
        elif rs:
            rlabel = f"reference\n{rs.get('kind', '')} {rs.get('spp', '?')} spp"
        else:
            rlabel = "reference"
        if entries:
            doc.fig("images", "Images and FLIP error maps",
                    "Top: the images (sRGB); bottom: the per-pixel FLIP error against the reference (0 = identical,"
                    " 1 = the largest perceived difference).",
                    F.image_grid(entries, ref, reference_label=rlabel.strip()))
    else:
        doc.p("No successful point has an image.")

    # 6. representative point
    doc.h2("Pipeline and timeline of one point", "pipeline")
    pid, why = representative_point(sw, cost)
    if pid is not None:
        pdir = sw.point_dir(pid)
        lab = dict(zip(sw.points["point_id"].astype(str), sw.points["label"].astype(str))).get(pid, pid)
        doc.p(f"Point {lab} ({pid}): {why}.")
        units = _read_csv(pdir / "timing.csv")
        queues = _read_csv(pdir / "queues.csv")
        trace = _load_trace(pdir / "trace.json")
        qunit = F.queue_columns(queues)[0] if queues is not None else "records"
        if units is not None and queues is not None:
            doc.fig("pipeline", f"Pipeline of {lab}",
                    "Units colored by utilization (the busiest unit has the colormap's top color); arrows are the "
                    "bounded queues, labelled with their time-weighted mean and peak occupancy and their capacity, "
                    f"in {qunit} (red: the queue was full at some time, so the unit before it was blocked).",
                    F.pipeline_diagram(units, queues, title=f"Pipeline of {lab}: units colored by utilization"))
        if trace is not None:
            capacities = F.queue_capacities(queues) if queues is not None else {}
            fc = trace.get("frame_cycles") or (float(ok.set_index("point_id").loc[pid, "frame_cycles"])
                                               if "frame_cycles" in ok else 0.0)
            tr = {u: [tuple(s) for s in segs] for u, segs in (trace.get("units") or {}).items()}
            qs = {c: [tuple(s) for s in ser] for c, ser in (trace.get("queues") or {}).items()}
            doc.fig("timeline", f"Timeline of {lab}",
                    "Each unit's state over simulated cycles (green busy, grey starved, red blocked) and each "
                    f"queue's occupancy in {qunit} (dotted line: its capacity).",
                    F.timeline(tr, qs, float(fc), queue_capacities=capacities, queue_unit=qunit,
                               title=f"Timeline of {lab}"))
        if units is None and trace is None:
            doc.p("This point has no timing.csv or trace.json.")
    else:
        doc.p("No successful point.")

    # 7. per-unit counters from results.csv
    if sw.results is not None and {"point_id", "kind", "unit", "name", "value"} <= set(sw.results.columns):
        cnt = sw.results[sw.results["kind"].astype(str) == "counter"]
        if len(cnt):
            ids = [p for p in ok["point_id"].astype(str) if p in set(cnt["point_id"])]
            if len(ids) > MAX_COUNTER_COLUMNS:
                pick = np.unique(np.round(np.linspace(0, len(ids) - 1, MAX_COUNTER_COLUMNS)).astype(int))
                ids = [ids[i] for i in pick]
            if ids:
                doc.h2("Per-unit counters", "unit-counters")
                lab = dict(zip(ok["point_id"].astype(str), ok["label"].astype(str)))
                c = cnt[cnt["point_id"].isin(ids)].copy()
                c["value"] = pd.to_numeric(c["value"], errors="coerce")
                piv = c.pivot_table(index=["unit", "name"], columns="point_id", values="value", aggfunc="first",
                                    sort=False)
                order = {u: i for i, u in enumerate(F.UNIT_ORDER)}
                piv = piv.reset_index()
                piv["_o"] = piv["unit"].map(lambda u: order.get(u, 99))
                piv = piv.sort_values("_o", kind="stable").drop(columns="_o")
                piv = piv[["unit", "name", *ids]].rename(columns={p: f"{lab.get(p, p)} ({p})" for p in ids})
                doc.p(f"Every counter of every unit from results.csv ({len(ids)} points, in {cost} order).")
                doc.table(_Table(piv.reset_index(drop=True)), collapsed="show the counters")

    # 8. failures
    doc.h2("Failed points", "failed")
    failed = sw.failed
    if len(failed):
        doc.items([f"{pid} ({lbl}): {err or 'no error message'}"
                   for pid, lbl, err in zip(failed["point_id"], failed["label"], failed["error"])])
    else:
        doc.p("None: every point ran.")

    return doc


def _accuracy_figure(acc: pd.DataFrame, metric: str, costs: list[str], color_by: str | None, higher: bool):
    return F.accuracy_cost(acc, metric=metric, costs=costs, color_by=color_by, higher_is_better=higher)


# ---------------------------------------------------------------------------
# command line
