"""Writing a run's outputs: images, JSON, and single files replaced atomically.

Whole output folders are claimed and written through
:class:`pipeline_sim.output_folder.OutputFolder`; single files through
:func:`atomic_write_bytes` (a temporary sibling renamed over the target).
"""

from __future__ import annotations

import io
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR
from PIL import Image

from pipeline_sim.errors import UserError
from pipeline_sim.output_folder import hold_lock, ordinary_mode, staging_prefix


def linear_to_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear float (H, W, channels) RGB(A) to 8-bit sRGB RGB (IEC 61966-2-1
    transfer curve), converted a band of rows at a time: the float64
    temporaries stay small however large the image. Of an image of fewer
    than three channels, the first is shown as grey."""
    out = np.empty(image.shape[:2] + (3,), np.uint8)
    rows = max(1, (1 << 18) // max(image.shape[1], 1))
    shown = slice(0, 3) if image.shape[2] >= 3 else slice(0, 1)
    for r in range(0, image.shape[0], rows):
        rgb = np.clip(np.nan_to_num(image[r : r + rows, :, shown].astype(np.float64)), 0.0, 1.0)
        srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
        out[r : r + rows] = np.round(srgb * 255.0)
    return out


def write_png(path: Path, image: np.ndarray) -> None:
    Image.fromarray(linear_to_srgb8(image), mode="RGB").save(path)


def exr_channel_names(channels: int) -> list[str]:
    """The OpenEXR channel names of an image of ``channels`` channels: R, G, B, A of four, R, G, B of
    three, Y of one, else C0, C1, ..."""
    return {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(channels, [f"C{i}" for i in range(channels)])


def write_exr(path: Path, image: np.ndarray) -> None:
    """Linear float32 OpenEXR (ZIP compressed) of an (H, W, channels) image, channels named by
    ``exr_channel_names``."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    image = np.asarray(image, dtype=np.float32)
    names = exr_channel_names(image.shape[2])
    if len(names) in (3, 4):  # interleaved, as one multi-channel entry: no copy of a float32 image
        channels = {"".join(names): np.ascontiguousarray(image)}
    else:
        channels = {name: np.ascontiguousarray(image[:, :, i]) for i, name in enumerate(names)}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def read_exr(path: Path) -> np.ndarray:
    """An image ``write_exr`` wrote, (H, W, channels) float32."""
    with OpenEXR.File(str(path)) as f:
        found = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    for packed in ("RGBA", "RGB"):
        if packed in found:
            return found[packed]
    names = exr_channel_names(len(found))
    return np.stack([found[name] for name in names], axis=2)


def write_json(path: Path, data: dict) -> None:
    """Strict JSON (RFC 8259): a NaN or infinity is an error here, not a
    ``NaN`` token other parsers reject; a figure with no finite value is
    written as null by its source (:func:`finite_or_none`)."""
    path.write_text(json.dumps(data, indent=2, sort_keys=True, default=_json_default, allow_nan=False) + "\n")


def _json_default(obj):
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serializable: {type(obj)}")


def finite_or_none(value: float | None) -> float | None:
    """``value`` as a float, or None (JSON null) when it has no finite value:
    a ratio over nothing (STE with no sample tested) or the PSNR of two
    identical images."""
    return None if value is None or not np.isfinite(value) else float(value)


