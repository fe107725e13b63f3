"""Z-cull: per-tile zmin/zmax over boxes of (t, u, v) space.

Implements docs/pipeline.md §2.4 (Nilsson12 §3; Munkberg11 §2). Each screen tile keeps a zmax
and a zmin for each of ``time_slices x lens_boxes x lens_boxes`` disjoint
boxes of (t, u, v) space. A (triangle, tile) record whose nearest depth z^lo
lies behind zmax in every box its intervals touch cannot pass the depth test
anywhere and is culled; one whose farthest depth z^hi lies in front of zmin
in every touched box passes everywhere, so the ROP needs no depth reads for
it. The ROP refreshes a tile's boxes from the depth buffer after writing it
(``ZCull.refresh``, the one path from the ROP to z-cull; its work is charged
to the ROP); a stale box only makes the test looser, never wrong. Which
refreshes a test sees depends on how far the ROP has got by then, so what
z-cull culls can move with the timing (``TIMING_DEPENDENT``).

It also answers interval-based occlusion queries (Nilsson12 §3, docs/passes.md): the records of a
draw that asks one (``Draw.query = "interval"``) are compared with the boxes and go no further; the
query answers "visible" at the first box whose zmax its z^lo does not lie behind, and stops
comparing there (``interval_query_kernel``).
"""

from __future__ import annotations

import threading
import weakref
from collections import deque

import numba as nb
import numpy as np

from pipeline_sim.definitions import N_OPS, OP_CMP, OP_MUL
from units.made_ahead import MadeAhead

# its events, in the order of the kernel's event vector, and what each counts
EVENT_MEANINGS = {
    "tiles_culled": "tiles z-cull rejected as hidden",
    "tiles_no_depth_read": "tiles z-cull found in front of everything drawn (the ROP skips their depth reads)",
    "box_lookups": "z-cull box lookups",
}
EVENTS = tuple(EVENT_MEANINGS)
EV_CULLED, EV_NOREAD, EV_LOOKUPS = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): what it culls and lets skip depth reads depends on the
# refreshes that reached it; the lookups (and their arithmetic and bytes) follow each record's intervals only
TIMING_DEPENDENT = ("records_out", "tiles_culled", "tiles_no_depth_read")
# the work of a refresh: tiles touched, tiles rescanned (all boxes of a tile's first refresh, else those
# a write may have lowered), depth samples read by the rescans, comparisons of a replaced depth with its box's zmax
REFRESH_WORK = ("tiles", "scans", "samples_read", "checks")
RF_TILES, RF_SCANS, RF_READ, RF_CHECKS = range(len(REFRESH_WORK))

_NO_TILES = np.zeros(0, np.int64)

# depth functions for which zmax culling is valid
CULL_LESS, CULL_LEQUAL, CULL_NONE = 0, 1, 2

# an interval query's answer and the work until it: tile records compared, box comparisons
QUERY_FIELDS = ("visible", "tiles", "box_comparisons")
Q_VISIBLE, Q_TILES, Q_BOXES = range(len(QUERY_FIELDS))


@nb.njit(cache=True, inline="always")
def _box_range(lo, hi, n, offset, scale):
    a = int(np.floor((lo + offset) * scale * n))
    b = int(np.floor((hi + offset) * scale * n))
    return max(0, min(n - 1, a)), max(0, min(n - 1, b))


