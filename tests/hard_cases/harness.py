"""Shared checks for the hard-case catalogue (PIPELINE.md §8).

A *case* is a named set of clip-space triangles ``(q, r, lens_x, lens_y)``
(each ``(N, 3, 4)`` / ``(N, 3, 2)`` float64, as ``draw_from_clip`` takes
them). The checks below are what §8 asks of every hard case:

* ``assert_finite``: no NaN or inf in the resolved image, the multisample
  depth buffer, any counter or the frame time of a full ``run_pass``;
* ``assert_intervals_sane``: every tile record the tile test keeps carries
  finite, ordered intervals inside their domains (a NaN interval would make
  every comparison false and silently drop samples);
* ``assert_exact_coverage``: end-to-end conservativeness. The pipeline's own
  exact sample test (``units.sample_tester.inside_test``) is run on *every*
  sample of the frame for *every* triangle, with no setup culling, screen
  bounds, traversal or tile test in front of it; a full ``run_pass`` with
  additive blending and the depth test off must cover exactly those samples
  (per-pixel counts) and write exactly their depths (a z^ that excluded a
  sample's depth would show as a clamped depth);
* ``assert_bbox_matches_hierarchical``: the BBOX traversal (every sample of
  the bounds) and the hierarchical tile tests give identical images and
  depth buffers, with the default architecture (depth test, z-cull, shading
  cache) and with the counting architecture;
* ``assert_tiles_conservative``: the unit-level check of ``test_tile_test``
  (random samples the exact test accepts lie in a kept tile whose
  (t^, u^, v^, z^) contain them), for any triangle of a case;
* ``assert_continuous``: a 1e-6 relative perturbation of every input
  coordinate changes the image only a little;
* ``covered_once``: counts for watertight meshes.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.config import load_arch
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.render import RenderPass, run_pass
from triangles import sample_inside_points, setup_and_tiles
from units.sample_tester import inside_test
from units.triangle_setup import TriangleSetup

W, H = 48, 32
CLEAR_DEPTH = 4.0  # outside [-1, 1]: an untouched sample is recognisable in the depth buffer

# per-sample shading of a unit color, additive blending, no depth test: the
# resolved red channel times spp is the number of (triangle, sample) hits of a pixel
COUNT = ("rop.depth_test='always'", "rop.blend='add'", "shading.mode='per_sample'")
INTERVAL_NAMES = ("t_lo", "t_hi", "u_lo", "u_hi", "v_lo", "v_hi", "z_lo", "z_hi")


# --------------------------------------------------------------------------- building blocks
def tri(*verts):
    """One triangle as a (1, 3, 4) array from three (x, y, z, w) tuples."""
    return np.array([verts], dtype=np.float64)


def no_lens(q):
    return np.zeros(q.shape[:2] + (2,))


def lens_for(q, r, radius, focus, scale=(1.0, 1.0)):
    """Clip-space lens shifts of a thin lens (draw.lens_shift with P[0,0], P[1,1] = ``scale``)."""
    lx = np.zeros(q.shape[:2] + (2,))
    ly = np.zeros(q.shape[:2] + (2,))
    for s, arr in enumerate((q, r)):
        coc = radius * (arr[..., 3] / focus - 1.0)
        lx[..., s] = scale[0] * coc
        ly[..., s] = scale[1] * coc
    return lx, ly


def make_draw(q, r=None, lx=None, ly=None, *, width=W, height=H, depth_w=None, color=None):
    q = np.asarray(q, dtype=np.float64)
    r = q.copy() if r is None else np.asarray(r, dtype=np.float64)
    lx = no_lens(q) if lx is None else lx
    ly = no_lens(q) if ly is None else ly
    d = draw_from_clip(q, r, lx, ly, color, width, height)
    d.depth_w = depth_w
    return d


def arch(*overrides, algorithm="hierarchical", backface=False):
    ov = [f"tile_test.algorithm='{algorithm}'", f"triangle_setup.backface_culling={str(backface).lower()}"]
    return load_arch(overrides=ov + list(overrides))


def render(draw, *, spp=16, seed=0, overrides=(), algorithm="hierarchical", backface=False, pattern="net",
           table=None, clear_depth=1.0, clear_color=(0.0, 0.0, 0.0, 0.0)):
    a = arch(*overrides, algorithm=algorithm, backface=backface)
    return run_pass(RenderPass(draw=draw, arch=a, spp=spp, seed=seed, clear_color=clear_color,
                               clear_depth=clear_depth, sample_pattern=pattern, sample_table=table))


def render_counts(draw, **kw):
    """Render with the counting architecture; returns the result."""
    kw.setdefault("clear_depth", CLEAR_DEPTH)
    return render(draw, overrides=COUNT + tuple(kw.pop("overrides", ())), **kw)


def counts_of(res):
    """Per-pixel number of covered (triangle, sample) pairs of a counting render."""
    spp = res.depth.shape[2]
    c = res.image[..., 0].astype(np.float64) * spp
    rc = np.round(c)
    assert np.all(np.abs(c - rc) < 1e-3 * np.maximum(1.0, rc)), "counting render is not integral"
    return rc.astype(np.int64)


# --------------------------------------------------------------------------- checks
def assert_finite(res, what=""):
    """No NaN or inf in the resolved image, the depth buffer, any counter, the timing."""
    assert np.all(np.isfinite(res.image)), f"{what}: non-finite value in the resolved image"
    assert np.all(np.isfinite(res.depth)), f"{what}: non-finite value in the depth buffer"
    vals = np.asarray(res.counters.value, dtype=np.float64)
    bad = ~np.isfinite(vals)
    assert not bad.any(), f"{what}: non-finite counters {res.counters[bad].to_string()}"
    assert np.all(vals >= 0), f"{what}: negative counters {res.counters[vals < 0].to_string()}"
    assert np.isfinite(res.timing.frame_cycles), f"{what}: non-finite frame time"
    for col in ("busy", "starved", "blocked"):
        assert np.all(np.isfinite(res.timing.units[col])), f"{what}: non-finite {col} cycles"


def assert_intervals_sane(kept, what=""):
    """Kept tile records: finite intervals inside their domains, lo <= hi."""
    for name in INTERVAL_NAMES:
        assert np.all(np.isfinite(kept[name])), f"{what}: non-finite {name} in a kept tile record"
    for a, b, lo, hi in (("t_lo", "t_hi", 0.0, 1.0), ("u_lo", "u_hi", -1.0, 1.0), ("v_lo", "v_hi", -1.0, 1.0),
                         ("z_lo", "z_hi", -1.0, 1.0)):
        assert np.all(kept[a] <= kept[b]), f"{what}: empty {a[0]}^ interval in a kept tile record"
        assert np.all(kept[a] >= lo) and np.all(kept[b] <= hi), f"{what}: {a[0]}^ outside [{lo}, {hi}]"


@nb.njit(cache=True)
def _exact_kernel(p0, dp, l0, dl, eps, ntri, sx, sy, su, sv, st, width, height, spp, backface, count, zlast,
                  tlast):
    for py in range(height):
        for px in range(width):
            base = (py * width + px) * spp
            for s in range(spp):
                k = base + s
                x = np.float32(px) + sx[k]
                y = np.float32(py) + sy[k]
                for tr in range(ntri):
                    ok, b0, b1, b2, z = inside_test(p0, dp, l0, dl, tr, x, y, st[k], su[k], sv[k], backface, eps)
                    if ok:
                        count[k] += 1
                        zlast[k] = z
                        tlast[k] = tr


def exact_coverage(draw, samples, backface=False):
    """The pipeline's exact test on every sample and triangle, no culling in front.

    Returns (per-sample hit count, depth of the last covering triangle,
    index of that triangle), each shaped (H, W, spp)."""
    setup = TriangleSetup(load_arch().triangle_setup, draw, 8)
    setup.run(np.arange(draw.n, dtype=np.int64))  # fills the float32 vertex tables of every triangle
    tb = setup.table
    n = samples.width * samples.height * samples.spp
    count = np.zeros(n, np.int64)
    zlast = np.full(n, np.float32(np.nan), np.float32)
    tlast = np.full(n, -1, np.int64)
    _exact_kernel(tb.p0_32, tb.dp_32, tb.l0_32, tb.dl_32, tb.edge_eps, draw.n, samples.x, samples.y, samples.u,
                  samples.v, samples.t, samples.width, samples.height, samples.spp, backface, count, zlast, tlast)
    shape = (samples.height, samples.width, samples.spp)
    return count.reshape(shape), zlast.reshape(shape), tlast.reshape(shape)


def assert_exact_coverage(draw, *, spp=16, seed=0, backface=False, overrides=(), pattern="net", table=None,
                          what="", ztol=2e-6):
    """End-to-end conservativeness: the pipeline covers exactly the samples its
    exact test accepts, with exactly their depths. Returns the counting render."""
    res = render_counts(draw, spp=spp, seed=seed, backface=backface, overrides=overrides, pattern=pattern,
                        table=table)
    assert_finite(res, what)
    count, zlast, _ = exact_coverage(draw, res.samples, backface)
    got = counts_of(res)
    want = count.sum(axis=2)
    missing = np.argwhere(got < want)
    extra = np.argwhere(got > want)
    assert len(missing) == 0, (f"{what}: culling rejected samples the exact test accepts at pixels (row, col) "
                               f"{missing[:8].tolist()} (got {got[tuple(missing[0])]} of {want[tuple(missing[0])]})")
    assert len(extra) == 0, f"{what}: samples covered that the exact test rejects at {extra[:8].tolist()}"
    hit = count > 0
    assert np.all(res.depth[~hit] == CLEAR_DEPTH), f"{what}: depth written to a sample nobody covers"
    dz = np.abs(res.depth[hit].astype(np.float64) - zlast[hit])
    if dz.size:
        i = int(np.argmax(dz))
        assert dz[i] <= ztol * (1.0 + abs(float(zlast[hit][i]))), (
            f"{what}: written depth {res.depth[hit][i]} differs from the exact depth {zlast[hit][i]}: "
            f"z^ excluded the sample and the clamp moved it")
    return res


def assert_bbox_matches_hierarchical(draw, *, spp=8, seed=0, backface=False, what=""):
    """BBOX (no culling) and the hierarchical tile tests: identical images and depths."""
    for overrides in ((), COUNT):
        out = {}
        for alg in ("bbox", "hierarchical"):
            out[alg] = render(draw, spp=spp, seed=seed, overrides=overrides, algorithm=alg, backface=backface,
                              clear_depth=CLEAR_DEPTH if overrides else 1.0)
            assert_finite(out[alg], f"{what} [{alg}]")
        b, h = out["bbox"], out["hierarchical"]
        diff = np.argwhere(np.any(b.image != h.image, axis=2))
        assert len(diff) == 0, (f"{what}: hierarchical image differs from BBOX at (row, col) {diff[:8].tolist()} "
                                f"(arch {overrides or 'default'})")
        ddiff = np.argwhere(np.any(b.depth != h.depth, axis=2))
        assert len(ddiff) == 0, f"{what}: hierarchical depth differs from BBOX at {ddiff[:8].tolist()}"
        assert h.counter("sample_tester", "samples_tested") <= b.counter("sample_tester", "samples_tested")
    return out


def assert_tiles_conservative(q, r, lx, ly, *, seed=0, n=200, width=W, height=H, tile_size=8, coarse_factor=2,
                              depth_w=None, what="", ztol=1e-4, min_points=0):
    """Unit level (setup, traverser, tile test): every triangle of the case, random
    samples its exact test accepts lie in the bounds, the time span and a kept tile
    whose intervals contain them. Returns the number of samples checked."""
    rng = np.random.default_rng(seed)
    total = 0
    for i in range(len(q)):
        qi, ri, lxi, lyi = q[i:i + 1], r[i:i + 1], lx[i:i + 1], ly[i:i + 1]
        setup, alive, kept = setup_and_tiles(qi, ri, lxi, lyi, width, height, tile_size, coarse_factor,
                                             depth_w=depth_w)
        assert_intervals_sane(kept, f"{what} triangle {i}")
        pts = sample_inside_points(setup, 0, rng, n, width, height)
        total += len(pts)
        if not pts:
            continue
        assert 0 in alive, f"{what}: setup culled triangle {i}, which covers samples"
        bx0, bx1, by0, by1 = setup.table.bounds[0]
        ts, te = setup.table.t_span[0]
        for x, y, t, u, v, z in pts:
            assert bx0 <= x < bx1 and by0 <= y < by1, f"{what}: screen bounds miss a covered sample"
            assert ts <= t <= te, f"{what}: temporal span misses a covered sample"
            tx, ty = int(x // tile_size), int(y // tile_size)
            hit = np.nonzero((kept["tx"] == tx) & (kept["ty"] == ty))[0]
            assert len(hit) == 1, f"{what}: tile ({tx},{ty}) of a covered sample (t={t}) was rejected"
            j = hit[0]
            assert kept["t_lo"][j] <= t <= kept["t_hi"][j], f"{what}: t^ excludes a covered sample"
            assert kept["u_lo"][j] <= u <= kept["u_hi"][j], f"{what}: u^ excludes a covered sample"
            assert kept["v_lo"][j] <= v <= kept["v_hi"][j], f"{what}: v^ excludes a covered sample"
            tol = ztol * (1 + abs(z))
            assert kept["z_lo"][j] - tol <= z <= kept["z_hi"][j] + tol, (
                f"{what}: z^ [{kept['z_lo'][j]}, {kept['z_hi'][j]}] excludes a covered sample's depth {z}")
    assert total >= min_points, f"{what}: only {total} covered samples found"
    return total


def perturb(arrays, rel=1e-6, seed=0):
    """Each coordinate times (1 + rel * N(0, 1))."""
    rng = np.random.default_rng(seed)
    return [None if a is None else a * (1.0 + rel * rng.standard_normal(a.shape)) for a in arrays]


def assert_continuous(q, r, lx, ly, *, width=W, height=H, spp=16, rel=1e-6, seeds=(0, 1), depth_w=None,
                      mean_tol=1e-3, max_samples=2, overrides=COUNT, what=""):
    """A tiny relative perturbation of the input changes the image only a little:
    mean absolute difference < ``mean_tol``, and no pixel moves by more than
    ``max_samples`` samples' weight."""
    base = render(make_draw(q, r, lx, ly, width=width, height=height, depth_w=depth_w), spp=spp,
                  overrides=overrides, clear_depth=CLEAR_DEPTH if overrides == COUNT else 1.0)
    assert_finite(base, what)
    for s in seeds:
        pq, pr, plx, ply = perturb((q, r, lx, ly), rel, s)
        res = render(make_draw(pq, pr, plx, ply, width=width, height=height, depth_w=depth_w), spp=spp,
                     overrides=overrides, clear_depth=CLEAR_DEPTH if overrides == COUNT else 1.0)
        assert_finite(res, what)
        d = np.abs(res.image.astype(np.float64) - base.image)
        assert d.mean() < mean_tol, f"{what}: perturbation {rel} changed the image by {d.mean()} on average"
        assert d.max() <= max_samples / spp + 1e-5, (
            f"{what}: perturbation {rel} changed pixel {np.unravel_index(np.argmax(d), d.shape)} by {d.max()}")
    return base


def full_screen_counts_are_one(res, what=""):
    c = counts_of(res)
    bad = np.argwhere(c != res.depth.shape[2])
    assert len(bad) == 0, (f"{what}: pixels {bad[:8].tolist()} have {c[tuple(bad[0])]} hits for "
                           f"{res.depth.shape[2]} samples (holes or double coverage)")
