"""The sample tester against a bare micro-kernel on the same tests, same run.

Issue 3 asks that the pipeline's sample tester (``sample_test_kernel`` in
units/sample_tester.py) sustain at least half the throughput of a bare numba
inside-test micro-kernel of the same dimension on the same samples. This
benchmark makes that comparison like for like:

1. It renders real scenes (default 5D, motion-only, defocus-only, static)
   and captures every batch of (triangle, tile) records that reaches
   ``SampleTester.run``.
2. It splits each batch by the dimension the tester uses for the record's
   triangle (2D, xyt, xyuv, xyuvt; the tester's ``dims``).
3. For each sub-batch it times (a) ``sample_test_kernel`` on the records, as
   ``SampleTester.run`` calls it (output buffers preallocated), and (b) the
   bare kernel of the same dimension (benchmarks/microkernel.py,
   ``RECORD_KERNELS``) on exactly the (triangle, sample) pairs the tester
   counts as tested (``samples_tested``: the tile's samples whose t, u, v lie
   in the record's intervals), gathered beforehand into contiguous
   structure-of-arrays blocks, one block per record. The gather is checked
   against the tester's own per-dimension counters.
4. Also (c): the same micro-kernel on every sample of each record's tile,
   the tester's whole input, without intervals: a brute-force tester. The
   second table compares the two in tile samples handled per second, the
   other reading of "the same samples".
5. Rates are tests per second of wall time; tester and micro-kernel calls
   alternate (which goes first flips every repeat); per-dimension totals are
   summed over the sub-batches of a repeat, and the table shows medians over
   repeats (the ratio is the median of the per-repeat ratios, its range in
   brackets).

Not timed: the tester's sample layout (``SampleTester.layout``: the frame's
samples in its tile-major, slot-major order), built once per pass on its first
batch; its time per scene is reported next to the table. Note also that the
micro-kernel reads its samples from the block just gathered (warm in cache),
the tester from the frame's sample arrays.

Run: ``python -m benchmarks.tester_speed`` (about a minute).
"""

from __future__ import annotations

import argparse
import gc
import time
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from benchmarks.instrument import patched
from benchmarks.microkernel import RECORD_KERNELS
from benchmarks.workloads import ROOT, default_pass
from pipeline_sim.counters import N_OPS
from pipeline_sim.render import run_pass
from units import sample_tester as st_mod
from units.sample_tester import EV_2D, EV_COVERED, EV_PIXELS, EV_TESTED, EVENTS, SampleTester

SCENES = ("default", "motion", "defocus", "static")
DIM_NAMES = ("2D", "xyt", "xyuv", "xyuvt")
_NO_LINES = np.zeros((0, 8), np.float32)
_NO_MASKS = np.zeros(0, np.uint64)
_NO_TUPLES = np.zeros(1, np.int8)
_OUT_KEYS = ("tri", "pix", "sidx", "z", "b0", "b1", "b2", "noread")


@dataclass
class SubBatch:
    """Records of one captured batch whose triangles use one dimension."""

    tester: SampleTester
    tiles: dict
    dim: int


def record_dims(tester: SampleTester, tri: np.ndarray) -> np.ndarray:
    """The tester's dimension index per record: 0 = 2D, 1 = xyt, 2 = xyuv, 3 = xyuvt."""
    if not tester.specialize:
        return np.full(len(tri), 3, np.int64)
    t = tester.table
    dp = t.dp_32[tri]
    dl = t.dl_32[tri]
    l0 = t.l0_32[tri]
    moving = (dp != 0).any(axis=(1, 2)) | (dl != 0).any(axis=(1, 2))
    lens = (l0 != 0).any(axis=(1, 2))
    return moving.astype(np.int64) + 2 * lens.astype(np.int64)


def capture(scenes=SCENES, scene_dir: Path = ROOT / "workloads" / "scenes") -> list[SubBatch]:
    """Render each scene, capturing the batches that reach ``SampleTester.run``; split by dimension."""
    subs: list[SubBatch] = []
    orig = SampleTester.run
    for name in scenes:
        got: list[tuple[SampleTester, dict]] = []

        def run(self, tiles, _orig=orig, _got=got):
            _got.append((self, {k: np.array(v, copy=True) for k, v in tiles.items()}))
            return _orig(self, tiles)

        with patched(SampleTester, "run", run):
            res = run_pass(default_pass(scene_path=scene_dir / f"{name}.toml"))
        # the batches are replayed against the samples each tester holds after the pass: its frame's
        assert res.regions.count == 1, f"{name}: the frame must be one screen region"
        for tester, tiles in got:
            dims = record_dims(tester, tiles["tri"])
            for d in range(4):
                keep = dims == d
                if keep.any():
                    subs.append(SubBatch(tester, {k: v[keep] for k, v in tiles.items()}, d))
    return subs


