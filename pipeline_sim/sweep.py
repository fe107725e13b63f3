"""Parameter sweeps: run a workload (a scene or any kind) over a grid of settings, with accuracy metrics.

A sweep file is TOML. Paths in it are relative to the sweep file itself:

.. code-block:: toml

    [sweep]
    scene = "../scenes/default.toml"          # required: a workload file (pipeline_sim.workload)
    arch = "my_arch.toml"                     # optional, applied over the default architecture
    set = ["zcull.time_slices=4"]             # optional fixed overrides for every point (as `run --set`)
    metrics = ["rmse", "psnr", "ssim", "flip"]  # optional subset of the metrics; default all
    # results = ["pcs_size"]                  # optional: results.json figures every point must have
    # maximize = []                           # optional: those of `results` where higher is better

    [reference]                               # optional; the image each point is measured against
    kind = "pipeline"                         # "pipeline" (default) or "accumulation"
    spp = 256                                 # pipeline: samples per pixel (power of two), default 256
    # passes = 256                            # accumulation: single-sample passes, default 256
    # seed = 12345                            # sample seed of the reference

    [grid]                                    # cartesian product of every key's values
    "image.spp" = [1, 4, 16]                  # image.width / height / spp / seed override the scene's [image]
    "tile_traverser.tile_size" = [8, 16]      # any hardware setting by its dotted path,
    "pass.shading_mode" = ["cache", "per_sample"]  # the pass state (pass.KEY, pass.clip.KEY)
    "simulation.tiles_per_batch" = [256, 512] # and the simulation options (simulation.KEY)
    # "workload.resolution" = [16, 32, 64]    # a key of a workload kind's own file (workload.KEY)

    [[zip]]                                   # zero or more groups: equal-length lists varied together
    "shading.cache_entries" = [256, 1024]
    "shading.cache_ways" = [4, 8]

Keys may be quoted (``"image.spp" = [...]``) or written as TOML dotted keys
(``image.spp = [...]``); both name the same setting. The points are the
cartesian product of the grid keys and the zip groups (each group is one axis
whose values are the tuples), the last axis varying fastest. The point
settings are applied after ``arch`` and ``set``. A sweep with no axes has one
point (the scene as it is).

Everything is checked before anything runs (:func:`load_sweep`): the tables
against their schema (:class:`SweepFile`, through ``pipeline_sim.schema``:
unknown keys with the nearest known name, types, required keys), setting
paths, empty or repeated value lists, zip groups of unequal length, a missing
workload or architecture file, and every point: its workload loaded
(:func:`~pipeline_sim.workload.load_workload`) with its settings
(``with_settings``) and checked as ``run`` checks it (its ``check``). A
problem is a one-line :class:`~pipeline_sim.errors.UserError` naming the
file and key.

Every point has a stable id, :func:`point_id`: a short hex hash of its sorted
setting assignments, so a resumed or extended sweep finds finished points
again whatever the order of the keys.

Results (:func:`run_sweep`) go into an output folder::

    sweep.json            resolved sweep (scene digest, arch, set, reference, metrics) and all points with ids
    points.csv            one row per finished point: the summary record
    results.csv           tidy: point_id, kind ("counter" | "summary"), unit ("" for summary), name, value
    records/<id>.json     one per finished point (summary, counters; traceback of a failed point)
    points/<id>/          image.npy, image.png, error_map.npy, counters.csv, timing.csv,
                          queues.csv, trace.json, run.json (the full resolved configuration)
    reference/<key>.npy   reference images, one per scene, image size and image-changing settings

A point is done when its record exists: running the same command again
computes only the missing points (a point folder without a record, left by a
killed run, is computed again) and rebuilds the two tables from the records.
A point that fails is recorded with status ``error`` and its message; the
sweep goes on (``retry_errors=True`` runs failed points again).

Command line: ``pipeline-sim sweep SWEEP.toml --out DIR [--executor
local|dask|serial] [--workers N] [--scheduler ADDRESS] [--quiet]``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import itertools
import json
import os
import platform
import sys
import time
import tomllib
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Callable, Iterator, Literal

import numpy as np
import pandas as pd
from pydantic import Field, Strict

from pipeline_sim import schema
from pipeline_sim.accuracy import METRICS, REFERENCE_KINDS, ReferenceSpec
from pipeline_sim.config import is_toml_value, literal as toml_literal
from pipeline_sim.definitions import ARITHMETIC
from pipeline_sim.errors import UserError, did_you_mean, read_input_text, unknown_key_error
from pipeline_sim.output import atomic_write_text
from pipeline_sim.output_folder import OutputFolder, check_writable_folder, clean_leftovers
from pipeline_sim.settings import FORBID, Text, count

__all__ = [
    "SweepSpec", "load_sweep", "point_id", "run_point", "run_sweep", "SUMMARY_FIELDS", "HOST_TIMING_FIELDS",
    "EXECUTORS"]

#: Setting paths under ``image.`` that override the scene's ``[image]`` table.
IMAGE_KEYS = ("width", "height", "spp", "seed")
#: Executors accepted by :func:`run_sweep`.
EXECUTORS = ("local", "dask", "serial")
#: Summary fields of every successful point, after its settings (metrics follow).
SUMMARY_FIELDS = (
    "frame_cycles", "wall_time_s", "ops_total", "samples_tested", "samples_covered", "ste",
    "shader_executions", "shader_executions_per_pixel", "depth_bytes_per_pixel", "bottleneck_unit",
)
#: Summary fields that measure the host rather than the simulation (differ between identical runs).
HOST_TIMING_FIELDS = ("wall_time_s",)
#: Grid keys under ``workload.`` replace keys of the workload kind's own file.
WORKLOAD_PREFIX = "workload."
#: Summary fields holding a workload's results (every number of its results.json, flattened; None where
#: it has no finite value).
RESULT_PREFIX = "result."

_ID_LENGTH = 12


# ---------------------------------------------------------------------------
# The sweep file


@dataclass
class SweepSpec:
    """A parsed, validated sweep file.

    ``points`` lists every point's settings (dotted path -> value) in run
    order; ``axes`` keeps the structure (each axis: its paths and its value
    tuples). Paths are absolute.
    """

    path: Path
    scene: Path
    scene_digest: str
    arch: Path | None
    arch_digest: str | None
    set: list[str]
    metrics: tuple[str, ...]
    reference: Any  # pipeline_sim.accuracy.ReferenceSpec
    axes: list[tuple[tuple[str, ...], list[tuple[Any, ...]]]]
    points: list[dict[str, Any]] = field(default_factory=list)
    results: tuple[str, ...] = ()  # the workload results every point must have (report metrics)
    maximize: tuple[str, ...] = ()  # those of `results` where higher is better

    @property
    def param_names(self) -> list[str]:
        """Every varied setting path, in axis order."""
        return [k for keys, _ in self.axes for k in keys]

    def to_dict(self) -> dict[str, Any]:
        """Plain, picklable, JSON-able form (what :func:`run_point` receives)."""
        return {
            "sweep": str(self.path),
            "scene": str(self.scene),
            "scene_digest": self.scene_digest,
            "arch": None if self.arch is None else str(self.arch),
            "arch_digest": self.arch_digest,
            "set": list(self.set),
            "metrics": list(self.metrics),
            "reference": dataclasses.asdict(self.reference),
            "results": list(self.results),
            "maximize": list(self.maximize),
        }


def point_id(params: dict[str, Any]) -> str:
    """Stable short hex id of a point: a hash of its sorted setting assignments."""
    text = json.dumps({str(k): v for k, v in params.items()}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:_ID_LENGTH]


def _describe(params: dict[str, Any]) -> str:
    return ", ".join(f"{k}={toml_literal(v)}" for k, v in params.items()) or "(no settings)"


def _split_params(params: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], list[str]]:
    """(image settings, keys of the workload's file, ``--set`` overrides of the hardware, pass state and
    simulation options) of a point."""
    image = {k.split(".", 1)[1]: v for k, v in params.items() if k.startswith("image.")}
    file_keys = {k.removeprefix(WORKLOAD_PREFIX): v for k, v in params.items() if k.startswith(WORKLOAD_PREFIX)}
    overrides = [f"{k}={toml_literal(v)}" for k, v in params.items()
                 if not k.startswith(("image.", WORKLOAD_PREFIX))]
    return image, file_keys, overrides


def result_figures(results: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, float | None]]:
    """Every number of a workload's ``results.json`` (booleans aside), nested keys joined by dots; a
    figure with no finite value (null in the file, or NaN) is None."""
    for key, value in results.items():
        if isinstance(value, dict):
            yield from result_figures(value, f"{prefix}{key}.")
        elif value is None:
            yield f"{prefix}{key}", None
        elif isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
            value = value.item() if isinstance(value, np.generic) else value
            yield f"{prefix}{key}", value if np.isfinite(value) else None


def _flatten(table: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``{"a": {"b": [..]}}`` and ``{"a.b": [..]}`` both give ``("a.b", [..])``."""
    for key, value in table.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _flatten(value, path + ".")
        else:
            yield path, value


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check_setting_path(where: str, key: str) -> None:
    """``key`` names a setting: ``image.KEY``, a hardware ``SECTION.KEY``, ``pass.KEY``, ``pass.clip.KEY`` or
    ``simulation.KEY`` (a setting that moved out of the architecture file says where it is now)."""
    from pipeline_sim.config import MOVED, moved_error, setting_effects

    if key in MOVED:
        raise moved_error(where, key, varied=True)
    if key.startswith(WORKLOAD_PREFIX) and all(key.removeprefix(WORKLOAD_PREFIX).split(".")):
        return  # a key of the workload's file: checked with the file's schema, value by value
    paths = {*setting_effects(), *(f"image.{k}" for k in IMAGE_KEYS)}
    if key in paths:
        return
    parts = key.split(".")
    if len(parts) < 2 or not all(parts):
        raise UserError(f"{where}: '{key}' is not a setting path (expected section.key, "
                        "e.g. tile_traverser.tile_size, pass.depth_test, image.spp or workload.KEY)")
    table = ".".join(parts[:-1])
    tables = sorted({p.rsplit(".", 1)[0] for p in paths})
    if table not in tables:
        raise UserError(f"{where}: unknown section '{table}' in '{key}'{did_you_mean(table, tables)}; "
                        f"known sections: {', '.join(tables)}")
    known = sorted(p.rsplit(".", 1)[1] for p in paths if p.rsplit(".", 1)[0] == table)
    raise unknown_key_error(f"{where}: [{table}]", parts[-1], known)


