"""Writing a run's outputs: images, JSON, and single files replaced atomically.

Whole output folders are claimed and written through
:class:`pipeline_sim.output_folder.OutputFolder`; single files through
:func:`atomic_write_bytes` (a temporary sibling renamed over the target).
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from pipeline_sim.output_folder import hold_lock, ordinary_mode, staging_prefix


def linear_to_srgb8(image: np.ndarray) -> np.ndarray:
    """Linear float (H, W, 3 or 4) RGB(A) to 8-bit sRGB RGB (IEC 61966-2-1
    transfer curve), converted a band of rows at a time: the float64
    temporaries stay small however large the image."""
    out = np.empty(image.shape[:2] + (3,), np.uint8)
    rows = max(1, (1 << 18) // max(image.shape[1], 1))
    for r in range(0, image.shape[0], rows):
        rgb = np.clip(np.nan_to_num(image[r : r + rows, :, :3].astype(np.float64)), 0.0, 1.0)
        srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
        out[r : r + rows] = np.round(srgb * 255.0)
    return out


def write_png(path: Path, image: np.ndarray) -> None:
    Image.fromarray(linear_to_srgb8(image), mode="RGB").save(path)


def write_exr(path: Path, image: np.ndarray) -> None:
    """Linear float32 RGBA OpenEXR (ZIP compressed)."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    rgba = np.ascontiguousarray(image, dtype=np.float32)  # no copy of a float32 image
    with OpenEXR.File(header, {"RGBA": rgba}) as f:
        f.write(str(path))


def read_exr(path: Path) -> np.ndarray:
    with OpenEXR.File(str(path)) as f:
        return np.asarray(f.channels()["RGBA"].pixels)


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
