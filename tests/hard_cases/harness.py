"""Shared checks for the hard-case catalogue (docs/pipeline.md §8).

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
  cache) and with the counting architecture, and z-cull off changes nothing;
* ``assert_tiles_conservative``: the unit-level check of ``test_tile_test``
  (random samples the exact test accepts lie in the bounds, the time span
  and a kept tile whose (t^, u^, v^, z^) and two-stage time lines contain
  them), for each triangle and every tile-test algorithm (``TILE_ALGORITHMS``);
  ``check_exact`` also runs every algorithm end to end (``VARIANTS``);
* ``check_conservative_mode``: the same promise for conservative mode (1x1
  tiles, one interval-shader run per pixel);
* ``assert_continuous``: a 1e-6 relative perturbation of every input
  coordinate changes the image only a little;
* ``check_scale_invariant``: clip coordinates are homogeneous, so the case
  with every coordinate and lens shift times a positive factor is the same
  scene: for every tile-test configuration it covers exactly the same
  samples with exactly the same depths;
* ``full_screen_counts_are_one``, ``assert_single_layer_counts`` and
  ``assert_closed_mesh_watertight``: watertightness of meshes (every sample
  once; at most once; front hits equal back hits along every sample ray);
* ``assert_matches_reference``: float32 coverage and depth at pixel centres
  against the float64 reference renderer, away from edges.

Cases are ``Case`` objects; ``check_exact``, ``check_bbox``, ``check_tiles``,
``check_continuity``, ``check_scale_invariant`` run the checks on them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from pipeline_sim.config import load_arch, pass_settings
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.render import RenderPass, run_pass
from triangles import sample_inside_points, setup_and_tiles
from units.sample_tester import inside_test
from units.triangle_setup import TriangleSetup

W, H = 48, 32
CLEAR_DEPTH = 4.0  # outside [-1, 1]: an untouched sample is recognisable in the depth buffer

# per-sample shading of a unit color, additive blending, no depth test: the
# resolved red channel times spp is the number of (triangle, sample) hits of a pixel
COUNT = ("pass.depth_test='always'", "pass.blend='add'", "pass.shading_mode='per_sample'")
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


def settings(*overrides, algorithm="hierarchical", backface=False):
    """The RenderPass keywords (arch, state, simulation) of these overrides, algorithm and backface culling."""
    ov = [f"tile_test.algorithm='{algorithm}'", f"pass.backface_culling={str(backface).lower()}"]
    return pass_settings(ov + list(overrides))


def render(draw, *, spp=16, seed=0, overrides=(), algorithm="hierarchical", backface=False, pattern="net",
           table=None, clear_depth=1.0, clear_color=(0.0, 0.0, 0.0, 0.0)):
    s = settings(*overrides, algorithm=algorithm, backface=backface)
    return run_pass(RenderPass(draw=draw, arch=s["arch"], simulation=s["simulation"], spp=spp, seed=seed,
                               clear_color=clear_color, clear_depth=clear_depth, sample_table=table,
                               state=s["state"].replace(sample_pattern=pattern)))


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
        if a != "z_lo":  # an empty z^ (plane test proves no depth) is harmless: no sample can be covered
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
    """BBOX (no culling) and the hierarchical tile tests give identical images and
    depths, with the default architecture (depth test, z-cull, shading cache) and
    with the counting one; and z-cull on or off changes nothing either."""
    default = {}
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
        if not overrides:
            default = out
    # z-cull is a culling test too: switching it off changes no pixel and no depth
    off = render(draw, spp=spp, seed=seed, overrides=("zcull.enabled=false",), backface=backface)
    assert_finite(off, what)
    on = default["hierarchical"]
    assert np.array_equal(on.image, off.image), f"{what}: z-cull changed the image"
    assert np.array_equal(on.depth, off.depth), f"{what}: z-cull changed the depth buffer"
    return default


TILE_ALGORITHMS = (("hierarchical", "linearized"), ("hierarchical", "quadratic"), ("hull", "linearized"),
                   ("dual_space", "linearized"), ("two_stage", "linearized"))


def assert_tiles_conservative(q, r, lx, ly, *, seed=0, n=200, width=W, height=H, tile_size=8, coarse_factor=2,
                              depth_w=None, what="", ztol=1e-4, min_points=0):
    """``assert_tiles_conservative_with`` for every tile-test algorithm and edge solver."""
    total = 0
    for algorithm, solver in TILE_ALGORITHMS:
        total = assert_tiles_conservative_with(q, r, lx, ly, seed=seed, n=n, width=width, height=height,
                                               tile_size=tile_size, coarse_factor=coarse_factor, depth_w=depth_w,
                                               what=f"{what} [{algorithm}, {solver}]", ztol=ztol,
                                               min_points=min_points, algorithm=algorithm, edge_solver=solver)
    return total


def assert_tiles_conservative_with(q, r, lx, ly, *, seed=0, n=200, width=W, height=H, tile_size=8, coarse_factor=2,
                                   depth_w=None, what="", ztol=1e-4, min_points=0, algorithm="hierarchical",
                                   edge_solver="linearized"):
    """Unit level (setup, traverser, tile test): every triangle of the case, random
    samples its exact test accepts lie in the bounds, the time span and a kept tile
    whose intervals contain them. Returns the number of samples checked."""
    rng = np.random.default_rng(seed)
    total = 0
    for i in range(len(q)):
        qi, ri, lxi, lyi = q[i:i + 1], r[i:i + 1], lx[i:i + 1], ly[i:i + 1]
        setup, alive, kept = setup_and_tiles(qi, ri, lxi, lyi, width, height, tile_size, coarse_factor,
                                             depth_w=depth_w, algorithm=algorithm, edge_solver=edge_solver)
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
            if "lines" in kept:  # two-stage time lines, in float32 as the sample tester evaluates them
                ln = kept["lines"][j]
                t32, u32, v32 = np.float32(t), np.float32(u), np.float32(v)
                assert ln[0] + ln[1] * u32 <= t32 <= ln[2] + ln[3] * u32, f"{what}: a time line in u excludes it"
                assert ln[4] + ln[5] * v32 <= t32 <= ln[6] + ln[7] * v32, f"{what}: a time line in v excludes it"
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


# --------------------------------------------------------------------------- float32 pipeline vs float64 reference
def centre_table(tuv):
    """A sample table with every sample at the pixel centre and the given (t, u, v)."""
    tuv = np.asarray(tuv, dtype=np.float64).reshape(-1, 3)
    tuv = tuv[np.argsort(tuv[:, 0], kind="stable")]
    table = np.zeros((len(tuv), 5))
    table[:, 0:2] = 0.5
    table[:, 2] = tuv[:, 1]
    table[:, 3] = tuv[:, 2]
    table[:, 4] = tuv[:, 0]
    return table


def reference_coverage(q, r, lx, ly, t, u, v, width, height, margin, backface=False):
    """float64 reference (tests/reference.py: clip, divide, Cramer) at the pixel centres.

    Returns (covered, depth, certain): ``certain`` marks pixels whose centre
    is at least ``margin`` pixels from every edge (the coverage does not change
    when the point moves by ``margin`` in any of eight directions)."""
    from reference import positions_at, render_static

    tris = positions_at(q, r, lx, ly, t, u, v)
    _, tid, depth = render_static(tris, None, width, height, (0.5, 0.5), cull_backfaces=backface)
    covered = tid >= 0
    certain = np.ones_like(covered)
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)):
        _, tj, _ = render_static(tris, None, width, height, (0.5 + margin * dx, 0.5 + margin * dy),
                                 cull_backfaces=backface)
        certain &= tj == tid
    return covered, depth, certain


def assert_matches_reference(q, r, lx, ly, tuv, *, width=W, height=H, margin=1e-3, ztol=1e-4, what="",
                             min_certain=0.5, backface=False):
    """float32 pipeline coverage and nearest depth at pixel centres equal the
    float64 reference wherever the centre is ``margin`` away from every edge."""
    table = centre_table(tuv)
    draw = make_draw(q, r, lx, ly, width=width, height=height)
    res = render(draw, spp=len(table), pattern="table", table=table, clear_depth=CLEAR_DEPTH, backface=backface)
    assert_finite(res, what)
    n_certain = 0
    for s in range(len(table)):
        t, u, v = table[s, 4], table[s, 2], table[s, 3]
        if not draw.has_motion:
            t = 0.5  # the sample generator pins t without motion
        if not draw.has_lens:
            u = v = 0.0
        cov, depth, certain = reference_coverage(q, r, lx, ly, t, u, v, width, height, margin, backface)
        got = res.depth[..., s] != CLEAR_DEPTH
        bad = np.argwhere(certain & (got != cov))
        assert len(bad) == 0, (f"{what}: at (t, u, v) = ({t}, {u}, {v}) float32 coverage differs from the float64 "
                               f"reference at (row, col) {bad[:8].tolist()} (pipeline {got[tuple(bad[0])]})")
        both = certain & cov & got
        dz = np.abs(res.depth[..., s][both].astype(np.float64) - depth[both])
        if dz.size:
            assert dz.max() <= ztol, f"{what}: depth differs from the float64 reference by {dz.max()}"
        n_certain += int(certain.sum())
    frac = n_certain / (len(table) * width * height)
    assert frac >= min_certain, f"{what}: only {frac:.2f} of the pixel centres are away from edges"
    return res


# --------------------------------------------------------------------------- named cases
def _has_key(section, key):
    return hasattr(getattr(load_arch(), section), key)


# tile-test configurations every case is also run with: flat traversal, small
# and large tiles, the per-tile edge slope bound where the architecture has it
VARIANTS = [(), ("tile_traverser.coarse_factor=1",), ("tile_traverser.tile_size=4", "tile_traverser.coarse_factor=2"),
            ("tile_traverser.tile_size=16",)]
if _has_key("tile_test", "gamma"):
    VARIANTS.append(("tile_test.gamma='tile'",))
# every other culling algorithm, and the quadratic edge test per tile and per pixel
INTERLEAVE = ("tile_test.algorithm='interleave_uvt'", "pass.sample_pattern='interleave'")
VARIANTS += [("tile_test.algorithm='hull'",), ("tile_test.algorithm='dual_space'",),
             ("tile_test.algorithm='two_stage'",), ("tile_test.algorithm='two_stage'", "tile_traverser.tile_size=1"),
             ("tile_test.edge_solver='quadratic'",),
             ("tile_test.edge_solver='quadratic'", "tile_traverser.tile_size=1", "tile_traverser.coarse_factor=8"),
             INTERLEAVE]


@dataclass
class Case:
    """A named triangle set of a hard case: clip-space vertices at t=0 (``q``) and
    t=1 (``r``) and lens shifts, as ``draw_from_clip`` takes them."""

    name: str
    q: np.ndarray
    r: np.ndarray | None = None
    lx: np.ndarray | None = None
    ly: np.ndarray | None = None
    depth_w: tuple | None = None
    width: int = W
    height: int = H
    spp: int = 16
    backface: bool = False
    min_covered: int = 1  # the case must cover at least this many samples (not vacuous)
    doc: str = ""  # which hard case this is and why it is hard

    def __post_init__(self):
        self.q = np.asarray(self.q, dtype=np.float64)
        self.r = self.q.copy() if self.r is None else np.asarray(self.r, dtype=np.float64)
        self.lx = no_lens(self.q) if self.lx is None else np.asarray(self.lx, dtype=np.float64)
        self.ly = no_lens(self.q) if self.ly is None else np.asarray(self.ly, dtype=np.float64)

    @property
    def arrays(self):
        return self.q, self.r, self.lx, self.ly

    def draw(self):
        return make_draw(*self.arrays, width=self.width, height=self.height, depth_w=self.depth_w)

    def __repr__(self):
        return self.name


def document(cases, docs):
    """Attach each case's docstring from ``docs`` (keyed by name, a trailing
    ``_backface_culled`` ignored); every case must have one."""
    for c in cases:
        c.doc = docs[c.name.removesuffix("_backface_culled")]
        assert c.doc, c.name
    return cases


def check_exact(case, seeds=(0,), variants=VARIANTS):
    """No NaN/inf anywhere, and the covered samples and depths are exactly those of
    the exact test with no culling in front, for every tile-test configuration."""
    draw = case.draw()
    covered = 0
    for seed in seeds:
        for ov in variants:
            res = assert_exact_coverage(draw, spp=case.spp, seed=seed, backface=case.backface, overrides=ov,
                                        pattern="interleave" if ov == INTERLEAVE else "net",
                                        what=f"{case.name} {ov or ''} seed {seed}")
            covered = max(covered, int(counts_of(res).sum()))
    assert covered >= case.min_covered, f"{case.name}: covers only {covered} samples, the case is vacuous"
    return covered


def check_scale_invariant(case, factors, seed=0, variants=VARIANTS):
    """The case scaled by each of ``factors`` (every clip coordinate and lens
    shift; the input must stay finite in float32) against the case itself,
    for every tile-test configuration: each render covers exactly the samples
    the exact test accepts, with their depths (``assert_exact_coverage``),
    and the scaled ones exactly the samples of the unscaled render. Under a
    power-of-two factor, which commutes with rounding, the depths are the
    same bits too; another factor rounds the vertices differently, which
    moves depths by float32 rounding (more where w is near 0).
    Returns the samples covered."""
    f32max = float(np.finfo(np.float32).max)
    scaled = []
    for s in factors:
        arrays = [a * s for a in case.arrays]
        assert all(np.all(np.abs(a) <= f32max) for a in arrays), f"{case.name}: x {s:g} is not finite in float32"
        exact = np.frexp(s)[0] == 0.5
        scaled.append((s, exact, make_draw(*arrays, width=case.width, height=case.height)))
    base_draw = make_draw(*case.arrays, width=case.width, height=case.height)
    covered = 0
    for ov in variants:
        pattern = "interleave" if ov == INTERLEAVE else "net"
        what = f"{case.name} {ov or ''}"
        base = assert_exact_coverage(base_draw, spp=case.spp, seed=seed, backface=case.backface, overrides=ov,
                                     pattern=pattern, what=what)
        hit = base.depth != CLEAR_DEPTH
        covered = max(covered, int(counts_of(base).sum()))
        for s, exact, d in scaled:
            res = assert_exact_coverage(d, spp=case.spp, seed=seed, backface=case.backface, overrides=ov,
                                        pattern=pattern, what=f"{what} x {s:g}")
            diff = np.argwhere(np.any((res.depth != CLEAR_DEPTH) != hit, axis=2))
            assert len(diff) == 0, (f"{what}: scaled by {s:g}, other samples are covered at (row, col) "
                                    f"{diff[:8].tolist()}")
            assert np.array_equal(counts_of(res), counts_of(base)), f"{what}: scaled by {s:g}, the hit counts differ"
            if exact:
                assert np.array_equal(res.depth, base.depth), f"{what}: scaled by {s:g}, the depths differ"
    assert covered >= case.min_covered, f"{case.name}: covers only {covered} samples, the case is vacuous"
    return covered


def check_bbox(case, seed=0):
    """BBOX vs hierarchical vs z-cull off (see ``assert_bbox_matches_hierarchical``),
    with red, green and blue vertices: the interpolated colors of the default
    (cached) and the per-sample shading stay convex combinations, inside [0, 1]."""
    rgb = np.broadcast_to(np.eye(3, dtype=np.float32), (len(case.q), 3, 3)).copy()
    draw = make_draw(*case.arrays, width=case.width, height=case.height, depth_w=case.depth_w, color=rgb)
    out = assert_bbox_matches_hierarchical(draw, spp=min(case.spp, 8), seed=seed, backface=case.backface,
                                           what=case.name)
    per_sample = render(draw, spp=min(case.spp, 8), seed=seed, backface=case.backface,
                        overrides=("pass.shading_mode='per_sample'",))
    assert_finite(per_sample, case.name)
    for res in (out["hierarchical"], per_sample):
        im = res.image[..., :3]
        assert im.min() >= -1e-6 and im.max() <= 1.0 + 1e-6, (
            f"{case.name}: interpolated colors leave [0, 1]: [{im.min()}, {im.max()}] (bad barycentrics)")
    return out


def check_tiles(case, seed=0, **kw):
    return assert_tiles_conservative(*case.arrays, seed=seed, width=case.width, height=case.height,
                                     depth_w=case.depth_w, what=case.name, **kw)


def check_continuity(case, **kw):
    return assert_continuous(*case.arrays, width=case.width, height=case.height, spp=case.spp,
                             depth_w=case.depth_w, what=case.name, **kw)


def flip_winding(a):
    return a[:, [0, 2, 1]]


def assert_closed_mesh_watertight(case, seeds=(0, 1), spp=4, min_fraction=0.02):
    """A closed mesh with the camera outside and the mesh inside [near, far]: along
    every sample ray the front faces hit equal the back faces hit. Front hits are
    counted with backface culling, back hits by culling the reversed winding;
    a hole or a double hit on a shared edge breaks the equality."""
    q, r, lx, ly = case.arrays
    front = make_draw(q, r, lx, ly, width=case.width, height=case.height)
    back = make_draw(flip_winding(q), flip_winding(r), flip_winding(lx), flip_winding(ly), width=case.width,
                     height=case.height)
    for seed in seeds:
        f = render_counts(front, spp=spp, seed=seed, backface=True)
        b = render_counts(back, spp=spp, seed=seed, backface=True)
        assert_finite(f, case.name)
        assert_finite(b, case.name)
        cf, cb = counts_of(f), counts_of(b)
        bad = np.argwhere(cf != cb)
        assert len(bad) == 0, (f"{case.name}: front and back hits differ at (row, col) {bad[:8].tolist()}: "
                               f"{cf[tuple(bad[0])]} front, {cb[tuple(bad[0])]} back (hole or double hit)")
        assert (cf > 0).mean() >= min_fraction, f"{case.name}: the mesh covers almost nothing"


# --------------------------------------------------------------------------- world-space meshes
FOV = np.radians(50.0)
_F = 1.0 / np.tan(FOV / 2)
# perspective projection with near 0.1 and far 10 (z/w = PERSPECTIVE[0] + PERSPECTIVE[1] / w)
PROJ = np.array([[_F / (W / H), 0, 0, 0], [0, _F, 0, 0], [0, 0, -1.0202020202020203, -0.20202020202020202],
                 [0, 0, -1, 0]])


def project(verts, faces):
    """Clip-space triangles (N, 3, 4) of a world-space mesh seen by a camera at the
    origin looking down -z."""
    verts = np.asarray(verts, dtype=np.float64)
    hom = np.c_[verts, np.ones(len(verts))] @ PROJ.T
    return hom[np.asarray(faces)]


def mesh_lens(q, r, radius, focus):
    """Thin-lens shifts (draw.lens_shift) for clip-space triangles made by ``project``."""
    return lens_for(q, r, radius, focus, (PROJ[0, 0], PROJ[1, 1]))


def grid_mesh(x0, x1, z0, z1, nx, nz, height):
    """A horizontal grid (a floor or ceiling at y = ``height``) of 2 nx nz triangles,
    vertices shared; returns (vertices, faces)."""
    xs = np.linspace(x0, x1, nx + 1)
    zs = np.linspace(z0, z1, nz + 1)
    vx, vz = np.meshgrid(xs, zs)
    verts = np.c_[vx.ravel(), np.full(vx.size, height), vz.ravel()]
    faces = []
    for j in range(nz):
        for i in range(nx):
            a = j * (nx + 1) + i
            b, c, d = a + 1, a + nx + 1, a + nx + 2
            faces += [(a, c, b), (b, c, d)] if (i + j) % 2 else [(a, c, d), (a, d, b)]
    return verts, np.array(faces)


def perspective_z(*arrays):
    """Set every vertex's z to the perspective relation z = C1 w + C0 (in place)."""
    from triangles import PERSPECTIVE

    for a in arrays:
        a[..., 2] = PERSPECTIVE[0] * a[..., 3] + PERSPECTIVE[1]
    return arrays


