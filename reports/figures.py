"""Figures for the run and sweep reports (matplotlib, Agg, no pyplot state).

Every figure function returns a :class:`matplotlib.figure.Figure` attached to
an Agg canvas; :func:`figure_png` turns one into PNG bytes. Nothing here
touches the network or the global pyplot figure manager, so the functions are
safe to call from worker threads and from tests.

Figures:

* :func:`cycle_breakdown`: one run, a stacked busy / starved / blocked bar per
  unit.
* :func:`sweep_cycle_breakdown`: a sweep, one row per point and one panel per
  unit, stacked busy / starved / blocked, the point's bottleneck unit marked.
* :func:`pipeline_diagram`: the seven units as boxes colored by utilization
  (:func:`utilization_colors`; colorbar), the queues as arrows labelled with
  mean / peak occupancy and capacity, in the unit the capacity counts
  (:func:`queue_columns`).
* :func:`timeline`: every unit's state over simulated cycles (colored
  horizontal segments, like a signal-trace viewer) and every queue's
  occupancy (step plots); long traces are binned (:func:`bin_trace`,
  :func:`bin_series`).
* :func:`accuracy_cost`: error against simulated cycles, ops and wall time,
  with the Pareto frontier (:func:`pareto_front`) marked.
* :func:`params_vs_metrics`: each swept parameter against each metric.
* :func:`image_grid`: images side by side with their FLIP error maps and the
  reference.
"""

from __future__ import annotations

import textwrap

import io
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import FancyArrowPatch, Patch, Rectangle
from matplotlib.ticker import EngFormatter, FuncFormatter, LogLocator, NullFormatter, PercentFormatter

from pipeline_sim.output import linear_to_srgb8

__all__ = [
    "UNIT_ORDER", "STATES", "STATE_COLORS", "UTIL_CMAP", "UNIT_LABELS",
    "figure_png", "png_data_uri", "short_param", "point_label",
    "cycle_breakdown", "sweep_cycle_breakdown",
    "utilization_norm", "utilization_colors", "queue_columns", "queue_capacities", "pipeline_diagram",
    "bin_trace", "bin_series", "timeline",
    "pareto_front", "accuracy_cost", "params_vs_metrics", "image_grid",
]

UNIT_ORDER = ("triangle_setup", "tile_traverser", "tile_test", "zcull", "sample_tester", "shading", "rop")
UNIT_LABELS = {"triangle_setup": "triangle setup", "tile_traverser": "tile traverser", "tile_test": "tile test",
               "zcull": "z-cull", "sample_tester": "sample tester", "shading": "shading", "rop": "ROP"}
_UNIT_SHORT = {"triangle_setup": "setup", "tile_traverser": "traverser", "tile_test": "tile test",
               "zcull": "z-cull", "sample_tester": "sample test", "shading": "shading", "rop": "ROP"}
STATES = ("busy", "starved", "blocked")
STATE_COLORS = {"busy": "#2a9d3f", "starved": "#c4c4c4", "blocked": "#d1495b"}
#: Colormap of the pipeline diagram: the busiest unit gets its top color.
UTIL_CMAP = "YlOrRd"

_DPI = 110
_ENG = EngFormatter(sep="")


# ---------------------------------------------------------------------------
# helpers


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=_DPI)
    FigureCanvasAgg(fig)
    return fig


def figure_png(fig: Figure, dpi: int = _DPI) -> bytes:
    """The figure as PNG bytes (no metadata chunk naming a web address)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None}, bbox_inches="tight", pad_inches=0.08)
    return buf.getvalue()


def _unit_label(unit: str) -> str:
    return UNIT_LABELS.get(unit, unit.replace("_", " "))


def _queue_label(channel: str) -> str:
    if "->" not in channel:
        return channel
    a, b = channel.split("->", 1)
    return f"{_UNIT_SHORT.get(a, a)}\u2192{_UNIT_SHORT.get(b, b)}"


_PARAM_ALIASES = {"image.spp": "spp", "tile_traverser.tile_size": "tile", "image.seed": "seed",
                  "pipeline.queue_depth": "qdepth", "shading.cache_entries": "cache"}


def short_param(path: str) -> str:
    """A short display name of a dotted parameter path (``image.spp`` -> ``spp``)."""
    return _PARAM_ALIASES.get(path, path.rsplit(".", 1)[-1])


def _fmt_value(v: Any) -> str:
    if isinstance(v, (float, np.floating)):
        if math.isfinite(v) and float(v).is_integer():
            return str(int(v))
        return f"{v:.3g}"
    return str(v)


def point_label(params: Mapping[str, Any], keys: Sequence[str] | None = None) -> str:
    """``spp=4 tile=8``: the values of ``keys`` (default: all) of a point's parameters."""
    keys = list(params) if keys is None else list(keys)
    return " ".join(f"{short_param(k)}={_fmt_value(params[k])}" for k in keys if k in params)


def _luminance(rgba) -> float:
    r, g, b = rgba[:3]
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def _empty(fig: Figure, message: str) -> Figure:
    ax = fig.add_subplot(111)
    ax.axis("off")
    ax.text(0.5, 0.5, message, ha="center", va="center", fontsize=11, color="0.4", transform=ax.transAxes)
    return fig


def _units_frame(units: pd.DataFrame) -> pd.DataFrame:
    """Units in pipeline order (unknown units after them)."""
    u = units.copy()
    order = {n: i for i, n in enumerate(UNIT_ORDER)}
    u["_o"] = [order.get(n, len(order) + i) for i, n in enumerate(u["unit"])]
    return u.sort_values("_o").drop(columns="_o").reset_index(drop=True)


