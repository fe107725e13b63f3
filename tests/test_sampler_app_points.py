"""Point sets from the rasterizer as a sampler (workloads/apps/sampling, docs/sampling-app.md): maximal
Poisson-disk sets by accelerated dart throwing, checked with k-d trees, a dense probe grid, scipy's
sampler and the random-sequential-adsorption coverage; adaptive white noise against its density, and its
cells' bound holding every sample the height field accepts (hypothesis)."""

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats
from scipy.spatial import cKDTree

from pipeline_sim.config import load_arch
from pipeline_sim.errors import UserError
from pipeline_sim.render import run_passes
from workloads.apps.sampling import (RECORD, Settings, _covered, accept_candidates, adaptive_white_noise,
                                     base_grid, density_cells, load_density, poisson_disk, reference_poisson,
                                     slab_bounds)

ARCH = load_arch()
# random sequential adsorption's jamming coverage by disks of radius r/2 in the plane (Feder 1980)
JAMMING = {2: 0.547}


def probe_gaps(points: np.ndarray, radius: float, spacing: float) -> int:
    """Probes of a grid over the unit cube farther than ``radius`` from every point."""
    d = points.shape[1]
    axis = np.arange(0.0, 1.0 + 1e-12, spacing)
    probes = np.stack(np.meshgrid(*[axis] * d, indexing="ij"), -1).reshape(-1, d)
    dist, _ = cKDTree(points).query(probes)
    return int((dist > radius).sum())


