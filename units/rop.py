"""ROP: depth test, blending, float multisample render targets, resolve.

Implements PIPELINE.md §2.7. Samples arrive in primitive order; each is
depth-tested against its multisample depth buffer entry with the configured
function, and on a pass its color is blended (replace, add, min, max) into a
float RGBA multisample color buffer. Resolve is a box filter over each
pixel's samples. After each batch the z-cull boxes of the touched tiles are
refreshed from the depth buffer.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.config import BLEND_MODES, DEPTH_FUNCS
from pipeline_sim.counters import N_OPS, OP_ADD, OP_CMP

EVENTS = ("depth_tests", "depth_passed", "depth_reads_skipped", "samples_written")
EV_TESTS, EV_PASSED, EV_SKIPPED, EV_WRITTEN = range(len(EVENTS))

DEPTH_BYTES = 4
COLOR_BYTES = 16


@nb.njit(cache=True)
def rop_kernel(pix, sidx, z, color, noread, spp, func, depth_write, blend, depth_buf, color_buf, ops, events, traffic):
    """Depth test and blend each sample in order (PIPELINE §2.7)."""
    for i in range(pix.shape[0]):
        k = pix[i] * spp + sidx[i]
        d = z[i]
        events[EV_TESTS] += 1
        if noread[i]:
            events[EV_SKIPPED] += 1
        else:
            traffic[0] += 4
        old = depth_buf[k]
        if func == 0:
            ok = d < old
        elif func == 1:
            ok = d <= old
        elif func == 2:
            ok = d > old
        elif func == 3:
            ok = d >= old
        elif func == 4:
            ok = d == old
        elif func == 5:
            ok = True
        else:
            ok = False
        ops[OP_CMP] += 1
        if not ok:
            continue
        events[EV_PASSED] += 1
        if depth_write:
            depth_buf[k] = d
            traffic[1] += 4
        if blend == 0:
            for c in range(4):
                color_buf[k, c] = color[i, c]
        else:
            traffic[0] += 16
            for c in range(4):
                if blend == 1:
                    color_buf[k, c] += color[i, c]
                elif blend == 2:
                    color_buf[k, c] = min(color_buf[k, c], color[i, c])
                else:
                    color_buf[k, c] = max(color_buf[k, c], color[i, c])
            ops[OP_ADD] += 4
        traffic[1] += 16
        events[EV_WRITTEN] += 1


class Rop:
    """Functional model of the ROP and the multisample render target."""

    name = "rop"
    events = EVENTS

    def __init__(self, config, width: int, height: int, spp: int, clear_color, clear_depth: float, zcull=None,
                 samples=None):
        self.config = config
        self.width = width
        self.height = height
        self.spp = spp
        self.depth = np.full(width * height * spp, clear_depth, np.float32)
        self.color = np.empty((width * height * spp, 4), np.float32)
        self.color[:] = np.asarray(clear_color, np.float32)
        self.func = DEPTH_FUNCS.index(config.depth_test)
        self.blend = BLEND_MODES.index(config.blend)
        self.zcull = zcull
        self.samples = samples

    def run(self, batch: dict[str, np.ndarray]) -> tuple[None, np.ndarray, np.ndarray, np.ndarray]:
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        traffic = np.zeros(2, np.int64)
        rop_kernel(batch["pix"], batch["sidx"], batch["z"], batch["color"], batch["noread"], self.spp, self.func,
                   self.config.depth_write, self.blend, self.depth, self.color, ops, events, traffic)
        if self.zcull is not None:
            zev = np.zeros(len(self.zcull.events), np.int64)
            self.zcull.refresh(batch["pix"], self.samples, self.depth, zev)
            self.zcull_refresh_events = zev
        return None, ops, events, traffic

    def resolve(self) -> np.ndarray:
        """Box-filter resolve: the mean of each pixel's samples, (H, W, 4) float32."""
        c = self.color.reshape(self.height, self.width, self.spp, 4)
        return c.mean(axis=2, dtype=np.float64).astype(np.float32)