def _log_axis(ax, which: str, eng: bool) -> None:
    """Log scale with ticks at 1, 2, 5 x 10^k, labelled plainly (or in engineering notation)."""
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    axis = ax.xaxis if which == "x" else ax.yaxis
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(EngFormatter(sep="") if eng else FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _wants_log(values: np.ndarray) -> bool:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return len(v) >= 2 and bool(np.all(v > 0)) and v.max() / v.min() >= 10.0


# ---------------------------------------------------------------------------
# cycle breakdown


def cycle_breakdown(units: pd.DataFrame, *, title: str | None = None,
                    frame_cycles: float | None = None) -> Figure:
    """One run: per unit, a horizontal bar of busy, starved and blocked cycles.

    ``units`` is ``TimingResult.units`` (unit, busy, starved, blocked, ...).
    The busiest unit (the bottleneck) is marked.
    """
    u = _units_frame(units)
    fig = _figure(8.0, 0.42 * max(len(u), 1) + 1.3)
    if u.empty:
        return _empty(fig, "no unit timing")
    ax = fig.add_subplot(111)
    y = np.arange(len(u))[::-1]
    left = np.zeros(len(u))
    for state in STATES:
        vals = u[state].to_numpy(float)
        ax.barh(y, vals, left=left, color=STATE_COLORS[state], label=state, height=0.7, edgecolor="white",
                linewidth=0.5)
        left += vals
    total = left.max() if len(left) else 0.0
    ax.set_yticks(y, [_unit_label(n) for n in u["unit"]])
    util = u["busy"].to_numpy(float) / np.where(left > 0, left, 1.0)
    b = int(np.argmax(u["busy"].to_numpy(float)))
    for k, (yi, ut, tot) in enumerate(zip(y, util, left)):
        mark = "  \u2605 bottleneck" if k == b else ""
        ax.text(tot + 0.01 * total, yi, f"{100 * ut:.0f}% busy{mark}", va="center", fontsize=8,
                fontweight="bold" if k == b else "normal")
    ax.get_yticklabels()[b].set_fontweight("bold")
    ax.xaxis.set_major_formatter(_ENG)
    ax.set_xlabel("simulated cycles")
    ax.set_xlim(0, total * 1.22 if total > 0 else 1)
    ax.legend(ncols=3, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False, fontsize=8.5)
    ax.spines[["top", "right"]].set_visible(False)
    fc = f" (frame {frame_cycles:,.0f} cycles)" if frame_cycles is not None else ""
    fig.suptitle((title or "Per-unit cycle breakdown") + fc, fontsize=11, y=1.0)
    fig.tight_layout()
    return fig


def sweep_cycle_breakdown(timings: Mapping[str, pd.DataFrame], *, bottleneck: Mapping[str, str] | None = None,
                          labels: Mapping[str, str] | None = None, normalize: bool = True,
                          title: str | None = None) -> Figure:
    """A sweep: one row per point, one panel per unit, stacked busy / starved / blocked.

    ``timings`` maps point ids (in display order) to their unit timing frame;
    ``bottleneck`` maps point ids to the bottleneck unit (default: the unit
    with the most busy cycles), marked with a black frame and a star.
    ``normalize`` shows fractions of the point's frame (busy + starved +
    blocked) instead of cycles, so points of very different cost compare.
    """
    ids = list(timings)
    units = [n for n in UNIT_ORDER if any(n in set(t["unit"]) for t in timings.values())]
    height = 0.3 * max(len(ids), 1) + 1.5
    fig = _figure(min(2.0 * max(len(units), 1) + 2.6, 17.0), height)
    if not ids or not units:
        return _empty(fig, "no unit timing")
    labels = dict(labels or {})
    axes = fig.subplots(1, len(units), sharey=True, squeeze=False)[0]
    y = np.arange(len(ids))[::-1]
    frames = {}
    for pid in ids:
        t = timings[pid]
        tot = (t["busy"] + t["starved"] + t["blocked"]).max() if len(t) else 0.0
        frames[pid] = float(tot) if tot > 0 else 1.0
    bn = {}
    for pid in ids:
        if bottleneck and isinstance(bottleneck.get(pid), str) and bottleneck.get(pid):
            bn[pid] = bottleneck[pid]
        else:
            t = timings[pid]
            bn[pid] = str(t.loc[t["busy"].idxmax(), "unit"]) if len(t) else ""
    xmax = 1.0 if normalize else max(frames.values())
    for ax, unit in zip(axes, units):
        left = np.zeros(len(ids))
        for state in STATES:
            vals = []
            for pid in ids:
                t = timings[pid]
                row = t[t["unit"] == unit]
                v = float(row[state].iloc[0]) if len(row) else 0.0
                vals.append(v / frames[pid] if normalize else v)
            vals = np.asarray(vals)
            ax.barh(y, vals, left=left, color=STATE_COLORS[state], height=0.72, label=state)
            left += vals
        for yi, pid in zip(y, ids):
            if bn[pid] == unit:
                ax.add_patch(Rectangle((0, yi - 0.4), xmax, 0.8, fill=False, edgecolor="black", linewidth=1.6,
                                       zorder=5))
                ax.text(xmax * 0.97, yi, "\u2605", ha="right", va="center", fontsize=9, color="black", zorder=6)
            row = timings[pid][timings[pid]["unit"] == unit]
            if not len(row):
                ax.text(xmax / 2, yi, "bypassed", ha="center", va="center", fontsize=7, color="0.45")
        ax.set_xlim(0, xmax)
        ax.set_ylim(-0.6, len(ids) - 0.4)
        ax.set_title(_unit_label(unit), fontsize=9)
        if normalize:
            ax.xaxis.set_major_formatter(PercentFormatter(1.0, decimals=0))
            ax.set_xticks([0, 0.5, 1.0])
        else:
            ax.xaxis.set_major_formatter(_ENG)
        ax.tick_params(axis="x", labelsize=7)
        ax.spines[["top", "right"]].set_visible(False)
    axes[0].set_yticks(y, [labels.get(pid, pid) for pid in ids], fontsize=8)
    handles = [Patch(color=STATE_COLORS[s], label=s) for s in STATES]
    handles.append(Line2D([], [], marker="$\u2605$", color="black", linestyle="none", markersize=9,
                          label="bottleneck unit"))
    fig.legend(handles=handles, ncols=4, loc="upper center", bbox_to_anchor=(0.5, 1 - 0.3 / height),
               frameon=False, fontsize=8.5)
    fig.suptitle(title or ("Per-unit cycle breakdown per point (fraction of frame cycles)" if normalize
                           else "Per-unit cycle breakdown per point (cycles)"), fontsize=11, y=1 - 0.05 / height)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.5 / height))
    return fig