@nb.njit(cache=True, nogil=True)
def zcull_kernel(tri, tx, ty, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, tiles_x,
                 nt, nl, zmax, zmin, func, keep, noread, ops, events):
    """Cull records whose z^ lies behind zmax in every touched box (Nilsson12 §3).

    The counts are kept in locals and added once (the compiler cannot tell the
    counter arrays from the boxes, so a count in them would be stored and
    reloaded at every box)."""
    lookups = 0
    culled = 0
    front_only = 0
    for i in range(tri.shape[0]):
        tile = ty[i] * tiles_x + tx[i]
        t0, t1 = _box_range(t_lo[i], t_hi[i], nt, 0.0, 1.0)
        a0, a1 = _box_range(u_lo[i], u_hi[i], nl, 1.0, 0.5)
        b0, b1 = _box_range(v_lo[i], v_hi[i], nl, 1.0, 0.5)
        zl = z_lo[i]
        zh = z_hi[i]
        far = zmax[tile]
        near = zmin[tile]
        behind = True
        front = True
        for it in range(t0, t1 + 1):
            for iu in range(a0, a1 + 1):
                for iv in range(b0, b1 + 1):
                    box = (it * nl + iu) * nl + iv
                    lookups += 1
                    zm = far[box]
                    if func == CULL_LESS:
                        if zl < zm:
                            behind = False
                    else:
                        if zl <= zm:
                            behind = False
                    if not zh < near[box]:
                        front = False
        keep[i] = not behind
        noread[i] = front and not behind
        if not behind:
            # this record may write depths >= z_lo into the boxes it touches:
            # lower their zmin now, so zmin stays a lower bound even for writes
            # still in flight between z-cull and the ROP
            for it in range(t0, t1 + 1):
                for iu in range(a0, a1 + 1):
                    for iv in range(b0, b1 + 1):
                        box = (it * nl + iu) * nl + iv
                        if zl < near[box]:
                            near[box] = zl
        if behind:
            culled += 1
        elif front:
            front_only += 1
    events[EV_LOOKUPS] += lookups
    events[EV_CULLED] += culled
    events[EV_NOREAD] += front_only
    ops[OP_CMP] += 2 * lookups
    ops[OP_MUL] += 6 * tri.shape[0]


@nb.njit(cache=True, nogil=True)
def interval_query_kernel(tx, ty, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, tiles_x, nt, nl, zmax, func, answer,
                          ops):
    """Interval-based occlusion query of one draw's tile records, in order (Nilsson12 §3): the records'
    (t^, u^, v^) select the boxes they touch and z^lo is compared with each box's zmax. A sample of the
    draw can pass the depth test (``func``: LESS or LEQUAL) only where z^lo lies in front of (LESS) or
    on (LEQUAL) the far depth of its box, so the first such comparison answers "visible" and ends the
    query; records after it are not looked at. ``answer`` (laid out as ``QUERY_FIELDS``) carries the
    answer and the records and comparisons spent until it, across the draw's batches."""
    for i in range(tx.shape[0]):
        if answer[Q_VISIBLE]:
            return
        answer[Q_TILES] += 1
        ops[OP_MUL] += 6
        tile = ty[i] * tiles_x + tx[i]
        t0, t1 = _box_range(t_lo[i], t_hi[i], nt, 0.0, 1.0)
        a0, a1 = _box_range(u_lo[i], u_hi[i], nl, 1.0, 0.5)
        b0, b1 = _box_range(v_lo[i], v_hi[i], nl, 1.0, 0.5)
        for it in range(t0, t1 + 1):
            for iu in range(a0, a1 + 1):
                for iv in range(b0, b1 + 1):
                    zm = zmax[tile, (it * nl + iu) * nl + iv]
                    answer[Q_BOXES] += 1
                    ops[OP_CMP] += 1
                    if z_lo[i] < zm or (func == CULL_LEQUAL and z_lo[i] == zm):
                        answer[Q_VISIBLE] = 1
                        return


@nb.njit(cache=True, inline="always")
def _sample_box(t, u, v, nt, nl):
    """The (t, u, v) box holding a sample."""
    it = min(nt - 1, int(t * nt))
    iu = min(nl - 1, max(0, int((u + 1.0) * 0.5 * nl)))
    iv = min(nl - 1, max(0, int((v + 1.0) * 0.5 * nl)))
    return (it * nl + iu) * nl + iv


@nb.njit(cache=True, inline="always")
def _box_max(depth, order, k0, k1):
    """The first largest of ``depth[order[k0:k1]]``, -inf if none."""
    top = -np.inf
    for k in range(k0, k1):
        d = depth[order[k]]
        if d > top:
            top = d
    return top


@nb.njit(cache=True, inline="always")
def _group_pixel(p, spp, nt, nl, st, su, sv, box_of, order, start, cursor):
    """Pixel ``p``'s samples' boxes and the pixel's samples grouped by box (see ``box_groups_kernel``);
    ``cursor``: scratch of one entry per box. On the pixel's own arrays (loops from 0 vectorize)."""
    nbox = start.shape[1] - 1
    k0, k1 = p * spp, (p + 1) * spp
    boxes, group, ends = box_of[k0:k1], order[k0:k1], start[p]
    pt, pu, pv = st[k0:k1], su[k0:k1], sv[k0:k1]
    for s in range(spp):
        boxes[s] = _sample_box(pt[s], pu[s], pv[s], nt, nl)
    ends[:] = 0
    for s in range(spp):
        ends[boxes[s] + 1] += 1
    for b in range(nbox):
        ends[b + 1] += ends[b]
        cursor[b] = ends[b]
    for s in range(spp):
        b = boxes[s]
        group[cursor[b]] = s
        cursor[b] += 1


