"""ROP: depth test, blending, float multisample render targets, resolve.

Implements docs/pipeline.md §2.7. Samples arrive in primitive order; each is
depth-tested against its multisample depth buffer entry with the configured
function, and on a pass its color is blended (replace, add, min, max) into a
float RGBA multisample color buffer (``add`` saturates at the largest finite
float32, so that the buffer stays finite however many layers add up).
Resolve is a box filter over each pixel's samples. The z-cull boxes of the
tiles a batch wrote are refreshed from the depth buffer through
``refresh_zcull``, the one path from the ROP to z-cull; its depth reads and
comparisons are the ROP's work.

The multisample buffers hold one screen region (``pipeline_sim.regions``)
at a time: when the pipeline moves the ROP on to the next region
(``open_region``), the current one is resolved into the image and its
buffers are dropped.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import BLEND_MODES, DEPTH_FUNCS, N_OPS, OP_ADD, OP_CMP
from units.zcull import RF_CHECKS, RF_READ, RF_SCANS, RF_TILES

EVENTS = ("depth_tests", "depth_passed", "depth_reads_skipped", "samples_written", "zcull_refresh_tiles",
          "zcull_refresh_scans")
EV_TESTS, EV_PASSED, EV_SKIPPED, EV_WRITTEN, EV_REFRESH_TILES, EV_REFRESH_SCANS = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): the samples z-cull passed and the reads it spared, and
# the refreshes; which samples pass the depth test, and so the writes and blends, do not (z-cull culls
# only samples that would fail it)
TIMING_DEPENDENT = ("records_in", "compare", "bytes_read", "depth_tests", "depth_reads_skipped",
                    "zcull_refresh_tiles", "zcull_refresh_scans")

DEPTH_BYTES = 4
COLOR_BYTES = 16
F32_MAX = np.float32(np.finfo(np.float32).max)


@nb.njit(cache=True)
def rop_kernel(pix, sidx, z, color, noread, spp, pix0, func, depth_write, blend, depth_buf, color_buf, prior, ops,
               events, traffic):
    """Depth test and blend each sample in order (docs/pipeline.md §2.7); the buffers start at pixel ``pix0``.

    ``prior[i]`` gets the depth record ``i`` replaced, NaN where it wrote no depth."""
    skipped = 0
    passed = 0
    for i in range(pix.shape[0]):
        k = (pix[i] - pix0) * spp + sidx[i]
        d = z[i]
        skipped += noread[i]
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
        prior[i] = np.nan
        if not ok:
            continue
        passed += 1
        if depth_write:
            prior[i] = old
            depth_buf[k] = d
        if blend == 0:
            for c in range(4):
                color_buf[k, c] = color[i, c]
        else:
            for c in range(4):
                if blend == 1:  # saturating: the sum of many layers stays a finite float32
                    color_buf[k, c] = min(max(color_buf[k, c] + color[i, c], -F32_MAX), F32_MAX)
                elif blend == 2:
                    color_buf[k, c] = min(color_buf[k, c], color[i, c])
                else:
                    color_buf[k, c] = max(color_buf[k, c], color[i, c])
    n = pix.shape[0]
    blended = passed if blend != 0 else 0
    events[EV_TESTS] += n
    events[EV_SKIPPED] += skipped
    events[EV_PASSED] += passed
    events[EV_WRITTEN] += passed
    ops[OP_CMP] += n
    ops[OP_ADD] += 4 * blended
    traffic[0] += DEPTH_BYTES * (n - skipped) + COLOR_BYTES * blended
    traffic[1] += (DEPTH_BYTES * passed if depth_write else 0) + COLOR_BYTES * passed


@nb.njit(cache=True)
def resolve_kernel(color_buf, spp, out):
    """Box filter (docs/pipeline.md §2.7): each pixel's mean over its ``spp`` samples, summed in float64."""
    for p in range(out.shape[0]):
        base = p * spp
        for c in range(4):
            acc = 0.0
            for s in range(spp):
                acc += color_buf[base + s, c]
            out[p, c] = acc / spp