# ---------------------------------------------------------------------------
# pipeline diagram


def utilization_norm(utilization: Mapping[str, float] | Sequence[float]) -> Normalize:
    """0 .. the highest utilization, so the busiest unit maps to the colormap's top."""
    vals = np.asarray(list(utilization.values()) if isinstance(utilization, Mapping) else list(utilization),
                      dtype=float)
    vals = vals[np.isfinite(vals)]
    top = float(vals.max()) if len(vals) else 1.0
    return Normalize(vmin=0.0, vmax=top if top > 0 else 1.0)


def utilization_colors(utilization: Mapping[str, float], cmap: str = UTIL_CMAP) -> dict[str, tuple]:
    """RGBA color per unit: ``cmap(utilization / max utilization)``.

    The unit with the highest utilization gets ``cmap(1.0)``, an idle unit
    ``cmap(0.0)``.
    """
    norm = utilization_norm(utilization)
    cm = colormaps[cmap]
    return {unit: tuple(float(c) for c in cm(float(np.clip(norm(u), 0.0, 1.0)))) for unit, u in utilization.items()}


def queue_columns(queues: pd.DataFrame) -> tuple[str, str | None, str, str]:
    """``(unit, capacity column, mean column, peak column)`` of a queues table
    (``TimingResult.queues`` or a ``queues.csv``): ``capacity_<unit>``,
    ``mean_<unit>``, ``peak_<unit>``, unit ``records`` or ``batches``. A
    ``queues.csv`` written before the columns named their unit has
    ``mean_occupancy`` and ``peak_occupancy`` in batches and no capacity in
    that unit (its ``depth`` counted batches of the default size)."""
    for unit in ("records", "batches"):
        if f"mean_{unit}" in queues:
            return unit, f"capacity_{unit}", f"mean_{unit}", f"peak_{unit}"
    return "batches", None, "mean_occupancy", "peak_occupancy"


def queue_capacities(queues: pd.DataFrame) -> dict[str, float]:
    """Channel -> capacity, in the unit of :func:`queue_columns` (empty if the table has none)."""
    cap = queue_columns(queues)[1]
    return dict(zip(queues["channel"], queues[cap])) if cap is not None else {}


def _count(v: float) -> str:
    """An occupancy, short, to three significant digits: ``0.53``, ``126``, ``2.05k``, ``262k``."""
    v = float(v)
    for scale, suffix in ((1e6, "M"), (1e3, "k")):
        if v >= 0.9995 * scale:  # what rounds to three digits at this scale
            return f"{v / scale:.3g}{suffix}"
    return f"{v:.0f}" if v.is_integer() else f"{v:.3g}"


