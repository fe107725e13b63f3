"""Tile test: a (triangle, tile) pair to conservative intervals (u^, v^, t^, z^).

Implements docs/pipeline.md §2.3. The culling algorithm (``tile_test.algorithm``)
is a module of ``units.culling`` that declares its events, record extensions
and setup part; ``tile_test_kernel_for`` compiles its branch, run per record with the
shared bounds of ``units.tile_test_bounds`` (the moving box and edges of
Munkberg11 §4, lens intervals after Laine11 and Wu13 §2-3, z^ from Nilsson12
App. A) or the module's own (convex hull, dual-space and two-stage time
bounds, tuple masks). With ``algorithm = "bbox"`` no tile is rejected and t^
is the triangle's whole time span: the BBOX baseline of Wu13 and Munkberg11,
against which the sample test efficiency of the tests is measured.

The user clip planes (Nilsson12 §2) are the unit's ``clips`` attribute
(t_lo, t_hi, u_lo, u_hi, v_lo, v_hi), read at each ``run``: a pass with
several draws sets them per batch. They bound every interval, so the sample
tester never covers a sample outside them.
"""

from __future__ import annotations

from typing import Callable

import numba as nb
import numpy as np

from pipeline_sim.definitions import N_OPS, OP_CMP, OP_MADD, OP_MUL, OP_RCP
from pipeline_sim.records import INTERVALS
from units import culling
from units.rounding import F32_REL, MARGIN_PX
from units.tile_test_bounds import (EV_ACCEPT, EV_REJ_BOX, EV_REJ_EDGE, EV_REJ_LENS, box_time_interval,
                                    edge_time_interval, lens_interval, plane_w_bounds)
from units.tile_test_dual import dual_time_interval, two_stage_lines
from units.tile_test_exact import exact_kernel
from units.tile_test_hull import hull_overlaps_tile
from units.tile_test_interleave import interleave_mask
from units.tile_test_quadratic import quadratic_time_interval
from units.tile_test_two_stage import LINE_F32_REL
from units.triangle_setup import FLAG_EDGE, FLAG_LENS, FLAG_PLANE, FLAG_WPOS

EVENTS = culling.EVENTS
EVENT_MEANINGS = culling.EVENT_MEANINGS
# the kernel's code of each algorithm: its place in the registry
ALGORITHM_CODES = {name: code for code, name in enumerate(culling.ALGORITHMS)}
ALG_HIERARCHICAL, ALG_BBOX, ALG_HULL, ALG_DUAL, ALG_TWO_STAGE, ALG_INTERLEAVE = (ALGORITHM_CODES[name] for name in (
    "hierarchical", "bbox", "hull", "dual_space", "two_stage", "interleave_uvt"))
# each algorithm's own rejections, where the registry puts them among the events
EV_REJ_HULL, EV_REJ_DUAL, EV_REJ_TWO, EV_REJ_TUPLES = (culling.event_offset(name) for name in (
    "hull", "dual_space", "two_stage", "interleave_uvt"))
# counters timing can move (docs/pipeline.md §4): none; upstream of z-cull, every tile is seen whatever the timing
TIMING_DEPENDENT: tuple[str, ...] = ()
_NO_TUPLES = np.zeros((0, 3))
_NO_LINES = np.zeros((0, 8), np.float32)
_NO_MASKS = np.zeros(0, np.uint64)
_NO_HULLS = culling.algorithm("hull").TRIANGLE_EXT.table(0)


_KERNELS: dict[int, Callable] = {}  # algorithm -> its compiled kernel


def tile_test_kernel_for(algorithm: int) -> Callable:
    """The tile test kernel of one culling algorithm (ALG_*), compiled on first use.

    The algorithm is a constant of each kernel, so numba prunes the other
    algorithms' branches before it compiles: a run compiles only the bounds
    its algorithm uses (every variant is cached on disk like any kernel). The
    edge solver stays an argument: as a constant too, it made the
    hierarchical kernel about 40% slower (measured, 0.104 against 0.072 s on
    the default pass's 351 batches).
    """
    kernel = _KERNELS.get(algorithm)
    if kernel is None:
        kernel = _KERNELS[algorithm] = _compile_kernel(int(algorithm))
    return kernel