def _read_sweep_toml(path: Path, where: str) -> dict[str, Any]:
    _, text = read_input_text(path, where, "sweep")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else "syntax error"
        raise UserError(f"{where}: invalid TOML: {msg}") from None


def _value_list(where: str, value: Any, unique: bool = True, lists: bool = False) -> list[Any]:
    """A non-empty list of TOML scalars, or with ``lists`` also lists of scalars (a workload file key's
    values), distinct unless ``unique`` is false."""
    if not isinstance(value, list):
        raise UserError(f"{where}: expected a list of values, e.g. [1, 4, 16], got {value!r}")
    if not value:
        raise UserError(f"{where}: the list of values is empty")
    seen: set[str] = set()
    for v in value:
        if not is_toml_value(v, lists):
            kinds = "numbers, booleans, strings or lists of them" if lists else "numbers, booleans or strings"
            raise UserError(f"{where}: values must be {kinds}, got {v!r}")
        canon = json.dumps(v)
        if unique and canon in seen:
            raise UserError(f"{where}: value {toml_literal(v)} is listed twice")
        seen.add(canon)
    return list(value)


# The sweep file's tables, validated by pydantic through pipeline_sim.schema (one-line errors naming
# the file and key, with did-you-mean); docs/sweep-format.md's table of them is generated from these.
_NonEmpty = Annotated[str, Strict(), Field(min_length=1)]
_REFERENCE = ReferenceSpec()