def reference_rsa(dimension: int, radius: float, seed: int, darts: int = 400_000) -> np.ndarray:
    """Random sequential adsorption by brute force: uniform darts, one after the other, each kept unless
    a kept point lies closer than r; in batches, each first screened against the points kept before it
    (a k-d tree), its survivors then taken one by one. Saturated up to gaps the darts miss."""
    rng = np.random.default_rng(seed + 100)
    kept = np.zeros((0, dimension))
    for batch in np.array_split(rng.random((darts, dimension)), darts // 2000):
        if len(kept):
            batch = batch[cKDTree(kept).query(batch)[0] >= radius]
        for p in batch:
            if not len(kept) or np.min(np.sum((kept - p) ** 2, axis=1)) >= radius**2:
                kept = np.vstack([kept, p])
    return kept


@pytest.mark.parametrize("dimension, radius", [(2, 0.06), (3, 0.2)])
def test_dart_throwing_gives_a_maximal_poisson_disk_set(dimension, radius):
    """No two points closer than r (k-d tree); every probe of a dense grid within r of a point (maximal);
    denser than scipy's Bridson sampler, which stops short of maximal; as many points as brute-force random
    sequential adsorption leaves (in 3D, a little more than brute force reaches); in 2D, the coverage of the r/2 disks, over the unit square grown by r/2
    on each side (their centres' reach), near the jamming limit."""
    s = Settings(method="poisson", dimension=dimension, radius=radius, spp=4, seed=3)
    _, out, pts, table = poisson_disk(s, ARCH, run_passes)
    assert pts.shape == (out["points"], dimension) and np.all((pts >= 0) & (pts < 1))
    assert not cKDTree(pts).query_pairs(radius * (1 - 1e-12))
    spacing = radius / (12 if dimension == 2 else 5)
    assert probe_gaps(pts, radius, spacing) == 0
    assert out["dropped_volume"] < 1e-9 and out["overflow"] == 0
    # without its points near the centre, the set is not maximal: the probe test can fail
    assert probe_gaps(pts[np.linalg.norm(pts - 0.5, axis=1) > 1.5 * radius], radius, spacing)
    ref, _ = reference_poisson(dimension, radius, 3)
    assert not cKDTree(ref).query_pairs(radius * (1 - 1e-12))
    assert len(pts) > len(ref)
    rsa = np.mean([len(reference_rsa(dimension, radius, seed)) for seed in range(3)])
    if dimension == 2:
        assert abs(len(pts) - rsa) < 0.04 * rsa
    else:  # brute force nears jamming only as darts^(-1/3) in 3D: its count stays a few percent short
        assert rsa - 3 < len(pts) < 1.1 * rsa
    if dimension == 2:  # enough points for the bulk's jamming coverage to show through the boundary's
        ball = math.pi * (radius / 2) ** 2
        assert abs(len(pts) * ball / (1 + radius) ** 2 - JAMMING[2]) < 0.1 * JAMMING[2]
    assert out["rounds"] == len(table) and table.candidates.sum() == out["candidates_appended"]
    assert table.voids.iloc[-1] > 0 and out["samples_tested"] >= out["candidates_appended"]


@pytest.mark.parametrize("dimension", [2, 3])
def test_accept_candidates_is_greedy_in_order(dimension):
    """The compute step against brute force: candidates taken in order, each kept unless a kept point
    lies closer than r."""
    rng = np.random.default_rng(dimension)
    radius = 0.1
    n0 = base_grid(dimension, radius)
    cand = np.zeros((600, 3))
    cand[:, :dimension] = rng.random((600, dimension))
    grid = np.full((n0, n0, n0 if dimension == 3 else 1), -1, np.int64)
    points = np.zeros((grid.size, 3))
    count = np.zeros(1, np.int64)
    accept_candidates(cand, points, count, grid, radius)
    kept = []
    for c in cand:
        if all(np.sum((c - k) ** 2) >= radius**2 for k in kept):
            kept.append(c)
    np.testing.assert_array_equal(points[:count[0]], np.array(kept))


@settings(max_examples=200, deadline=None)
@given(st.integers(2, 3), st.integers(0, 2**32 - 1), st.integers(0, 4))
def test_a_void_is_dropped_only_when_covered(dimension, seed, level):
    """Conservative void culling: a cell reported covered has every point of it (random probes and its
    corners) within r of some point."""
    rng = np.random.default_rng(seed)
    radius = 0.15
    n0 = base_grid(dimension, radius)
    grid = np.full((n0, n0, n0 if dimension == 3 else 1), -1, np.int64)
    points = np.zeros((grid.size, 3))
    count = np.zeros(1, np.int64)
    cand = np.zeros((40, 3))
    cand[:, :dimension] = rng.random((40, dimension))
    accept_candidates(cand, points, count, grid, radius)
    side = 1.0 / (n0 * 2**level)
    origin = np.zeros(3)
    origin[:dimension] = rng.integers(0, n0 * 2**level, dimension) * side
    if _covered(origin, side, dimension, points, grid, radius):
        probes = origin[:dimension] + side * np.concatenate(
            [rng.random((200, dimension)), np.indices((2,) * dimension).reshape(dimension, -1).T])
        dist, _ = cKDTree(points[:count[0], :dimension]).query(probes)
        assert np.all(dist <= radius * (1 + 1e-12))


# ---------------------------------------------------------------------------------------------- density


def test_adaptive_white_noise_follows_the_density():
    """Points under the camera image's height field: the count is spp x the density's integral, the counts
    over 8 x 8 blocks pass a chi-square test against the density (and fail it against a uniform one), the
    x marginal passes a Kolmogorov-Smirnov test, and every point lies under the height field."""
    s = Settings(method="density", resolution=48, cell=4, levels=6, spp=4, seed=2)
    rho = load_density(s.image, Path("."), s.resolution)
    passes, out, pts = adaptive_white_noise(s, rho, ARCH, run_passes)
    records = passes["density"].append.records
    expected = s.spp * rho.sum(dtype=np.float64)
    assert abs(len(pts) - expected) < 4 * math.sqrt(expected)
    assert out["chi2_pvalue"] > 1e-3
    assert np.all(records[:, RECORD.index("t")] < rho[pts[:, 1].astype(int), pts[:, 0].astype(int)])
    # the same block test against a uniform density rejects these points
    h, w = rho.shape
    blocks = np.histogram2d(pts[:, 1], pts[:, 0], bins=8, range=((0, h), (0, w)))[0].ravel()
    assert stats.chisquare(blocks).pvalue < 1e-6
    # x marginal: within a pixel column, x is uniform; the column's weight is its density's sum
    column = rho.sum(axis=0, dtype=np.float64)
    cdf_at = np.concatenate([[0.0], np.cumsum(column) / column.sum()])

    def cdf(x):
        i = np.clip(np.floor(x).astype(int), 0, w - 1)
        return cdf_at[i] + (x - i) * (cdf_at[i + 1] - cdf_at[i])

    assert stats.kstest(pts[:, 0], cdf).pvalue > 1e-3
    assert out["bound_volume"] >= rho.sum()


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 20), st.integers(1, 20), st.integers(1, 8), st.integers(1, 16), st.data())
def test_density_cells_bound_every_sample_under_the_height_field(h, w, cell, levels, data):
    """A sample (x, y, t) is under the height field when t < rho at its pixel (float32, as the shader's
    fetch compares); the largest such t, one float32 below rho, must lie in exactly one cell of the
    bound, under that cell's clip plane. Densities include 0, 1, the clip planes' own heights and their
    float32 neighbours (the rounding up's edges)."""
    planes = slab_bounds(levels).astype(np.float32)
    edges = np.concatenate([planes, np.nextafter(planes, np.float32(0)), np.nextafter(planes, np.float32(2))])
    value = st.one_of(st.sampled_from(sorted(float(e) for e in edges if 0.0 <= e <= 1.0)),
                      st.floats(0.0, 1.0, width=32))
    rho = np.array(data.draw(st.lists(value, min_size=h * w, max_size=h * w)), np.float32).reshape(h, w)
    py, px = np.mgrid[0:h, 0:w]
    bounds = slab_bounds(levels)
    holding = np.zeros((h, w), int)
    plane = np.zeros((h, w))
    for k, corners in density_cells(rho, cell, levels).items():
        for cx, cy in corners:
            inside = (px >= cx) & (px < cx + cell) & (py >= cy) & (py < cy + cell)
            holding += inside
            plane[inside] = bounds[k]
    accepted = rho > 0  # some t in [0, rho) exists
    highest = np.nextafter(rho, np.float32(0)).astype(np.float64)
    assert (holding[accepted] == 1).all()
    assert (highest[accepted] < plane[accepted]).all()


