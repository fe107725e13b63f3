"""Tests for pipeline_sim.sampling (Munkberg11 §5 / App. A sample patterns).

Each property is checked against an independent construction: nets by brute
force over all elementary boxes, matrices by F2 products of the original
Grünschloß-Keller matrices and by binomial closed forms written out here.
"""

from __future__ import annotations

import itertools
import math
import time
from math import comb

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import qmc

from pipeline_sim.errors import UserError
from pipeline_sim.sampling import (
    SampleSet,
    _POLY_TOL,
    _argsort,
    _concentric_many,
    _concentric_polar,
    _same_float32,
    _sincos_poly,
    concentric_disk,
    generator_matrices,
    grunschloss_keller_matrices,
    make_samples,
    map_lens,
    sobol_direction_numbers,
    sobol_points,
    t_ordered_net,
    t_ordered_net5,
)

# ---------------------------------------------------------------------------
# independent helpers
# ---------------------------------------------------------------------------


def gk_original(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """C1 exchange, C2 upper-triangular ones, C3 = binom(l, k) mod 2 (1-based)."""
    c1 = np.zeros((m, m), dtype=np.int64)
    for k in range(m):
        c1[k, m - 1 - k] = 1
    c2 = np.array([[1 if k <= l else 0 for l in range(m)] for k in range(m)], dtype=np.int64)
    c3 = np.array(
        [[comb(l, k) % 2 for l in range(1, m + 1)] for k in range(1, m + 1)], dtype=np.int64
    )
    return c1.reshape(m, m), c2.reshape(m, m), c3.reshape(m, m)


def net_ints(c: np.ndarray, m: int) -> np.ndarray:
    """Eq. 11 times 2^m: digits d_0..d_{m-1} of j, product in F2, row k weight 2^-(k+1)."""
    j = np.arange(2**m)
    d = (j[:, None] >> np.arange(m)[None, :]) & 1
    prod = (d @ np.asarray(c, dtype=np.int64).T) % 2
    return (prod * (2 ** (m - 1 - np.arange(m)))[None, :]).sum(axis=1)


def is_net(cols: list[np.ndarray], m: int) -> bool:
    """Brute force: every elementary box of volume 2^-m holds exactly one point."""
    cols = [np.asarray(c, dtype=np.int64) for c in cols]
    if any(len(c) != 2**m for c in cols):
        return False
    if any(((c < 0) | (c >= 2**m)).any() for c in cols):
        return False
    for split in itertools.product(range(m + 1), repeat=len(cols)):
        if sum(split) != m:
            continue
        box = np.zeros(2**m, dtype=np.int64)
        for c, l in zip(cols, split):
            box = (box << l) | (c >> (m - l))
        if not (np.bincount(box, minlength=2**m) == 1).all():
            return False
    return True


def strata(values: np.ndarray, m: int) -> np.ndarray:
    """floor(coord * 2^m): removes the jitter."""
    return np.floor(values.astype(np.float64) * 2**m).astype(np.int64)


def table_for(spp: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tab = rng.random((spp, 5))
    tab[:, 2:4] = 2 * tab[:, 2:4] - 1
    return tab


# ---------------------------------------------------------------------------
# generator matrices and the unscrambled net
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("m", range(1, 13))
def test_generator_matrices_closed_forms(m):
    c1, c2, c3 = gk_original(m)
    g1, g2, g3 = grunschloss_keller_matrices(m)
    assert (g1 == c1).all() and (g2 == c2).all() and (g3 == c3).all()
    d = (c3 @ c1) % 2  # digit permutation D = C3 C1
    p1, p2, pt = generator_matrices(m)
    for mat in (p1, p2, pt):
        assert mat.dtype == np.uint8 and mat.shape == (m, m)
    assert (p1 == (c1 @ d) % 2).all()
    assert (p2 == (c2 @ d) % 2).all()
    assert (pt == (c3 @ d) % 2).all() and (pt == c1).all()
    for k in range(1, m + 1):
        for l in range(1, m + 1):
            assert p1[k - 1, l - 1] == comb(m + 1 - l, m + 1 - k) % 2
            assert p2[k - 1, l - 1] == comb(m - l, k - 1) % 2


@pytest.mark.parametrize("m", range(1, 17))
def test_c3_is_involution(m):
    c3 = gk_original(m)[2]
    assert ((c3 @ c3) % 2 == np.eye(m, dtype=np.int64)).all()


@pytest.mark.parametrize("m", range(1, 9))
def test_t_ordered_net(m):
    pts = t_ordered_net(m)
    assert pts.shape == (2**m, 3) and pts.dtype == np.float64
    ints = np.rint(pts * 2**m).astype(np.int64)
    assert (ints == pts * 2**m).all()
    assert (pts[:, 2] == np.arange(2**m) / 2**m).all()
    assert is_net([ints[:, 0], ints[:, 1], ints[:, 2]], m)
    assert is_net([ints[:, 0], ints[:, 1]], m)
    c1, c2, c3 = gk_original(m)
    original = {tuple(p) for p in zip(net_ints(c1, m), net_ints(c2, m), net_ints(c3, m))}
    assert len(original) == 2**m
    assert original == {tuple(p) for p in ints}
    # the original net's (x, y) are the LP points: x_j = j / 2^m
    assert (net_ints(c1, m) == np.arange(2**m)).all()
    # t order: row j equals the eq. 11 product with the closed-form matrices
    p1 = [[comb(m + 1 - l, m + 1 - k) % 2 for l in range(1, m + 1)] for k in range(1, m + 1)]
    assert (ints[:, 0] == net_ints(np.array(p1), m)).all()


def test_t_ordered_net_large_and_trivial():
    assert (t_ordered_net(0) == np.zeros((1, 3))).all()
    pts = t_ordered_net(16)
    assert pts.shape == (65536, 3)
    ints = np.rint(pts * 65536).astype(np.int64)
    for c in range(3):  # each 1D projection is a permutation of the strata
        assert (np.sort(ints[:, c]) == np.arange(65536)).all()


# ---------------------------------------------------------------------------
# scrambled per-pixel samples
# ---------------------------------------------------------------------------


def check_pixel_nets(s: SampleSet, m: int) -> None:
    for p in range(s.npix):
        sl = s.pixel_slice(p)
        x, y, t = strata(s.x[sl], m), strata(s.y[sl], m), strata(s.t[sl], m)
        assert is_net([x, y, t], m)
        assert (np.diff(s.t[sl]) > 0).all() or m == 0
        a = strata((s.u[sl].astype(np.float64) + 1) / 2, m)
        b = strata((s.v[sl].astype(np.float64) + 1) / 2, m)
        assert is_net([a, b], m)


@pytest.mark.parametrize("m", range(0, 7))
def test_scrambled_pixels_are_nets(m):
    s = make_samples(3, 2, 2**m, 7, lens=True, motion=True, pattern="net", lens_shape="square")
    assert len(s.x) == 6 * 2**m
    for arr in (s.x, s.y, s.u, s.v, s.t):
        assert arr.dtype == np.float32 and arr.shape == (6 * 2**m,)
    assert ((s.x >= 0) & (s.x < 1) & (s.y >= 0) & (s.y < 1) & (s.t >= 0) & (s.t < 1)).all()
    check_pixel_nets(s, m)
    if m >= 2:  # jittered, not quantized to the strata; pixels differ
        assert not (s.x * 2**m == np.floor(s.x * 2**m)).all()
        assert not (s.t * 2**m == np.floor(s.t * 2**m)).all()
        assert not np.array_equal(s.x[s.pixel_slice(0)], s.x[s.pixel_slice(1)])


@settings(max_examples=25, deadline=None)
@given(m=st.integers(0, 10), seed=st.integers(0, 2**64 - 1))
def test_property_any_seed_gives_scrambled_net(m, seed):
    s = make_samples(2, 1, 2**m, seed, lens=True, motion=True, pattern="net", lens_shape="square")
    check_pixel_nets(s, m)


def test_disk_lens_and_sorted_time():
    s = make_samples(16, 8, 16, 3, lens=True, motion=True)
    r2 = s.u.astype(np.float64) ** 2 + s.v.astype(np.float64) ** 2
    assert (r2 <= 1 + 1e-6).all()
    assert r2.max() > 0.8 and (np.abs(s.u) > 0.5).any()
    t = s.t.reshape(-1, 16)
    assert (np.diff(t, axis=1) > 0).all()


def test_flags_zero_lens_and_fix_time():
    on = make_samples(8, 4, 8, 5, lens=True, motion=True)
    off = make_samples(8, 4, 8, 5, lens=False, motion=False)
    assert (off.u == 0).all() and (off.v == 0).all() and (off.t == 0.5).all()
    assert not off.lens and not off.motion
    assert np.array_equal(on.x, off.x) and np.array_equal(on.y, off.y)


def test_determinism_and_seed_dependence():
    for pattern in ("net", "random"):
        a = make_samples(10, 6, 8, 11, lens=True, motion=True, pattern=pattern)
        b = make_samples(10, 6, 8, 11, lens=True, motion=True, pattern=pattern)
        c = make_samples(10, 6, 8, 12, lens=True, motion=True, pattern=pattern)
        for f in ("x", "y", "u", "v", "t"):
            assert np.array_equal(getattr(a, f), getattr(b, f))
            assert not np.array_equal(getattr(a, f), getattr(c, f))


@pytest.mark.parametrize("pattern", ["net", "random", "table", "net5"])
def test_row_range_equals_slice(pattern):
    kw = dict(lens=True, motion=True, pattern=pattern)
    if pattern == "table":
        kw.update(table=table_for(8), scramble_table=True)
    full = make_samples(13, 9, 8, 21, **kw)
    part = make_samples(13, 9, 8, 21, rows=(3, 7), **kw)
    assert part.row0 == 3 and part.height == 4 and part.width == 13
    sl = slice(3 * 13 * 8, 7 * 13 * 8)
    for f in ("x", "y", "u", "v", "t"):
        assert np.array_equal(getattr(part, f), getattr(full, f)[sl])
    empty = make_samples(13, 9, 8, 21, rows=(5, 5), **kw)
    assert len(empty.x) == 0


def test_row_range_across_thread_chunks():
    full = make_samples(200, 100, 2, 4, lens=True, motion=True)  # > one 16384-pixel chunk
    part = make_samples(200, 100, 2, 4, lens=True, motion=True, rows=(37, 91))
    sl = slice(37 * 200 * 2, 91 * 200 * 2)
    for f in ("x", "y", "u", "v", "t"):
        assert np.array_equal(getattr(part, f), getattr(full, f)[sl])


@settings(max_examples=40, deadline=None)
@given(keys=st.lists(st.integers(0, 20), max_size=200))
def test_kernel_argsort_is_stable_sort(keys):
    for dtype in (np.uint64, np.float32):
        k = np.array(keys, dtype=dtype)
        assert np.array_equal(_argsort(k), np.argsort(k, kind="stable"))


def test_large_spp_random_and_table_sorted():
    s = make_samples(3, 2, 100, 1, lens=True, motion=True, pattern="random")
    assert (np.diff(s.t.reshape(-1, 100), axis=1) >= 0).all()
    tab = table_for(100, 2)
    r = make_samples(3, 2, 100, 1, lens=True, motion=True, pattern="table", table=tab,
                     scramble_table=True)
    for p in range(6):
        got = np.stack([r.x, r.y, r.u, r.v, r.t], axis=1)[r.pixel_slice(p)].astype(float)
        assert any(matches_rotation(got, tab, i) for i in range(100))


def test_pixel_slice_layout():
    s = make_samples(5, 3, 4, 0, lens=False, motion=True)
    assert s.pixel_slice(0) == slice(0, 4)
    assert s.pixel_slice(2 * 5 + 1) == slice(44, 48)
    with pytest.raises(IndexError):
        s.pixel_slice(15)


def test_random_pattern():
    s = make_samples(7, 5, 6, 2, lens=True, motion=True, pattern="random")
    assert ((s.x >= 0) & (s.x < 1) & (s.t >= 0) & (s.t < 1)).all()
    assert (np.diff(s.t.reshape(-1, 6), axis=1) >= 0).all()
    assert (s.u.astype(np.float64) ** 2 + s.v.astype(np.float64) ** 2 <= 1 + 1e-6).all()
    assert abs(float(s.x.mean()) - 0.5) < 0.1


def test_table_pattern():
    tab = table_for(8, 4)
    order = np.argsort(tab[:, 4])
    s = make_samples(4, 3, 8, 9, lens=True, motion=True, pattern="table", table=tab)
    expect = tab[order].astype(np.float32)
    for p in range(12):
        sl = s.pixel_slice(p)
        got = np.stack([s.x[sl], s.y[sl], s.u[sl], s.v[sl], s.t[sl]], axis=1)
        assert np.array_equal(got, expect)
    r = make_samples(4, 3, 8, 9, lens=True, motion=True, pattern="table", table=tab,
                     scramble_table=True)
    for p in range(12):
        sl = r.pixel_slice(p)
        assert (np.diff(r.t[sl]) >= 0).all()
        assert ((r.x[sl] >= 0) & (r.x[sl] < 1) & (r.t[sl] < 1)).all()
        got = np.stack([r.x[sl], r.y[sl], r.u[sl], r.v[sl], r.t[sl]], axis=1).astype(float)
        assert any(matches_rotation(got, tab, i) for i in range(8))
    assert not np.array_equal(r.x[r.pixel_slice(0)], r.x[r.pixel_slice(1)])


def matches_rotation(got: np.ndarray, tab: np.ndarray, i: int) -> bool:
    """Is ``got`` the table toroidally shifted in x, y, t (first sample from row i)?"""
    shift = np.zeros(5)
    for c in (0, 1, 4):
        shift[c] = (got[0, c] - tab[i, c]) % 1.0
    want = tab + shift
    want[:, [0, 1, 4]] %= 1.0
    want = want[np.argsort(want[:, 4], kind="stable")]
    return bool(np.allclose(want, got, atol=1e-6))


@pytest.mark.parametrize(
    "row, col, value, fragment",
    [(2, 0, 1.0, "row 2, column 0"), (5, 3, -1.5, "row 5, column 3"),
     (1, 4, np.nan, "row 1, column 4"), (0, 1, np.inf, "row 0, column 1"),
     (3, 4, -0.1, "row 3, column 4")],
)
def test_bad_table_raises(row, col, value, fragment):
    tab = table_for(8)
    tab[row, col] = value
    with pytest.raises(UserError, match=fragment):
        make_samples(2, 2, 8, 0, lens=True, motion=True, pattern="table", table=tab)
    with pytest.raises(UserError, match=fragment):  # a set of no rows checks the table too (a pass does so first)
        make_samples(2, 2, 8, 0, lens=True, motion=True, pattern="table", table=tab, rows=(0, 0))


def test_bad_parameters_raise():
    with pytest.raises(UserError, match="spp"):
        make_samples(2, 2, 12, 0, lens=True, motion=True)
    with pytest.raises(UserError, match="shape"):
        make_samples(2, 2, 8, 0, lens=True, motion=True, pattern="table", table=table_for(4))
    with pytest.raises(UserError, match="table"):
        make_samples(2, 2, 8, 0, lens=True, motion=True, pattern="table")
    with pytest.raises(UserError, match="did you mean 'random'"):
        make_samples(2, 2, 8, 0, lens=True, motion=True, pattern="randon")
    with pytest.raises(UserError, match="lens_shape"):
        make_samples(2, 2, 8, 0, lens=True, motion=True, lens_shape="hexagon")
    with pytest.raises(UserError, match="rows"):
        make_samples(2, 2, 8, 0, lens=True, motion=True, rows=(1, 3))
    with pytest.raises(UserError, match="width"):
        make_samples(0, 2, 8, 0, lens=True, motion=True)
    with pytest.raises(UserError, match="seed"):
        make_samples(2, 2, 8, -1, lens=True, motion=True)
    # table works with any spp, not only powers of two
    s = make_samples(2, 2, 3, 0, lens=True, motion=True, pattern="table", table=table_for(3))
    assert len(s.x) == 12


# ---------------------------------------------------------------------------
# lens maps
# ---------------------------------------------------------------------------


def test_concentric_measure_preserving_density():
    n = 512  # jittered grid: one uniform point per cell
    rng = np.random.default_rng(3)
    a, b = np.meshgrid(np.arange(n), np.arange(n))
    a = (a.ravel() + rng.random(n * n)) / n
    b = (b.ravel() + rng.random(n * n)) / n
    u, v = concentric_disk(a, b)
    r2 = u**2 + v**2
    assert r2.max() <= 1 + 1e-12
    # uniform on the disk <=> r^2 and angle are uniform
    hist = np.histogram(r2, bins=16, range=(0, 1))[0] / r2.size
    assert np.abs(hist - 1 / 16).max() < 0.0015
    ang = np.histogram(np.arctan2(v, u), bins=16, range=(-np.pi, np.pi))[0] / r2.size
    assert np.abs(ang - 1 / 16).max() < 0.0015


def test_concentric_cell_images_have_equal_area():
    cells, k = 8, 64
    for i in range(cells):
        for j in range(cells):
            s = np.linspace(0, 1, k, endpoint=False)
            a0, b0 = i / cells, j / cells
            h = 1 / cells
            ba = np.concatenate([a0 + s * h, np.full(k, a0 + h), a0 + h - s * h, np.full(k, a0)])
            bb = np.concatenate([np.full(k, b0), b0 + s * h, np.full(k, b0 + h), b0 + h - s * h])
            u, v = concentric_disk(ba, bb)
            area = 0.5 * abs(np.dot(u, np.roll(v, -1)) - np.dot(v, np.roll(u, -1)))
            assert area == pytest.approx(np.pi / cells**2, rel=2e-3)


def test_kernel_concentric_matches_public_and_square():
    rng = np.random.default_rng(1)
    a, b = rng.random(1000), rng.random(1000)
    a[:3], b[:3] = 0.5, [0.5, 0.25, 0.75]
    u1, v1 = concentric_disk(a, b)
    u2, v2 = _concentric_many(a, b)
    assert np.allclose(u1, u2, rtol=0, atol=6e-8) and np.allclose(v1, v2, rtol=0, atol=6e-8)  # float32 rounding
    assert u1[0] == 0 and v1[0] == 0
    us, vs = map_lens(a, b, "square")
    assert np.allclose(us, 2 * a - 1) and np.allclose(vs, 2 * b - 1)


def test_lens_polynomial_within_its_bound():
    """The lens map's sin and cos polynomial against extended-precision sin and cos and against the C
    library's (math.sin, math.cos) over its whole range of angles: the ends of both wedges, the reduction
    threshold and random angles of 24-bit points. Its bound ``_POLY_TOL`` must hold with a wide margin (the
    C library's own error is below one unit in the last place)."""
    rng = np.random.default_rng(5)
    ab = rng.integers(0, 1 << 24, (2, 20000)) / 2**24
    phis = [_concentric_polar(a, b)[1] for a, b in ab.T]
    ends = [-np.pi / 4, 0.0, np.pi / 4, np.pi / 4 + 1e-3, np.pi / 2, 3 * np.pi / 4]
    phis = np.array(phis + [np.nextafter(e, d) for e in ends for d in (-np.inf, np.inf)] + ends)
    phis = np.concatenate([phis, np.linspace(-np.pi / 4, 3 * np.pi / 4, 20001)])
    got = np.array([_sincos_poly(p) for p in phis])
    ld = phis.astype(np.longdouble)
    libm = np.array([(math.sin(p), math.cos(p)) for p in phis])
    for k, exact in ((0, np.sin(ld)), (1, np.cos(ld))):
        assert np.max(np.abs(got[:, k] - exact)) < 2e-16
        assert np.max(np.abs(got[:, k] - libm[:, k])) < _POLY_TOL / 32


def _points_the_polynomial_rounds_otherwise(second_wedge: bool, k: int, count: int) -> list[tuple[float, float]]:
    """Unit-square points whose ``r cos phi`` (k 0) or ``r sin phi`` (k 1) rounds to another float32 by the
    lens polynomial than by the C library: angles where the two differ in float64, the radius moved onto a
    float32 rounding midpoint of the product (Newton steps), then float64 steps around it."""
    rng = np.random.default_rng(11 + 2 * k + second_wedge)
    libm = (math.cos, math.sin)[k]

    def polar(x: float, other: float) -> tuple[float, float]:
        return _concentric_polar(other, x) if second_wedge else _concentric_polar(x, other)

    found = []
    while len(found) < count:
        x, other = 0.75 + 0.25 * rng.random(), 0.15 + 0.7 * rng.random()  # |2 other - 1| < 2 x - 1
        if _sincos_poly(polar(x, other)[1])[1 - k] == libm(polar(x, other)[1]):
            continue
        f = np.float32(polar(x, other)[0] * libm(polar(x, other)[1]))
        mid = (float(f) + float(np.nextafter(f, np.float32(2)))) / 2
        for _ in range(20):
            r, phi = polar(x, other)
            r2, phi2 = polar(x + 1e-9, other)
            slope = (r2 * libm(phi2) - r * libm(phi)) / 1e-9
            x -= (r * libm(phi) - mid) / slope
        for step in range(-64, 65):
            xs = x + step * np.spacing(x)
            r, phi = polar(xs, other)
            if np.float32(r * _sincos_poly(phi)[1 - k]) != np.float32(r * libm(phi)):
                found.append((other, xs) if second_wedge else (xs, other))
                break
    return found


@pytest.mark.parametrize("second_wedge", [False, True])
@pytest.mark.parametrize("k", [0, 1])
def test_lens_map_falls_back_to_the_c_library_where_the_polynomial_rounds_otherwise(second_wedge, k):
    """Where the polynomial's float64 product lies on the other side of a float32 rounding boundary from the
    C library's (points built for it, since at random it almost never happens), the lens map gives the C
    library's float32: without its fallback it would give the polynomial's."""
    points = np.array(_points_the_polynomial_rounds_otherwise(second_wedge, k, 4))
    got = _concentric_many(points[:, 0], points[:, 1])[k]
    for (a, b), g in zip(points, got):
        r, phi = _concentric_polar(a, b)
        assert g == np.float32(r * (math.cos, math.sin)[k](phi))
        assert g != np.float32(r * _sincos_poly(phi)[1 - k])


@settings(max_examples=300, deadline=None)
@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.integers(-4, 4))
def test_same_float32_only_when_the_whole_bound_rounds_alike(r, w, shift):
    """``_same_float32`` may say yes only when every value within the bound around ``w`` rounds to one
    float32 of w's sign. Adversarial values too: w on a float32 rounding midpoint, or a few float64 steps
    from one, where the answer must be no."""
    f = np.float32(w)
    mid = (np.float64(f) + np.float64(np.nextafter(f, np.float32(np.inf)))) / 2
    for x in (w, np.float64(mid) + shift * np.spacing(mid)):
        bound = abs(r) * _POLY_TOL + abs(x) * 2.0**-50
        if _same_float32(r, x):
            probes = [x + k * bound / 4 for k in range(-4, 5)]
            assert len({np.float32(p).view(np.uint32).item() for p in probes}) == 1
        if x == mid:
            assert not _same_float32(r, x)


# ---------------------------------------------------------------------------
# quality and speed
# ---------------------------------------------------------------------------


def test_star_discrepancy_beats_random():
    m = 8
    net = t_ordered_net(m)[:, :2]
    s = make_samples(1, 1, 2**m, 5, lens=False, motion=True, pattern="net")
    scrambled = np.stack([s.x, s.y], axis=1).astype(np.float64)
    d_net = qmc.discrepancy(net, method="L2-star")
    d_scr = qmc.discrepancy(scrambled, method="L2-star")
    rng = np.random.default_rng(0)
    d_rnd = [qmc.discrepancy(rng.random((2**m, 2)), method="L2-star") for _ in range(20)]
    print(f"L2-star discrepancy, 256 points: net {d_net:.5f}, scrambled {d_scr:.5f}, "
          f"random mean {np.mean(d_rnd):.5f} (min {np.min(d_rnd):.5f})")
    assert d_net < min(d_rnd) and d_scr < min(d_rnd)


def test_speed_small_frame():
    make_samples(8, 8, 16, 0, lens=True, motion=True)  # warm up the JIT
    start = time.perf_counter()
    s = make_samples(320, 180, 16, 0, lens=True, motion=True)
    assert time.perf_counter() - start < 1.0
    assert len(s.x) == 320 * 180 * 16


# --------------------------------------------------------------------------- #
# stratified and Sobol alternatives
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("spp", [1, 3, 8, 16])
def test_stratified_pattern_one_sample_per_stratum_per_dimension(spp):
    s = make_samples(6, 5, spp, 7, lens=True, motion=True, pattern="stratified", lens_shape="square")
    for dim in (s.x, s.y, s.t, (s.u + 1) / 2, (s.v + 1) / 2):
        strata = np.floor(dim.astype(np.float64) * spp).astype(int).reshape(-1, spp)
        for row in strata:
            assert sorted(row) == list(range(spp))
    assert np.all(np.diff(s.t.reshape(-1, spp), axis=1) >= 0)


@pytest.mark.parametrize("m", [0, 2, 4, 6])
def test_sobol_pattern_keeps_the_net_strata(m):
    """A digital shift keeps Sobol's stratification: every 1D projection has one
    point per 1/2^m stratum and (x, y) is a (0, m, 2)-net, in every pixel."""
    spp = 1 << m
    s = make_samples(4, 3, spp, 11, lens=True, motion=True, pattern="sobol", lens_shape="square")
    for p in range(12):
        sl = slice(p * spp, (p + 1) * spp)
        ix = np.floor(s.x[sl].astype(np.float64) * spp).astype(int)
        iy = np.floor(s.y[sl].astype(np.float64) * spp).astype(int)
        it = np.floor(s.t[sl].astype(np.float64) * spp).astype(int)
        assert sorted(ix) == sorted(iy) == sorted(it) == list(range(spp))
        for k in range(m + 1):
            cells = (ix >> (m - k)) * (1 << (m - k)) + (iy >> k)
            assert len(set(cells.tolist())) == spp
        assert np.all(np.diff(s.t[sl]) >= 0)


def test_sobol_pattern_needs_power_of_two():
    with pytest.raises(UserError, match="power of two"):
        make_samples(2, 2, 6, 0, lens=False, motion=True, pattern="sobol")


def test_discrepancy_ranks_the_patterns():
    """scipy's L2-star discrepancy of (x, y, t) per pixel: the nets beat uniform random."""
    from scipy.stats import qmc

    def mean_disc(pattern):
        s = make_samples(8, 8, 16, 5, lens=False, motion=True, pattern=pattern)
        pts = np.stack([s.x, s.y, s.t], axis=1).astype(np.float64).reshape(-1, 16, 3)
        return np.mean([qmc.discrepancy(p) for p in pts])

    d = {p: mean_disc(p) for p in ("net", "sobol", "stratified", "random")}
    assert d["net"] < d["random"] / 3 and d["sobol"] < d["random"] / 3 and d["stratified"] < d["random"]


# ---------------------------------------------------------------------------
# Interleave UVT
# ---------------------------------------------------------------------------


def test_interleave_pixels_share_a_fixed_tuple_set():
    s = make_samples(16, 8, 4, 3, lens=True, motion=True, pattern="interleave", interleave_tuples=16)
    assert s.tuples.shape == (16, 3) and s.tup.shape == (16 * 8 * 4,)
    # every sample carries exactly its tuple's (u, v, t)
    np.testing.assert_array_equal(s.u, s.tuples[s.tup, 0].astype(np.float32))
    np.testing.assert_array_equal(s.t, s.tuples[s.tup, 2].astype(np.float32))
    per_pixel = s.tup.reshape(-1, 4)
    # a pixel's tuples are distinct, one per 1/spp time stratum, sorted by t
    assert all(len(set(p)) == 4 for p in per_pixel)
    t = s.t.reshape(-1, 4)
    assert np.all(np.diff(t, axis=1) > 0)
    np.testing.assert_array_equal(np.floor(t * 4), np.tile(np.arange(4), (len(t), 1)))
    # neighbouring pixels use all n tuples between them
    assert set(per_pixel[:4].ravel()) == set(range(16))
    assert np.all(np.hypot(s.tuples[:, 0], s.tuples[:, 1]) <= 1.0)


def test_interleave_tuple_set_is_deterministic_and_seed_independent():
    a = make_samples(8, 8, 8, 1, lens=True, motion=True, pattern="interleave", interleave_tuples=64)
    b = make_samples(8, 8, 8, 2, lens=True, motion=True, pattern="interleave", interleave_tuples=64)
    np.testing.assert_array_equal(a.tuples, b.tuples)  # a fixed hardware table
    assert not np.array_equal(a.x, b.x)  # the (x, y) jitter still follows the seed


def test_interleave_lens_points_per_group_are_stratified():
    # within one group (one pixel's tuples) the lens points, mapped back to the
    # square, form a (0, m, 2)-net up to a shift: one point per 1/spp column
    from pipeline_sim.sampling import interleave_tuple_set

    tup = interleave_tuple_set(64, 16, lens_shape="square")
    for g in range(4):
        u = (tup[g::4, 0] + 1.0) / 2.0
        assert sorted(np.floor(u * 16).astype(int)) == list(range(16))


def test_interleave_needs_spp_dividing_the_tuple_count():
    with pytest.raises(UserError, match="must divide"):
        make_samples(4, 4, 3, 0, lens=True, motion=True, pattern="interleave", interleave_tuples=16)


# ---------------------------------------------------------------------------
# net5: the t-ordered (t, m, 5)-net
# ---------------------------------------------------------------------------

#: The t-value of the net5 pattern's (t, m, 5)-net for spp = 2^m, as docs/pipeline.md §3 states it.
NET5_T = {0: 0, 1: 0, 2: 1, 3: 2, 4: 2, 5: 2, 6: 2, 7: 2, 8: 3, 9: 3, 10: 3}


def is_tnet(ints: np.ndarray, m: int, t: int) -> bool:
    """Brute force: ``ints`` (2^m, s) holds m-digit integer coordinates; every
    elementary box of volume 2^(t-m) (d_1 + ... + d_s = m - t leading digits)
    holds exactly 2^t points."""
    n, s = ints.shape
    for split in itertools.product(range(m - t + 1), repeat=s):
        if sum(split) != m - t:
            continue
        box = np.zeros(n, dtype=np.int64)
        for c, l in zip(ints.T, split):
            box = (box << l) | (c >> (m - l))
        if not (np.bincount(box, minlength=2 ** (m - t)) == 2**t).all():
            return False
    return True


def pixel_ints(s: SampleSet, p: int, m: int) -> np.ndarray:
    """(spp, 5) strata of pixel p's samples in (x, y, u, v, t), square lens mapped back to [0, 1)."""
    sl = s.pixel_slice(p)
    a = (s.u[sl].astype(np.float64) + 1.0) / 2.0
    b = (s.v[sl].astype(np.float64) + 1.0) / 2.0
    return np.stack([strata(s.x[sl], m), strata(s.y[sl], m), strata(a, m), strata(b, m), strata(s.t[sl], m)], axis=1)


@pytest.mark.parametrize("m", sorted(NET5_T))
def test_net5_pixels_are_t_m_5_nets_in_t_order(m):
    """Every pixel's samples form a (t, m, 5)-net with the stated t, and sorted
    position s holds the sample of t stratum s (the tester's range lookup)."""
    spp = 1 << m
    s = make_samples(3, 2, spp, 19, lens=True, motion=True, pattern="net5", lens_shape="square")
    for p in range(s.npix):
        ints = pixel_ints(s, p, m)
        assert is_tnet(ints, m, NET5_T[m]), f"pixel {p}"
        assert np.array_equal(ints[:, 4], np.arange(spp))
        assert np.all(np.diff(s.t[s.pixel_slice(p)]) > 0)
    assert ((s.x >= 0) & (s.x < 1) & (s.y >= 0) & (s.y < 1) & (s.t >= 0) & (s.t < 1)).all()
    if m >= 2:  # scrambled per pixel and jittered below the strata
        assert not np.array_equal(s.x[s.pixel_slice(0)], s.x[s.pixel_slice(1)])
        assert not (s.u * 2**m == np.floor(s.u * 2**m)).all()


@pytest.mark.parametrize("m", range(4, 11))
def test_net5_t_value_is_tight_and_beats_the_padded_net(m):
    """The stated t is the smallest for the unscrambled net; the default pattern,
    whose lens comes from a separate randomly paired 2D net, is not a net of that t."""
    net = np.round(t_ordered_net5(m) * 2**m).astype(np.int64)
    assert is_tnet(net, m, NET5_T[m])
    if NET5_T[m] > 0:
        assert not is_tnet(net, m, NET5_T[m] - 1)
    old = make_samples(4, 2, 1 << m, 19, lens=True, motion=True, pattern="net", lens_shape="square")
    assert not any(is_tnet(pixel_ints(old, p, m), m, NET5_T[m]) for p in range(old.npix))


@pytest.mark.parametrize("m", range(17))
def test_sobol_points_are_scipys(m):
    """The 5D Sobol points made here (no scipy at run time) against scipy's unscrambled ones, same order."""
    ref = qmc.Sobol(d=5, scramble=False).random_base2(m) * 2**m
    assert np.array_equal(ref, np.round(ref))  # the first 2^m points have m digits
    assert np.array_equal(sobol_points(m), ref.T.astype(np.int64))


def test_sobol_direction_numbers_are_odd_and_in_range():
    """m_k is odd and below 2^k (so v_k has its lowest set digit at k), for every dimension."""
    m = 16
    v = sobol_direction_numbers(m)
    for j in range(m):
        mk = v[:, j] >> (m - 1 - j)
        assert np.all(mk % 2 == 1) and np.all(mk < 2 ** (j + 1))
        assert np.all(v[:, j] & ((1 << (m - 1 - j)) - 1) == 0)


@pytest.mark.parametrize("m", [0, 1, 5, 9])
def test_net5_points_are_sobol_with_the_index_as_time(m):
    """Against scipy: its unscrambled 4D Sobol point k (Gray-code order) is point
    gray(k) = k ^ (k >> 1) of the net, whose t is gray(k) / 2^m."""
    ref = qmc.Sobol(d=4, scramble=False).random_base2(m)
    k = np.arange(1 << m)
    net = t_ordered_net5(m)
    assert np.array_equal(net[k ^ (k >> 1), :4], ref)
    assert np.array_equal(net[:, 4], k / 2**m)


def test_net5_determinism_flags_and_bands():
    kw = dict(lens=True, motion=True, pattern="net5")
    a = make_samples(10, 6, 16, 11, **kw)
    b = make_samples(10, 6, 16, 11, **kw)
    c = make_samples(10, 6, 16, 12, **kw)
    band = make_samples(10, 6, 16, 11, rows=(2, 5), **kw)
    off = make_samples(10, 6, 16, 11, lens=False, motion=False, pattern="net5")
    for f in ("x", "y", "u", "v", "t"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
        assert not np.array_equal(getattr(a, f), getattr(c, f))
        assert np.array_equal(getattr(band, f), getattr(a, f)[2 * 10 * 16:5 * 10 * 16])
    assert (off.u == 0).all() and (off.v == 0).all() and (off.t == 0.5).all()
    assert np.array_equal(off.x, a.x) and np.array_equal(off.y, a.y)
    r2 = a.u.astype(np.float64) ** 2 + a.v.astype(np.float64) ** 2
    assert (r2 <= 1 + 1e-6).all()
    with pytest.raises(UserError, match="power of two"):
        make_samples(2, 2, 12, 0, lens=True, motion=True, pattern="net5")


def test_net5_integrates_a_moving_defocused_edge_better():
    """RMSE over 4096 pixels (independent scrambles) of a 5D integrand, the
    indicator of a half-space moving in t and shifted by the lens, at 256 spp
    against its exact mean 1/2 (the half-space halves the cube through its
    centre): the jointly stratified pattern beats the default's randomly
    paired lens, and uniform random samples by far."""
    w = np.array([1.0, 0.6, 0.7, 0.5, 0.9])  # x, y, a, b, t on the unit cube

    def rmse(pattern):
        s = make_samples(64, 64, 256, 3, lens=True, motion=True, pattern=pattern, lens_shape="square")
        pts = np.stack([s.x, s.y, (s.u + 1) / 2, (s.v + 1) / 2, s.t], axis=1).astype(np.float64)
        est = (pts @ w < w.sum() / 2).reshape(-1, 256).mean(axis=1)
        return float(np.sqrt(np.mean((est - 0.5) ** 2)))

    e = {p: rmse(p) for p in ("net5", "net", "random")}
    assert e["net5"] < 0.95 * e["net"] and e["net5"] < 0.6 * e["random"], e