def pipeline_diagram(units: pd.DataFrame, queues: pd.DataFrame, *, title: str | None = None,
                     cmap: str = UTIL_CMAP) -> Figure:
    """The seven units as boxes colored by utilization, the queues as labelled arrows.

    ``units`` is ``TimingResult.units`` (a unit that is not there is drawn as
    bypassed), ``queues`` is ``TimingResult.queues`` (channel, capacity,
    mean and peak occupancy, :func:`queue_columns`); a queue whose peak
    reached its capacity (it was full: back-pressure) is labelled in red.
    """
    unit, cap_col, mean_col, peak_col = queue_columns(queues)
    w_box, gap, h_box = 1.7, 1.35, 1.25
    xs = {u: 1.2 + i * (w_box + gap) for i, u in enumerate(UNIT_ORDER)}
    t = units.set_index("unit") if len(units) else pd.DataFrame()
    util = {u: float(t.loc[u, "utilization"]) for u in UNIT_ORDER if u in t.index}
    colors = utilization_colors(util, cmap) if util else {}
    busiest = max(util, key=util.get) if util else None
    fig = _figure(15.5, 3.3)
    ax = fig.add_axes((0.01, 0.25, 0.98, 0.67))
    ax.set_xlim(-0.1, xs[UNIT_ORDER[-1]] + w_box + 0.2)
    ax.set_ylim(-1.05, h_box + 0.95)
    ax.set_aspect("equal")
    ax.axis("off")
    for u in UNIT_ORDER:
        x = xs[u]
        if u in util:
            col = colors[u]
            ax.add_patch(Rectangle((x, 0), w_box, h_box, facecolor=col, edgecolor="black",
                                   linewidth=2.2 if u == busiest else 1.0, zorder=2))
            tc = "white" if _luminance(col) < 0.45 else "black"
            r = t.loc[u]
            ax.text(x + w_box / 2, h_box * 0.68, _unit_label(u), ha="center", va="center", fontsize=9.5,
                    fontweight="bold", color=tc, zorder=3)
            ax.text(x + w_box / 2, h_box * 0.34, f"util {100 * util[u]:.1f}%", ha="center", va="center",
                    fontsize=9, color=tc, zorder=3)
            # a thin busy / starved / blocked bar under the box
            tot = float(r["busy"] + r["starved"] + r["blocked"]) or 1.0
            left = x
            for state in STATES:
                wdt = w_box * float(r[state]) / tot
                ax.add_patch(Rectangle((left, -0.28), wdt, 0.16, facecolor=STATE_COLORS[state], edgecolor="none",
                                       zorder=2))
                left += wdt
            if u == busiest:
                ax.text(x + w_box / 2, -0.45, "\u25b2 bottleneck", ha="center", va="top", fontsize=8.5,
                        fontweight="bold")
        else:
            ax.add_patch(Rectangle((x, 0), w_box, h_box, facecolor="white", edgecolor="0.55", linestyle="--",
                                   hatch="//", linewidth=1.0, zorder=2))
            ax.text(x + w_box / 2, h_box * 0.68, _unit_label(u), ha="center", va="center", fontsize=9.5,
                    color="0.45", zorder=3, bbox=dict(facecolor="white", edgecolor="none", pad=1))
            ax.text(x + w_box / 2, h_box * 0.3, "bypassed", ha="center", va="center", fontsize=8.5, color="0.45",
                    zorder=3, bbox=dict(facecolor="white", edgecolor="none", pad=1))

    def qtext(row) -> tuple[str, str]:
        cap = row[cap_col] if cap_col is not None and pd.notna(row[cap_col]) else None
        peak = row[peak_col]
        full = cap is not None and peak >= cap
        txt = f"mean {_count(row[mean_col])}\npeak {_count(peak)}" + (f"/{_count(cap)}" if cap is not None else "")
        return txt, ("#b00020" if full else "black")

    for _, row in queues.iterrows():
        ch = str(row["channel"])
        txt, col = qtext(row)
        if "->" not in ch:  # the input queue into the first unit
            first = next((u for u in UNIT_ORDER if u in util), UNIT_ORDER[0])
            x1 = xs[first]
            ax.add_patch(FancyArrowPatch((x1 - 1.1, h_box / 2), (x1, h_box / 2), arrowstyle="-|>",
                                         mutation_scale=14, color="0.2", linewidth=1.4, zorder=1))
            ax.text(x1 - 0.6, h_box / 2 + 0.1, f"{ch}\n{txt}", ha="center", va="bottom", fontsize=7.5, color=col)
            continue
        a, b = ch.split("->", 1)
        if a not in xs or b not in xs:
            continue
        ia, ib = UNIT_ORDER.index(a), UNIT_ORDER.index(b)
        if ib == ia + 1:
            p0, p1 = (xs[a] + w_box, h_box / 2), (xs[b], h_box / 2)
            ax.add_patch(FancyArrowPatch(p0, p1, arrowstyle="-|>", mutation_scale=14, color="0.2", linewidth=1.4,
                                         zorder=1))
            ax.text((p0[0] + p1[0]) / 2, h_box / 2 + 0.1, txt, ha="center", va="bottom", fontsize=8, color=col)
        else:  # a queue over bypassed units
            p0, p1 = (xs[a] + w_box * 0.8, h_box), (xs[b] + w_box * 0.2, h_box)
            rise = 0.6  # the arc's height above the boxes, whatever its length
            ax.add_patch(FancyArrowPatch(p0, p1, arrowstyle="-|>", mutation_scale=14, color="0.2", linewidth=1.4,
                                         connectionstyle=f"arc3,rad={-2 * rise / (p1[0] - p0[0]):.4f}", zorder=4))
            xm = (p0[0] + p1[0]) / 2
            ax.text(xm, h_box + rise + 0.04, txt.replace("\n", "  "), ha="center",
                    va="bottom", fontsize=8, color=col, zorder=5,
                    bbox=dict(facecolor="white", edgecolor="none", pad=1, alpha=0.85))
    if util:
        cax = fig.add_axes((0.3, 0.13, 0.4, 0.06))
        sm = ScalarMappable(norm=utilization_norm(util), cmap=colormaps[cmap])
        cb = fig.colorbar(sm, cax=cax, orientation="horizontal")
        cb.ax.xaxis.set_major_formatter(PercentFormatter(1.0, decimals=0))
        cb.set_label(f"utilization (busy / frame cycles); queue labels: mean / peak occupancy / capacity ({unit}), "
                     "red = queue was full", fontsize=8.5)
        cb.ax.tick_params(labelsize=8)
        handles = [Patch(color=STATE_COLORS[s], label=s) for s in STATES]
        fig.legend(handles=handles, ncols=3, loc="lower right", bbox_to_anchor=(0.99, 0.08), frameon=False,
                   fontsize=8, title="bar under each unit", title_fontsize=8)
    fig.suptitle(title or "Pipeline: units colored by utilization, queues labelled with occupancy", fontsize=11,
                 y=0.97)
    return fig