def finite_results(value: Any) -> Any:
    """A workload's results for results.json: every float (numpy's too) through :func:`finite_or_none` and
    numpy integers as ints, inside dicts and lists as well; text as it is."""
    if isinstance(value, (float, np.floating)):
        return finite_or_none(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, dict):
        return {k: finite_results(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_results(v) for v in value]
    return value


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary sibling, flush it to disk, then rename it over ``path``.

    The file gets the mode an existing ``path`` had, else the umask's
    ordinary mode (not the temporary file's private 0600).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = os.stat(path).st_mode & 0o7777
    except OSError:
        mode = ordinary_mode(directory=False)
    fd, tmp = tempfile.mkstemp(prefix=staging_prefix(path.name), suffix=".tmp", dir=path.parent)
    try:
        hold_lock(fd)   # while locked, no other process takes it for a killed writer's leftover
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def atomic_write_text(path: Path, text: str) -> None:
    """``atomic_write_bytes`` for UTF-8 text."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_save_npy(path: Path, array: np.ndarray) -> None:
    """``np.save`` through a temporary file and a rename."""
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    atomic_write_bytes(path, buf.getvalue())


#: A pass or table name as it may name a file or folder of the run folder.
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]*")


def file_name(name: str, what: str) -> str:
    """``name`` (of a pass or a table) as a file or folder name, or a one-line error."""
    if not _NAME.fullmatch(name):
        raise UserError(f"{what} name '{name}' cannot name a file: use letters, digits and _ . + - "
                        "(not first)")
    return name


def write_pass(folder: Path, result) -> None:
    """One pass's outputs into ``folder``: image.npy, image.exr, image.png, counters.csv,
    timing.csv, queues.csv and trace.json (docs/outputs.md)."""
    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "image.npy", result.image)
    write_exr(folder / "image.exr", result.image)
    write_png(folder / "image.png", result.image)
    result.counters.to_csv(folder / "counters.csv", index=False)
    result.timing.units.to_csv(folder / "timing.csv", index=False)
    result.timing.queues.to_csv(folder / "queues.csv", index=False)
    trace = {"units": result.timing.traces, "queues": result.timing.queue_series,
             "frame_cycles": result.timing.frame_cycles}
    (folder / "trace.json").write_text(json.dumps(trace, separators=(",", ":"), default=_json_default,
                                                  allow_nan=False) + "\n")


def _changes(base: dict, other: dict) -> dict[str, Any]:
    """The settings of the architecture ``other`` that differ from ``base``, as dotted paths."""
    return {f"{section}.{key}": value for section, keys in other.items() for key, value in keys.items()
            if base.get(section, {}).get(key) != value}


def pass_record(p, result, arch: dict) -> dict[str, Any]:
    """run.json's record of one pass: its state as it ran, the architecture settings it changed
    from the workload's, and what it did."""
    from pipeline_sim.workload import pass_state
    from reports.run_report import headline

    return {**pass_state(p), "arch_changes": _changes(arch, p.arch.to_dict()), "dimensions": result.dimensions,
            "units_used": result.units_used,
            "bypassed": [u for u in ("zcull", "sample_tester") if u not in result.units_used],
            "screen_regions": result.region_info, "frame_cycles": result.timing.frame_cycles,
            "headline": headline(result), "wall_time_s": result.wall_time}


def _files(result) -> dict[str, list[str]]:
    """run.json's lists of a workload's arrays, figures and images, each list when it has any."""
    files = {"arrays": [f"{name}.npy" for name in result.arrays], "figures": [f"{name}.png" for name in result.figures],
             "images": [f"images/{name}.png" for name in result.images]}
    return {key: names for key, names in files.items() if names}


def write_derived(folder: Path, result) -> None:
    """What a workload derived from its passes, into ``folder``: ``results.json``, one CSV per table, one .npy
    per array, one PNG per figure and ``images/`` (a run folder's and a sweep point's)."""
    for name, table in result.tables.items():
        table.to_csv(folder / f"{file_name(name, 'table')}.csv", index=False)
    for name, array in result.arrays.items():
        np.save(folder / f"{file_name(name, 'array')}.npy", array)
    for name, figure in result.figures.items():
        figure.savefig(folder / f"{file_name(name, 'figure')}.png", dpi=100)
    for name, image in result.images.items():
        (folder / "images").mkdir(exist_ok=True)
        stem = file_name(name, "image")
        np.save(folder / "images" / f"{stem}.npy", image)
        write_png(folder / "images" / f"{stem}.png", image)
    write_json(folder / "results.json", result.results)


def write_run(folder: Path, workload, result, info: dict[str, Any]) -> dict[str, Any]:
    """A workload's run folder (docs/outputs.md) into ``folder`` (an output folder's staging):
    ``passes/<pass>/`` for every pass, ``results.json``, one CSV per table, one .npy per array, one PNG
    per figure, ``images/`` (the workload's images), ``run.json``
    (everything resolved, plus ``info``) and the report. Returns run.json's content."""
    from reports.run_report import headline, html_report, markdown_report, run_figures

    arch = workload.arch.to_dict()
    states = {p.name: p for p in workload.states}
    passes = []  # in run order (run.json's keys are sorted)
    for name, r in result.passes.items():
        write_pass(folder / "passes" / file_name(name, "pass"), r)
        passes.append(pass_record(states[name], r, arch))
    write_derived(folder, result)
    total = result.total()
    run_info = {"kind": workload.kind, "workload": {**workload.resolved(), "digest": workload.digest},
                "arch": arch, "passes": passes, "results": sorted(result.results),
                "tables": [f"{name}.csv" for name in result.tables], **_files(result),
                "frame_cycles": total.timing.frame_cycles,
                "headline": headline(total), "wall_time_s": total.wall_time, **info}
    write_json(folder / "run.json", run_info)
    figures = run_figures(result)
    (folder / "report.md").write_text(markdown_report(result, run_info, files_dir=folder / "report_files",
                                                      figures=figures))
    (folder / "report.html").write_text(html_report(result, run_info, figures=figures))
    return run_info