@dataclass
class SweepTable:
    """``[sweep]``: what every point runs."""

    __pydantic_config__ = FORBID
    scene: _NonEmpty = schema.key(
        "the workload file every point runs (a scene or any kind), relative to the sweep file")
    arch: _NonEmpty | None = schema.key("an architecture file applied over the default one", default=None)
    set: list[Text] = schema.key('"section.key=value" overrides applied to every point, as `run --set`',
                           default_factory=list)
    metrics: Annotated[list[Literal[METRICS]], Field(min_length=1)] = schema.key(
        "the image metrics measured (a subset of " + ", ".join(METRICS) + ")", default_factory=lambda: list(METRICS))
    results: list[Text] = schema.key(
        "figures of the workload's results.json (nested keys joined by dots) every point must have; the first "
        "is the report's default error metric (every finite figure is in points.csv as result.NAME anyway)",
        default_factory=list)
    maximize: list[Text] = schema.key("those of `results` where higher is better (lower is, by default)",
                                      default_factory=list)

    def check(self, where: str) -> None:
        for name in ("metrics", "results", "maximize"):
            values = getattr(self, name)
            if len(set(values)) != len(values):
                raise UserError(f"{where}.{name}: a name is listed twice")
        for m in self.maximize:
            if m not in self.results:
                raise UserError(f"{where}.maximize: '{m}' is not one of the sweep's results "
                                f"({', '.join(self.results) or 'none listed'})")


@dataclass
class ReferenceTable:
    """``[reference]``: the image each point is measured against (:class:`~pipeline_sim.accuracy.ReferenceSpec`)."""

    __pydantic_config__ = FORBID
    kind: Literal[REFERENCE_KINDS] = schema.key(
        "`pipeline`: the pipeline at `spp`, one shader execution per sample; `accumulation`: `passes` "
        "single-sample renders averaged", default=_REFERENCE.kind)
    spp: count(1, 1 << 16) = schema.key("pipeline: samples per pixel, a power of two", default=_REFERENCE.spp)
    passes: count(1) = schema.key("accumulation: single-sample passes", default=_REFERENCE.passes)
    seed: count(0, (1 << 63) - 1) = schema.key("the reference's sample seed", default=_REFERENCE.seed)