@nb.njit(cache=True, nogil=True)
def box_groups_kernel(spp, nt, nl, st, su, sv, box_of, order, start):
    """Each sample's z-cull box and each pixel's samples grouped by box, for the ROP's refresh of the
    boxes' zmax (Nilsson12 §3; ``refresh_kernel``): ``box_of[k]`` the box of sample k (its (t, u, v) in
    ``st``, ``su``, ``sv``), ``order[p * spp:(p + 1) * spp]`` pixel p's sample indices in box order (a
    stable counting sort, so in sample order within a box) and ``start[p, b] .. start[p, b + 1]`` box b's
    run of them, for every pixel. Depends on the samples only."""
    cursor = np.empty(start.shape[1] - 1, np.int32)
    for p in range(start.shape[0]):
        _group_pixel(p, spp, nt, nl, st, su, sv, box_of, order, start, cursor)


@nb.njit(cache=True, nogil=True)
def refresh_kernel(pix, sidx, prior, width, spp, tile_size, tiles_x, nt, nl, st, su, sv, depth, zmax, exact, slot,
                   box_of, order, start, grouped, pmax, dirty, work, scanned):
    """Set zmax of every box of the tiles touched by ``pix`` to the largest depth of its samples
    (Nilsson12 §3: the ROP keeps z-cull's per-tile bounds up to date).

    A box that holds no sample gets -inf: nothing there can be covered. The
    first refresh of a tile from this depth buffer (``exact`` 0) reads all of
    it. After that, depths only decrease under a LESS/LEQUAL test, so a box's
    largest depth can only have changed where a record replaced a depth
    (``prior``; NaN: none) not below the box's zmax: only those boxes need
    their samples read (the work counted); the others keep their zmax, which
    is exactly what a rescan gives, and tiles with no such box are not
    rescanned. Depths only decreasing also makes a zmax read before later
    writes land an upper bound. (zmin is kept by the z-cull test itself, see
    ``zcull_kernel``.) ``work`` gets the refresh's work, laid out as
    ``REFRESH_WORK``.

    What the modelled rescan reads is computed without reading it: the same
    argument per pixel keeps each pixel's largest depth per box (``pmax``,
    set at the tile's first refresh) exact by rereading only the (pixel, box)
    pairs a write may have lowered, through each sample's box ``box_of`` and
    the pixel's samples grouped by box, ``order`` and ``start``: made with the
    samples (``box_groups_kernel``) when ``grouped``, else here, at the tile's
    first refresh, from the samples' (t, u, v) ``st``, ``su``, ``sv``
    (``dirty``: all False between calls). A tile's zmax is the first largest
    of its pixels' maxima in row-major order, which is the first largest of
    its samples in the order a scan reads them: the same bits.

    The tiles rescanned (whose zmax rows were rewritten) go to ``scanned``, in
    order; returns their number."""
    n = pix.shape[0]
    nbox = zmax.shape[1]
    rows = min(n, zmax.shape[0])  # at most one row per tile the samples can touch
    touched = np.empty(rows, np.int64)
    # per touched tile, the boxes to rescan: all of a tile's first refresh, else those a write may have lowered
    stale = np.empty((rows, nbox), np.bool_)  # rows filled as tiles are first touched
    pairs = np.empty(n, np.int64)  # the (pixel, box) pairs to reread, as pixel * nbox + box
    n_pairs = 0
    n_touched = 0
    checks = 0
    last_pix = -1
    tile = 0
    j = 0
    base = 0
    first = False
    for i in range(n):
        if pix[i] != last_pix:  # a pixel's samples come together: divide once per pixel
            last_pix = pix[i]
            py = last_pix // width
            tile = (py // tile_size) * tiles_x + (last_pix - py * width) // tile_size
            first = exact[tile] == 0
            if slot[tile] == 0:
                touched[n_touched] = tile
                stale[n_touched, :] = first
                n_touched += 1
                slot[tile] = n_touched
            j = slot[tile] - 1
            base = last_pix * spp
        if not first:
            checks += 1
            b = box_of[base + sidx[i]]
            # a pixel's largest depth in a box is at most the tile's: only a depth not below the first can be
            # not below the second
            if prior[i] >= pmax[last_pix, b]:
                if prior[i] >= zmax[tile, b]:
                    stale[j, b] = True
                if not dirty[last_pix, b]:
                    dirty[last_pix, b] = True
                    pairs[n_pairs] = last_pix * nbox + b
                    n_pairs += 1
    work[RF_CHECKS] += checks
    work[RF_TILES] += n_touched
    for m in range(n_pairs):
        p = pairs[m] // nbox
        b = pairs[m] - p * nbox
        dirty[p, b] = False
        base = p * spp
        pmax[p, b] = _box_max(depth[base:base + spp], order[base:base + spp], start[p, b], start[p, b + 1])
    height_px = depth.shape[0] // (width * spp)
    cursor = np.empty(nbox, np.int32)
    n_scanned = 0
    for j in range(n_touched):
        tile = touched[j]
        slot[tile] = 0
        mask = stale[j]
        if not mask.any():
            continue
        work[RF_SCANS] += 1
        scanned[n_scanned] = tile
        n_scanned += 1
        fresh = exact[tile] == 0
        exact[tile] = 1
        zrow = zmax[tile]
        zrow[:] = -np.inf
        tyy = tile // tiles_x
        txx = tile - tyy * tiles_x
        x0 = txx * tile_size
        x1 = min(x0 + tile_size, width)
        read = 0
        for py in range(tyy * tile_size, min((tyy + 1) * tile_size, height_px)):
            for p in range(py * width + x0, py * width + x1):
                if fresh:  # the pixel's first refresh: the largest depth of each of its boxes
                    if not grouped:
                        _group_pixel(p, spp, nt, nl, st, su, sv, box_of, order, start, cursor)
                    k0, k1 = p * spp, (p + 1) * spp
                    group, own, ends = order[k0:k1], depth[k0:k1], start[p]
                    for b in range(nbox):
                        pmax[p, b] = _box_max(own, group, ends[b], ends[b + 1])
                for b in range(nbox):  # every box recomputed; only the stale boxes' samples count as read
                    if mask[b]:
                        read += start[p, b + 1] - start[p, b]
                    if pmax[p, b] > zrow[b]:
                        zrow[b] = pmax[p, b]
        work[RF_READ] += read
    return n_scanned


class BoxGroups:
    """Each sample's z-cull box and each pixel's samples grouped by box (``box_groups_kernel``), per sample
    set: what the ROP's refresh of a screen region reads besides its depths.

    They depend on the samples only, so ``prepare`` makes a set's on the thread that makes the set ahead
    (``pipeline_sim.regions.RegionSamples``, beside the sample tester's layout), and ``take`` hands the
    refresh a set's groups, or, for a set not prepared, buffers for them that the refresh fills tile by
    tile as it first reaches each (only the tiles written are grouped then). Groups prepared for sets of
    earlier rows (regions the pipeline has passed) are dropped; the buffers of the groups taken before
    serve the next set's, unless a set's are prepared already. Thread-safe.
    """

    def __init__(self, nt: int, nl: int):
        self.nt = nt
        self.nl = nl
        self.ahead = MadeAhead()  # the groups prepared, by sample set
        self._lock = threading.Lock()
        self._free: tuple | None = None  # the buffers of groups no longer read
        self._taken: tuple | None = None

    def prepare(self, samples, waited_for: bool = False):
        """Make the groups of ``samples`` now, for a later ``take``; returns ``samples``. (``waited_for``:
        as ``TileMajorLayouts.prepare`` takes it; the groups are made on this thread either way.)"""
        box_of, order, start = self._buffers(samples)
        box_groups_kernel(samples.spp, self.nt, self.nl, samples.t, samples.u, samples.v, box_of, order, start)
        self.ahead.hold(samples, (box_of, order, start))
        return samples

    def take(self, samples) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """(box_of, order, start, grouped) for ``samples``: the groups prepared (``grouped`` True), else
        buffers for them, to be filled by the refresh."""
        got, _, later = self.ahead.take(samples)
        with self._lock:
            # what the groups taken before leave serves the next set's, unless that one is prepared already
            self._free = None if later else self._taken
            self._taken = None
        groups = got if got is not None else self._buffers(samples)
        with self._lock:
            self._taken = groups
        return groups + (got is not None,)

    def _buffers(self, samples) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n, spp = len(samples.t), samples.spp
        pixels = n // spp
        with self._lock:
            free, self._free = self._free, None
        if free is not None and len(free[0]) >= n and len(free[2]) >= pixels:
            return free[0][:n], free[1][:n], free[2][:pixels]
        return np.empty(n, np.uint8), np.empty(n, np.uint16), np.empty((pixels, self.nt * self.nl * self.nl + 1),
                                                                         np.int32)


class ZCull:
    """Functional model of the z-cull unit and its per-tile box memory."""

    name = "zcull"
    events = EVENTS
    event_meanings = EVENT_MEANINGS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, depth_func: str, tile_size: int, width: int, height: int, clear_depth: float,
                 motion: bool = True, lens: bool = True):
        self.config = config
        self.tile_size = tile_size
        self.width = width
        self.tiles_x = (width + tile_size - 1) // tile_size
        self.tiles_y = (height + tile_size - 1) // tile_size
        # a dimension the draw does not use gets one box: no storage, no lookups
        self.nt = config.time_slices if motion else 1
        self.nl = config.lens_boxes if lens else 1
        nbox = self.nt * self.nl * self.nl
        ntiles = self.tiles_x * self.tiles_y
        # zmax as the z-cull test sees it, and as the ROP's refreshes have left it: the two differ only while
        # refreshes wait to be published (``publish_refresh``), when the ROP works ahead of the simulation
        self.zmax = np.full((ntiles, nbox), clear_depth, np.float32)
        self.refreshed_zmax = self.zmax.copy()
        self._unpublished: deque[tuple[np.ndarray, np.ndarray]] = deque()  # (tiles, their zmax rows) per refresh
        self.zmin = np.full((ntiles, nbox), clear_depth, np.float32)
        # refresh state: per tile, whether zmax is exact for the ROP's current
        # depth buffer (``_buffer``) and a scratch slot; each sample's box, and
        # per pixel its samples grouped by box (indices in the pixel: below
        # MAX_SPP = 2^16), from ``groups``, each box's largest depth and a
        # scratch flag (see ``refresh_kernel``)
        self.exact = np.zeros(ntiles, np.uint8)
        self.slot = np.zeros(ntiles, np.int64)
        self.groups = BoxGroups(self.nt, self.nl)
        self._grouped: tuple = ()
        self.pmax = np.empty((0, nbox), np.float32)
        self.dirty = np.zeros((0, nbox), np.bool_)
        self._buffer = None
        self.func = {"less": CULL_LESS, "lequal": CULL_LEQUAL}.get(depth_func, CULL_NONE)
        self.active = bool(config.enabled) and self.func != CULL_NONE
        # per draw asking an interval query: its answer and work, laid out as ``QUERY_FIELDS``
        self.queries: dict[int, np.ndarray] = {}

    def run(self, tiles: dict[str, np.ndarray], query: int | None = None
            ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Cull a batch of tile records; or, with ``query`` (the draw, asking an interval query, whose
        records these are), answer its query from them and pass none on."""
        n = len(tiles["tri"])
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        if query is not None:
            answer = self.queries.setdefault(query, np.zeros(len(QUERY_FIELDS), np.int64))
            boxes = answer[Q_BOXES]
            interval_query_kernel(tiles["tx"], tiles["ty"], tiles["t_lo"], tiles["t_hi"], tiles["u_lo"],
                                  tiles["u_hi"], tiles["v_lo"], tiles["v_hi"], tiles["z_lo"], self.tiles_x, self.nt,
                                  self.nl, self.zmax, self.func, answer, ops)
            events[EV_LOOKUPS] += answer[Q_BOXES] - boxes
            return {name: arr[:0] for name, arr in tiles.items()}, ops, events
        keep = np.ones(n, np.bool_)
        noread = np.zeros(n, np.bool_)
        if self.active:
            zcull_kernel(tiles["tri"], tiles["tx"], tiles["ty"], tiles["t_lo"], tiles["t_hi"], tiles["u_lo"],
                         tiles["u_hi"], tiles["v_lo"], tiles["v_hi"], tiles["z_lo"], tiles["z_hi"],
                         self.tiles_x, self.nt, self.nl, self.zmax, self.zmin, self.func, keep, noread,
                         ops, events)
        if keep.all():  # the common case: nothing culled, nothing to compact
            out = dict(tiles)
            out["noread"] = noread
        else:
            kept = np.flatnonzero(keep)  # (indexing a dozen arrays by it: two fifths of the time by the mask)
            out = {name: arr[kept] for name, arr in tiles.items()}
            out["noread"] = noread[kept]  # depth reads this tile's samples can skip
        return out, ops, events

    def query_answer(self, draw: int) -> dict[str, bool | int]:
        """Draw ``draw``'s interval query: ``visible`` (False: every record it sent lies behind the boxes
        it touches, or it sent none), and the ``tiles`` (records) and ``box_comparisons`` spent until it."""
        answer = self.queries.get(draw, np.zeros(len(QUERY_FIELDS), np.int64))
        return {"visible": bool(answer[Q_VISIBLE]), "tiles": int(answer[Q_TILES]),
                "box_comparisons": int(answer[Q_BOXES])}

    def refresh(self, pix: np.ndarray, sidx: np.ndarray, prior: np.ndarray, samples, depth: np.ndarray,
                publish: bool = True) -> np.ndarray:
        """Refresh the boxes of the tiles touched by the samples ``pix, sidx`` from the ROP's
        ``depth`` (``prior``: the depth each one replaced, NaN: none); returns the work done,
        laid out as ``REFRESH_WORK``. Called through ``Rop.refresh_zcull`` (and by ``pipeline_sim.jit``'s
        warm-up).

        The new boxes go to ``refreshed_zmax``, which the next refresh starts from, and, with
        ``publish``, to ``zmax`` at once; else they wait, in order, for ``publish_refresh`` (the ROP
        working ahead of the simulation on a thread of its own: z-cull sees each refresh when the
        simulation reaches the ROP step that made it, as if made then)."""
        if publish and self._unpublished:
            raise RuntimeError("a z-cull refresh published while earlier ones wait: it would overtake them")
        work = np.zeros(len(REFRESH_WORK), np.int64)
        tiles = _NO_TILES
        if self.active and len(pix):
            if self._buffer is None or self._buffer() is not depth:
                # a new depth buffer (the next screen region): its tiles start with a full scan
                self._buffer = weakref.ref(depth)
                self.exact[:] = 0
                npix, nbox = len(depth) // samples.spp, self.zmax.shape[1]
                self._grouped = self.groups.take(samples)
                # a tile's entries are set at its first refresh (``dirty`` stays all False): those of the last
                # buffer, if of its size, serve
                if len(self.pmax) != npix:
                    self.pmax = np.empty((npix, nbox), np.float32)
                    self.dirty = np.zeros((npix, nbox), np.bool_)
            # ``samples`` and ``depth`` hold rows from samples.row0, a tile row
            # (the screen region the ROP is working on): index the tiles from there
            first = samples.row0 // self.tile_size * self.tiles_x
            local = pix - samples.row0 * self.width if samples.row0 else pix
            scanned = np.empty(min(len(pix), len(self.zmax) - first), np.int64)
            n = refresh_kernel(local, sidx, prior, self.width, samples.spp, self.tile_size, self.tiles_x, self.nt,
                               self.nl, samples.t, samples.u, samples.v, depth, self.refreshed_zmax[first:],
                               self.exact[first:], self.slot[first:], *self._grouped, self.pmax, self.dirty, work,
                               scanned)
            tiles = scanned[:n] + first
        rows = self.refreshed_zmax[tiles]
        if publish:
            self.zmax[tiles] = rows
        else:
            self._unpublished.append((tiles, rows))
        return work

    def publish_refresh(self) -> None:
        """Let the z-cull test see the oldest refresh made with ``publish`` off."""
        if not self._unpublished:
            raise RuntimeError("no z-cull refresh waits to be published")
        tiles, rows = self._unpublished.popleft()
        self.zmax[tiles] = rows