# ---------------------------------------------------------------------------
# timeline


def bin_trace(segments: Sequence[tuple[float, float, str]], frame_cycles: float, bins: int
              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Bin a unit trace: ``(edges, {state: fraction of each bin spent in it})``.

    Exact: the fraction is the overlap of the state's segments with the bin
    (segments are non-overlapping and in time order, as the simulator writes
    them).
    """
    edges = np.linspace(0.0, float(frame_cycles), bins + 1)
    width = np.diff(edges)
    out = {}
    seg = list(segments)
    for state in STATES:
        s = np.array([(a, b) for a, b, st in seg if st == state and b > a], dtype=float).reshape(-1, 2)
        if not len(s):
            out[state] = np.zeros(bins)
            continue
        s = s[np.argsort(s[:, 0], kind="stable")]
        dur = s[:, 1] - s[:, 0]
        before = np.concatenate([[0.0], np.cumsum(dur)[:-1]])
        xp = np.column_stack([s[:, 0], s[:, 1]]).ravel()
        fp = np.column_stack([before, before + dur]).ravel()
        cum = np.interp(edges, xp, fp, left=0.0, right=fp[-1])
        out[state] = np.clip(np.diff(cum) / np.where(width > 0, width, 1.0), 0.0, 1.0)
    return edges, out


def bin_series(series: Sequence[tuple[float, float]], frame_cycles: float, bins: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bin a step series of (time, level) changes: ``(edges, time-weighted mean, max)`` per bin."""
    edges = np.linspace(0.0, float(frame_cycles), bins + 1)
    arr = np.asarray(series, dtype=float).reshape(-1, 2)
    if not len(arr):
        z = np.zeros(bins)
        return edges, z, z
    tt, lv = arr[:, 0], arr[:, 1]
    # integral of the step function at each change point
    durations = np.diff(np.append(tt, max(float(frame_cycles), tt[-1])))
    cum_at = np.concatenate([[0.0], np.cumsum(lv * durations)])
    knots = np.append(tt, max(float(frame_cycles), tt[-1]))

    def integral(x):
        i = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(tt) - 1)
        base = cum_at[i] + lv[i] * (x - knots[i])
        return np.where(x < tt[0], 0.0, base)

    cum = integral(edges)
    width = np.diff(edges)
    mean = np.diff(cum) / np.where(width > 0, width, 1.0)
    start_idx = np.clip(np.searchsorted(tt, edges[:-1], side="right") - 1, 0, len(tt) - 1)
    mx = np.maximum.reduceat(lv, start_idx)
    nxt = np.append(start_idx[1:], len(tt) - 1)
    inside = tt[nxt] < edges[1:]
    mx = np.where(inside, np.maximum(mx, lv[nxt]), mx)
    return edges, mean, mx


def timeline(traces: Mapping[str, Sequence[tuple[float, float, str]]],
             queue_series: Mapping[str, Sequence[tuple[float, float]]], frame_cycles: float, *,
             queue_capacities: Mapping[str, float] | None = None, queue_unit: str = "records",
             max_segments: int = 2500, bins: int = 1000, title: str | None = None) -> Figure:
    """Every unit's busy / starved / blocked state and every queue's occupancy over cycles.

    A unit with more than ``max_segments`` trace segments (or a queue with
    more than ``max_segments`` changes) is binned into ``bins`` time bins:
    each bin of a unit row is split vertically by the fraction of the bin
    spent in each state; a queue shows the time-weighted mean level per bin
    (line) and the maximum (shaded). Occupancies and ``queue_capacities``
    (a dotted line) count ``queue_unit``.
    """
    frame = float(frame_cycles) if frame_cycles and frame_cycles > 0 else 1.0
    rows = list(UNIT_ORDER) + [u for u in traces if u not in UNIT_ORDER]
    chans = list(queue_series)
    capacities = dict(queue_capacities or {})
    fig = _figure(13.0, 2.9 + 0.55 * len(chans) + 0.3)
    gs = fig.add_gridspec(1 + len(chans), 1, height_ratios=[3.6] + [0.62] * len(chans), hspace=0.18)
    ax = fig.add_subplot(gs[0])
    binned_any = False
    for k, unit in enumerate(rows):
        y = len(rows) - 1 - k
        if unit not in traces:
            ax.text(frame / 2, y, "bypassed", ha="center", va="center", fontsize=8, color="0.5")
            continue
        seg = traces[unit]
        if len(seg) <= max_segments:
            for state in STATES:
                bars = [(a, b - a) for a, b, st in seg if st == state and b > a]
                if bars:
                    ax.broken_barh(bars, (y - 0.38, 0.76), facecolors=STATE_COLORS[state], edgecolor="none")
        else:
            binned_any = True
            edges, frac = bin_trace(seg, frame, bins)
            x = edges
            lo = np.full(bins, y - 0.38)
            for state in STATES:
                hi = lo + 0.76 * frac[state]
                ax.fill_between(x, np.append(lo, lo[-1]), np.append(hi, hi[-1]), step="post",
                                color=STATE_COLORS[state], linewidth=0)
                lo = hi
    ax.set_yticks(range(len(rows))[::-1], [_unit_label(u) for u in rows], fontsize=8.5)
    ax.set_ylim(-0.6, len(rows) - 0.4)
    ax.set_xlim(0, frame)
    ax.tick_params(axis="x", labelbottom=False)
    ax.spines[["top", "right"]].set_visible(False)
    handles = [Patch(color=STATE_COLORS[s], label=s) for s in STATES]
    ax.legend(handles=handles, ncols=3, loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False, fontsize=8.5)
    last = ax
    for i, ch in enumerate(chans):
        qa = fig.add_subplot(gs[1 + i], sharex=ax)
        ser = np.asarray(queue_series[ch], dtype=float).reshape(-1, 2)
        cap = capacities.get(ch)
        top = max(float(cap) if cap else 0.0, float(ser[:, 1].max()) if len(ser) else 0.0, 1.0)
        if len(ser) > max_segments:
            binned_any = True
            edges, mean, mx = bin_series(ser, frame, bins)
            qa.fill_between(edges, 0, np.append(mx, mx[-1]), step="post", color="#9ecae1", linewidth=0,
                            label="max")
            qa.step(edges, np.append(mean, mean[-1]), where="post", color="#08519c", linewidth=0.9, label="mean")
        elif len(ser):
            xs = np.append(ser[:, 0], frame)
            ys = np.append(ser[:, 1], ser[-1, 1])
            qa.fill_between(xs, 0, ys, step="post", color="#9ecae1", linewidth=0)
            qa.step(xs, ys, where="post", color="#08519c", linewidth=0.9)
        if cap:
            qa.axhline(cap, color="#b00020", linewidth=0.6, linestyle=":")
        qa.set_ylim(0, top * 1.05)
        qa.set_yticks([0, top] if top else [0])
        qa.tick_params(axis="y", labelsize=6.5)
        qa.set_ylabel(_queue_label(ch), rotation=0, ha="right", va="center", fontsize=7.5)
        qa.spines[["top", "right"]].set_visible(False)
        if i < len(chans) - 1:
            qa.tick_params(axis="x", labelbottom=False)
        last = qa
    last.xaxis.set_major_formatter(_ENG)
    last.set_xlabel("simulated cycles")
    if not chans:
        ax.tick_params(axis="x", labelbottom=True)
        ax.xaxis.set_major_formatter(_ENG)
        ax.set_xlabel("simulated cycles")
    note = f" (binned into {bins} time bins)" if binned_any else ""
    fig.suptitle((title or f"Timeline: unit states and queue occupancy ({queue_unit}; dotted = capacity)") + note,
                 fontsize=11, y=0.995)
    fig.subplots_adjust(left=0.13, right=0.99, top=0.93, bottom=0.07)
    return fig