@nb.njit(cache=True)
def gather_tested(tri_ids, tile_x, tile_y, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, lines, masks, general, tile_size,
                  width, height, spp, sx, sy, su, sv, st, stup, gx, gy, gu, gv, gt, rec_off, whole_tile=False):
    """The samples the tester counts as tested, per record, into gx..gt (absolute x, y).

    Same interval rules as the tester: float32 bounds rounded inwards, and
    with two-stage lines or Interleave UVT masks (only where t, u or v
    matter) the time lines and the tuple bit. With ``whole_tile``, every
    sample of the record's tile instead (what a brute-force tester without
    intervals would test). Returns the number gathered.
    """
    has_lines = lines.shape[0] == tri_ids.shape[0]
    has_masks = masks.shape[0] == tri_ids.shape[0]
    extra = (has_lines or has_masks) and general
    m = 0
    rec_off[0] = 0
    for i in range(tri_ids.shape[0]):
        ta = st_mod._f32_at_least(t_lo[i])
        tb = st_mod._f32_at_most(t_hi[i])
        ua = st_mod._f32_at_least(u_lo[i])
        ub = st_mod._f32_at_most(u_hi[i])
        va = st_mod._f32_at_least(v_lo[i])
        vb = st_mod._f32_at_most(v_hi[i])
        if has_lines:
            lc, ls, hc, hs = lines[i, 0], lines[i, 1], lines[i, 2], lines[i, 3]
            mc, ms, kc, ks = lines[i, 4], lines[i, 5], lines[i, 6], lines[i, 7]
        else:
            lc, ls, hc, hs = np.float32(0), np.float32(0), np.float32(1), np.float32(0)
            mc, ms, kc, ks = np.float32(0), np.float32(0), np.float32(1), np.float32(0)
        mk = masks[i] if has_masks else np.uint64(0xFFFFFFFFFFFFFFFF)
        px0 = tile_x[i] * tile_size
        px1 = min(px0 + tile_size, width)
        fpx0 = np.float32(px0)
        for py in range(tile_y[i] * tile_size, min((tile_y[i] + 1) * tile_size, height)):
            fy = np.float32(py)
            for px in range(px0, px1):
                fcol = np.float32(px - px0)
                for s in range(spp):
                    k = (py * width + px) * spp + s
                    t = st[k]
                    u = su[k]
                    v = sv[k]
                    ok = whole_tile or (t >= ta and t <= tb and u >= ua and u <= ub and v >= va and v <= vb)
                    if ok and extra and not whole_tile:
                        ok = (t >= lc + ls * u and t <= hc + hs * u and t >= mc + ms * v and t <= kc + ks * v
                              and ((mk >> np.uint64(stup[k])) & np.uint64(1)) != 0)
                    if ok:
                        gx[m] = (fpx0 + fcol) + sx[k]
                        gy[m] = fy + sy[k]
                        gu[m] = u
                        gv[m] = v
                        gt[m] = t
                        m += 1
        rec_off[i + 1] = m
    return m


class _Buffers:
    """Output and gather buffers, sized for the largest sub-batch, reused by every call."""

    def __init__(self, cap: int, n_rec: int):
        self.out = [np.empty(cap, np.int32), np.empty(cap, np.int32), np.empty(cap, np.int32),
                    np.empty(cap, np.float32), np.empty(cap, np.float32), np.empty(cap, np.float32),
                    np.empty(cap, np.float32), np.empty(cap, np.bool_)]
        self.g = [np.empty(cap, np.float32) for _ in range(5)]
        self.rec_off = np.empty(n_rec + 1, np.int64)


def tester_args(sb: SubBatch, buf: _Buffers, ops: np.ndarray, events: np.ndarray) -> tuple:
    """``sample_test_kernel``'s arguments, exactly as ``SampleTester.run`` passes them."""
    return sb.tester.kernel_args(sb.tiles, dict(zip(_OUT_KEYS, buf.out)), ops, events)


def gather(sb: SubBatch, buf: _Buffers, whole_tile: bool = False) -> int:
    tr, tiles, s = sb.tester, sb.tiles, sb.tester.samples
    return gather_tested(tiles["tri"], tiles["tx"], tiles["ty"], tiles["t_lo"], tiles["t_hi"], tiles["u_lo"],
                         tiles["u_hi"], tiles["v_lo"], tiles["v_hi"], tiles.get("lines", _NO_LINES),
                         tiles.get("mask", _NO_MASKS), sb.dim != 0 or not tr.specialize, tr.tile_size, s.width,
                         s.height, s.spp, s.x, s.y, s.u, s.v, s.t, s.tup if s.tup is not None else _NO_TUPLES,
                         *buf.g, buf.rec_off, whole_tile)


