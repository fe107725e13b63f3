"""The rasterizer as a volumetric sampler and integrator (workloads/apps/sampling, docs/sampling-app.md):
counts against exact prism volumes, each sample in at most one prism or slab, the torus against its
closed forms."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline_sim.config import load_arch
from pipeline_sim.errors import UserError
from pipeline_sim.render import run_pass, run_passes
from workloads.apps.sampling import (RECORD, Settings, append_shader, integrate_torus, prism_draw,
                                     reference_prism_volume, reference_torus, sampler_pass, slab_bounds,
                                     torus_slab_radii)
from runs import run_doc_example

ARCH = load_arch()
W = H = 32
SEEDS = 10
# a triangle turning by a quarter turn about (16, 16) over the shutter: its area is quadratic in t, half
# its size at mid-shutter
P0 = np.array([[[3.0, 4.0], [25.0, 6.0], [10.0, 27.0]]])
P1 = np.stack([32.0 - P0[..., 1], P0[..., 0]], axis=-1)


def appended(draws, spp, seed, params, pattern="random", table=None):
    p = sampler_pass(draws, spp, seed, pattern, append_shader, params, ARCH, "p", capacity=200_000)
    p.sample_table = table
    result = run_pass(p)
    assert result.append.overflow == 0
    return result.append.records


def z_of_counts(counts, expected):
    """The z score of the mean of independent counts whose variance is at most their mean (the random
    pattern: per pixel, binomial counts)."""
    return (np.mean(counts) - expected) / math.sqrt(expected / len(counts))


def test_reference_prism_volume_against_monte_carlo():
    """The quadrature (exact for the area's polynomial) against brute-force point-in-triangle counts."""
    rng = np.random.default_rng(1)
    n = 400_000
    t, x, y = rng.random(n), rng.random(n) * W, rng.random(n) * H
    r2, a = rng.random(n), 2 * np.pi * rng.random(n)
    u, v = np.sqrt(r2) * np.cos(a), np.sqrt(r2) * np.sin(a)
    l0 = np.array([[[2.0, 1.0], [-3.0, 0.5], [0.0, 2.0]]])
    l1 = np.array([[[-1.0, 2.0], [1.0, -2.0], [3.0, 0.0]]])
    for lens in (False, True):
        p = (1 - t)[:, None, None] * P0[0] + t[:, None, None] * P1[0]
        if lens:
            shift = (1 - t)[:, None, None] * l0[0] + t[:, None, None] * l1[0]
            p = p + shift * np.stack([u, v], axis=1)[:, None, :]
        e = [p[:, (k + 1) % 3] - p[:, k] for k in range(3)]
        d = [e[k][:, 0] * (y - p[:, k, 1]) - e[k][:, 1] * (x - p[:, k, 0]) for k in range(3)]
        inside = ((d[0] > 0) & (d[1] > 0) & (d[2] > 0)) | ((d[0] < 0) & (d[1] < 0) & (d[2] < 0))
        mc = inside.mean() * W * H * (np.pi if lens else 1.0)
        exact = reference_prism_volume(P0, P1, lens0=l0 if lens else None, lens1=l1 if lens else None)[0]
        assert abs(mc - exact) < 4 * math.sqrt(mc * W * H * (np.pi if lens else 1.0) / n) + 1e-9


def test_counts_in_a_moving_prism_match_rho_times_volume():
    """xyt: over many scrambles, the samples appended from one moving triangle average spp x its volume."""
    spp = 8
    draw = prism_draw(P0, P1, W, H, objects=[0])
    expected = spp * reference_prism_volume(P0, P1)[0]
    # the middle-of-the-shutter area times 1 misses the quadratic term by far more than the test's error
    assert abs(spp * reference_prism_volume(0.5 * (P0 + P1), 0.5 * (P0 + P1))[0] - expected) > 0.05 * expected
    counts = [len(appended([draw], spp, seed, np.ones(1))) for seed in range(SEEDS)]
    assert abs(z_of_counts(counts, expected)) < 4.0


def test_counts_in_xyuvt_with_lens_shifted_vertices():
    """xyuvt: each vertex shifted by its own lens offset per unit (u, v), changing over the shutter; the
    density is spp per pixel per unit t per lens disk area pi."""
    spp = 8
    l0 = np.array([[[2.0, 1.0], [-3.0, 0.5], [0.0, 2.0]]])
    l1 = np.array([[[-1.0, 2.0], [1.0, -2.0], [3.0, 0.0]]])
    draw = prism_draw(P0, P1, W, H, lens0=l0, lens1=l1, objects=[0])
    expected = spp * reference_prism_volume(P0, P1, lens0=l0, lens1=l1)[0] / math.pi
    records = [appended([draw], spp, seed, np.ones(1)) for seed in range(SEEDS)]
    assert np.ptp(records[0][:, RECORD.index("u")]) > 1.0  # the lens is sampled
    assert abs(z_of_counts([len(r) for r in records], expected)) < 4.0


def test_a_static_prism_cut_by_clip_planes_is_a_volume_of_xyt():
    """A static triangle cut by clip planes in t: the pass samples t, and the count is spp x area x the
    slab's width (a pass without motion used to put every sample at t = 0.5: none or all of them)."""
    spp = 8
    draw = prism_draw(P0, P0, W, H, t_lo=0.25, t_hi=0.625, objects=[0])
    expected = spp * reference_prism_volume(P0, P0, 0.25, 0.625)[0]
    records = [appended([draw], spp, seed, np.full(1, 0.625)) for seed in range(SEEDS)]
    t = np.concatenate(records)[:, RECORD.index("t")]
    assert t.min() >= 0.25 and t.max() < 0.625
    assert abs(z_of_counts([len(r) for r in records], expected)) < 4.0


def quad(shift_x: float) -> tuple[np.ndarray, np.ndarray]:
    """A square (4, 4)-(20, 20) moving right by ``shift_x`` pixels, as two triangles sharing the diagonal's
    vertex paths."""
    corners = np.array([[4.0, 4.0], [20.0, 4.0], [20.0, 20.0], [4.0, 20.0]])
    tri = corners[[[0, 1, 2], [0, 2, 3]]]
    return tri, tri + [shift_x, 0.0]


# per-pixel sample table (x, y, u, v, t), t sorted: on the moving diagonal (x - y = 6 t in pixels of equal
# row and column: 0.875 - 0.125 = 6 x 0.125), at the slab bound t = 0.5 (also on the diagonal there:
# 0.75 - 0.75 + 3 = 3 = 6 x 0.5), and elsewhere (none on the square's outer edges)
TABLE = np.array([[0.875, 0.125, 0, 0, 0.125], [0.3, 0.6, 0, 0, 0.2], [0.5, 0.5, 0, 0, 0.5],
                  [0.75, 0.75, 0, 0, 0.5], [0.3, 0.9, 0, 0, 0.7], [0.6, 0.1, 0, 0, 0.9]])


@pytest.mark.parametrize("half_open", [True, False])
def test_shared_vertex_paths_and_slab_bounds_place_each_sample_once(half_open):
    """Two slabs [0, 0.5) and [0.5, 1] of a moving square split along its diagonal: every sample inside
    the square, on the diagonal or at t = 0.5 included, is appended exactly once. Without the half-open
    slab rule (closed clip planes on both sides), the samples at t = 0.5 come twice."""
    p0, p1 = quad(6.0)
    bounds = slab_bounds(2)
    draws = [prism_draw(p0, p1, W, H, t_lo=bounds[k], t_hi=bounds[k + 1], objects=[k, k]) for k in range(2)]
    records = appended(draws, len(TABLE), 0, bounds[1:] if half_open else np.ones(2), table=TABLE)
    x, y, t = (records[:, RECORD.index(c)].astype(np.float64) for c in "xyt")
    key = (np.floor(y) * W + np.floor(x)) * len(TABLE) + records[:, RECORD.index("sample")]
    # brute force: the samples of the table strictly inside the square at their t
    py, px, k = np.meshgrid(np.arange(H), np.arange(W), np.arange(len(TABLE)), indexing="ij")
    sx, sy, stt = px + TABLE[k, 0], py + TABLE[k, 1], TABLE[k, 4]
    inside = (sx > 4 + 6 * stt) & (sx < 20 + 6 * stt) & (sy > 4) & (sy < 20)
    on_diagonal = np.isclose(sx - 6 * stt, sy) & inside
    assert on_diagonal.sum() >= 20 and (inside & (stt == 0.5)).sum() >= 30
    want = np.sort(((py * W + px) * len(TABLE) + k)[inside])
    counted, times = np.unique(key, return_counts=True)
    if half_open:
        assert times.max() == 1
        np.testing.assert_array_equal(counted, want)
    else:
        assert np.all(t[np.isin(key, counted[times > 1])] == 0.5)
        assert (times > 1).sum() == (inside & (stt == 0.5)).sum()


def test_tessellated_solid_counts_once_and_matches_volume():
    """A ring of moving triangles sharing vertex paths, in three slabs: no (pixel, sample) is appended
    twice, and the count over scrambles matches spp x the solid's volume."""
    a = 2 * np.pi * np.arange(7) / 6
    ring = np.stack([np.cos(a), np.sin(a)], 1)
    c0, c1 = np.array([15.0, 16.0]), np.array([18.0, 14.0])
    i = np.arange(6)

    def tris(centre, outer, inner):
        o, n = centre + outer * ring, centre + inner * ring
        return np.concatenate([np.stack([o[i], o[i + 1], n[i + 1]], 1), np.stack([o[i], n[i + 1], n[i]], 1)])

    p0, p1 = tris(c0, 12.0, 4.0), tris(c1, 10.0, 6.0)
    bounds = slab_bounds(3)
    draws = [prism_draw(p0, p1, W, H, t_lo=bounds[k], t_hi=bounds[k + 1], objects=np.full(12, k)) for k in range(3)]
    expected = 8 * sum(reference_prism_volume(p0, p1, bounds[k], bounds[k + 1]).sum() for k in range(3))
    counts = []
    for seed in range(SEEDS):
        r = appended(draws, 8, seed, bounds[1:])
        key = (np.floor(r[:, 1]) * W + np.floor(r[:, 0])) * 8 + r[:, RECORD.index("sample")]
        assert len(np.unique(key)) == len(key)
        counts.append(len(r))
    assert abs(z_of_counts(counts, expected)) < 4.0


# ------------------------------------------------------------------------------------------------ torus


@settings(max_examples=300, deadline=None)
@given(st.floats(0.5, 5.0), st.floats(0.05, 0.45), st.floats(0.0, 1.0), st.floats(0.0, 1.0),
       st.floats(0.0, 1.0))
def test_torus_slab_bound_is_conservative(major, ratio, a, b, f):
    """The slab's linearly varying circles hold the torus's annulus at every z of the slab."""
    minor = ratio * major
    z0, z1 = sorted((-minor + 2 * minor * a, -minor + 2 * minor * b))
    if z1 - z0 < 1e-6 * minor:
        return
    z = z0 + f * (z1 - z0)
    o0, o1, i0, i1 = torus_slab_radii(major, minor, z0, z1)
    w = (z - z0) / (z1 - z0)
    h = math.sqrt(max(minor * minor - z * z, 0.0))
    assert (1 - w) * o0 + w * o1 >= major + h
    assert (1 - w) * i0 + w * i1 <= major - h


def torus(**changes) -> Settings:
    base = dict(method="torus", resolution=48, spp=16, slabs=6, segments=16)
    return Settings(**{**base, **changes})


def test_torus_integrals_match_the_closed_forms():
    """Volume 2 pi^2 R r^2, integral of x^2 + y^2 = 2 pi^2 R r^2 (R^2 + 3 r^2 / 4), of z^2 = pi^2 R r^4 / 2,
    each within four standard errors; the bound holds the torus and the sample count is the volume's."""
    s = torus(major=1.5, minor=0.5)
    _, out = integrate_torus(s, ARCH, run_passes)
    exact = reference_torus(1.5, 0.5)
    assert exact["volume"] == pytest.approx(2 * math.pi**2 * 1.5 * 0.25)
    for name in ("volume", "xy2", "z2"):
        assert abs(out[name] - exact[name]) < 4 * out[f"{name}_se"], name
    assert out["bound_volume"] > exact["volume"]
    assert out["samples_covered"] > out["points_inside"]


def test_torus_error_falls_with_density():
    """The random pattern's error falls as rho^-1/2: the RMS error over scrambles at 64 spp is well below
    that at 4 spp, and the standard error falls by sqrt(16)."""
    rms, se = {}, {}
    for spp in (4, 64):
        runs = [integrate_torus(torus(spp=spp, seed=seed), ARCH, run_passes)[1] for seed in range(4)]
        rms[spp] = math.sqrt(np.mean([r["volume_rel_error"] ** 2 for r in runs]))
        se[spp] = np.mean([r["volume_se"] for r in runs])
    assert se[4] / se[64] == pytest.approx(4.0, rel=0.1)
    assert rms[64] < rms[4] / 1.5


def test_bad_torus_is_one_line(tmp_path):
    from pipeline_sim.workload import load_workload

    f = tmp_path / "t.toml"
    f.write_text('kind = "sampling"\nmethod = "torus"\nmajor = 1.0\nminor = 1.5\n')
    with pytest.raises(UserError, match=r"t.toml: minor: the minor radius 1.5 must be less than"):
        load_workload(f, ARCH).check()
    f.write_text('kind = "sampling"\nmethod = "torus"\nmajr = 1.0\n')
    with pytest.raises(UserError, match=r"did you mean 'major'"):
        load_workload(f, ARCH)
    f.write_text('kind = "sampling"\nmethod = "torus"\npattern = "net"\nspp = 3\n')
    with pytest.raises(UserError, match=r"t\.toml: spp = 3 must be a power of two"):
        load_workload(f, ARCH).check()


def test_the_doc_example_runs_as_written():
    """docs/sampling-app.md's example runs and prints its count."""
    import contextlib
    import io
    import re
    from pathlib import Path

    scope, printed = run_doc_example("sampling-app.md")
    assert "samples appended" in printed
    assert set(scope["records"][:, RECORD.index("object")]) == {0.0, 1.0}


def test_the_cost_sweep_validates_and_measures_the_error_against_cycles(tmp_path):
    """workloads/sweeps/sampling_cost.toml validates; the same study in small runs the torus per point and
    puts its errors beside the simulated cycles: more samples, more cycles, a smaller standard error."""
    from pathlib import Path

    from pipeline_sim.sweep import load_sweep, run_sweep

    root = Path(__file__).resolve().parent.parent
    study = load_sweep(root / "workloads/sweeps/sampling_cost.toml")
    assert len(study.points) == 24 and {p["image.spp"] for p in study.points} == {4, 16, 64, 256}
    sweep = tmp_path / "s.toml"
    sweep.write_text(f'[sweep]\nscene = "{root}/workloads/apps/sampling/torus.toml"\n'
                     'results = ["volume_error", "volume_se"]\n[grid]\n"image.spp" = [4, 16]\n'
                     '"workload.resolution" = [24]\n"workload.slabs" = [4]\n')
    frame = run_sweep(load_sweep(sweep), tmp_path / "out", executor="serial", progress=False).set_index("image.spp")
    assert frame.loc[16, "frame_cycles"] > frame.loc[4, "frame_cycles"]
    assert frame.loc[16, "result.volume_se"] == pytest.approx(frame.loc[4, "result.volume_se"] / 2, rel=0.1)
    assert (frame["result.volume_error"] < 4 * frame["result.volume_se"] / reference_torus(1.0, 0.4)["volume"]).all()