def assert_single_layer_counts(res, full_rows=(), what=""):
    """An open single-layer surface: no sample is covered twice; the given rows are
    covered completely (no holes)."""
    c = counts_of(res)
    spp = res.depth.shape[2]
    over = np.argwhere(c > spp)
    assert len(over) == 0, f"{what}: double coverage at (row, col) {over[:8].tolist()}"
    for row in full_rows:
        holes = np.nonzero(c[row] != spp)[0]
        assert len(holes) == 0, f"{what}: holes in row {row} at columns {holes[:8].tolist()}: {c[row, holes[:8]]}"


def check_conservative_mode(case, spp=64, seed=5, ztol=1e-5):
    """Conservative mode (Nilsson12 §2: 1x1 tiles, no sample tester, one interval-shader
    run per (triangle, pixel)): finite output, and every (pixel, t) the exact test
    covers is emitted with t in t^ and its depth in z^. Single-triangle cases."""
    from pipeline_sim.sampling import make_samples
    from pipeline_sim.shaders import interval_shader

    assert len(case.q) == 1
    d = case.draw()
    s = pass_settings(["pass.mode='conservative'", "pass.depth_test='always'",
                       f"pass.backface_culling={str(case.backface).lower()}"])
    res = run_pass(RenderPass(draw=d, **s, spp=1, shader=interval_shader, clear_color=(2, 2, -1, -1),
                              clear_depth=CLEAR_DEPTH))
    assert_finite(res, f"{case.name} conservative mode")
    s = make_samples(case.width, case.height, spp, seed, lens=d.has_lens, motion=d.has_motion, pattern="net")
    count, z, _ = exact_coverage(d, s, case.backface)
    rows, cols, js = np.nonzero(count > 0)
    k = (rows * case.width + cols) * spp + js
    t = s.t[k].astype(np.float64)
    zz = z[rows, cols, js].astype(np.float64)
    tl, zl, th, zh = (res.image[rows, cols, c].astype(np.float64) for c in range(4))
    tol = ztol * (1.0 + np.abs(zz))
    bad = np.nonzero((t < tl) | (t > th) | (zz < zl - tol) | (zz > zh + tol))[0]
    assert len(bad) == 0, (f"{case.name}: conservative mode misses covered (pixel, t) at (row, col) "
                           f"{np.c_[rows[bad], cols[bad]][:8].tolist()}: t = {t[bad[0]]} vs t^ [{tl[bad[0]]}, "
                           f"{th[bad[0]]}], z = {zz[bad[0]]} vs z^ [{zl[bad[0]]}, {zh[bad[0]]}]")
    return len(t)


def sphere(subdivisions=1, radius=0.6):
    """(vertices, faces) of an icosphere centred at the origin."""
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices), np.asarray(s.faces)