def layout_seconds(subs: list[SubBatch]) -> list[float]:
    """Seconds to build each captured tester's sample layout afresh (once per pass)."""
    out = []
    for tester in {id(sb.tester): sb.tester for sb in subs}.values():
        fresh = SampleTester(tester.config, tester.table, tester.samples, tester.tile_size, tester.backface_culling,
                             tester.specialize)
        c0 = time.perf_counter()
        fresh.layout()
        out.append(time.perf_counter() - c0)
    return out


def measure(scenes=SCENES, repeats: int = 5, subs: list[SubBatch] | None = None, log=None, tester_kernel=None,
            tester_kernel_args=None) -> dict:
    """Tester and micro-kernel rates per dimension (see the module docstring).

    ``tester_kernel`` and ``tester_kernel_args(sub_batch, buffers, ops,
    events)`` replace ``sample_test_kernel`` and ``tester_args`` (to compare
    another version of the kernel). Returns {"dims": {name: {...}}, "all":
    {...}, "repeats": n, "records": n, "check_tested_equal": bool,
    "layout_s": [...]}; rates in tests per second.
    """
    if subs is None:
        subs = capture(scenes)
    kernel = tester_kernel or st_mod.sample_test_kernel
    make_args = tester_kernel_args or tester_args
    cap = max(len(sb.tiles["tri"]) * sb.tester.tile_size ** 2 * sb.tester.samples.spp for sb in subs)
    buf = _Buffers(cap, max(len(sb.tiles["tri"]) for sb in subs))
    ops = np.zeros(N_OPS, np.int64)
    events = np.zeros(len(EVENTS), np.int64)
    # per dimension, per repeat: seconds, and totals of one pass (tests, scanned, covered)
    t_tester = np.zeros((4, repeats))
    t_micro = np.zeros((4, repeats))
    t_brute = np.zeros((4, repeats))  # the micro-kernel on every sample of each record's tile
    tile_samples = np.zeros(4, np.int64)
    tests = np.zeros(4, np.int64)
    gathered = np.zeros(4, np.int64)
    scanned = np.zeros(4, np.int64)
    covered = np.zeros(4, np.int64)
    micro_inside = np.zeros(4, np.int64)
    tests_by_counter = np.zeros(4, np.int64)
    # warm both kernels (compile or load from the cache) outside the timing
    for sb in subs[:1]:
        m = gather(sb, buf)
        kernel(*make_args(sb, buf, ops, events))
        t = sb.tester.table
        for kern in RECORD_KERNELS:
            kern(sb.tiles["tri"], buf.rec_off, *(g[:m] for g in buf.g), t.p0_32, t.dp_32, t.l0_32, t.dl_32)
    gc.collect()
    gc_was = gc.isenabled()
    gc.disable()
    try:
        for rep in range(repeats):
            if log:
                log(f"repeat {rep + 1}/{repeats}")
            tester_first = rep % 2 == 0
            for sb in subs:
                d = sb.dim
                m = gather(sb, buf)
                t = sb.tester.table
                kern = RECORD_KERNELS[d]
                margs = (sb.tiles["tri"], buf.rec_off, *(g[:m] for g in buf.g), t.p0_32, t.dp_32, t.l0_32,
                         t.dl_32)
                events[:] = 0
                targs = make_args(sb, buf, ops, events)
                for which in ((0, 1) if tester_first else (1, 0)):
                    if which == 0:
                        c0 = time.perf_counter()
                        n_cov, stop = kernel(*targs)
                        t_tester[d, rep] += time.perf_counter() - c0
                        assert stop == len(sb.tiles["tri"]), "outputs sized for every record"
                    else:
                        c0 = time.perf_counter()
                        counts = kern(*margs)
                        t_micro[d, rep] += time.perf_counter() - c0
                m_all = gather(sb, buf, whole_tile=True)
                c0 = time.perf_counter()
                kern(sb.tiles["tri"], buf.rec_off, *(g[:m_all] for g in buf.g), t.p0_32, t.dp_32, t.l0_32, t.dl_32)
                t_brute[d, rep] += time.perf_counter() - c0
                if rep == 0:
                    tile_samples[d] += m_all
                if rep == 0:
                    tests[d] += events[EV_TESTED]
                    tests_by_counter[d] += events[EV_2D + d]
                    gathered[d] += m
                    scanned[d] += events[EV_PIXELS] * sb.tester.samples.spp
                    covered[d] += events[EV_COVERED]
                    micro_inside[d] += int(counts.sum())
                    assert n_cov == events[EV_COVERED]
    finally:
        if gc_was:
            gc.enable()
    out: dict = {"repeats": repeats, "records": int(sum(len(sb.tiles["tri"]) for sb in subs)),
                 "sub_batches": len(subs), "scenes": list(scenes),
                 "tile_size": subs[0].tester.tile_size, "spp": subs[0].tester.samples.spp,
                 "layout_s": layout_seconds(subs),
                 "check_tested_equal": bool(np.array_equal(tests, gathered)
                                            and np.array_equal(tests, tests_by_counter)),
                 "dims": {}}

    def row(tt, tm, tb, n, sc, cov, mic, whole):
        med_t, med_m, med_b = float(np.median(tt)), float(np.median(tm)), float(np.median(tb))
        return {"tests": int(n), "scanned": int(sc), "tester_covered": int(cov), "micro_inside": int(mic),
                "tile_samples": int(whole), "brute_s": med_b, "brute_times_s": tb.tolist(),
                "tester_rate_tile_samples": whole / med_t if med_t else float("nan"),
                "brute_rate": whole / med_b if med_b else float("nan"),
                "ratio_brute": float(np.median(tb / tt)) if n else float("nan"),
                "tester_s": med_t, "micro_s": med_m, "tester_times_s": tt.tolist(), "micro_times_s": tm.tolist(),
                "tester_rate": n / med_t if med_t else float("nan"), "micro_rate": n / med_m if med_m else float("nan"),
                "ratio": float(np.median(tm / tt)) if n else float("nan"),
                "ratio_range": [float((tm / tt).min()), float((tm / tt).max())] if n else [float("nan")] * 2}

    for d in range(4):
        if tests[d]:
            out["dims"][DIM_NAMES[d]] = row(t_tester[d], t_micro[d], t_brute[d], tests[d], scanned[d], covered[d],
                                            micro_inside[d], tile_samples[d])
    out["all"] = row(t_tester.sum(0), t_micro.sum(0), t_brute.sum(0), tests.sum(), scanned.sum(), covered.sum(),
                     micro_inside.sum(), tile_samples.sum())
    return out