# ---------------------------------------------------------------------------
# accuracy against cost


def pareto_front(cost: Sequence[float], error: Sequence[float]) -> np.ndarray:
    """Boolean mask of the points no other point dominates (lower is better on both).

    A point is dominated when another has cost <= and error <= with at least
    one strictly lower. Points with a NaN or infinite coordinate are never on
    the front and dominate nothing. Identical points are all on the front.
    """
    c = np.asarray(cost, dtype=float)
    e = np.asarray(error, dtype=float)
    n = len(c)
    mask = np.zeros(n, dtype=bool)
    valid = np.isfinite(c) & np.isfinite(e)
    idx = np.flatnonzero(valid)
    if not len(idx):
        return mask
    order = idx[np.lexsort((e[idx], c[idx]))]
    best = math.inf
    i = 0
    while i < len(order):
        j = i
        while j < len(order) and c[order[j]] == c[order[i]]:
            j += 1
        group = order[i:j]
        gmin = e[group].min()
        if gmin < best:
            mask[group[e[group] == gmin]] = True
            best = gmin
        i = j
    return mask


_COST_LABELS = {"frame_cycles": "simulated frame cycles", "ops_total": "arithmetic ops (total)",
                "wall_time_s": "wall time of the simulation (s)"}


def _color_scale(values: pd.Series):
    """Discrete colors for the values of the coloring parameter: (colors per row, legend handles)."""
    vals = sorted(pd.unique(values.dropna()), key=lambda v: (isinstance(v, str), v))
    cm = colormaps["viridis"]
    n = max(len(vals), 1)
    lut = {v: cm(0.1 + 0.8 * (i / (n - 1) if n > 1 else 0.5)) for i, v in enumerate(vals)}
    colors = [lut.get(v, (0.5, 0.5, 0.5, 1.0)) for v in values]
    return colors, lut


