"""Image files (pipeline_sim/output.py): OpenEXR and PNG of images of any channel count."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from pipeline_sim.output import read_exr, write_exr, write_png


@pytest.mark.parametrize("channels", [1, 2, 3, 4, 5, 11])
def test_exr_holds_every_channel_bit_for_bit(tmp_path, channels):
    """What ``write_exr`` writes is the image, read back through OpenEXR's own channel list: every channel
    of every pixel, negative values and values above 1 included, named R, G, B, A of four channels, R, G, B
    of three, Y of one and C0, C1, ... otherwise."""
    img = (np.random.default_rng(channels).random((7, 5, channels)) * 40 - 20).astype(np.float32)
    write_exr(tmp_path / "x.exr", img)
    np.testing.assert_array_equal(read_exr(tmp_path / "x.exr"), img)
    with OpenEXR.File(str(tmp_path / "x.exr"), separate_channels=True) as f:
        stored = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    names = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(channels, [f"C{i}" for i in range(channels)])
    assert sorted(stored) == sorted(names)
    for i, name in enumerate(names):
        np.testing.assert_array_equal(stored[name], img[:, :, i])


def _srgb8(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1, one value at a time."""
    def one(x):
        x = min(max(float(x), 0.0), 1.0)
        return round(255 * (12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055))
    return np.vectorize(one)(linear).astype(np.uint8)


@pytest.mark.parametrize("channels", [1, 2, 3, 4, 6])
def test_png_shows_the_first_three_channels_or_the_first_as_grey(tmp_path, channels):
    img = np.random.default_rng(channels).random((6, 4, channels)).astype(np.float32) * 1.2 - 0.1
    write_png(tmp_path / "x.png", img)
    got = np.asarray(Image.open(tmp_path / "x.png"))
    shown = img[:, :, :3] if channels >= 3 else np.repeat(img[:, :, :1], 3, axis=2)
    np.testing.assert_array_equal(got, _srgb8(shown))