@dataclass
class SweepFile:
    """A sweep file's top-level tables (the ``[grid]`` and ``[[zip]]`` keys are setting paths, checked
    against the settings' own schemas point by point)."""

    __pydantic_config__ = FORBID
    sweep: SweepTable = schema.key('a [sweep] table with scene = "..."')
    reference: ReferenceTable = schema.key("the reference image", default_factory=ReferenceTable)
    grid: dict[str, Any] = schema.key("setting path -> its values; every combination", default_factory=dict)
    zip: list[dict[str, Any]] = schema.key("groups of equal-length value lists varied together", default_factory=list)


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a sweep file (format: the module docstring).

    Raises :class:`UserError` (one line naming the file and key) for any
    problem, including a point whose settings do not make a valid
    architecture or image, or that its workload would refuse; nothing is run.
    """
    from pipeline_sim.config import load_arch, parse_override
    from pipeline_sim.scene import check_image_value
    from pipeline_sim.workload import load_workload

    p = Path(path)
    where = str(path)
    data = _read_sweep_toml(p, where)
    if isinstance(data.get("zip"), dict):  # one group written [zip] rather than [[zip]]
        data["zip"] = [data["zip"]]
    spec_file = schema.build(SweepFile, data, where)
    sw = spec_file.sweep
    base_dir = p.parent

    scene_path = (base_dir / sw.scene).resolve()
    if not scene_path.is_file():
        raise UserError(f"{where}: sweep.scene: scene file '{sw.scene}' not found (resolved to '{scene_path}')")

    # architecture: file, then fixed overrides
    arch_path = None
    if sw.arch is not None:
        arch_path = (base_dir / sw.arch).resolve()
        if not arch_path.is_file():
            raise UserError(f"{where}: sweep.arch: architecture file '{sw.arch}' not found "
                            f"(resolved to '{arch_path}')")
    fixed = sw.set
    try:
        for text in fixed:
            section, key, _ = parse_override(text)
            _check_setting_path(f"{where}: sweep.set", f"{section}.{key}")
            if section == "image":
                raise UserError(f"{where}: sweep.set: '{text}': image settings belong in the scene or in [grid]")
    except UserError as exc:
        msg = str(exc)
        raise UserError(msg if msg.startswith(where) else f"{where}: sweep.set: {msg}") from None
    try:
        base = load_arch(arch_path, None)
    except UserError as exc:
        raise UserError(f"{where}: sweep.arch: {exc}") from None
    try:
        loaded = load_workload(scene_path, base)
    except UserError as exc:
        raise UserError(f"{where}: sweep.scene: {exc}") from None
    try:
        workload = loaded.with_settings(list(fixed))
    except UserError as exc:
        raise UserError(f"{where}: sweep.set: {exc}") from None

    metrics = tuple(x for x in METRICS if x in sw.metrics)
    try:
        reference = ReferenceSpec(**dataclasses.asdict(spec_file.reference))
    except UserError as exc:
        raise UserError(f"{where}: [reference]: {exc}") from None

    # axes
    axes: list[tuple[tuple[str, ...], list[tuple[Any, ...]]]] = []
    owner: dict[str, str] = {}
    # a setting's value wrong on its own (type, range); a cross-key rule (cache_entries a
    # multiple of cache_ways) is judged per point below, where other keys may make it right
    alone_errors: dict[tuple[str, str], tuple[str, str]] = {}

    def check_values(table: str, key: str, values: list[Any]) -> None:
        loc = f"{where}: {table} {key}"
        if key in owner:
            raise UserError(f"{loc}: '{key}' is already varied in {owner[key]}")
        owner[key] = table
        section, name = key.split(".", 1)
        for v in values:
            if section == "image":
                check_image_value(name, v, f"{loc} = {toml_literal(v)}")
                continue
            try:
                if key.startswith(WORKLOAD_PREFIX):
                    load_workload(scene_path, base, file_keys={name: v})
                else:
                    workload.with_settings([f"{key}={toml_literal(v)}"])
            except UserError as exc:
                alone_errors[(key, json.dumps(v))] = (table, str(exc))

    for key, value in _flatten(spec_file.grid):
        loc = f"{where}: [grid] {key}"
        _check_setting_path(loc, key)
        values = _value_list(loc, value, lists=key.startswith(WORKLOAD_PREFIX))
        check_values("[grid]", key, values)
        axes.append(((key,), [(v,) for v in values]))

    for i, group in enumerate(spec_file.zip, 1):
        table = f"[[zip]] #{i}"
        gloc = f"{where}: {table}"
        items = list(_flatten(group))
        if not items:
            raise UserError(f"{gloc}: the group is empty")
        keys, columns = [], []
        for key, value in items:
            loc = f"{gloc} {key}"
            _check_setting_path(loc, key)
            value = _value_list(loc, value, unique=False,  # a zip column may repeat a value
                                lists=key.startswith(WORKLOAD_PREFIX))
            check_values(table, key, value)
            keys.append(key)
            columns.append(value)
        lengths = {len(c) for c in columns}
        if len(lengths) > 1:
            desc = ", ".join(f"{k} has {len(c)}" for k, c in zip(keys, columns))
            raise UserError(f"{gloc}: lists must have equal lengths ({desc})")
        tuples = list(zip(*columns))
        if len({json.dumps(t) for t in tuples}) != len(tuples):
            raise UserError(f"{gloc}: a combination of values is listed twice")
        axes.append((tuple(keys), tuples))

    # points: every point's workload built now, exactly as run_point builds it, and checked as `run`
    # checks it (its samples, its memory, its geometry)
    points: list[dict[str, Any]] = []
    images: dict[str, Any] = {}
    reference_spp = reference.spp if reference.kind == "pipeline" else 1
    for combo in itertools.product(*(values for _, values in axes)):
        params: dict[str, Any] = {}
        for (keys, _), values in zip(axes, combo):
            params.update(zip(keys, values))
        image, file_keys, overrides = _split_params(params)
        at = f"{where}: point {_describe(params)}"
        image_key = json.dumps([image, file_keys], sort_keys=True)
        try:
            if image_key not in images:
                images[image_key] = load_workload(scene_path, base, image, file_keys) if image or file_keys \
                    else loaded
            point = images[image_key].with_settings(list(fixed) + overrides)
        except UserError as exc:
            for k, v in params.items():  # blame one key when it alone gives this error
                table, msg = alone_errors.get((k, json.dumps(v)), ("", ""))
                if msg == str(exc):
                    raise UserError(f"{where}: {table} {k} = {toml_literal(v)}: "
                                    f"{msg.removeprefix('--set: ').removeprefix(f'{scene_path}: ')}") from None
            raise UserError(f"{at}: {exc}") from None
        try:
            point.check(reference_spp=reference_spp if point.reference_scene() is not None else None)
        except UserError as exc:  # the workload names its file: the point names it here
            raise UserError(f"{at}: {str(exc).removeprefix(f'{point.path}: ')}") from None
        points.append(params)

    return SweepSpec(
        path=p.resolve(), scene=scene_path, scene_digest=loaded.digest, arch=arch_path,
        arch_digest=None if arch_path is None else _file_digest(arch_path), set=list(fixed),
        metrics=metrics, reference=reference, axes=axes, points=points, results=tuple(sw.results),
        maximize=tuple(sw.maximize),
    )


# ---------------------------------------------------------------------------
# One point


def _atomic_write_csv(path: Path, frame: pd.DataFrame) -> None:
    atomic_write_text(path, frame.to_csv(index=False))


def _json_text(data: Any, indent: int | None = 2) -> str:
    from pipeline_sim.output import _json_default

    seps = None if indent else (",", ":")
    return json.dumps(data, indent=indent, sort_keys=indent is not None, default=_json_default, separators=seps,
                      allow_nan=False) + "\n"


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, UserError):
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _summarize(result: Any, metrics: dict[str, float | None]) -> dict[str, Any]:
    """The point's summary record (STE None when no sample was tested)."""
    from reports.run_report import headline

    hd = headline(result)
    c = result.counters
    units = result.timing.units
    busiest = units.loc[units.busy.idxmax(), "unit"] if len(units) else ""
    out = {
        "frame_cycles": float(hd["frame_cycles"]),
        "wall_time_s": float(hd["wall_time_s"]),
        "ops_total": int(c[c.counter.isin(ARITHMETIC)].value.sum()),
        "samples_tested": int(hd["samples_tested"]),
        "samples_covered": int(hd["samples_covered"]),
        "ste": hd["ste"],
        "shader_executions": int(hd["shader_executions"]),
        "shader_executions_per_pixel": float(hd["shader_executions_per_pixel"]),
        "depth_bytes_per_pixel": float(hd["depth_bytes_per_pixel"]),
        "bottleneck_unit": str(busiest),
    }
    out.update(metrics)
    return out