def _compile_kernel(algorithm: int) -> Callable:
    @nb.njit(cache=True, nogil=True)
    def tile_test_kernel(tri_ids, tile_x, tile_y, tile_size, width, height, edge_test, quadratic, gamma_per_tile,
                         lens_bounds, clips, p0, dp, l0, dl, t_span, flags, edge_f, edge_h, edge_gamma, edge_g, edge_fg,
                         edge_abs, plane_n, plane_d, hull, hull_n, hull_off, tuples, depth_c1, depth_c0,
                         out_keep, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, lines, mask, ops, events):
        """Test each (triangle, tile) record; fill its intervals and ``out_keep``.

        ``algorithm`` (ALG_*): hierarchical, Munkberg11 §4.1-4.2 (t^ from the moving box
        and the linearized or, with ``quadratic``, the exact quadratic edges) and
        lens bounds (u^, v^); BBOX (no rejection); the convex hull of McGuire10
        (Wu13 §3.2); dual-space bounds (Laine11, Wu13 §2);
        two-stage culling (Wu13 §3.3-3.4), which also writes per-record time
        ``lines`` linear in u and v; Interleave UVT, which writes a tuple
        ``mask``. z^ from Nilsson12 App. A for all of them; clip planes (Nilsson12 §2).
        """
        for i in range(tri_ids.shape[0]):
            tri = tri_ids[i]
            fl = flags[tri]
            x0 = tile_x[i] * tile_size - MARGIN_PX
            x1 = min((tile_x[i] + 1) * tile_size, width) + MARGIN_PX
            y0 = tile_y[i] * tile_size - MARGIN_PX
            y1 = min((tile_y[i] + 1) * tile_size, height) + MARGIN_PX
            ta = max(t_span[tri, 0], clips[0])  # user clip planes bound every interval (Nilsson12 §2)
            tb = min(t_span[tri, 1], clips[1])
            out_keep[i] = False
            wpos = (fl & FLAG_WPOS) != 0
            has_lens = (fl & FLAG_LENS) != 0
            ulo, uhi, vlo, vhi = clips[2], clips[3], clips[4], clips[5]
            lo, hi = ta, tb
            if algorithm == ALG_HIERARCHICAL:
                lo, hi = box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ta, tb, ops)
                if lo > hi:
                    events[EV_REJ_BOX] += 1
                    continue
                if edge_test and (fl & FLAG_EDGE) != 0:
                    if quadratic:
                        lo, hi = quadratic_time_interval(edge_f, edge_g, edge_h, edge_abs, tri, x0, x1, y0, y1, lo, hi,
                                                         ops)
                    else:
                        lo, hi = edge_time_interval(edge_h, edge_gamma, edge_g, edge_fg, edge_abs, gamma_per_tile, tri,
                                                     x0, x1, y0, y1, lo, hi, ops)
                    if lo > hi:
                        events[EV_REJ_EDGE] += 1
                        continue
                    # the box taken over the narrowed [lo, hi] is tighter (Munkberg11 §4.1 applied again)
                    if lo > ta or hi < tb:
                        lo, hi = box_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, lo, hi, ops)
                        if lo > hi:
                            events[EV_REJ_BOX] += 1
                            continue
            elif algorithm == ALG_HULL:
                if wpos and not has_lens and hull_n[tri] > 0:
                    # the sample tester's float32 vertices move the true hull by ~F32_REL of its coordinates
                    mag = 1.0
                    for k in range(hull_n[tri]):
                        mag = max(mag, abs(hull[tri, k, 0]) + abs(hull[tri, k, 1]))
                    pad = F32_REL * mag
                    if not hull_overlaps_tile(hull, hull_n, hull_off, tri, x0 - pad, x1 + pad, y0 - pad, y1 + pad, ops):
                        events[EV_REJ_HULL] += 1
                        continue
            elif algorithm == ALG_INTERLEAVE:
                mk = interleave_mask(p0, dp, l0, dl, tri, tuples, x0, x1, y0, y1, ta, tb, ops)
                if mk == 0:
                    events[EV_REJ_TUPLES] += 1
                    continue
                mask[i] = mk
            # a triangle without lens shift is seen alike from every lens position
            lens_live = has_lens and wpos and (
                (algorithm == ALG_HIERARCHICAL and lens_bounds) or algorithm == ALG_DUAL or algorithm == ALG_TWO_STAGE)
            if lens_live:  # Wu13 §3.3 (stage 1): lens bounds from the vertices at the ends of t^
                a, b = lens_interval(p0, dp, l0, dl, tri, 0, x0, x1, lo, hi, ops)
                ulo, uhi = max(ulo, a), min(uhi, b)
                if ulo > uhi:
                    events[EV_REJ_LENS] += 1
                    continue
                a, b = lens_interval(p0, dp, l0, dl, tri, 1, y0, y1, lo, hi, ops)
                vlo, vhi = max(vlo, a), min(vhi, b)
                if vlo > vhi:
                    events[EV_REJ_LENS] += 1
                    continue
            if algorithm == ALG_DUAL and wpos:
                lo, hi = dual_time_interval(p0, dp, l0, dl, tri, x0, x1, y0, y1, ulo, uhi, vlo, vhi, lo, hi, ops)
                if lo > hi:
                    events[EV_REJ_DUAL] += 1
                    continue
            if algorithm == ALG_TWO_STAGE:
                if wpos:  # Wu13 §3.4 (stage 2): time bounds linear in u (x axis) and v (y axis)
                    l_c, l_s, h_c, h_s = two_stage_lines(p0, dp, l0, dl, tri, 0, x0, x1, ulo, uhi, lo, hi, ops)
                    m_c, m_s, k_c, k_s = two_stage_lines(p0, dp, l0, dl, tri, 1, y0, y1, vlo, vhi, lo, hi, ops)
                else:
                    l_c, l_s, h_c, h_s = lo, 0.0, hi, 0.0
                    m_c, m_s, k_c, k_s = lo, 0.0, hi, 0.0
                lo = max(lo, min(l_c + l_s * ulo, l_c + l_s * uhi), min(m_c + m_s * vlo, m_c + m_s * vhi))
                hi = min(hi, max(h_c + h_s * ulo, h_c + h_s * uhi), max(k_c + k_s * vlo, k_c + k_s * vhi))
                ops[OP_MADD] += 8
                ops[OP_CMP] += 8
                if lo > hi:
                    events[EV_REJ_TWO] += 1
                    continue
                lines[i, 0] = l_c - LINE_F32_REL * (abs(l_c) + abs(l_s))
                lines[i, 1] = l_s
                lines[i, 2] = h_c + LINE_F32_REL * (abs(h_c) + abs(h_s))
                lines[i, 3] = h_s
                lines[i, 4] = m_c - LINE_F32_REL * (abs(m_c) + abs(m_s))
                lines[i, 5] = m_s
                lines[i, 6] = k_c + LINE_F32_REL * (abs(k_c) + abs(k_s))
                lines[i, 7] = k_s
            zl, zh = -1.0, 1.0
            if wpos:
                zl, zh = np.inf, -np.inf
                for s in range(2):
                    t = lo if s == 0 else hi
                    for k in range(3):
                        z = (p0[tri, k, 2] + t * dp[tri, k, 2]) / (p0[tri, k, 3] + t * dp[tri, k, 3])
                        zl = min(zl, z)
                        zh = max(zh, z)
                if (fl & FLAG_PLANE) != 0:
                    w_lo, w_hi = plane_w_bounds(plane_n, plane_d, tri, x0, x1, y0, y1, lo, hi, ops)
                    # z/w = c1 + c0 / w grows with w (c0 < 0)
                    if w_hi < np.inf:
                        zh = min(zh, depth_c1 + depth_c0 / w_hi)
                    if w_lo > 0.0:
                        zl = max(zl, depth_c1 + depth_c0 / w_lo)
                pad = 1e-6 * (1.0 + abs(zl) + abs(zh))
                zl = max(-1.0, zl - pad)
                zh = min(1.0, zh + pad)
                ops[OP_MADD] += 12
                ops[OP_RCP] += 6
                ops[OP_MUL] += 6
                ops[OP_CMP] += 12
            ops[OP_CMP] += 6
            if ulo > uhi or vlo > vhi:
                events[EV_REJ_LENS] += 1
                continue
            out_keep[i] = True
            events[EV_ACCEPT] += 1
            t_lo[i] = lo
            t_hi[i] = hi
            u_lo[i] = ulo
            u_hi[i] = uhi
            v_lo[i] = vlo
            v_hi[i] = vhi
            z_lo[i] = zl
            z_hi[i] = zh

    return tile_test_kernel


