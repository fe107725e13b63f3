"""The net5 pattern bit for bit against a slow reference written from its definition.

The reference follows the scrambled-net definition of ``_net5_kernel``'s
docstring (Munkberg11 §5 for the t order, Matousek 1998 for the scramble) in
plain Python integers, one sample at a time: the unscrambled points are
scipy's 4D Sobol points with the index as time, each pixel scrambles every
dimension's digits by a random unit lower-triangular matrix and a digital
shift drawn from the SplitMix64 stream of (seed, pixel, stream, index), and
the jitter below the strata comes from the stream at the sample's t-sorted
position. Nothing here calls the kernel's helpers, so a faster kernel must
reproduce every float of every sample exactly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import qmc

from pipeline_sim.sampling import SampleSet, _concentric_many, make_samples

MASK = (1 << 64) - 1
GOLDEN = 0x9E3779B97F4A7C15
PIXEL_SALT = 0xD1B54A32D192ED03
STREAM = 40  # scramble columns and shift of dimension d: STREAM + d; jitter x y: +5, u v: +6, t: +7
FRAC = 24  # fixed-point bits of every coordinate


def splitmix(z: int) -> int:
    """The SplitMix64 finaliser on a 64-bit integer."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def concentric(a: float, b: float) -> tuple[float, float]:
    """Shirley-Chiu concentric map of [0,1)^2 onto the unit disk, by cases, with the C library's cos and sin."""
    sa, sb = 2.0 * a - 1.0, 2.0 * b - 1.0
    if sa == 0.0 and sb == 0.0:
        return 0.0, 0.0
    if abs(sa) > abs(sb):
        r, phi = sa, (math.pi / 4) * (sb / sa)
    else:
        r, phi = sb, (math.pi / 2) - (math.pi / 4) * (sa / sb)
    return r * math.cos(phi), r * math.sin(phi)


def reference_net5(width: int, height: int, spp: int, seed: int, *, lens: bool, motion: bool,
                   lens_shape: str, rows: tuple[int, int]) -> dict[str, np.ndarray]:
    """Samples of image rows ``rows`` as float32 arrays x, y, u, v, t, pixel-major, t-sorted in each pixel."""
    m = spp.bit_length() - 1
    jb = FRAC - m
    k = np.arange(spp)
    sobol = np.rint(qmc.Sobol(d=4, scramble=False).random_base2(m) * spp).astype(np.int64)
    points = np.empty((spp, 5), dtype=np.int64)  # net point j: Sobol point k with gray(k) = j, and t digits j
    points[k ^ (k >> 1), :4] = sobol
    points[:, 4] = k
    npix = width * (rows[1] - rows[0])
    out = {name: np.empty(npix * spp, dtype=np.float32) for name in "xyuvt"}
    seed_key = splitmix((seed + GOLDEN) & MASK)
    for q in range(npix):
        key = splitmix(seed_key ^ splitmix((((rows[0] * width + q) * GOLDEN) + PIXEL_SALT) & MASK))

        def rand(stream: int, i: int) -> int:
            return splitmix((key + ((stream << 40) + i + 1) * GOLDEN) & MASK)

        def top(h: int, bits: int) -> int:
            return (h & MASK) >> (64 - bits) if bits else 0

        lower = [[(1 << b) | (rand(STREAM + d, b) & ((1 << b) - 1)) for b in range(m)] for d in range(5)]
        shift = [top(rand(STREAM + d, m), m) for d in range(5)]

        def scramble(d: int, digits: int) -> int:
            out_digits = shift[d]
            for b in range(m):
                if digits >> b & 1:
                    out_digits ^= lower[d][b]
            return out_digits

        for j in range(spp):
            x, y, a, b, s = (scramble(d, int(points[j, d])) for d in range(5))
            h, g = rand(STREAM + 5, s), rand(STREAM + 6, s)
            i = q * spp + s
            out["x"][i] = ((x << jb) | top(h, jb)) / 2**FRAC
            out["y"][i] = ((y << jb) | top(h << 24, jb)) / 2**FRAC
            out["t"][i] = ((s << jb) | top(rand(STREAM + 7, s), jb)) / 2**FRAC if motion else 0.5
            ua, vb = ((a << jb) | top(g, jb)) / 2**FRAC, ((b << jb) | top(g << 24, jb)) / 2**FRAC
            if not lens:
                out["u"][i] = out["v"][i] = 0.0
            elif lens_shape == "square":
                out["u"][i], out["v"][i] = 2.0 * ua - 1.0, 2.0 * vb - 1.0
            else:
                out["u"][i], out["v"][i] = concentric(ua, vb)
    return out