def format_table(res: dict) -> str:
    lines = [f"{'dims':>6} {'tests':>11} {'scan/test':>9} {'tester s':>9} {'micro s':>8} {'tester M/s':>10} "
             f"{'micro M/s':>10} {'tester/micro':>12} {'(range)':>13}"]
    for name, r in list(res["dims"].items()) + [("all", res["all"])]:
        lo, hi = r["ratio_range"]
        lines.append(f"{name:>6} {r['tests']:>11,} {r['scanned'] / r['tests']:>9.2f} {r['tester_s']:>9.4f} "
                     f"{r['micro_s']:>8.4f} {r['tester_rate'] / 1e6:>10.1f} {r['micro_rate'] / 1e6:>10.1f} "
                     f"{r['ratio']:>12.3f} {f'[{lo:.3f}, {hi:.3f}]':>13}")
    lines.append(f"{res['records']:,} (triangle, tile) records ({res['tile_size']}x{res['tile_size']} pixels, "
                 f"{res['spp']} spp) in {res['sub_batches']} sub-batches from {', '.join(res['scenes'])}; medians "
                 f"of {res['repeats']} interleaved repeats; gathered tests == tester's samples_tested: "
                 f"{res['check_tested_equal']}")
    lines.append("")
    lines.append("the same records against a brute-force tester: the micro-kernel on every sample of each record's "
                 "tile (the tester's input), no intervals")
    lines.append(f"{'dims':>6} {'tile samples':>12} {'tester s':>9} {'brute s':>8} {'tester M/s':>10} "
                 f"{'brute M/s':>10} {'tester/brute':>12}")
    for name, r in list(res["dims"].items()) + [("all", res["all"])]:
        lines.append(f"{name:>6} {r['tile_samples']:>12,} {r['tester_s']:>9.4f} {r['brute_s']:>8.4f} "
                     f"{r['tester_rate_tile_samples'] / 1e6:>10.1f} {r['brute_rate'] / 1e6:>10.1f} "
                     f"{r['ratio_brute']:>12.2f}")
    lines.append("(rates in tile samples per second: a tester that skips samples outside a record's intervals "
                 "handles its tile's samples faster than one that tests them all)")
    lines.append("tester's sample layout, built once per pass (not timed above): "
                 + ", ".join(f"{1e3 * x:.0f} ms" for x in res["layout_s"]))
    return "\n".join(lines)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = measure(tuple(a.scenes), repeats=a.repeats, log=lambda m: print(m, flush=True))
    print(format_table(res))
    print(f"({time.perf_counter() - t0:.1f} s)")
    return res


if __name__ == "__main__":
    main()