class TileTest:
    """Functional model of the tile test unit."""

    name = "tile_test"
    events = EVENTS
    event_meanings = EVENT_MEANINGS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, table, tile_size: int, width: int, height: int,
                 depth_w: tuple[float, float] | None = None, clips: np.ndarray | None = None,
                 tuples: np.ndarray | None = None, extension: tuple | None = None, exact_time: bool = False):
        """``table``: triangle setup's table; ``clips``: the user clip planes (t_lo, t_hi, u_lo, u_hi,
        v_lo, v_hi) of the first batches' draw (``clips`` is set again per batch when the draws of a
        pass differ); ``extension``: its culling algorithm's fields (``TriangleSetup.extension``),
        needed when the algorithm declares some; ``exact_time``: narrow each 1x1 tile's t^ of a
        motion-only triangle to the exact hull of the times it meets the closed pixel
        (``units.tile_test_exact``), dropping the record where there are none (conservative mode)."""
        self.config = config
        self.clips = np.array([0.0, 1.0, -1.0, 1.0, -1.0, 1.0]) if clips is None else np.asarray(clips, np.float64)
        self.table = table
        self.tile_size = tile_size
        self.width = width
        self.height = height
        self.depth_c1, self.depth_c0 = depth_w if depth_w is not None else (0.0, 0.0)
        self.algorithm = culling.algorithm(config.algorithm)
        if self.algorithm.NEEDS_TUPLES and tuples is None:
            raise ValueError(f"{config.algorithm} needs the sample set's (u, v, t) tuples")
        self.tuples = tuples if tuples is not None else _NO_TUPLES
        if extension is None and self.algorithm.TRIANGLE_EXT.names:
            raise ValueError(f"{config.algorithm} needs triangle setup's {self.algorithm.TRIANGLE_EXT.names}: "
                             "TriangleSetup(..., culling=units.culling.algorithm(name)).extension")
        self.extension = extension if extension is not None else self.algorithm.TRIANGLE_EXT.table(0)
        if exact_time and tile_size != 1:
            raise ValueError("exact time intervals are per pixel: they need 1x1 tiles (conservative mode)")
        self.exact_time = exact_time

    def run(self, tiles: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Test a batch of tile records; return the survivors with their intervals and the
        algorithm's tile-record extension (``pipeline_sim.records.TILE`` and ``TILE_EXT``)."""
        n = len(tiles["tri"])
        alg = self.algorithm
        keep = np.zeros(n, np.bool_)
        iv = np.empty((len(INTERVALS), n))
        ext_out = alg.TILE_EXT.allocate(n)
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        t = self.table
        h = self.extension if alg.NAME == "hull" else _NO_HULLS
        cfg = self.config
        kernel = tile_test_kernel_for(ALGORITHM_CODES[alg.NAME])
        kernel(tiles["tri"], tiles["tx"], tiles["ty"], self.tile_size, self.width, self.height, cfg.edge_test,
               cfg.edge_solver == "quadratic", cfg.gamma == "tile", cfg.lens_bounds, self.clips,
               t.p0, t.dp, t.l0, t.dl, t.t_span, t.flags, t.edge_f, t.edge_h, t.edge_gamma, t.edge_g,
               t.edge_fg, t.edge_abs, t.plane_n, t.plane_d, h.hull, h.hull_n, h.hull_off, self.tuples,
               self.depth_c1, self.depth_c0, keep, *iv, ext_out.get("lines", _NO_LINES),
               ext_out.get("mask", _NO_MASKS), ops, events)
        if self.exact_time:
            motion_only = ((t.flags & FLAG_WPOS) != 0) & ((t.flags & FLAG_LENS) == 0)
            cleared = exact_kernel(tiles["tri"], tiles["tx"], tiles["ty"], motion_only, t.p0, t.dp, keep, iv[0], iv[1],
                                   ops)
            events[EV_ACCEPT] -= cleared
            events[EV_REJ_EDGE] += cleared
        kept = np.flatnonzero(keep)  # (indexing a dozen arrays by it: two fifths of the time by the mask)
        res = {name: arr[kept] for name, arr in tiles.items()}
        res.update({name: row[kept] for name, row in zip(INTERVALS, iv)})
        res.update({name: arr[kept] for name, arr in ext_out.items()})
        res["noread"] = np.zeros(len(res["tri"]), np.bool_)  # set by z-cull when it runs
        return res, ops, events