def assert_same_bits(s: SampleSet, ref: dict[str, np.ndarray]) -> None:
    for name, want in ref.items():
        got = getattr(s, name)
        diff = np.flatnonzero(got.view(np.uint32) != want.view(np.uint32))
        assert got.shape == want.shape and diff.size == 0, (
            f"{name}: {diff.size} of {want.size} differ, first at {diff[:1]}: {got[diff[:1]]} != {want[diff[:1]]}")


def check(width: int, height: int, spp: int, seed: int, lens: bool, motion: bool, lens_shape: str,
          rows: tuple[int, int] | None = None) -> None:
    s = make_samples(width, height, spp, seed, lens=lens, motion=motion, pattern="net5", lens_shape=lens_shape,
                     rows=rows)
    ref = reference_net5(width, height, spp, seed, lens=lens, motion=motion, lens_shape=lens_shape,
                         rows=rows or (0, height))
    assert_same_bits(s, ref)


@pytest.mark.parametrize("spp", [1 << m for m in range(9)])
@pytest.mark.parametrize("lens_shape", ["disk", "square"])
def test_net5_equals_reference_at_every_spp(spp, lens_shape):
    check(3, 2, spp, 5, True, True, lens_shape)


@pytest.mark.parametrize("lens, motion", [(True, False), (False, True), (False, False)])
@pytest.mark.parametrize("lens_shape", ["disk", "square"])
def test_net5_equals_reference_with_flags_off(lens, motion, lens_shape):
    check(5, 3, 16, 2**64 - 1, lens, motion, lens_shape)


def test_net5_equals_reference_in_a_row_band():
    check(7, 6, 64, 123, True, True, "disk", rows=(2, 5))


def test_net5_equals_reference_across_thread_chunks():
    """More than one work item of pixels (4096 each), so several kernel calls fill the arrays."""
    check(70, 60, 2, 9, True, True, "disk")


def test_kernel_concentric_map_equals_reference_bits():
    """The kernels' concentric map (branch-free angles, sin and cos by a polynomial, the C library's sincos
    where the polynomial cannot settle the float32) against the map by cases above with the C library's cos
    and sin, in float32 bits: the centre, both diagonals (where the wedges meet), points next to the axes
    (results near zero, where the polynomial gives way) and random 24-bit points."""
    rng = np.random.default_rng(4)
    grid = np.arange(0, 1 << FRAC, 4099) / 2**FRAC
    near = (np.arange(-300, 301) + (1 << (FRAC - 1))) / 2**FRAC  # 2a - 1 or 2b - 1 within 600 steps of 0
    other = rng.integers(0, 1 << FRAC, near.size) / 2**FRAC
    a = np.concatenate([[0.5], grid, grid, near, other, rng.integers(0, 1 << FRAC, 200000) / 2**FRAC])
    b = np.concatenate([[0.5], grid, 1.0 - grid, other, near, rng.integers(0, 1 << FRAC, 200000) / 2**FRAC])
    u, v = _concentric_many(a, b)
    want = np.array([concentric(x, y) for x, y in zip(a, b)]).astype(np.float32)
    assert u.dtype == v.dtype == np.float32
    assert np.array_equal(u.view(np.uint32), want[:, 0].view(np.uint32))
    assert np.array_equal(v.view(np.uint32), want[:, 1].view(np.uint32))