def accuracy_cost(points: pd.DataFrame, *, metric: str = "flip",
                  costs: Sequence[str] = ("frame_cycles", "ops_total", "wall_time_s"),
                  color_by: str | None = "image.spp", label_params: Sequence[str] | None = None,
                  label_all: bool | None = None, higher_is_better: bool | None = None,
                  title: str | None = None) -> Figure:
    """Error against each cost, one panel per cost, Pareto frontier marked.

    ``points`` has one row per successful point with the metric, the cost
    columns and the parameter columns. Points are colored by ``color_by``
    (when it is a column with more than one value) and labelled by
    ``label_params`` (default: none; the ``label`` column if present):
    frontier points always, all points when there are at most 14
    (``label_all``). Axes are log-scaled where values span 10x or more.
    ``higher_is_better`` (default: for psnr and ssim) makes the frontier
    prefer high values of the metric.
    """
    if higher_is_better is None:
        higher_is_better = metric in ("psnr", "ssim")
    costs = [c for c in costs if c in points.columns]
    fig = _figure(5.2 * max(len(costs), 1), 4.6)
    pts = points[np.isfinite(pd.to_numeric(points.get(metric), errors="coerce"))] if metric in points else points[:0]
    if pts.empty or not costs:
        return _empty(fig, f"no successful point has a value of '{metric}'")
    axes = fig.subplots(1, len(costs), squeeze=False)[0]
    err = pd.to_numeric(pts[metric], errors="coerce").to_numpy(float)
    colored = color_by is not None and color_by in pts.columns and pts[color_by].nunique() > 1
    if colored:
        colors, lut = _color_scale(pts[color_by])
    else:
        colors, lut = ["#3274a1"] * len(pts), {}
    if "label" in pts.columns:
        labels = [str(s) for s in pts["label"]]
    elif label_params:
        labels = [point_label(r, label_params) for r in pts[list(label_params)].to_dict("records")]
    else:
        labels = [""] * len(pts)
    label_all = len(pts) <= 14 if label_all is None else label_all
    better = "higher" if higher_is_better else "lower"
    for ax, cost in zip(axes, costs):
        cv = pd.to_numeric(pts[cost], errors="coerce").to_numpy(float)
        front = pareto_front(cv, -err if higher_is_better else err)
        ax.scatter(cv, err, c=colors, s=42, edgecolors="white", linewidths=0.6, zorder=3)
        ax.scatter(cv[front], err[front], s=110, facecolors="none", edgecolors="black", linewidths=1.3, zorder=4)
        fo = np.argsort(cv[front])
        fx, fy = cv[front][fo], err[front][fo]
        if len(fx):
            ax.step(fx, fy, where="post", color="black", linewidth=1.1, linestyle="--", zorder=2)
        if _wants_log(cv):
            _log_axis(ax, "x", eng=cost != "wall_time_s")
        elif cost != "wall_time_s":
            ax.xaxis.set_major_formatter(_ENG)
        if _wants_log(err):
            _log_axis(ax, "y", eng=False)
        # labels: frontier points first, then the others; a label that would overlap one already
        # placed is left out
        ax.autoscale_view()
        placed: list[tuple[float, float, float]] = []
        px = fig.dpi / 72.0
        for i in sorted(range(len(pts)), key=lambda i: (not front[i], cv[i])):
            if not (labels[i] and (front[i] or label_all) and np.isfinite(cv[i])):
                continue
            x, y = ax.transData.transform((cv[i], err[i]))
            x, y = x + 5 * px, y + 4 * px
            wdt = 0.62 * 7 * px * len(labels[i])
            if any(abs(y - py) < 9 * px and x < px0 + pw and px0 < x + wdt for px0, py, pw in placed):
                continue
            placed.append((x, y, wdt))
            ax.annotate(labels[i], (cv[i], err[i]), xytext=(5, 4), textcoords="offset points", fontsize=7,
                        color="black" if front[i] else "0.4", zorder=5)
        ax.set_xlabel(_COST_LABELS.get(cost, cost))
        ax.set_ylabel(f"{metric} ({better} is better)")
        ax.grid(True, which="major", alpha=0.3)
        ax.set_title(f"{metric} vs {cost}", fontsize=10)
    handles = [Line2D([], [], marker="o", color="none", markerfacecolor="none", markeredgecolor="black",
                      markersize=9, label="Pareto frontier"),
               Line2D([], [], color="black", linestyle="--", label="best error at this cost")]
    if colored:
        handles += [Line2D([], [], marker="o", color="none", markerfacecolor=c, markeredgecolor="white",
                           markersize=8, label=f"{short_param(color_by)}={_fmt_value(v)}") for v, c in lut.items()]
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncols=min(len(handles), 8),
               frameon=False, fontsize=8.5)
    better = "higher" if higher_is_better else "lower"
    fig.suptitle(title or f"What does accuracy cost? Error ({metric}, {better} is better) against cost", fontsize=12)
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------
# parameters against metrics


def _numeric(series: pd.Series) -> bool:
    return pd.to_numeric(series, errors="coerce").notna().all()