def test_density_image_errors_are_one_line(tmp_path):
    with pytest.raises(UserError, match="neither an image file nor a scikit-image sample image"):
        load_density("nosuchimage", tmp_path, 16)
    with pytest.raises(UserError, match="image: no file"):
        load_density("missing.png", tmp_path, 16)
    from PIL import Image

    Image.fromarray(np.zeros((8, 8), np.uint8)).save(tmp_path / "black.png")
    with pytest.raises(UserError, match="is black"):
        load_density("black.png", tmp_path, 16)


def test_a_run_writes_the_point_set_and_its_plot(tmp_path):
    """`pipeline-sim run` of a Poisson file: results.json's counts, points.npy (the set it counts, r
    apart), points.png and rounds.csv, listed in run.json (the workload's arrays and figures)."""
    import json

    from pipeline_sim.cli import main

    f = tmp_path / "p.toml"
    f.write_text('kind = "sampling"\nmethod = "poisson"\ndimension = 2\nradius = 0.25\nspp = 4\n')
    out = tmp_path / "run"
    assert main(["run", str(f), "--out", str(out), "--quiet", "--seed", "1"]) == 0
    results = json.loads((out / "results.json").read_text())
    pts = np.load(out / "points.npy")
    assert results["points"] == len(pts) and isinstance(results["points"], int)
    assert not cKDTree(pts).query_pairs(0.25 * (1 - 1e-12))
    info = json.loads((out / "run.json").read_text())
    assert info["arrays"] == ["points.npy"] and info["figures"] == ["points.png"]
    assert (out / "points.png").stat().st_size > 1000 and (out / "rounds.csv").is_file()
    assert info["workload"]["settings"]["seed"] == 1
