"""Per-pixel 5D sample patterns (x, y, u, v, t) for stochastic rasterization.

The ``net`` pattern (the default before ``net5``, and the pattern of accuracy
references) follows Munkberg et al., "Hierarchical Stochastic Motion
Blur Rasterization" (HPG 2011), §5 and Appendix A (eq. 10-19): the
Grünschloß-Keller (0, m, 3)-net in base 2 with generator matrices

* ``C1`` = exchange matrix (``x_j = j / 2^m``),
* ``C2[k, l] = 1 if k <= l`` (with ``C1``: the Larcher-Pillichshammer points),
* ``C3[k, l] = binom(l, k) mod 2`` (1-based; an involution over F2),

re-ordered by the digit permutation ``D = C3 C1`` so that the time component
becomes sequential.  The t-ordered matrices are ``C1' = C1 C3 C1``
(``binom(m+1-l, m+1-k) mod 2``, eq. 17), ``C2' = C2 C3 C1``
(``binom(m-l, k-1) mod 2``, eq. 19) and ``C3 D = C1``, so point ``j`` has
``t_j = j / 2^m`` while ``(x_j, y_j)`` are the LP points in another order.

Each pixel gets its own random digital scramble (XOR of each component's m
digits with a per-pixel mask, Kollig & Keller 2002), which keeps the
(0, m, 3)-net property, plus a uniform jitter inside the finest stratum.  The
lens coordinates are "padded" from an independently scrambled 2D LP net,
assigned through a per-pixel random permutation and mapped to the unit disk
with the Shirley-Chiu concentric map (or to the square ``[-1, 1]^2``).

The ``net5`` pattern (the default) is stratified in all five dimensions and
still t-ordered:
the first 2^m points of the 4D Sobol sequence give (x, y, u, v) and the point's
index gives ``t = j / 2^m`` (the index-as-coordinate construction that turns a
(t, s)-sequence into a (t, m, s+1)-net; Niederreiter 1992, Lemma 4.22). Each
pixel applies Matousek's random linear scramble (a random lower-triangular
digit matrix and a digital shift per dimension), which keeps every
elementary interval of the net and has the variance of Owen's nested
scrambling (Owen 2003), plus a jitter inside the finest stratum. The
scrambled t digits are a permutation of 0..2^m-1, so each point is written
straight to its t-sorted position.

All randomness comes from a counter-based hash of ``(seed, pixel, stream,
index)``, so a pixel's samples depend only on the seed and its global pixel
index: generating a band of rows gives exactly the rows of the full frame.
Coordinates are produced as 24-bit fixed-point values, so every float32
coordinate is exact, ``< 1`` and ``floor(coord * 2^m)`` is the net stratum.
The per-pixel loops are numba kernels (cached, GIL-free) run over pixel chunks
on a thread pool.
"""

from __future__ import annotations

import ctypes
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from math import comb, factorial

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

from pipeline_sim.errors import UserError, did_you_mean

__all__ = [
    "PATTERNS",
    "SampleSet",
    "check_spp",
    "interleave_groups",
    "interleave_tuple_set",
    "concentric_disk",
    "generator_matrices",
    "grunschloss_keller_matrices",
    "make_samples",
    "map_lens",
    "net5_columns",
    "net_integer_coords",
    "sobol_direction_numbers",
    "sobol_points",
    "square_lens",
    "t_ordered_net",
    "t_ordered_net5",
    "MAX_SPP",
]

#: Largest samples-per-pixel accepted by :func:`make_samples`.
MAX_SPP = 1 << 16
#: Fixed-point precision of generated coordinates (float32 mantissa).
_FRAC_BITS = 24
#: Sample patterns :func:`make_samples` generates; "table" also needs the user's table.
PATTERNS = ("net", "random", "stratified", "sobol", "table", "interleave", "net5")
#: The default pattern (of :func:`make_samples` and of a pass, ``PassState.sample_pattern``): stratified in all
#: five dimensions, its error falls faster with spp than ``net``'s (docs/performance.md, convergence).
DEFAULT_PATTERN = "net5"
#: Patterns whose spp must be a power of two (their strata are nets in base 2).
_POWER_OF_TWO = ("net", "sobol", "net5")
_LENS_SHAPES = ("disk", "square")
_TABLE_COLUMNS = ("x", "y", "u", "v", "t")
_MASK64 = (1 << 64) - 1

# ---------------------------------------------------------------------------
# Generator matrices and unscrambled nets
# ---------------------------------------------------------------------------


def _check_m(m: int, limit: int = 31) -> None:
    if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 0 <= m <= limit:
        raise UserError(f"net size m must be an integer in 0..{limit}, got {m!r}")