class Rop:
    """Functional model of the ROP and the multisample render target.

    ``rows``: the image rows ``[r0, r1)`` of the first screen region (default:
    the whole frame, then the only region); ``samples``: that region's
    samples, needed to refresh z-cull's boxes; ``keep_depth``: also keep the
    whole frame's per-sample depth (``frame_depth``) over several regions
    (with one region it is the depth buffer itself).
    """

    name = "rop"
    events = EVENTS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, state, width: int, height: int, spp: int, clear_color, clear_depth: float, zcull=None,
                 samples=None, rows: tuple[int, int] | None = None, keep_depth: bool = True):
        self.config = config
        self.width = width
        self.height = height
        self.spp = spp
        self.clear_color = np.asarray(clear_color, np.float32)
        self.clear_depth = np.float32(clear_depth)
        self.func = DEPTH_FUNCS.index(state.depth_test)
        self.depth_write = state.depth_write
        self.blend = BLEND_MODES.index(state.blend)
        self.zcull = zcull
        rows = (0, height) if rows is None else tuple(rows)
        self.one_region = rows == (0, height)
        self.image = np.empty((height, width, 4), np.float32)
        self.image[:] = self.clear_color
        self.frame_depth = (np.full(width * height * spp, clear_depth, np.float32)
                            if keep_depth and not self.one_region else None)
        self._open(rows, samples)

    def _open(self, rows: tuple[int, int], samples) -> None:
        """Fresh (cleared) buffers for image rows ``rows``, whose samples are ``samples``."""
        r0, r1 = rows
        n = (r1 - r0) * self.width * self.spp
        self.rows = rows
        self.pix0 = r0 * self.width
        self.depth = np.full(n, self.clear_depth, np.float32)
        self.color = np.empty((n, 4), np.float32)
        self.color[:] = self.clear_color
        self.samples = samples

    def _resolve_region(self) -> None:
        """Box-filter the current region into the image (and keep its depth when asked)."""
        r0, r1 = self.rows
        resolve_kernel(self.color, self.spp, self.image[r0:r1].reshape(-1, 4))
        if self.frame_depth is not None:
            self.frame_depth[self.pix0 * self.spp : r1 * self.width * self.spp] = self.depth

    def open_region(self, rows: tuple[int, int], samples=None) -> None:
        """Move on to the next screen region, image rows ``rows`` (its ``samples``
        refresh z-cull's boxes): the current one is resolved into the image and
        its buffers are dropped for fresh ones."""
        self._resolve_region()
        self._open(rows, samples)

    def run(self, batch: dict[str, np.ndarray]) -> tuple[tuple | None, np.ndarray, np.ndarray, np.ndarray]:
        """Depth-test and blend a batch (of samples of the current region). Returns its z-cull refresh
        request (for ``refresh_zcull``; None without z-cull), arithmetic, events and traffic (bytes read,
        written)."""
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        traffic = np.zeros(2, np.int64)
        prior = np.empty(len(batch["pix"]), np.float32)
        rop_kernel(batch["pix"], batch["sidx"], batch["z"], batch["color"], batch["noread"], self.spp, self.pix0,
                   self.func, self.depth_write, self.blend, self.depth, self.color, prior, ops, events,
                   traffic)
        request = (batch["pix"], batch["sidx"], prior) if self.zcull is not None else None
        return request, ops, events, traffic

    def refresh_zcull(self, requests: list[tuple]) -> tuple[np.ndarray, np.ndarray, int]:
        """Refresh z-cull's boxes for the samples of ``requests`` (from ``run``, of the current
        screen region, in order) from the depth buffer as it is now. Returns the ROP's work for
        it: arithmetic (one compare per replaced depth checked against its box's zmax and per
        sample rescanned), events (tiles refreshed and rescanned) and the depth bytes read."""
        if len(requests) == 1:
            pix, sidx, prior = requests[0]
        else:
            pix, sidx, prior = (np.concatenate([r[k] for r in requests]) for k in range(3))
        work = self.zcull.refresh(pix, sidx, prior, self.samples, self.depth)
        ops = np.zeros(N_OPS, np.int64)
        ops[OP_CMP] = work[RF_CHECKS] + work[RF_READ]
        events = np.zeros(len(EVENTS), np.int64)
        events[EV_REFRESH_TILES] = work[RF_TILES]
        events[EV_REFRESH_SCANS] = work[RF_SCANS]
        return ops, events, int(work[RF_READ]) * DEPTH_BYTES

    def resolve(self) -> np.ndarray:
        """Box-filter resolve: the mean of each pixel's samples, (H, W, 4) float32
        (the ROP's own image, not a copy: a frame's image can be gigabytes)."""
        self._resolve_region()
        return self.image

    def depth_samples(self) -> np.ndarray | None:
        """The frame's per-sample depth, (H, W, spp), after ``resolve``; None
        when the frame spans several regions and ``keep_depth`` was off."""
        d = self.depth if self.one_region else self.frame_depth
        return None if d is None else d.reshape(self.height, self.width, self.spp)
