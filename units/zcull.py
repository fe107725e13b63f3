"""Z-cull: per-tile zmin/zmax over boxes of (t, u, v) space.

Implements PIPELINE.md §2.4 (000 §3; 002 §2). Each screen tile keeps a zmax
and a zmin for each of ``time_slices x lens_boxes x lens_boxes`` disjoint
boxes of (t, u, v) space. A (triangle, tile) record whose nearest depth z^lo
lies behind zmax in every box its intervals touch cannot pass the depth test
anywhere and is culled; one whose farthest depth z^hi lies in front of zmin
in every touched box passes everywhere, so the ROP needs no depth reads for
it. The ROP refreshes a tile's boxes from the depth buffer after writing it;
a stale box only makes the test looser, never wrong.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.counters import N_OPS, OP_CMP, OP_MUL

EVENTS = ("tiles_culled", "tiles_no_depth_read", "box_lookups", "tile_refreshes")
EV_CULLED, EV_NOREAD, EV_LOOKUPS, EV_REFRESH = range(len(EVENTS))

# depth functions for which zmax culling is valid
CULL_LESS, CULL_LEQUAL, CULL_NONE = 0, 1, 2


@nb.njit(cache=True, inline="always")
def _box_range(lo, hi, n, offset, scale):
    a = int(np.floor((lo + offset) * scale * n))
    b = int(np.floor((hi + offset) * scale * n))
    return max(0, min(n - 1, a)), max(0, min(n - 1, b))


@nb.njit(cache=True)
def zcull_kernel(tri, tx, ty, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, z_lo, z_hi, tiles_x,
                 nt, nl, zmax, zmin, func, keep, noread, ops, events):
    """Cull records whose z^ lies behind zmax in every touched box (000 §3)."""
    for i in range(tri.shape[0]):
        tile = ty[i] * tiles_x + tx[i]
        t0, t1 = _box_range(t_lo[i], t_hi[i], nt, 0.0, 1.0)
        a0, a1 = _box_range(u_lo[i], u_hi[i], nl, 1.0, 0.5)
        b0, b1 = _box_range(v_lo[i], v_hi[i], nl, 1.0, 0.5)
        behind = True
        front = True
        for it in range(t0, t1 + 1):
            for iu in range(a0, a1 + 1):
                for iv in range(b0, b1 + 1):
                    box = (it * nl + iu) * nl + iv
                    events[EV_LOOKUPS] += 1
                    zm = zmax[tile, box]
                    if func == CULL_LESS:
                        if z_lo[i] < zm:
                            behind = False
                    else:
                        if z_lo[i] <= zm:
                            behind = False
                    if not z_hi[i] < zmin[tile, box]:
                        front = False
                    ops[OP_CMP] += 2
        ops[OP_MUL] += 6
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
                        if z_lo[i] < zmin[tile, box]:
                            zmin[tile, box] = z_lo[i]
        if behind:
            events[EV_CULLED] += 1
        elif front:
            events[EV_NOREAD] += 1


@nb.njit(cache=True)
def refresh_kernel(pix, width, spp, tile_size, tiles_x, nt, nl, st, su, sv, depth, zmax, mark, events):
    """Recompute zmax of every tile touched by ``pix`` from the depth buffer.

    Depths only decrease under a LESS/LEQUAL test with writes, so a zmax read
    before later writes land stays an upper bound. (zmin is kept by the
    z-cull test itself, see ``zcull_kernel``.)"""
    n_touched = 0
    touched = np.empty(pix.shape[0], np.int64)
    for i in range(pix.shape[0]):
        py = pix[i] // width
        px = pix[i] - py * width
        tile = (py // tile_size) * tiles_x + px // tile_size
        if mark[tile] == 0:
            mark[tile] = 1
            touched[n_touched] = tile
            n_touched += 1
    height_px = depth.shape[0] // (width * spp)
    nbox = zmax.shape[1]
    for j in range(n_touched):
        tile = touched[j]
        mark[tile] = 0
        for b in range(nbox):
            zmax[tile, b] = -np.inf
        tyy = tile // tiles_x
        txx = tile - tyy * tiles_x
        for py in range(tyy * tile_size, min((tyy + 1) * tile_size, height_px)):
            for px in range(txx * tile_size, min((txx + 1) * tile_size, width)):
                base = (py * width + px) * spp
                for s in range(spp):
                    k = base + s
                    it = min(nt - 1, int(st[k] * nt))
                    iu = min(nl - 1, max(0, int((su[k] + 1.0) * 0.5 * nl)))
                    iv = min(nl - 1, max(0, int((sv[k] + 1.0) * 0.5 * nl)))
                    box = (it * nl + iu) * nl + iv
                    d = depth[k]
                    if d > zmax[tile, box]:
                        zmax[tile, box] = d
        # a box that holds no sample stays at -inf: nothing there can be covered
        events[EV_REFRESH] += 1


class ZCull:
    """Functional model of the z-cull unit and its per-tile box memory."""

    name = "zcull"
    events = EVENTS

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
        self.zmax = np.full((ntiles, nbox), clear_depth, np.float32)
        self.zmin = np.full((ntiles, nbox), clear_depth, np.float32)
        self.mark = np.zeros(ntiles, np.int8)
        self.func = {"less": CULL_LESS, "lequal": CULL_LEQUAL}.get(depth_func, CULL_NONE)
        self.active = bool(config.enabled) and self.func != CULL_NONE

    def run(self, tiles: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        n = len(tiles["tri"])
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        keep = np.ones(n, np.bool_)
        noread = np.zeros(n, np.bool_)
        if self.active:
            zcull_kernel(tiles["tri"], tiles["tx"], tiles["ty"], tiles["t_lo"], tiles["t_hi"], tiles["u_lo"],
                         tiles["u_hi"], tiles["v_lo"], tiles["v_hi"], tiles["z_lo"], tiles["z_hi"],
                         self.tiles_x, self.nt, self.nl, self.zmax, self.zmin, self.func, keep, noread,
                         ops, events)
        out = {name: arr[keep] for name, arr in tiles.items()}
        out["noread"] = noread[keep]  # depth reads this tile's samples can skip
        return out, ops, events

    def refresh(self, pix: np.ndarray, samples, depth: np.ndarray, events: np.ndarray) -> None:
        """Refresh the boxes of the tiles touched by ``pix`` (called by the ROP)."""
        if self.active and len(pix):
            # ``samples`` and ``depth`` hold rows from samples.row0, a tile row
            # (the screen region the ROP is working on): index the tiles from there
            first = samples.row0 // self.tile_size * self.tiles_x
            local = pix - samples.row0 * self.width if samples.row0 else pix
            refresh_kernel(local, self.width, samples.spp, self.tile_size, self.tiles_x, self.nt, self.nl,
                           samples.t, samples.u, samples.v, depth, self.zmax[first:], self.mark[first:], events)