def grunschloss_keller_matrices(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Original Grünschloß-Keller matrices ``(C1, C2, C3)`` (Munkberg11 eq. 13-14), uint8 m x m."""
    _check_m(m)
    c1 = np.fliplr(np.eye(m, dtype=np.uint8)).copy()
    c2 = np.triu(np.ones((m, m), dtype=np.uint8))
    c3 = np.array(
        [[comb(l, k) & 1 for l in range(1, m + 1)] for k in range(1, m + 1)], dtype=np.uint8
    ).reshape(m, m)
    return c1, c2, c3


def generator_matrices(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """t-ordered matrices ``(C1', C2', C_t)`` of Munkberg11 eq. 12 / 17 / 19, uint8 m x m.

    ``C1'[k, l] = binom(m+1-l, m+1-k) mod 2``, ``C2'[k, l] = binom(m-l, k-1) mod 2``
    (1-based) and the time matrix is the exchange matrix, so ``t_j = j / 2^m``.
    """
    _check_m(m)
    c1p = np.array(
        [[comb(m + 1 - l, m + 1 - k) & 1 for l in range(1, m + 1)] for k in range(1, m + 1)],
        dtype=np.uint8,
    ).reshape(m, m)
    c2p = np.array(
        [[comb(m - l, k - 1) & 1 for l in range(1, m + 1)] for k in range(1, m + 1)],
        dtype=np.uint8,
    ).reshape(m, m)
    ct = np.fliplr(np.eye(m, dtype=np.uint8)).copy()
    return c1p, c2p, ct


def net_integer_coords(matrix: np.ndarray) -> np.ndarray:
    """Integer coordinates ``2^m * x_j`` (j = 0..2^m-1) of one component, eq. 11.

    Row k (0-based) of the F2 product is the digit of weight ``2^-(k+1)``; the
    product is evaluated by XOR-ing packed columns, as in the paper's GetXY.
    """
    c = np.asarray(matrix, dtype=np.uint64) & np.uint64(1)
    m = c.shape[0]
    weights = np.uint64(1) << np.arange(m - 1, -1, -1, dtype=np.uint64)
    columns = (c * weights[:, None]).sum(axis=0, dtype=np.uint64)  # packed column l
    j = np.arange(1 << m, dtype=np.uint64)
    out = np.zeros(1 << m, dtype=np.uint64)
    for l in range(m):
        bit = (j >> np.uint64(l)) & np.uint64(1)
        out ^= bit * columns[l]
    return out


def t_ordered_net(m: int) -> np.ndarray:
    """Unscrambled t-ordered (0, m, 3)-net: shape (2^m, 3) float64 columns (x, y, t).

    Row j has ``t = j / 2^m``; ``(x, y)`` are the Larcher-Pillichshammer points.
    """
    _check_m(m, 24)
    c1p, c2p, ct = generator_matrices(m)
    scale = 1.0 / (1 << m)
    return np.stack(
        [net_integer_coords(c).astype(np.float64) * scale for c in (c1p, c2p, ct)], axis=1
    )


# ---------------------------------------------------------------------------
# Lens maps
# ---------------------------------------------------------------------------


def concentric_disk(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley-Chiu concentric map of ``[0,1)^2`` onto the unit disk (area preserving)."""
    sa = 2.0 * np.asarray(a, dtype=np.float64) - 1.0
    sb = 2.0 * np.asarray(b, dtype=np.float64) - 1.0
    first = np.abs(sa) > np.abs(sb)
    r = np.where(first, sa, sb)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(
            first, (np.pi / 4) * (sb / sa), (np.pi / 2) - (np.pi / 4) * (sa / sb)
        )
    phi = np.where(r == 0.0, 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def square_lens(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map ``[0,1)^2`` to the square lens ``[-1,1)^2``."""
    return 2.0 * np.asarray(a, dtype=np.float64) - 1.0, 2.0 * np.asarray(b, dtype=np.float64) - 1.0


def map_lens(a: np.ndarray, b: np.ndarray, shape: str = "disk") -> tuple[np.ndarray, np.ndarray]:
    """Map unit-square lens samples to the lens shape ``"disk"`` or ``"square"``."""
    if shape == "disk":
        return concentric_disk(a, b)
    if shape == "square":
        return square_lens(a, b)
    raise UserError(f"lens_shape: unknown shape '{shape}'{did_you_mean(shape, _LENS_SHAPES)}")


# ---------------------------------------------------------------------------
# Counter-based hashing (numba kernels)
# ---------------------------------------------------------------------------

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_PIX_SALT = np.uint64(0xD1B54A32D192ED03)

# Random streams (per pixel).
_S_MASK_X, _S_MASK_Y, _S_MASK_T, _S_MASK_A, _S_MASK_B = 0, 1, 2, 3, 4
_S_JIT_XY, _S_JIT_T, _S_JIT_AB = 5, 6, 7
_S_PERM = 10
_S_RND_X, _S_RND_Y, _S_RND_T, _S_RND_A, _S_RND_B = 11, 12, 13, 14, 15
_S_ROT = 16
_S_STRAT = 17  # stratified: jitter streams 17..21, permutation keys 22..25
_S_SOBOL = 30  # sobol: digital-shift masks per dimension 30..34, jitter 35..39
_S_NET5 = 40  # net5: scramble matrix columns and shift per dimension 40..44, jitter 45..47

_JIT = dict(nogil=True, cache=True)


@numba.njit("uint64(uint64)", **_JIT)
def _mix(z: np.uint64) -> np.uint64:
    """SplitMix64 finaliser."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@numba.njit("uint64(uint64, int64)", **_JIT)
def _pixel_key(seed_key: np.uint64, p: np.int64) -> np.uint64:
    return _mix(seed_key ^ _mix(np.uint64(p) * _GOLDEN + _PIX_SALT))


@numba.njit("uint64(int64, int64)", **_JIT)
def _counter(stream: np.int64, i: np.int64) -> np.uint64:
    """The hashed counter of (stream, index), the same for every pixel."""
    return ((np.uint64(stream) << np.uint64(40)) + np.uint64(i) + np.uint64(1)) * _GOLDEN


@numba.njit("uint64(uint64, int64, int64)", **_JIT)
def _rand(key: np.uint64, stream: np.int64, i: np.int64) -> np.uint64:
    """64 random bits for (pixel key, stream, index)."""
    return _mix(key + _counter(stream, i))


@numba.njit("uint64(uint64, int64)", **_JIT)
def _top_bits(h: np.uint64, n: np.int64) -> np.uint64:
    if n <= 0:
        return np.uint64(0)
    return h >> np.uint64(64 - n)


@numba.njit("float64(uint64)", **_JIT)
def _fixed_to_unit(v: np.uint64) -> np.float64:
    """24-bit fixed point -> [0, 1) (exact in float32)."""
    return np.float64(v) * (1.0 / 16777216.0)


@numba.njit(error_model="numpy", **_JIT)
def _concentric_polar(a: float, b: float) -> tuple[float, float]:
    """Radius and angle of the Shirley-Chiu concentric map of ``(a, b)``, branch-free.

    Both wedges' angles are computed and one selected (the other may divide by
    zero, hence numpy's error model: an inf or NaN that is never used); the
    centre gets angle 0, so ``r cos phi`` and ``r sin phi`` are +0 there.
    """
    sa = 2.0 * a - 1.0
    sb = 2.0 * b - 1.0
    phi_a = (np.pi / 4) * (sb / sa)
    phi_b = (np.pi / 2) - (np.pi / 4) * (sa / sb)
    first = abs(sa) > abs(sb)
    r = sa if first else sb
    phi = phi_a if first else phi_b
    return r, phi if r != 0.0 else 0.0


@intrinsic
def _sincos(typingctx, x):
    """``(sin x, cos x)`` from one call of the C library's ``sincos`` (float64).

    The lens map's reference for the few points its polynomial cannot settle
    (LLVM turns a scalar ``np.sin`` and ``np.cos`` of one value into this
    call anyway; both give the same bits).
    """
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        dbl = ir.DoubleType()
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [dbl, dbl.as_pointer(), dbl.as_pointer()]), "sincos")
        sin_p = cgutils.alloca_once(builder, dbl)
        cos_p = cgutils.alloca_once(builder, dbl)
        builder.call(fn, [args[0], sin_p, cos_p])
        return context.make_tuple(builder, signature.return_type, [builder.load(sin_p), builder.load(cos_p)])

    return types.UniTuple(types.float64, 2)(types.float64), codegen


if os.name != "posix" or not hasattr(ctypes.CDLL(None), "sincos"):  # no C sincos (not glibc): two calls
    @numba.njit(**_JIT)
    def _sincos(x: float) -> tuple[float, float]:  # noqa: F811
        return np.sin(x), np.cos(x)


# Taylor coefficients of sin (y^3 .. y^19) and cos (y^4 .. y^18) about 0: on |y| <= 0.79 the
# truncation error is below 4e-21, far under the rounding of the float64 evaluation
_SIN_TAYLOR = tuple((-1) ** k / factorial(2 * k + 1) for k in range(1, 10))
_COS_TAYLOR = tuple((-1) ** k / factorial(2 * k) for k in range(2, 10))
# pi/2 as float64 and the float64 nearest its remainder
_PIO2_HI = 1.5707963267948966
_PIO2_LO = 6.123233995736766e-17
# bound on |sin, cos by the polynomial - the C library's| (the two together are
# within 3e-16; measured and tested), and on the rounding of the products
_POLY_TOL = 2.0 ** -46
_PRODUCT_TOL = 2.0 ** -50


@numba.njit(inline="always", **_JIT)
def _sincos_poly(phi: float) -> tuple[float, float]:
    """``(sin phi, cos phi)`` for the concentric map's angles, phi in [-pi/4, 3pi/4].

    Angles above pi/4 (plus a margin) are reduced by pi/2 (sin phi = cos y,
    cos phi = -sin y); each is then a Taylor polynomial in Horner form,
    branch-free so that a loop of it vectorizes."""
    s1, s2, s3, s4, s5, s6, s7, s8, s9 = _SIN_TAYLOR
    c2, c3, c4, c5, c6, c7, c8, c9 = _COS_TAYLOR
    reduce = phi > 0.7863981633974483
    y = (phi - _PIO2_HI) - _PIO2_LO if reduce else phi
    z = y * y
    sin_y = y + y * z * (s1 + z * (s2 + z * (s3 + z * (s4 + z * (s5 + z * (s6 + z * (s7 + z * (s8 + z * s9))))))))
    cos_y = 1.0 - 0.5 * z + z * z * (c2 + z * (c3 + z * (c4 + z * (c5 + z * (c6 + z * (c7 + z * (c8 + z * c9)))))))
    return (cos_y if reduce else sin_y), (-sin_y if reduce else cos_y)


@numba.njit(inline="always", **_JIT)
def _same_float32(r: float, w: float) -> bool:
    """True when every value within the error bound of ``w = r * (sin or cos)``
    rounds to one float32, of ``w``'s sign (float32 rounding is monotonic: the
    two ends of the interval decide)."""
    bound = abs(r) * _POLY_TOL + abs(w) * _PRODUCT_TOL
    lo = w - bound
    hi = w + bound
    return ((lo > 0.0) | (hi < 0.0)) & (np.float32(lo) == np.float32(hi))


@numba.njit(error_model="numpy", **_JIT)
def _lens_map(a: np.ndarray, b: np.ndarray, square: bool, u: np.ndarray, v: np.ndarray) -> None:
    """Lens points ``(u, v)`` (float32 arrays) of the unit-square points ``(a, b)`` (float64, overwritten).

    The disk map runs in two vectorized loops, the branch-free radii and angles,
    then ``r cos phi`` and ``r sin phi`` with sin and cos from ``_sincos_poly``.
    Each float32 result is the one the C library's ``sincos`` gives (the
    rounding of ``r cos phi`` to float32 hides the last bits of float64): a
    point whose result could round otherwise, lying within the error bound of
    a float32 rounding boundary (about 6 in a million, and exact zeros), is
    recomputed with the C library's ``sincos``.
    """
    if square:
        for i in range(a.size):
            u[i] = 2.0 * a[i] - 1.0
            v[i] = 2.0 * b[i] - 1.0
        return
    for i in range(a.size):
        a[i], b[i] = _concentric_polar(a[i], b[i])
    unsettled = 0
    for i in range(a.size):
        r = a[i]
        sin_phi, cos_phi = _sincos_poly(b[i])
        wu = r * cos_phi
        wv = r * sin_phi
        u[i] = wu
        v[i] = wv
        unsettled += np.int64(not (_same_float32(r, wu) & _same_float32(r, wv)))
    if unsettled:
        for i in range(a.size):
            r = a[i]
            sin_phi, cos_phi = _sincos_poly(b[i])
            if not (_same_float32(r, r * cos_phi) & _same_float32(r, r * sin_phi)):
                sin_phi, cos_phi = _sincos(b[i])
                u[i] = r * cos_phi
                v[i] = r * sin_phi


@numba.njit(**_JIT)
def _concentric_many(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kernel concentric map on arrays, float32 (used to test it against :func:`concentric_disk`)."""
    u = np.empty(a.size, dtype=np.float32)
    v = np.empty(a.size, dtype=np.float32)
    _lens_map(a.copy(), b.copy(), False, u, v)
    return u, v


@numba.njit(**_JIT)
def _shuffle(key: np.uint64, perm: np.ndarray) -> None:
    """Fisher-Yates permutation of 0..n-1 driven by the pixel's hash stream."""
    n = perm.size
    for i in range(n):
        perm[i] = i
    for i in range(n - 1, 0, -1):
        h = _rand(key, _S_PERM, i)
        k = np.int64(((h >> np.uint64(32)) * np.uint64(i + 1)) >> np.uint64(32))
        tmp = perm[i]
        perm[i] = perm[k]
        perm[k] = tmp


@numba.njit(**_JIT)
def _argsort(keys: np.ndarray) -> np.ndarray:
    """Stable argsort: insertion sort on runs of 16, then bottom-up merges."""
    n = keys.size
    order = np.empty(n, dtype=np.int64)
    run = 16
    for start in range(0, n, run):
        for i in range(start, min(n, start + run)):
            k = keys[i]
            j = i
            while j > start and keys[order[j - 1]] > k:
                order[j] = order[j - 1]
                j -= 1
            order[j] = i
    if n <= run:
        return order
    buf = np.empty(n, dtype=np.int64)
    width = run
    while width < n:
        for lo in range(0, n, 2 * width):
            mid = min(n, lo + width)
            hi = min(n, lo + 2 * width)
            a, b, o = lo, mid, lo
            while a < mid and b < hi:
                if keys[order[b]] < keys[order[a]]:
                    buf[o] = order[b]
                    b += 1
                else:
                    buf[o] = order[a]
                    a += 1
                o += 1
            while a < mid:
                buf[o] = order[a]
                a += 1
                o += 1
            while b < hi:
                buf[o] = order[b]
                b += 1
                o += 1
        order, buf = buf, order
        width *= 2
    return order


_CHUNK = 4096  # pixels per thread-pool work item (a screen region of 128 rows is several)


@numba.njit(**_JIT)
def _net_kernel(
    p0, lo, hi, spp, m, seed_key, xs, ys, lens_y, lens, motion, square, ox, oy, ou, ov, ot
):
    jb = _FRAC_BITS - m  # jitter bits below the finest stratum
    perm = np.empty(spp, dtype=np.int64)
    la = np.empty(spp)
    lb = np.empty(spp)
    for lp in range(lo, hi):
        key = _pixel_key(seed_key, p0 + lp)
        mx = _top_bits(_rand(key, _S_MASK_X, 0), m)
        my = _top_bits(_rand(key, _S_MASK_Y, 0), m)
        mt = _top_bits(_rand(key, _S_MASK_T, 0), m)
        base = lp * spp
        # Scrambled t digits are a permutation of 0..spp-1, so sorted position s
        # has t-stratum s and comes from net index j = s ^ mt: no sort needed.
        for s in range(spp):
            j = np.uint64(s) ^ mt
            h = _rand(key, _S_JIT_XY, s)  # 24 jitter bits each for x and y
            xi = ((xs[j] ^ mx) << np.uint64(jb)) | _top_bits(h, jb)
            yi = ((ys[j] ^ my) << np.uint64(jb)) | _top_bits(h << np.uint64(24), jb)
            ox[base + s] = _fixed_to_unit(xi)
            oy[base + s] = _fixed_to_unit(yi)
            if motion:
                ti = (np.uint64(s) << np.uint64(jb)) | _top_bits(_rand(key, _S_JIT_T, s), jb)
                ot[base + s] = _fixed_to_unit(ti)
            else:
                ot[base + s] = 0.5
        if lens:
            ma = _top_bits(_rand(key, _S_MASK_A, 0), m)
            mb = _top_bits(_rand(key, _S_MASK_B, 0), m)
            _shuffle(key, perm)
            for s in range(spp):
                i = perm[s]
                h = _rand(key, _S_JIT_AB, s)
                la[s] = _fixed_to_unit(((np.uint64(i) ^ ma) << np.uint64(jb)) | _top_bits(h, jb))
                lb[s] = _fixed_to_unit(((lens_y[i] ^ mb) << np.uint64(jb)) | _top_bits(h << np.uint64(24), jb))
            _lens_map(la, lb, square, ou[base:base + spp], ov[base:base + spp])


@numba.njit(**_JIT)
def _random_kernel(p0, lo, hi, spp, seed_key, lens, motion, square, ox, oy, ou, ov, ot):
    nb = _FRAC_BITS
    tkeys = np.empty(spp, dtype=np.uint64)
    la = np.empty(spp)
    lb = np.empty(spp)
    for lp in range(lo, hi):
        key = _pixel_key(seed_key, p0 + lp)
        base = lp * spp
        for i in range(spp):
            tkeys[i] = _top_bits(_rand(key, _S_RND_T, i), nb)
        order = _argsort(tkeys)
        for s in range(spp):
            i = order[s]
            ox[base + s] = _fixed_to_unit(_top_bits(_rand(key, _S_RND_X, i), nb))
            oy[base + s] = _fixed_to_unit(_top_bits(_rand(key, _S_RND_Y, i), nb))
            ot[base + s] = _fixed_to_unit(tkeys[i]) if motion else 0.5
            if lens:
                la[s] = _fixed_to_unit(_top_bits(_rand(key, _S_RND_A, i), nb))
                lb[s] = _fixed_to_unit(_top_bits(_rand(key, _S_RND_B, i), nb))
        if lens:
            _lens_map(la, lb, square, ou[base:base + spp], ov[base:base + spp])


@numba.njit(**_JIT)
def _stratified_kernel(p0, lo, hi, spp, seed_key, lens, motion, square, ox, oy, ou, ov, ot):
    """Jittered stratification: each of t, x, y, a, b has one sample per 1/spp
    stratum; the strata are paired across dimensions by per-pixel random
    permutations (Latin hypercube), and the samples come out in t order."""
    nb = _FRAC_BITS
    perm = np.empty(spp, dtype=np.int64)
    strata = np.empty((4, spp), dtype=np.int64)
    la = np.empty(spp)
    lb = np.empty(spp)
    for lp in range(lo, hi):
        key = _pixel_key(seed_key, p0 + lp)
        base = lp * spp
        for d in range(4):  # x, y, a, b: a permutation each, from its own key
            _shuffle(_mix(key + np.uint64(_S_STRAT + 5 + d)), perm)
            for i in range(spp):
                strata[d, i] = perm[i]
        for s in range(spp):  # sample s lies in t stratum s: already t-ordered
            jt = _fixed_to_unit(_top_bits(_rand(key, _S_STRAT, s), nb))
            ot[base + s] = min((s + jt) / spp, _BELOW_ONE) if motion else 0.5
            jx = _fixed_to_unit(_top_bits(_rand(key, _S_STRAT + 1, s), nb))
            jy = _fixed_to_unit(_top_bits(_rand(key, _S_STRAT + 2, s), nb))
            ox[base + s] = min((strata[0, s] + jx) / spp, _BELOW_ONE)
            oy[base + s] = min((strata[1, s] + jy) / spp, _BELOW_ONE)
            if lens:
                ja = _fixed_to_unit(_top_bits(_rand(key, _S_STRAT + 3, s), nb))
                jb = _fixed_to_unit(_top_bits(_rand(key, _S_STRAT + 4, s), nb))
                la[s] = (strata[2, s] + ja) / spp
                lb[s] = (strata[3, s] + jb) / spp
        if lens:
            _lens_map(la, lb, square, ou[base:base + spp], ov[base:base + spp])


@numba.njit(**_JIT)
def _sobol_kernel(p0, lo, hi, spp, m, seed_key, base_pts, lens, motion, square, ox, oy, ou, ov, ot):
    """The first 2^m points of the 5D Sobol sequence (:func:`sobol_points`)
    with a per-pixel random digital shift (XOR of the top m digits) in each dimension and a jitter inside the finest stratum; sorted by t.
    ``base_pts`` holds the points' m-digit integer coordinates (x, y, t, a, b)."""
    nb = _FRAC_BITS
    tkeys = np.empty(spp, dtype=np.uint64)
    coords = np.empty((5, spp), dtype=np.float64)
    la = np.empty(spp)
    lb = np.empty(spp)
    for lp in range(lo, hi):
        key = _pixel_key(seed_key, p0 + lp)
        base = lp * spp
        for d in range(5):
            mask = _top_bits(_rand(key, _S_SOBOL + d, 0), m)
            for i in range(spp):
                digit = np.uint64(base_pts[d, i]) ^ mask
                jit = _top_bits(_rand(key, _S_SOBOL + 5 + d, i), nb - m)
                coords[d, i] = _fixed_to_unit((digit << np.uint64(nb - m)) | jit)
        for i in range(spp):
            tkeys[i] = np.uint64(coords[2, i] * 16777216.0)
        order = _argsort(tkeys)
        for s in range(spp):
            i = order[s]
            ox[base + s] = coords[0, i]
            oy[base + s] = coords[1, i]
            ot[base + s] = coords[2, i] if motion else 0.5
            la[s] = coords[3, i]
            lb[s] = coords[4, i]
        if lens:
            _lens_map(la, lb, square, ou[base:base + spp], ov[base:base + spp])


_DIGITS = np.uint64(0xFFFF)  # a dimension's digits (m <= 16) in a packed word
_D16, _D32, _D48 = np.uint64(16), np.uint64(32), np.uint64(48)


def _net5_tables(m: int) -> tuple[np.ndarray, np.ndarray]:
    """What every pixel's scramble shares: the counters of its random draws
    ``(d, b)``, b <= m, of stream ``_S_NET5 + d``, flattened, and the digits of
    the generator columns (:func:`net5_columns`) as masks, ``bits[d, l, b]``
    all ones where column l of dimension d has digit b."""
    ctr = np.array([_counter(_S_NET5 + d, b) for d in range(5) for b in range(m + 1)], dtype=np.uint64)
    digit = (net5_columns(m)[:, :, None] >> np.arange(m, dtype=np.uint64)) & np.uint64(1)
    return ctr, np.uint64(0) - digit


@numba.njit(**_JIT)
def _net5_scramble(key: np.uint64, m: int, ctr: np.ndarray, bits: np.ndarray, rnd: np.ndarray, lcol: np.ndarray,
                   sc: np.ndarray) -> None:
    """One pixel's scrambled generator: ``sc[d, l] = L_d C_d`` column l (l < m) and
    ``sc[d, m]`` the digital shift ``e_d``, for the rows d = x, y, u, v, t of the
    generator whose digits and draws :func:`_net5_tables` gives."""
    for i in range(ctr.size):  # the pixel's draws, one vectorized loop
        rnd[i] = _mix(key + ctr[i])
    for d in range(5):
        for b in range(m):  # column b of L_d: bit b set, random bits below it
            one = np.uint64(1) << np.uint64(b)
            lcol[b] = one | (rnd[d * (m + 1) + b] & (one - np.uint64(1)))
        for l in range(m):  # XOR of L_d's columns at the set bits of C_d's column l
            acc = np.uint64(0)
            for b in range(m):
                acc ^= lcol[b] & bits[d, l, b]
            sc[d, l] = acc
        sc[d, m] = _top_bits(rnd[d * (m + 1) + m], m)


@numba.njit(**_JIT)
def _net5_kernel(p0, lo, hi, spp, m, seed_key, ctr, bits, lens, motion, square, ox, oy, ou, ov, ot):
    """The t-ordered (t, m, 5)-net: ``bits`` (5, m, m) holds the digits of the
    generator columns of x, y, u, v (4D Sobol) and t (the index, column l = 2^l)
    and ``ctr`` the counters of the scramble draws (:func:`_net5_tables`).

    Per pixel and dimension d a random scramble ``y = L_d x ^ e_d`` (Matousek
    1998): ``L_d`` is lower triangular in digit order with a unit diagonal, so
    the top k digits of y depend only on the top k digits of x, bijectively,
    and every elementary interval maps onto one of the same shape. Applied to
    the generator columns once per pixel (``L_d C_d``), the points then follow
    in Gray-code order with one XOR per dimension, and each point's digits go
    to its scrambled t stratum, which is its t-sorted position (Munkberg11 §5).
    The jitter bits below the strata are hashed from that position, so a
    second pass over the positions in order makes the samples: hashes, fixed
    point to float and the lens map run over a whole pixel at a time.
    """
    jb = np.uint64(_FRAC_BITS - m)  # jitter bits below the finest stratum (8..24)
    drop = np.uint64(64 - _FRAC_BITS + m)  # h >> drop: the top jb bits of h
    low = np.uint64(_FRAC_BITS)  # the next jb bits: (h << 24) >> drop
    rnd = np.empty(ctr.size, dtype=np.uint64)
    lcol = np.empty(max(m, 1), dtype=np.uint64)
    sc = np.empty((5, m + 1), dtype=np.uint64)
    digits = np.empty(spp, dtype=np.uint64)  # x, y, u, v digits by t stratum, 16 bits each
    packed = np.empty(m + 1, dtype=np.uint64)  # the columns and shift of x, y, u, v so packed
    tz = np.zeros(spp, dtype=np.int64)  # index k flips bit tz[k] of the Gray code
    for k in range(1, spp):
        while not (k >> tz[k]) & 1:
            tz[k] += 1
    la = np.empty(spp)
    lb = np.empty(spp)
    for lp in range(lo, hi):
        key = _pixel_key(seed_key, p0 + lp)
        _net5_scramble(key, m, ctr, bits, rnd, lcol, sc)
        for l in range(m + 1):
            packed[l] = sc[0, l] | (sc[1, l] << _D16) | (sc[2, l] << _D32) | (sc[3, l] << _D48)
        cur, ct = packed[m], sc[4, m]
        for k in range(spp):
            if k:
                cur ^= packed[tz[k]]
                ct ^= sc[4, tz[k]]
            digits[ct] = cur
        base = lp * spp
        xo, yo, to = ox[base:base + spp], oy[base:base + spp], ot[base:base + spp]
        for s in range(spp):
            h = _rand(key, _S_NET5 + 5, s)
            xo[s] = _fixed_to_unit(((digits[s] & _DIGITS) << jb) | (h >> drop))
            yo[s] = _fixed_to_unit((((digits[s] >> _D16) & _DIGITS) << jb) | ((h << low) >> drop))
        if motion:
            for s in range(spp):
                to[s] = _fixed_to_unit((np.uint64(s) << jb) | (_rand(key, _S_NET5 + 7, s) >> drop))
        else:
            for s in range(spp):
                to[s] = 0.5
        if lens:
            for s in range(spp):
                g = _rand(key, _S_NET5 + 6, s)
                la[s] = _fixed_to_unit((((digits[s] >> _D32) & _DIGITS) << jb) | (g >> drop))
                lb[s] = _fixed_to_unit(((digits[s] >> _D48) << jb) | ((g << low) >> drop))
            _lens_map(la, lb, square, ou[base:base + spp], ov[base:base + spp])


def net5_columns(m: int) -> np.ndarray:
    """(5, m) generator columns of the t-ordered (t, m, 5)-net, rows x, y, u, v, t.

    Column l of a row holds the m digits (top bit = weight 1/2) that bit l of
    the point index j contributes: x, y, u, v are Sobol dimensions 1-4
    (:func:`sobol_points`, whose points come in Gray-code order, so point
    2^(l+1) - 1 is column l) and t's column l is 2^l, so t = j / 2^m.
    """
    _check_m(m, 16)
    pts = sobol_points(m)[:4]
    cols = np.empty((5, m), dtype=np.uint64)
    for l in range(m):
        cols[:4, l] = pts[:, (1 << (l + 1)) - 1]
        cols[4, l] = 1 << l
    return cols


def t_ordered_net5(m: int) -> np.ndarray:
    """Unscrambled t-ordered (t, m, 5)-net: shape (2^m, 5) float64 columns (x, y, u, v, t).

    Row j is point j of the 4D Sobol sequence with ``t = j / 2^m`` appended.
    """
    cols = net5_columns(m)
    j = np.arange(1 << m, dtype=np.uint64)
    ints = np.zeros((1 << m, 5), dtype=np.uint64)
    for l in range(m):
        ints ^= ((j >> np.uint64(l)) & np.uint64(1))[:, None] * cols[:, l][None, :]
    return ints.astype(np.float64) / (1 << m)


# Sobol dimensions 2-5 (dimension 1 has every m_k = 1): the degree s of the primitive polynomial, its
# inner coefficients a (bits a_1 .. a_(s-1), a_1 the highest) and the initial odd m_1 .. m_s, from Joe and
# Kuo's direction numbers (new-joe-kuo-6.21201), which scipy.stats.qmc.Sobol uses too
_SOBOL_POLYNOMIALS = ((1, 0, (1,)), (2, 1, (1, 3)), (3, 1, (1, 3, 1)), (3, 2, (1, 1, 1)))


def sobol_direction_numbers(m: int) -> np.ndarray:
    """(5, m) direction numbers of the first five Sobol dimensions as m-digit integers: column k - 1 is
    v_k = m_k 2^(m - k), k = 1 .. m, with m_k from Bratley and Fox's recurrence (1988)
    m_k = 2 a_1 m_(k-1) ^ 4 a_2 m_(k-2) ^ ... ^ 2^(s-1) a_(s-1) m_(k-s+1) ^ 2^s m_(k-s) ^ m_(k-s)."""
    _check_m(m)
    v = np.empty((5, m), dtype=np.int64)
    v[0] = [1 << (m - 1 - j) for j in range(m)]
    for d, (s, a, initial) in enumerate(_SOBOL_POLYNOMIALS, start=1):
        mk = list(initial[:m])  # mk[j] = m_(j+1)
        for j in range(s, m):
            value = mk[j - s] ^ (mk[j - s] << s)
            for i in range(1, s):
                if (a >> (s - 1 - i)) & 1:
                    value ^= mk[j - i] << i
            mk.append(value)
        v[d] = [mk[j] << (m - 1 - j) for j in range(m)]
    return v


def sobol_points(m: int) -> np.ndarray:
    """(5, 2^m) integer coordinates (m digits) of the first 2^m points of the
    unscrambled 5D Sobol sequence, dimensions x, y, t, a, b, in Gray-code order
    (point k is the XOR of the direction numbers at the set bits of k ^ (k >> 1)),
    as scipy.stats.qmc.Sobol gives them (``tests/test_sampling.py``). Made here
    rather than by scipy, whose ``stats`` package takes 0.5 to 0.6 s to import: every run
    that samples with ``net5`` or ``sobol`` would pay that before its first pass."""
    v = sobol_direction_numbers(m)
    k = np.arange(1 << m, dtype=np.int64)
    gray = k ^ (k >> 1)
    pts = np.zeros((5, 1 << m), dtype=np.int64)
    for j in range(m):
        pts ^= ((gray >> j) & 1)[None, :] * v[:, j:j + 1]
    return pts


_BELOW_ONE = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


@numba.njit(**_JIT)
def _wrap_unit(x: float) -> float:
    """Toroidal wrap to [0, 1), clamped so the float32 value stays below 1."""
    x = x - np.floor(x)
    return min(x, _BELOW_ONE)


@numba.njit(**_JIT)
def _table_kernel(p0, lo, hi, spp, seed_key, table, rotate, lens, motion, ox, oy, ou, ov, ot):
    tt = np.empty(spp, dtype=np.float32)
    for lp in range(lo, hi):
        base = lp * spp
        if rotate:
            key = _pixel_key(seed_key, p0 + lp)
            rx = _fixed_to_unit(_top_bits(_rand(key, _S_ROT, 0), _FRAC_BITS))
            ry = _fixed_to_unit(_top_bits(_rand(key, _S_ROT, 1), _FRAC_BITS))
            rt = _fixed_to_unit(_top_bits(_rand(key, _S_ROT, 2), _FRAC_BITS))
            for i in range(spp):
                tt[i] = np.float32(_wrap_unit(table[i, 4] + rt))
            order = _argsort(tt)
            for s in range(spp):
                i = order[s]
                ox[base + s] = _wrap_unit(table[i, 0] + rx)
                oy[base + s] = _wrap_unit(table[i, 1] + ry)
                ot[base + s] = tt[i] if motion else 0.5
                if lens:
                    ou[base + s] = table[i, 2]
                    ov[base + s] = table[i, 3]
        else:  # table is pre-sorted by t
            for s in range(spp):
                ox[base + s] = min(table[s, 0], _BELOW_ONE)
                oy[base + s] = min(table[s, 1], _BELOW_ONE)
                ot[base + s] = table[s, 4] if motion else 0.5
                if lens:
                    ou[base + s] = table[s, 2]
                    ov[base + s] = table[s, 3]


def _run_chunked(kernel, p0: int, npix: int, spp: int, *args) -> None:
    """Run ``kernel(p0, lo, hi, spp, *args)`` over pixel chunks on a thread pool.

    The kernels release the GIL and each pixel's values depend only on (seed,
    global pixel index, sample index), so chunking never changes the output.
    """
    bounds = [(lo, min(npix, lo + _CHUNK)) for lo in range(0, npix, _CHUNK)]
    workers = min(len(bounds), os.cpu_count() or 1)
    if workers <= 1:
        for lo, hi in bounds:
            kernel(p0, lo, hi, spp, *args)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for fut in [pool.submit(kernel, p0, lo, hi, spp, *args) for lo, hi in bounds]:
            fut.result()


# ---------------------------------------------------------------------------
# Public sample sets
# ---------------------------------------------------------------------------


@dataclass
class SampleSet:
    """Structure-of-arrays samples, pixel-major, sorted by t within each pixel.

    Pixel ``p = (row - row0) * width + col`` owns ``[p*spp, (p+1)*spp)`` of every
    array. ``x, y`` are offsets within the pixel in [0,1), ``u, v`` the lens
    position (unit disk or [-1,1]^2; zero without lens), ``t`` the shutter time
    in [0,1) (0.5 without motion; an unscrambled user table may also hold 1.0).
    ``height`` is the number of rows held; they
    are image rows ``row0 .. row0+height-1``.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    t: np.ndarray
    spp: int
    width: int
    height: int
    lens: bool
    motion: bool
    row0: int = 0
    # Interleave UVT only: the shared (u, v, t) tuples, (n, 3) float64, and
    # each sample's index into them (int8); None for every other pattern
    tuples: np.ndarray | None = None
    tup: np.ndarray | None = None
    # an unscrambled sample table: sample s of every pixel is row s of the t-sorted table, and that row
    # is its tuple (the pass's fixed tuple set is the table itself)
    table_rows: bool = False

    @property
    def npix(self) -> int:
        """Number of pixels held."""
        return self.width * self.height

    def __len__(self) -> int:
        return self.npix * self.spp

    def pixel_slice(self, p: int) -> slice:
        """Index range of pixel ``p = (row - row0) * width + col`` in the arrays."""
        if not 0 <= p < self.npix:
            raise IndexError(f"pixel {p} outside 0..{self.npix - 1}")
        return slice(p * self.spp, (p + 1) * self.spp)


def _check_int(name: str, value: object, lo: int, hi: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise UserError(f"{name} must be an integer, got {value!r}")
    value = int(value)
    if value < lo or (hi is not None and value > hi):
        rng = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise UserError(f"{name} must be {rng}, got {value}")
    return value


def _validate_table(table: object, spp: int) -> np.ndarray:
    try:
        arr = np.array(table, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise UserError(f"sample table: not a numeric array ({exc})") from None
    if arr.shape != (spp, 5):
        raise UserError(
            f"sample table: shape {arr.shape} but expected ({spp}, 5) = (spp, columns x y u v t)"
        )
    limits = ((0.0, 1.0, False), (0.0, 1.0, False), (-1.0, 1.0, True), (-1.0, 1.0, True),
              (0.0, 1.0, True))
    for col, (name, (lo, hi, closed)) in enumerate(zip(_TABLE_COLUMNS, limits)):
        vals = arr[:, col]
        bad = ~np.isfinite(vals) | (vals < lo) | ((vals > hi) if closed else (vals >= hi))
        if bad.any():
            row = int(np.argmax(bad))
            interval = f"[{lo:g}, {hi:g}{']' if closed else ')'}"
            raise UserError(
                f"sample table row {row}, column {col} ('{name}'): value {vals[row]!r} "
                f"is not finite in {interval}"
            )
    return arr


def _seed_key(seed: int) -> np.uint64:
    z = (seed + 0x9E3779B97F4A7C15) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return np.uint64(z ^ (z >> 31))


def check_spp(pattern: str, spp: int, interleave_tuples: int, where: str = "") -> None:
    """The rule of sample pattern ``pattern`` on ``spp``: a power of two for ``net``, ``sobol`` and ``net5``
    (their strata), a divisor of ``interleave_tuples`` for ``interleave`` (each pixel takes a whole
    group of the tuple set). A one-line :class:`UserError` prefixed with ``where`` otherwise."""
    prefix = f"{where}: " if where else ""
    if pattern in _POWER_OF_TWO and spp & (spp - 1):
        raise UserError(f"{prefix}spp = {spp} must be a power of two for the '{pattern}' sample pattern "
                        "(pass.sample_pattern)")
    if pattern == "interleave" and (spp > interleave_tuples or interleave_tuples % spp):
        raise UserError(f"{prefix}spp = {spp} must divide pass.interleave_tuples = {interleave_tuples} for "
                        "the 'interleave' sample pattern")


def make_samples(
    width: int,
    height: int,
    spp: int,
    seed: int,
    *,
    lens: bool,
    motion: bool,
    pattern: str = DEFAULT_PATTERN,
    table: np.ndarray | None = None,
    lens_shape: str = "disk",
    scramble_table: bool = False,
    rows: tuple[int, int] | None = None,
    interleave_tuples: int = 64,
) -> SampleSet:
    """Generate the 5D samples of a ``width x height`` frame (or rows ``[r0, r1)``).

    pattern ``"net"``: per-pixel scrambled, jittered t-ordered (0, m, 3)-net
    (``spp = 2^m``) with a padded, permuted 2D net on the lens; ``"random"``:
    uniform samples; ``"stratified"``: jittered, one sample per 1/spp stratum
    of each dimension (Latin hypercube pairing); ``"sobol"``: the 5D Sobol
    points with a per-pixel digital shift (``spp = 2^m``); ``"net5"``: the
    t-ordered (t, m, 5)-net (4D Sobol in (x, y, u, v), ``t = j / 2^m``) with a
    per-pixel random linear scramble and jitter (``spp = 2^m``); ``"table"``: the user's (spp, 5) table (columns x, y, u, v,
    t) in every pixel, optionally Cranley-Patterson rotated per pixel;
    ``"interleave"``: Interleave UVT (see ``interleave_tuple_set``).
    Values depend only on (seed, pixel index, sample index).
    """
    width = _check_int("width", width, 1)
    height = _check_int("height", height, 1)
    spp = _check_int("spp", spp, 1, MAX_SPP)
    seed = _check_int("seed", seed, 0, _MASK64)
    lens, motion, scramble_table = bool(lens), bool(motion), bool(scramble_table)
    if pattern not in PATTERNS:
        raise UserError(
            f"sample pattern: unknown pattern '{pattern}'{did_you_mean(str(pattern), PATTERNS)};"
            f" known: {', '.join(PATTERNS)}"
        )
    if lens_shape not in _LENS_SHAPES:
        raise UserError(
            f"lens_shape: unknown shape '{lens_shape}'{did_you_mean(str(lens_shape), _LENS_SHAPES)}"
        )
    if pattern == "table" and table is None:
        raise UserError("sample pattern 'table' needs a table of shape (spp, 5)")
    if pattern != "table" and table is not None:
        raise UserError(f"a sample table was given but pattern is '{pattern}' (use 'table')")
    if pattern == "interleave":
        return _interleave_samples(width, height, spp, seed, lens=lens, motion=motion, n_tuples=interleave_tuples,
                                   lens_shape=lens_shape, rows=rows)
    check_spp(pattern, spp, interleave_tuples)
    if rows is None:
        r0, r1 = 0, height
    else:
        if len(rows) != 2:
            raise UserError(f"rows must be a pair (r0, r1), got {rows!r}")
        r0 = _check_int("rows[0]", rows[0], 0, height)
        r1 = _check_int("rows[1]", rows[1], r0, height)

    arr = _validate_table(table, spp) if pattern == "table" else None  # (a set of no rows checks it too)
    nrows = r1 - r0
    npix = width * nrows
    n = npix * spp
    ox = np.empty(n, dtype=np.float32)
    oy = np.empty(n, dtype=np.float32)
    ot = np.empty(n, dtype=np.float32)
    ou = np.zeros(n, dtype=np.float32) if not lens else np.empty(n, dtype=np.float32)
    ov = np.zeros(n, dtype=np.float32) if not lens else np.empty(n, dtype=np.float32)
    key = _seed_key(seed)
    p0 = r0 * width
    square = lens_shape == "square"
    if npix:
        if pattern == "net":
            m = spp.bit_length() - 1
            c1p, c2p, _ = generator_matrices(m)
            xs = net_integer_coords(c1p)
            ys = net_integer_coords(c2p)
            lp_y = net_integer_coords(grunschloss_keller_matrices(m)[1])
            _run_chunked(_net_kernel, p0, npix, spp, m, key, xs, ys, lp_y, lens, motion,
                         square, ox, oy, ou, ov, ot)
        elif pattern == "random":
            _run_chunked(_random_kernel, p0, npix, spp, key, lens, motion, square,
                         ox, oy, ou, ov, ot)
        elif pattern == "stratified":
            _run_chunked(_stratified_kernel, p0, npix, spp, key, lens, motion, square,
                         ox, oy, ou, ov, ot)
        elif pattern == "net5":
            m = spp.bit_length() - 1
            _run_chunked(_net5_kernel, p0, npix, spp, m, key, *_net5_tables(m), lens, motion, square,
                         ox, oy, ou, ov, ot)
        elif pattern == "sobol":
            m = spp.bit_length() - 1
            _run_chunked(_sobol_kernel, p0, npix, spp, m, key, sobol_points(m), lens, motion, square,
                         ox, oy, ou, ov, ot)
        else:
            arr = arr[np.argsort(arr[:, 4], kind="stable")]
            _run_chunked(_table_kernel, p0, npix, spp, key, arr, scramble_table, lens,
                         motion, ox, oy, ou, ov, ot)
    return SampleSet(x=ox, y=oy, u=ou, v=ov, t=ot, spp=spp, width=width, height=nrows,
                     lens=lens, motion=motion, row0=r0, table_rows=pattern == "table" and not scramble_table)


# ---------------------------------------------------------------------------
# Interleave UVT (Fatahalian09, as Wu13 §2 and Munkberg11 §2 describe it)
# ---------------------------------------------------------------------------


def interleave_tuple_set(n: int, spp: int, lens_shape: str = "disk") -> np.ndarray:
    """The fixed set of ``n`` (u, v, t) tuples of Interleave UVT, (n, 3), sorted by t.

    Tuple i = g + G s (G = n / spp groups, s < spp) has t = (i + 0.5) / n, so
    each group holds one tuple per 1/spp time stratum. A group's lens points
    are a 2D (0, m, 2)-net (the (y, t) projection of the t-ordered net,
    visited in a stride order that decouples lens from time; stratified
    jitter when spp is not a power of two), Cranley-Patterson shifted per
    group, so every pixel's spp tuples are well spread in (u, v, t).
    """
    n = _check_int("interleave_tuples", n, 1, 64)
    spp = _check_int("spp", spp, 1, n)
    check_spp("interleave", spp, n, "interleave")
    groups = n // spp
    rng = np.random.default_rng(0x1EAF)  # a fixed table, the same in every run
    if spp & (spp - 1) == 0:
        net = t_ordered_net(spp.bit_length() - 1)
        order = (np.arange(spp) * ((spp // 3) | 1)) % spp
        lens = net[order][:, 1:3]
    else:
        lens = np.stack([(np.arange(spp) + rng.random(spp)) / spp,
                         (rng.permutation(spp) + rng.random(spp)) / spp], axis=1)
    out = np.empty((n, 3))
    for g in range(groups):
        ab = (lens + rng.random(2)) % 1.0
        u, v = map_lens(ab[:, 0], ab[:, 1], lens_shape)
        i = g + groups * np.arange(spp)
        out[i, 0], out[i, 1] = u, v
    out[:, 2] = (np.arange(n) + 0.5) / n
    return out


def interleave_groups(width: int, height: int, n_groups: int, row0: int = 0) -> np.ndarray:
    """Group of each pixel, (height, width) int: neighbouring pixels use different
    groups of tuples, in a repeating interleaved pattern."""
    ys, xs = np.mgrid[row0:row0 + height, 0:width]
    stride = max(1, int(round(np.sqrt(n_groups)))) | 1
    return (xs + stride * ys) % n_groups


def _interleave_samples(width: int, height: int, spp: int, seed: int, *, lens: bool, motion: bool,
                        n_tuples: int, lens_shape: str, rows: tuple[int, int] | None) -> SampleSet:
    """Interleave UVT: pixel group g takes tuples g, g + G, g + 2G, ... (G = n / spp),
    so each pixel sees spp of the n tuples, spread in time; (x, y) stay per-sample
    stratified (the t-ordered net, or stratified when spp is not a power of two)."""
    tuples = interleave_tuple_set(n_tuples, spp, lens_shape)
    base = make_samples(width, height, spp, seed, lens=False, motion=False,
                        pattern="net" if spp & (spp - 1) == 0 else "stratified", rows=rows)
    if not lens:
        tuples[:, :2] = 0.0
    if not motion:
        tuples[:, 2] = 0.5
    tuples = tuples.astype(np.float32).astype(np.float64)  # exactly the samples' float32 values
    groups = n_tuples // spp
    g = interleave_groups(width, base.height, groups, base.row0).reshape(-1, 1)
    tup = (g + groups * np.arange(spp)[None, :]).reshape(-1).astype(np.int8)
    return SampleSet(x=base.x, y=base.y, u=tuples[tup, 0].astype(np.float32), v=tuples[tup, 1].astype(np.float32),
                     t=tuples[tup, 2].astype(np.float32), spp=spp, width=width, height=base.height, lens=lens,
                     motion=motion, row0=base.row0, tuples=tuples, tup=tup)