def params_vs_metrics(points: pd.DataFrame, params: Sequence[str], metrics: Sequence[str], *,
                      max_lines: int = 10, title: str | None = None) -> Figure:
    """A grid: rows are metrics, columns are swept parameters.

    In a panel the x axis is the parameter; each combination of the other
    swept parameters is a line (up to ``max_lines`` combinations, otherwise a
    scatter colored by the first other parameter). Power-of-two parameters
    spanning 8x or more use a log2 axis.
    """
    params = [p for p in params if p in points.columns]
    metrics = [m for m in metrics if m in points.columns]
    fig = _figure(max(3.6 * max(len(params), 1), 6.0), 2.8 * max(len(metrics), 1) + 0.9)
    if points.empty or not params or not metrics:
        return _empty(fig, "no swept parameter or metric to plot")
    axes = fig.subplots(len(metrics), len(params), squeeze=False)
    for j, p in enumerate(params):
        others = [q for q in params if q != p]
        numeric = _numeric(points[p])
        if numeric:
            xvals = pd.to_numeric(points[p])
            cats = None
        else:
            cats = sorted(pd.unique(points[p].astype(str)))
            xvals = points[p].astype(str).map({c: i for i, c in enumerate(cats)})
        groups = list(points.groupby(others, dropna=False, sort=True)) if others else [((), points)]
        as_lines = len(groups) <= max_lines
        cm = colormaps["tab10"]
        for i, m in enumerate(metrics):
            ax = axes[i, j]
            yv = pd.to_numeric(points[m], errors="coerce")
            if as_lines:
                for g, (key, sub) in enumerate(groups):
                    key = key if isinstance(key, tuple) else (key,)
                    xs = xvals.loc[sub.index]
                    order = np.argsort(xs.to_numpy(float), kind="stable")
                    lbl = point_label(dict(zip(others, key)), others) if others else None
                    ax.plot(xs.to_numpy(float)[order], yv.loc[sub.index].to_numpy(float)[order], marker="o",
                            markersize=4, linewidth=1.2, color=cm(g % 10), label=lbl)
            else:
                cby = others[0]
                cvals, _ = _color_scale(points[cby])
                ax.scatter(xvals.to_numpy(float), yv.to_numpy(float), c=cvals, s=18)
            if numeric:
                v = xvals.to_numpy(float)
                ints = np.all(v > 0) and np.all(np.mod(np.log2(v), 1) == 0)
                if ints and v.max() / v.min() >= 8:
                    ax.set_xscale("log", base=2)
                    ax.set_xticks(sorted(set(v)), [_fmt_value(x) for x in sorted(set(v))])
                    ax.xaxis.set_minor_formatter(NullFormatter())
                elif _wants_log(v):
                    _log_axis(ax, "x", eng=True)
                elif len(set(v)) <= 12:
                    ax.set_xticks(sorted(set(v)), [_fmt_value(x) for x in sorted(set(v))])
            else:
                ax.set_xticks(range(len(cats)), cats)
            if _wants_log(yv.to_numpy(float)):
                _log_axis(ax, "y", eng=m in ("frame_cycles", "ops_total"))
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=8)
            if j == 0:
                ax.set_ylabel(m)
            if i == len(metrics) - 1:
                ax.set_xlabel(p)
        if as_lines and others:
            axes[0, j].legend(fontsize=6.5, title=" ".join(short_param(q) for q in others), title_fontsize=7,
                              loc="best", frameon=False)
        elif others:
            axes[0, j].set_title(f"colored by {short_param(others[0])}", fontsize=8)
    fig.suptitle(title or "Swept parameters against metrics (one line per combination of the other parameters)",
                 fontsize=11)
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------
# images


def image_grid(entries: Sequence[tuple[str, np.ndarray, np.ndarray | None]],
               reference: np.ndarray | None = None, *, reference_label: str = "reference",
               title: str | None = None) -> Figure:
    """Images side by side (top row) with their FLIP error maps (bottom row).

    ``entries`` are ``(label, image (H, W, 3|4) linear, error map (H, W) or
    None)``; ``reference``, if given, is the first column. Error maps use the
    magma colormap on the FLIP range [0, 1] (shared colorbar); each map's
    mean is in its title.
    """
    cols = ([(reference_label, reference, None)] if reference is not None else []) + list(entries)
    if not cols:
        return _empty(_figure(6, 2), "no images")
    h, w = cols[0][1].shape[:2]
    cw = 2.7 if len(cols) <= 5 else 2.1
    ch = cw * h / w
    fig = _figure(cw * len(cols) + 0.9, 2 * ch + 1.1)
    fig.set_layout_engine("constrained")
    axes = fig.subplots(2, len(cols), squeeze=False)
    im = None
    for k, (label, img, emap) in enumerate(cols):
        a0, a1 = axes[0, k], axes[1, k]
        a0.imshow(linear_to_srgb8(np.asarray(img)), interpolation="nearest")
        a0.set_title("\n".join(textwrap.wrap(str(label), 24)) or label, fontsize=7)
        for a in (a0, a1):
            a.set_xticks([])
            a.set_yticks([])
        if emap is not None:
            em = np.asarray(emap, dtype=float)
            im = a1.imshow(em, cmap="magma", vmin=0.0, vmax=1.0, interpolation="nearest")
            a1.set_title(f"FLIP mean {np.nanmean(em):.4f}", fontsize=8)
        else:
            a1.set_facecolor("white")
            for s in a1.spines.values():
                s.set_visible(False)
            a1.text(0.5, 0.5, "reference" if k == 0 and reference is not None else "no error map",
                    ha="center", va="center", fontsize=8, color="0.5", transform=a1.transAxes)
    if im is not None:
        fig.colorbar(im, ax=list(axes[1, :]), fraction=0.03, pad=0.01, label="FLIP error", shrink=0.9)
    fig.suptitle(title or "Images (top) and their FLIP error maps against the reference (bottom)", fontsize=11)
    return fig


# ---------------------------------------------------------------------------
# embedding


def png_data_uri(png: bytes) -> str:
    """``data:image/png;base64,...`` for PNG bytes.

    The base64 text never contains ``http`` (in any case): if it would, a
    padding ``tEXt`` chunk is inserted after the header, which shifts the
    encoding without changing the picture. So a page can be checked for
    network references by a plain text search.
    """
    import base64
    import struct
    import zlib

    def enc(data: bytes) -> str:
        return base64.b64encode(data).decode("ascii")

    text = enc(png)
    if "http" not in text.lower() or not png.startswith(b"\x89PNG\r\n\x1a\n"):
        return "data:image/png;base64," + text
    head, rest = png[:33], png[33:]  # signature + IHDR chunk
    for k in range(1, 200):
        body = b"tEXt" + b"pad\x00" + b"x" * k
        chunk = struct.pack(">I", len(body) - 4) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
        text = enc(head + chunk + rest)
        if "http" not in text.lower():
            break
    return "data:image/png;base64," + text