def run_point(spec_dict: dict[str, Any], params: dict[str, Any], out_dir: str | Path) -> dict[str, Any]:
    """Run one point in this process; write its folder and record; return its summary.

    ``spec_dict`` is :meth:`SweepSpec.to_dict`. Any exception is caught: the
    point is then recorded with ``status = "error"`` and a one-line message.
    Writes ``out_dir/points/<id>/`` (whole, atomically), then
    ``out_dir/records/<id>.json`` (atomically) which marks the point done.
    """
    out = Path(out_dir)
    pid = point_id(params)
    counters: list[list[Any]] = []
    tb = None
    try:
        summary, counters = _run_point(spec_dict, params, out, pid)
    except Exception as exc:  # recorded, the sweep goes on
        summary = {"point_id": pid, "status": "error", **params, "error": _one_line(exc)}
        tb = traceback.format_exc()
    record = {"point_id": pid, "params": params, "summary": summary, "counters": counters, "traceback": tb,
              "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "host": platform.node()}
    atomic_write_text(out / "records" / f"{pid}.json", _json_text(record))
    return summary


def _run_point(spec: dict[str, Any], params: dict[str, Any], out: Path,
               pid: str) -> tuple[dict[str, Any], list[list[Any]]]:
    from pipeline_sim.accuracy import ReferenceSpec, error_map, error_metrics, reference_image
    from pipeline_sim.cli import _package_versions
    from pipeline_sim.config import load_arch
    from pipeline_sim.jit import warm_up
    from pipeline_sim.output import file_name, finite_or_none, write_derived, write_json, write_pass, write_png
    from pipeline_sim.workload import load_workload

    compile_s = warm_up()
    image_params, file_keys, overrides = _split_params(params)
    overrides = list(spec["set"]) + overrides
    workload = load_workload(spec["scene"], load_arch(spec["arch"]), image_params, file_keys) \
        .with_settings(overrides)
    arch = workload.arch
    run = workload.run()
    result = run.total()

    # a workload with one image to measure (a scene) is measured against its reference
    scene = workload.reference_scene()
    t0 = time.perf_counter()
    if scene is not None:
        ref_spec = ReferenceSpec(**spec["reference"])
        reference = reference_image(scene, ref_spec, cache_dir=out / "reference", arch=arch)
    t1 = time.perf_counter()
    all_metrics = error_metrics(result.image, reference) if scene is not None else {}
    # an image identical to its reference has an infinite PSNR: null in the records
    metrics = {k: finite_or_none(all_metrics.get(k)) for k in spec["metrics"]}
    emap = error_map(result.image, reference) if scene is not None else None
    t2 = time.perf_counter()

    figures = dict(result_figures(run.results))
    missing = [r for r in spec.get("results", []) if r not in figures]
    if missing:
        raise UserError(f"the workload's results.json has no figure {', '.join(missing)} "
                        f"(it has: {', '.join(figures) or 'none'})")
    summary = {"point_id": pid, "status": "ok", **params, **_summarize(result, metrics),
               **{f"{RESULT_PREFIX}{k}": v for k, v in figures.items()}}
    info = {
        "point_id": pid,
        "params": params,
        "sweep": spec["sweep"],
        "scene": spec["scene"],
        "scene_digest": workload.digest,
        "kind": workload.kind,
        "workload": workload.resolved(),
        **({"image": dataclasses.asdict(scene.image), "seed": scene.image.seed} if scene is not None else {}),
        "arch_file": spec["arch"],
        "set": overrides,
        "arch": arch.to_dict(),
        **({"pass": scene.pass_state.to_dict(), "simulation": scene.simulation.to_dict()} if scene is not None else {}),
        "reference": spec["reference"],
        "metrics": metrics,
        "summary": summary,
        "dimensions": result.dimensions,
        "units_used": result.units_used,
        "bypassed": [u for u in ("zcull", "sample_tester") if u not in result.units_used],
        "screen_regions": result.region_info,
        "frame_cycles": result.timing.frame_cycles,
        "wall_time_s": result.wall_time,
        "reference_time_s": t1 - t0,
        "metrics_time_s": t2 - t1,
        "compile_time_s": compile_s,
        "versions": _package_versions(),
        "host": platform.node(),
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    trace = {"units": result.timing.traces, "queues": result.timing.queue_series,
             "frame_cycles": result.timing.frame_cycles}
    # the point's folder is the sweep's own: a folder left by an earlier try is written over
    with OutputFolder(out / "points" / pid, "sweep point", force=True) as folder:
        tmp = folder.staging
        np.save(tmp / "image.npy", result.image)
        if emap is not None:
            np.save(tmp / "error_map.npy", np.asarray(emap, dtype=np.float32))
        write_png(tmp / "image.png", result.image)
        result.counters.to_csv(tmp / "counters.csv", index=False)
        result.timing.units.to_csv(tmp / "timing.csv", index=False)
        result.timing.queues.to_csv(tmp / "queues.csv", index=False)
        (tmp / "trace.json").write_text(_json_text(trace, indent=None))
        write_json(tmp / "run.json", info)
        if len(run.passes) > 1 or run.results or run.tables or run.arrays or run.figures or run.images:
            for name, r in run.passes.items():  # a workload of several passes or with derived results
                write_pass(tmp / "passes" / file_name(name, "pass"), r)
            write_derived(tmp, run)
        folder.commit()
    c = result.counters
    counters = [[str(u), str(n), int(v)] for u, n, v in zip(c.unit, c.counter, c.value)]
    return summary, counters


# ---------------------------------------------------------------------------
# Tables


def _read_record(path: Path) -> dict[str, Any] | None:
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and isinstance(rec.get("summary"), dict) else None


def _result_columns(spec: SweepSpec, records: dict[str, dict[str, Any]]) -> list[str]:
    """The workload-result columns of the points: the sweep's listed results first, then the others as found."""
    columns = [f"{RESULT_PREFIX}{r}" for r in spec.results]
    for p in spec.points:
        rec = records.get(point_id(p))
        if rec is not None:
            columns += [k for k in rec["summary"] if k.startswith(RESULT_PREFIX) and k not in columns]
    return columns


def _points_frame(spec: SweepSpec, records: dict[str, dict[str, Any]]) -> pd.DataFrame:
    params = spec.param_names
    columns = ["point_id", "status", *params, *SUMMARY_FIELDS, *spec.metrics, *_result_columns(spec, records),
               "error"]
    rows = []
    for p in spec.points:
        rec = records.get(point_id(p))
        if rec is not None:
            row = dict(rec["summary"])
            row.setdefault("error", "")
            rows.append(row)
    frame = pd.DataFrame(rows, columns=columns)
    return frame


def _results_frame(spec: SweepSpec, records: dict[str, dict[str, Any]]) -> pd.DataFrame:
    names = [n for n in SUMMARY_FIELDS if n != "bottleneck_unit"] + list(spec.metrics) + _result_columns(spec, records)
    rows: list[tuple[str, str, str, str, Any]] = []
    for p in spec.points:
        pid = point_id(p)
        rec = records.get(pid)
        if rec is None:
            continue
        rows.extend((pid, "counter", u, n, v) for u, n, v in rec.get("counters") or [])
        s = rec["summary"]
        rows.extend((pid, "summary", "", n, s[n]) for n in names if n in s)
    frame = pd.DataFrame([r[:4] for r in rows], columns=["point_id", "kind", "unit", "name"])
    frame["value"] = pd.Series([r[4] for r in rows], dtype=object)  # counters stay integers
    return frame


def _write_tables(out: Path, spec: SweepSpec, records: dict[str, dict[str, Any]]) -> pd.DataFrame:
    points = _points_frame(spec, records)
    _atomic_write_csv(out / "points.csv", points)
    _atomic_write_csv(out / "results.csv", _results_frame(spec, records))
    return points


# ---------------------------------------------------------------------------
# Running a sweep


def _fingerprint(spec: SweepSpec) -> dict[str, Any]:
    """What makes earlier records in a folder reusable: everything but the point list."""
    d = spec.to_dict()
    return {k: d[k] for k in ("scene_digest", "arch_digest", "set", "metrics", "reference")}


@contextlib.contextmanager
def _folder_lock(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``out`` (released by the OS if the process dies)."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        yield
        return
    fh = open(out / ".sweep.lock", "w")
    try:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise UserError(f"{out}: another sweep is running in this folder") from None
        yield
    finally:
        fh.close()


def _clean_leftovers(out: Path) -> None:
    """Remove the temporary files and folders killed processes left in the sweep folder."""
    for folder in (out, out / "points", out / "records", out / "reference"):
        clean_leftovers(folder)


#: What a sweep writes in its results folder (``--force`` replaces these in a folder of other files).
SWEEP_NAMES = ("sweep.json", "points.csv", "results.csv", "points/", "records/", "reference/", ".sweep.lock")


def _read_sweep_meta(out: Path) -> dict[str, Any] | None:
    """The ``sweep.json`` this tool wrote in ``out``, or None if there is none (or it is not the tool's)."""
    try:
        doc = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("fingerprint"), dict) else None


def _claim_folder(out: Path, force: bool) -> None:
    """Refuse a folder that holds something other than a sweep's results, unless ``force``; check it is writable."""
    if os.path.lexists(out) and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder; give a new, empty or sweep results folder")
    if out.is_dir() and not force and _read_sweep_meta(out) is None:
        try:
            foreign = sorted(e.name for e in out.iterdir())
        except OSError as exc:
            raise UserError(f"--out {out}: cannot read it: {exc.strerror}") from None
        if foreign:
            raise UserError(f"--out {out}: exists and does not hold a sweep's results ({', '.join(foreign[:3])}"
                            f"{', ...' if len(foreign) > 3 else ''}); give a new or empty folder, or add --force to "
                            f"write the sweep into it ({', '.join(SWEEP_NAMES)} would be replaced, nothing else)")
    check_writable_folder(out, "--out")


def _prepare_folder(spec: SweepSpec, out: Path) -> None:
    """Check an existing folder holds the same sweep; write ``sweep.json``."""
    meta = out / "sweep.json"
    fp = _fingerprint(spec)
    written = _read_sweep_meta(out)
    if written is not None:
        old = written["fingerprint"]
        changed = [k for k in fp if json.dumps(old.get(k), sort_keys=True) != json.dumps(fp[k], sort_keys=True)]
        if changed:
            raise UserError(f"{meta}: the folder holds results of a different sweep ({', '.join(changed)} "
                            "changed); use another output folder or delete this one")
    doc = {
        "sweep_file": str(spec.path),
        "spec": spec.to_dict(),
        "fingerprint": fp,
        "axes": [{"keys": list(keys), "values": [list(v) for v in values]} for keys, values in spec.axes],
        "points": [{"point_id": point_id(p), "params": p} for p in spec.points],
        "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    atomic_write_text(meta, _json_text(doc))


class _Progress:
    """tqdm on a terminal, else one plain line per finished point (stderr)."""

    def __init__(self, total: int, done: int, enabled: bool) -> None:
        self.total, self.k, self.enabled = total, done, enabled
        self.bar = None
        if enabled and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, unit="point", desc="sweep", file=sys.stderr)

    def message(self, text: str) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)

    def update(self, summary: dict[str, Any]) -> None:
        self.k += 1
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.update(1)
            if summary.get("status") != "ok":
                self.bar.write(f"{summary['point_id']} error: {summary.get('error', '')}", file=sys.stderr)
            return
        status = summary.get("status", "?")
        wall = summary.get("wall_time_s")
        tail = f"wall={wall:.2f}s" if isinstance(wall, float) else summary.get("error", "")
        print(f"[{self.k}/{self.total}] {summary['point_id']} {status} {tail}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _warm_parent(spec: SweepSpec) -> float:
    """Compile or load every kernel in this process so workers only load the cache."""
    from pipeline_sim.jit import warm_up

    start = time.perf_counter()
    warm_up()
    if spec.reference.kind == "accumulation":  # the sample-table kernel is not in warm_up
        from pipeline_sim.sampling import make_samples

        make_samples(4, 4, 1, 0, lens=True, motion=True, pattern="table",
                     table=np.full((1, 5), 0.5, dtype=np.float32))
    return time.perf_counter() - start


def _failed(params: dict[str, Any], exc: BaseException) -> dict[str, Any]:
    return {"point_id": point_id(params), "status": "error", **params, "error": f"worker failed: {_one_line(exc)}"}


def _run_local(spec_dict: dict, pending: list[dict], out: Path, workers: int,
               finish: Callable[[dict, dict], None]) -> None:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    from pipeline_sim.memory import keep_freed_memory

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=keep_freed_memory)
    try:
        futures = {pool.submit(run_point, spec_dict, p, str(out)): p for p in pending}
        for fut in as_completed(futures):
            params = futures[fut]
            try:
                summary = fut.result()
            except BrokenProcessPool:
                raise RuntimeError("a sweep worker process died; finished points are kept, "
                                   "run the same command again to resume") from None
            except Exception as exc:
                summary = _failed(params, exc)
            finish(params, summary)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _run_dask(spec_dict: dict, pending: list[dict], out: Path, workers: int, scheduler: str | None,
              finish: Callable[[dict, dict], None]) -> None:
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
        client = Client(cluster)
    try:
        futures = {}
        for p in pending:
            fut = client.submit(run_point, spec_dict, p, str(out), pure=False)
            futures[fut.key] = (fut, p)
        for fut in as_completed([f for f, _ in futures.values()]):
            params = futures[fut.key][1]
            try:
                summary = fut.result()
            except Exception as exc:
                summary = _failed(params, exc)
            finish(params, summary)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_sweep(spec: SweepSpec, out_dir: str | Path, *, executor: str = "local", workers: int | None = None,
              scheduler: str | None = None, progress: bool = True, retry_errors: bool = False,
              force: bool = False) -> pd.DataFrame:
    """Run every point of ``spec`` not already done in ``out_dir``; return the points table.

    ``executor``: ``"local"`` (a spawn process pool of ``workers``, default
    ``os.cpu_count()``), ``"dask"`` (``scheduler`` address, else a
    LocalCluster of ``workers`` processes on 127.0.0.1, closed at the end) or
    ``"serial"`` (in this process). Finished points (a record exists) are
    never run again; ``retry_errors`` reruns points recorded as errors.
    ``out_dir`` must be new, empty or a sweep's results folder; ``force``
    writes the sweep into any other folder without removing anything there.
    """
    if executor not in EXECUTORS:
        raise UserError(f"executor: unknown executor '{executor}'{did_you_mean(executor, EXECUTORS)}; "
                        f"known: {', '.join(EXECUTORS)}")
    if workers is not None and workers < 1:
        raise UserError(f"workers: must be at least 1, got {workers}")
    out = Path(out_dir).resolve()
    _claim_folder(out, force)
    with _folder_lock(out):
        _clean_leftovers(out)
        _prepare_folder(spec, out)
        (out / "records").mkdir(exist_ok=True)
        records: dict[str, dict[str, Any]] = {}
        for params in spec.points:
            pid = point_id(params)
            rec = _read_record(out / "records" / f"{pid}.json")
            if rec is not None and not (retry_errors and rec["summary"].get("status") != "ok"):
                records[pid] = rec
        pending = [p for p in spec.points if point_id(p) not in records]
        total = len(spec.points)
        _write_tables(out, spec, records)
        bar = _Progress(total, total - len(pending), progress)
        if not pending:
            bar.message(f"sweep: all {total} points already done in {out}")
            bar.close()
            return _write_tables(out, spec, records)
        n = min(workers or os.cpu_count() or 1, len(pending))
        if executor == "serial":
            where = "in this process"
        elif executor == "dask" and scheduler:
            where = f"scheduler {scheduler}"
        else:
            where = f"{n} worker{'s' * (n > 1)}"
        bar.message(f"sweep: {total} points, {total - len(pending)} done, {len(pending)} to run "
                    f"({executor}, {where}) -> {out}")
        spec_dict = spec.to_dict()

        def finish(params: dict[str, Any], summary: dict[str, Any]) -> None:
            pid = point_id(params)
            path = out / "records" / f"{pid}.json"
            rec = _read_record(path)
            if rec is None or rec.get("summary", {}).get("status") != summary.get("status"):
                # the worker could not write it (died, or no shared folder): record what we know
                rec = {"point_id": pid, "params": params, "summary": summary, "counters": [], "traceback": None,
                       "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "host": platform.node()}
                atomic_write_text(path, _json_text(rec))
            records[pid] = rec
            _write_tables(out, spec, records)
            bar.update(summary)

        try:
            if executor == "serial":
                _warm_parent(spec)
                for params in pending:
                    finish(params, run_point(spec_dict, params, str(out)))
            elif executor == "local":
                _warm_parent(spec)
                _run_local(spec_dict, pending, out, n, finish)
            else:
                _warm_parent(spec)
                _run_dask(spec_dict, pending, out, n, scheduler, finish)
        finally:
            bar.close()
        return _write_tables(out, spec, records)
