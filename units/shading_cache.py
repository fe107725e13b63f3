"""Shading: a memoization shading cache, or one shader execution per sample.

Implements docs/pipeline.md §2.6 (Nilsson12 §2 and §8; Ragan-Kelley et al. 2011).

Cache mode (decoupled sampling): a covered sample takes its barycentric
position on the triangle, projects that surface point with the reference
camera (the pass's shading view (u, v, t): by default the lens centre at
mid-shutter t=0.5; a chosen eye for stereo) and quantizes it to the shading grid
(``shading_rate`` pixels per cell). The key (triangle, cell) is looked up in
a set-associative cache with LRU or FIFO replacement; on a miss the shader
runs once at the cell centre (barycentrics from the reference edge
functions) and the result is stored. Samples at other times and lens
positions that see the same surface point hit and reuse it.

Per-sample mode: every covered sample is shaded at its own (t, u, v) and
barycentrics, a 1:1 mapping (caustics, sampling).

Conservative mode: the shader runs once per (triangle, pixel) record with
the tile intervals (u^, v^, t^, z^) as inputs (Nilsson12 §2).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import (COMMON, IN_B, IN_DEPTH, IN_MATERIAL, IN_NX, IN_NY, IN_NZ, IN_OBJECT, IN_PX, IN_R,
                                      IN_SAMPLE, IN_T, IN_T_HI, IN_T_LO, IN_TRIANGLE, IN_TUPLE, IN_U, IN_U_HI, IN_U_LO,
                                      IN_V, IN_V_HI, IN_V_LO, IN_X, IN_Y, IN_Z_HI, IN_Z_LO, N_INPUTS, N_OPS, OP_CMP,
                                      OP_MADD, OP_MUL, OP_RCP)

# its events, in the order of the kernel's event vector, and what each counts
EVENT_MEANINGS = {
    "lookups": "shading-cache lookups",
    "hits": "lookups that found their entry",
    "misses": "lookups that did not",
    "evictions": "entries evicted",
    "shader_executions": "shader executions",
}
EVENTS = tuple(EVENT_MEANINGS)
EV_LOOKUP, EV_HIT, EV_MISS, EV_EVICT, EV_EXEC = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): all, since its samples come through z-cull, which tests
# against the depth the ROP has refreshed by that simulated time
TIMING_DEPENDENT = COMMON + EVENTS

REPL_LRU, REPL_FIFO = 0, 1
CELL_BITS = 21
CELL_LIMIT = 1 << (CELL_BITS - 1)  # shading-grid cells are keyed in [-2^20, 2^20) per axis
CELL_MASK = (1 << CELL_BITS) - 1
HASH_MUL = np.uint64(0x9E3779B97F4A7C15)
MAX_CACHED_TRIANGLES = (1 << (64 - 2 * CELL_BITS)) - 1  # a key's triangle field: the bits above the two cells


@nb.njit(cache=True, inline="always")
def run_end(values, i):
    """The end of the run of ``values[i]``'s value that starts at ``i``: 64 values at a time while they
    all equal it (a count over a fixed-length view, which vectorizes), then one at a time."""
    n = values.shape[0]
    first = values[i]
    j = i + 1
    while j + 64 <= n:
        block = values[j:j + 64]
        others = 0
        for k in range(64):
            others += np.int64(block[k] != first)
        if others:
            break
        j += 64
    while j < n and values[j] == first:
        j += 1
    return j


@nb.njit(cache=True, error_model="numpy")
def _run_keys(tr, b0, b1, b2, ref, rate, keys):
    """``cell_keys`` for one run of triangle ``tr``: views of the run, indexed from 0, so that no index can
    be negative and numba's negative-index wraparound leaves the loop to vectorize (a loop over
    ``range(i, j)`` of the whole arrays measured four times slower). Returns the samples in front."""
    # the triangle's vertices seen by the reference camera (the pass's shading view; default t = 0.5,
    # lens centre)
    x0, x1, x2 = ref[tr, 0, 0], ref[tr, 1, 0], ref[tr, 2, 0]
    y0, y1, y2 = ref[tr, 0, 1], ref[tr, 1, 1], ref[tr, 2, 1]
    w0, w1, w2 = ref[tr, 0, 2], ref[tr, 1, 2], ref[tr, 2, 2]
    high = np.int64(tr) << np.int64(42)
    n_in_front = 0
    for k in range(b0.shape[0]):
        X = b0[k] * x0 + b1[k] * x1 + b2[k] * x2
        Y = b0[k] * y0 + b1[k] * y1 + b2[k] * y2
        W = b0[k] * w0 + b1[k] * w1 + b2[k] * w2
        front = W > 1e-20
        inv = 1.0 / W
        fx = X * inv / rate
        fy = Y * inv / rate
        cell = front & (abs(fx) < CELL_LIMIT) & (abs(fy) < CELL_LIMIT)
        cx = np.int64(np.floor(fx)) if cell else np.int64(0)
        cy = np.int64(np.floor(fy)) if cell else np.int64(0)
        key = high + ((cy + CELL_LIMIT) << np.int64(CELL_BITS)) + (cx + CELL_LIMIT)
        keys[k] = key if cell else np.int64(-1)
        n_in_front += np.int64(front)
    return n_in_front


@nb.njit(cache=True, error_model="numpy")
def cell_keys(tri, b0, b1, b2, ref, rate, keys):
    """Each sample's shading-cache key (Nilsson12 §2, §8; Ragan-Kelley et al. 2011): its surface point
    seen by the reference camera, quantized to the shading grid, with its triangle.

    ``keys[i]`` = triangle << 42 | (cell y + CELL_LIMIT) << 21 | (cell x + CELL_LIMIT), or -1 where the
    sample has no grid cell. Returns the number of samples in front of the reference camera.

    Samples come in runs of one triangle (``run_end``): its reference vertices are read once a run, and
    the loop over the run (``_run_keys``) is branch-free (a sample without a cell computes a value that
    is dropped; numpy's error model, so a zero W divides without a check), which numba vectorizes.
    """
    n_in_front = 0
    i = 0
    while i < tri.shape[0]:
        j = run_end(tri, i)
        n_in_front += _run_keys(tri[i], b0[i:j], b1[i:j], b2[i:j], ref, rate, keys[i:j])
        i = j
    return n_in_front


@nb.njit(cache=True, nogil=True)
def cache_kernel(tri, b0, b1, b2, ref, rate, tags, stamps, entry_req, clock, replacement,
                 keys, sample_src, req_entry, req_tri, req_l, req_sample, ops, events):
    """Shading-cache lookups in sample order (Nilsson12 §2, §8; Ragan-Kelley et al. 2011).

    Returns (number of shading requests, new clock). A sample's color is row
    ``sample_src[i]`` of the palette (the entries' stored colors, then this
    batch's shaded requests): row e for a hit on an entry filled in an earlier
    batch, row entries + r for request r of this batch (its own miss, or a hit
    on an entry filled in this batch). ``req_sample[r]``: the sample that made
    request r, the first that points at it. ``keys`` and the per-sample and
    per-request outputs are scratch of at least len(tri) rows.
    """
    nsets = tags.shape[0]
    ways = tags.shape[1]
    entries = nsets * ways
    set_mask = np.uint64(nsets - 1)
    pow2 = (nsets & (nsets - 1)) == 0  # the set index is a mask then, not a division
    nreq = 0
    l = np.empty(3)
    # counted in locals, written once: a kernel's counter arrays may alias its outputs for all numba knows
    n_miss = 0
    n_hit = 0
    n_evict = 0
    n_uncached = 0
    # the keys first, in a loop of their own: its iterations are independent, so the core overlaps them,
    # and the lookups below are short enough to overlap too (measured on the default pass: about 10 ns a
    # lookup, 15 with keys and lookups in one loop, 29 with that and an early-exit tag search as well)
    n_in_front = cell_keys(tri, b0, b1, b2, ref, rate, keys)
    for i in range(tri.shape[0]):
        tr = tri[i]
        key = keys[i]
        clock += 1
        if key == -1:
            # the surface point is behind the reference camera (or absurdly far
            # off screen): it has no shading-grid cell, so it is shaded on its
            # own, uncached, at its own barycentrics
            n_uncached += 1
            req_entry[nreq] = -1
            req_tri[nreq] = tr
            req_l[0, nreq] = b0[i]
            req_l[1, nreq] = b1[i]
            req_l[2, nreq] = b2[i]
            req_sample[nreq] = i
            sample_src[i] = entries + nreq
            nreq += 1
            continue
        h = (np.uint64(key) * HASH_MUL) >> np.uint64(33)
        st = int(h & set_mask) if pow2 else int(h % np.uint64(nsets))
        # a key is in at most one way of its set: no early exit, so the search has no unpredictable branch
        hit_way = -1
        for w in range(ways):
            if tags[st, w] == key:
                hit_way = w
        if hit_way >= 0:
            n_hit += 1
            e = st * ways + hit_way
            if replacement == REPL_LRU:
                stamps[st, hit_way] = clock
            r = entry_req[e]
            sample_src[i] = entries + r if r >= 0 else e
            continue
        n_miss += 1
        victim = 0
        best = np.int64(1) << 62
        for w in range(ways):
            if tags[st, w] == -1:
                victim = w
                best = -1
                break
            if stamps[st, w] < best:
                best = stamps[st, w]
                victim = w
        if best != -1:
            n_evict += 1
        tags[st, victim] = key
        stamps[st, victim] = clock
        e = st * ways + victim
        entry_req[e] = nreq
        req_entry[nreq] = e
        req_tri[nreq] = tr
        # barycentrics of the cell centre on the reference triangle
        sx = (((key & CELL_MASK) - CELL_LIMIT) + 0.5) * rate
        sy = ((((key >> CELL_BITS) & CELL_MASK) - CELL_LIMIT) + 0.5) * rate
        for k in range(3):
            ii = (k + 1) % 3
            jj = (k + 2) % 3
            a = ref[tr, jj, 1] * ref[tr, ii, 2] - ref[tr, jj, 2] * ref[tr, ii, 1]
            b = ref[tr, jj, 2] * ref[tr, ii, 0] - ref[tr, jj, 0] * ref[tr, ii, 2]
            c = ref[tr, jj, 0] * ref[tr, ii, 1] - ref[tr, jj, 1] * ref[tr, ii, 0]
            l[k] = a * sx + b * sy + c
        tot = l[0] + l[1] + l[2]
        if tot != 0.0 and np.isfinite(tot):
            # clamp to the triangle so attributes stay in range
            for k in range(3):
                l[k] = max(0.0, l[k] / tot)
            s = l[0] + l[1] + l[2]
            if s > 0:
                for k in range(3):
                    req_l[k, nreq] = l[k] / s
            else:
                req_l[0, nreq] = b0[i]
                req_l[1, nreq] = b1[i]
                req_l[2, nreq] = b2[i]
        else:
            req_l[0, nreq] = b0[i]
            req_l[1, nreq] = b1[i]
            req_l[2, nreq] = b2[i]
        req_sample[nreq] = i
        sample_src[i] = entries + nreq
        nreq += 1
    n = tri.shape[0]
    events[EV_LOOKUP] += n
    events[EV_HIT] += n_hit
    events[EV_MISS] += n_miss + n_uncached
    events[EV_EVICT] += n_evict
    events[EV_EXEC] += nreq
    # per lookup: the reference point (9 madd); with it in front, its cell (1 rcp, 4 mul) and the
    # set's tags (ways compares); per cached miss, the cell centre's barycentrics (9 mul, 12 madd, 1 rcp)
    ops[OP_MADD] += 9 * n + 12 * n_miss
    ops[OP_MUL] += 4 * n_in_front + 9 * n_miss
    ops[OP_RCP] += n_in_front + n_miss
    ops[OP_CMP] += ways * (n - n_uncached)
    return nreq, clock


@nb.njit(cache=True, nogil=True)
def store_requests(req_entry, shaded, entry_color, entry_req):
    """Store each request's color in its cache entry (-1: uncached, no grid
    cell); requests in order, so an entry refilled within the batch keeps its
    last request's color. The entry then holds a color, no pending request."""
    for r in range(req_entry.shape[0]):
        e = req_entry[r]
        if e >= 0:
            for c in range(shaded.shape[1]):
                entry_color[e, c] = shaded[r, c]
            entry_req[e] = -1


@nb.njit(cache=True, nogil=True)
def deliver_colors(sample_src, palette, color):
    """Each sample's color: row ``sample_src[i]`` of ``palette`` (see ``cache_kernel``). Rows of four
    channels, the common case, are copied by a loop of fixed length, which the compiler unrolls (measured
    2.2 times faster than the loop over ``palette.shape[1]``)."""
    if palette.shape[1] == 4:
        for i in range(sample_src.shape[0]):
            r = sample_src[i]
            for c in range(4):
                color[i, c] = palette[r, c]
        return
    for i in range(sample_src.shape[0]):
        r = sample_src[i]
        for c in range(palette.shape[1]):
            color[i, c] = palette[r, c]


@nb.njit(cache=True, nogil=True)
def request_points(first, pix, z, width, x, y, depth):
    """Each shading request's pixel centre and depth, those of the sample that made it (``first[r]``,
    whose pixel ``pix`` counts ``width`` to a row): one loop instead of a fancy index, a divmod and
    two conversions in numpy, each a call of its own for a batch of a few hundred requests."""
    for r in range(first.shape[0]):
        i = first[r]
        p = pix[i]
        x[r] = np.float32(p % width + 0.5)
        y[r] = np.float32(p // width + 0.5)
        depth[r] = z[i]


@nb.njit(cache=True, nogil=True)
def interpolate_kernel(req_tri, req_l, req_t, req_u, req_v, req_x, req_y, req_depth,
                       pos, nrm, color, material, object_id, inputs, ops):
    """Perspective-correct attribute interpolation for shading requests (Munkberg11 §8 'interpolation setup')."""
    for i in range(req_tri.shape[0]):
        tr = req_tri[i]
        t = req_t[i]
        for c in range(3):
            p = 0.0
            n = 0.0
            col = 0.0
            for k in range(3):
                lk = req_l[k, i]
                p += lk * (pos[0, tr, k, c] + t * (pos[1, tr, k, c] - pos[0, tr, k, c]))
                n += lk * (nrm[0, tr, k, c] + t * (nrm[1, tr, k, c] - nrm[0, tr, k, c]))
                col += lk * color[tr, k, c]
            inputs[IN_PX + c, i] = p
            inputs[IN_NX + c, i] = n
            inputs[IN_R + c, i] = col
        nl = np.sqrt(inputs[IN_NX, i] ** 2 + inputs[IN_NY, i] ** 2 + inputs[IN_NZ, i] ** 2)
        if nl > 0:
            for c in range(3):
                inputs[IN_NX + c, i] /= nl
        inputs[IN_T, i] = t
        inputs[IN_U, i] = req_u[i]
        inputs[IN_V, i] = req_v[i]
        inputs[IN_X, i] = req_x[i]
        inputs[IN_Y, i] = req_y[i]
        inputs[IN_DEPTH, i] = req_depth[i]
        inputs[IN_MATERIAL, i] = material[tr]
        inputs[IN_OBJECT, i] = object_id[tr]
        inputs[IN_TRIANGLE, i] = tr
    n = req_tri.shape[0]
    ops[OP_MADD] += n * 27
    ops[OP_MUL] += n * 6
    ops[OP_RCP] += n


def cache_scratch(n: int) -> tuple[np.ndarray, ...]:
    """``cache_kernel``'s scratch for batches of up to ``n`` samples: keys, sample_src, req_entry, req_tri,
    req_l, req_sample."""
    return (np.empty(n, np.int64), np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32),
            np.empty((3, n), np.float64), np.empty(n, np.int32))


class Shading:
    """Functional model of the shading unit: cache (or 1:1) plus shader cores.

    The shader is called as ``shader(inputs, params, textures, out, append)``
    (``pipeline_sim.shaders``): ``textures`` a tuple of float32 (H, W, layers)
    arrays, ``out`` (shading points, ``channels``) its named outputs side by
    side, ``append`` the pass's append buffer (records, count).
    """

    name = "shading"
    events = EVENTS
    event_meanings = EVENT_MEANINGS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, mode: str, shading_rate: float, draw, table, samples, shader, params: np.ndarray,
                 textures, conservative: bool, channels: int = 4, append: tuple | None = None,
                 shading_view: tuple[float, float, float] = (0.0, 0.0, 0.5)):
        self.config = config
        self.shading_rate = shading_rate
        self.shading_view = shading_view  # (u, v, t) of the reference camera: the table's ``ref`` is seen from it
        self.draw = draw
        self.table = table
        self.samples = samples  # of the screen region the batches are in (``use_samples``)
        self.shader = shader
        self.params = np.ascontiguousarray(params, dtype=np.float32)
        self.textures = () if textures is None else tuple(np.ascontiguousarray(t, dtype=np.float32) for t in textures)
        self.channels = channels
        # no append buffer: an empty one, every append counted as overflow
        self.append = (np.zeros((0, 1), np.float32), np.zeros(1, np.int64)) if append is None else append
        self.conservative = conservative
        self.cached = mode == "cache" and not conservative
        if self.cached and draw.n > MAX_CACHED_TRIANGLES:
            raise ValueError(f"the shading cache keys at most {MAX_CACHED_TRIANGLES:,} triangles, not {draw.n:,}")
        ways = config.cache_ways
        nsets = config.cache_entries // ways
        self.tags = np.full((nsets, ways), -1, np.int64)
        self.stamps = np.zeros((nsets, ways), np.int64)
        self.entry_req = np.full(nsets * ways, -1, np.int32)
        self.entry_color = np.zeros((nsets * ways, channels), np.float32)
        self.clock = 0
        self.scratch = cache_scratch(0)  # the cache kernel's, grown to the largest batch
        self.view = np.zeros((3, 0), np.float32)  # the shading view's (t, u, v) per request, grown likewise

    def use_samples(self, samples) -> None:
        """Shade the next batches with ``samples`` (their screen region's; conservative mode reads none)."""
        self.samples = samples

    def _shade(self, inputs: np.ndarray) -> np.ndarray:
        out = np.zeros((inputs.shape[1], self.channels), np.float32)
        if inputs.shape[1]:
            self.shader(inputs, self.params, self.textures, out, self.append)
        return out

    def run(self, batch: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        if self.conservative:
            return self._run_conservative(batch, ops, events)
        n = len(batch["tri"])
        s = self.samples
        if self.cached:
            if len(self.scratch[0]) < n:
                self.scratch = cache_scratch(n)
            keys, sample_src, req_entry, req_tri, req_l, req_sample = self.scratch
            nreq, self.clock = cache_kernel(
                batch["tri"], batch["b0"], batch["b1"], batch["b2"], self.table.ref, self.shading_rate,
                self.tags, self.stamps, self.entry_req, self.clock,
                REPL_LRU if self.config.replacement == "lru" else REPL_FIFO, keys, sample_src, req_entry,
                req_tri, req_l, req_sample, ops, events)
            if self.view.shape[1] < nreq:
                u, v, t = self.shading_view
                self.view = np.repeat(np.array([[t], [u], [v]], np.float32), max(nreq, 2 * self.view.shape[1]),
                                      axis=1)
            x, y, depth = (np.empty(nreq, np.float32) for _ in range(3))
            request_points(req_sample[:nreq], batch["pix"], batch["z"], s.width, x, y, depth)
            inputs = np.zeros((N_INPUTS, nreq), np.float32)
            interpolate_kernel(req_tri[:nreq], req_l[:, :nreq], *self.view[:, :nreq], x, y, depth, self.draw.pos,
                               self.draw.nrm, self.draw.color, self.draw.material, self.draw.object_id, inputs, ops)
            inputs[IN_SAMPLE:IN_TUPLE + 1] = -1  # a shading point of the reference camera is no sample
            shaded = self._shade(inputs)
            color = np.empty((n, self.channels), np.float32)
            deliver_colors(sample_src[:n], np.concatenate((self.entry_color, shaded)), color)
            store_requests(req_entry[:nreq], shaded, self.entry_color, self.entry_req)
        else:
            py, px = np.divmod(batch["pix"], s.width)
            k = (batch["pix"].astype(np.int64) - s.row0 * s.width) * s.spp + batch["sidx"]
            st, su, sv = s.t[k], s.u[k], s.v[k]
            req_l = np.stack([batch["b0"], batch["b1"], batch["b2"]]).astype(np.float64)
            inputs = np.zeros((N_INPUTS, n), np.float32)
            interpolate_kernel(batch["tri"], req_l, st, su, sv,
                               (px + s.x[k]).astype(np.float32), (py + s.y[k]).astype(np.float32), batch["z"],
                               self.draw.pos, self.draw.nrm, self.draw.color, self.draw.material,
                               self.draw.object_id, inputs, ops)
            inputs[IN_SAMPLE] = batch["sidx"]
            inputs[IN_TUPLE] = s.tup[k] if s.tup is not None else batch["sidx"] if s.table_rows else -1
            color = self._shade(inputs)
            events[EV_EXEC] += n  # 1:1 shading: no cache lookups
        out = dict(batch)
        out["color"] = color
        return out, ops, events

    def _run_conservative(self, batch, ops, events):
        n = len(batch["tri"])
        inputs = np.zeros((N_INPUTS, n), np.float32)
        tri = batch["tri"]
        inputs[IN_X] = batch["tx"] + 0.5
        inputs[IN_Y] = batch["ty"] + 0.5
        inputs[IN_MATERIAL] = self.draw.material[tri]
        inputs[IN_OBJECT] = self.draw.object_id[tri]
        inputs[IN_TRIANGLE] = tri
        for row, name in ((IN_T_LO, "t_lo"), (IN_T_HI, "t_hi"), (IN_U_LO, "u_lo"), (IN_U_HI, "u_hi"),
                          (IN_V_LO, "v_lo"), (IN_V_HI, "v_hi"), (IN_Z_LO, "z_lo"), (IN_Z_HI, "z_hi")):
            inputs[row] = batch[name]
        inputs[IN_T] = 0.5 * (batch["t_lo"] + batch["t_hi"])
        inputs[IN_DEPTH] = batch["z_lo"]
        inputs[IN_R:IN_B + 1] = self.draw.color[tri].mean(axis=1).T
        inputs[IN_SAMPLE:IN_TUPLE + 1] = -1  # a tile, no sample
        color = self._shade(inputs)
        events[EV_EXEC] += n
        out = {"tri": tri, "pix": (batch["ty"] * self.draw.width + batch["tx"]).astype(np.int32),
               "sidx": np.zeros(n, np.int32), "z": batch["z_lo"].astype(np.float32),
               "noread": batch.get("noread", np.zeros(n, np.bool_)), "color": color}
        return out, ops, events
