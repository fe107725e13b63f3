"""ROP: depth test, blending, float multisample render targets, resolves.

Implements docs/pipeline.md §2.7. Samples arrive in primitive order; each is
depth-tested against its multisample depth buffer entry with the pass's
function, and blended into each of the pass's render targets
(``pipeline_sim.definitions.Target``): per channel replace, add, min or max
(``add`` saturates at the largest finite float32, so that the buffer stays
finite however many layers add up), where the depth test passes or
regardless of it, for the draws the target takes. Per draw it counts the
samples passing the depth test (the query). Resolves: a box filter over
each pixel's samples, one weighted mean per lens region, or none (the
per-sample data kept). The z-cull boxes of the tiles a batch wrote are
refreshed from the depth buffer through ``refresh_zcull``, the one path
from the ROP to z-cull; its depth reads and comparisons are the ROP's work.

The multisample buffers hold one screen region (``pipeline_sim.regions``)
at a time: when the pipeline moves the ROP on to the next region
(``open_region``), the current one is resolved into the images and its
buffers are dropped.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pipeline_sim.definitions import BLEND_MODES, DEPTH_FUNCS, N_OPS, OP_ADD, OP_CMP, ShaderOutput, default_targets
from units.zcull import RF_CHECKS, RF_READ, RF_SCANS, RF_TILES

# its events, in the order of the kernel's event vector, and what each counts
EVENT_MEANINGS = {
    "depth_tests": "sample depth tests",
    "depth_passed": "samples that passed",
    "depth_reads_skipped": "depth reads skipped on z-cull's word",
    "samples_written": "samples written to the multisample buffers",
    "zcull_refresh_tiles": "tiles whose z-cull boxes were checked after a batch",
    "zcull_refresh_scans": "tiles rescanned to refresh their z-cull boxes",
}
EVENTS = tuple(EVENT_MEANINGS)
EV_TESTS, EV_PASSED, EV_SKIPPED, EV_WRITTEN, EV_REFRESH_TILES, EV_REFRESH_SCANS = range(len(EVENTS))
# counters timing can move (docs/pipeline.md §4): the samples z-cull passed and the reads it spared, and
# the refreshes; which samples pass the depth test, and so the writes and blends, do not (z-cull culls
# only samples that would fail it)
TIMING_DEPENDENT = ("records_in", "compare", "bytes_read", "depth_tests", "depth_reads_skipped",
                    "zcull_refresh_tiles", "zcull_refresh_scans")

DEPTH_BYTES = 4
CHANNEL_BYTES = 4  # a float32 channel of a render target
F32_MAX = np.float32(np.finfo(np.float32).max)
_NO_TRIANGLES = np.zeros(0, np.int32)
_NOT_KEPT = np.zeros(0, np.bool_)


@nb.njit(cache=True, inline="always")
def depth_passes(func, d, old):
    """The depth test ``func`` (a code of ``DEPTH_FUNCS``) of a sample's depth ``d`` against ``old``."""
    if func == 0:
        return d < old
    if func == 1:
        return d <= old
    if func == 2:
        return d > old
    if func == 3:
        return d >= old
    if func == 4:
        return d == old
    return func == 5


@nb.njit(cache=True, inline="always")
def blend_sample(buf, k, color, i, c0, modes):
    """Blend record ``i``'s colour channels ``c0..`` into entry ``k`` of one render target, channel ``c``
    with blend ``modes[c]`` (replace, add, min, max; docs/pipeline.md §2.7)."""
    for c in range(buf.shape[1]):
        b = modes[c]
        x = color[i, c0 + c]
        if b == 0:
            buf[k, c] = x
        elif b == 1:  # saturating: the sum of many layers stays a finite float32
            buf[k, c] = min(max(buf[k, c] + x, -F32_MAX), F32_MAX)
        elif b == 2:
            buf[k, c] = min(buf[k, c], x)
        else:
            buf[k, c] = max(buf[k, c], x)


@nb.njit(cache=True, nogil=True)
def rop_kernel(pix, sidx, z, tri, color, noread, spp, pix0, func, depth_write, depth_buf, tri_draw, by_draw, query,
               passed, prior, buf, c0, copy, ops, events, traffic):
    """Depth test each sample in order (docs/pipeline.md §2.7); the buffers start at pixel ``pix0``.
    ``passed[i]`` (unless empty) gets whether record ``i`` passed, for ``blend_kernel`` to write the
    targets; ``prior[i]`` the depth it replaced, NaN where it wrote no depth. ``query`` counts per draw the
    samples passing (Nilsson12 §3); ``by_draw``: the samples' draws are those of their triangles
    (``tri_draw[tri]``), else all draw 0. ``copy``: the first target ``buf`` is the common one (replaced
    on every channel where the test passes, for every draw), written here from channel ``c0`` of
    ``color`` in the same loop (the default pass's case, chosen once per pass)."""
    skipped = 0
    n_passed = 0
    per_draw = query.shape[0] > 1  # one draw: its query is the count of samples passed
    keep = passed.shape[0] > 0
    rgba = buf.shape[1] == 4
    for i in range(pix.shape[0]):
        k = (pix[i] - pix0) * spp + sidx[i]
        d = z[i]
        skipped += noread[i]
        old = depth_buf[k]
        ok = depth_passes(func, d, old)
        if keep:
            passed[i] = ok
        prior[i] = np.nan
        if ok:
            n_passed += 1
            if per_draw:
                query[tri_draw[tri[i]] if by_draw else 0] += 1
            if depth_write:
                prior[i] = old
                depth_buf[k] = d
            if copy:  # the first target replaced on every channel: the sample's values copied
                if rgba:  # of a fixed length, which the compiler unrolls
                    for c in range(4):
                        buf[k, c] = color[i, c0 + c]
                else:
                    for c in range(buf.shape[1]):
                        buf[k, c] = color[i, c0 + c]
    if not per_draw:
        query[0] += n_passed
    n = pix.shape[0]
    events[EV_TESTS] += n
    events[EV_SKIPPED] += skipped
    events[EV_PASSED] += n_passed
    events[EV_WRITTEN] += n_passed
    ops[OP_CMP] += n
    traffic[0] += DEPTH_BYTES * (n - skipped)
    traffic[1] += DEPTH_BYTES * n_passed if depth_write else 0
    if copy:
        traffic[1] += CHANNEL_BYTES * buf.shape[1] * n_passed


@nb.njit(cache=True, nogil=True)
def blend_kernel(pix, sidx, tri, color, passed, spp, pix0, tri_draw, by_draw, buf, c0, modes, blended, every,
                 some_draws, draw_ok, ops, traffic):
    """Blend each sample, in order, into a render target (docs/pipeline.md §2.7; the target as
    ``Rop.target_args`` gives it) from the samples' depth-test results ``passed``: where it passed (or
    ``every``), for the draws the target takes. A write moves the target's channels; a blend other than
    replace (on ``blended`` channels) reads them first and counts one addition per such channel (min and
    max too)."""
    writes = 0
    for i in range(pix.shape[0]):
        if (passed[i] or every) and not (some_draws and not draw_ok[tri_draw[tri[i]] if by_draw else 0]):
            writes += 1
            blend_sample(buf, (pix[i] - pix0) * spp + sidx[i], color, i, c0, modes)
    nbytes = CHANNEL_BYTES * buf.shape[1] * writes
    ops[OP_ADD] += blended * writes
    traffic[0] += nbytes if blended else 0
    traffic[1] += nbytes


@nb.njit(cache=True, nogil=True)
def resolve_kernel(color_buf, spp, out):
    """Box filter (docs/pipeline.md §2.7): each pixel's mean over its ``spp`` samples, summed in float64 in
    sample order. Four channels at a time in one pass, as four independent sums (not one waiting on the
    other's additions); the channels after the last four one by one."""
    nc = out.shape[1]
    quads = nc - nc % 4
    for p in range(out.shape[0]):
        block = color_buf[p * spp:(p + 1) * spp]
        for c in range(0, quads, 4):
            a0 = a1 = a2 = a3 = 0.0
            for s in range(spp):
                a0 += block[s, c]
                a1 += block[s, c + 1]
                a2 += block[s, c + 2]
                a3 += block[s, c + 3]
            out[p, c] = a0 / spp
            out[p, c + 1] = a1 / spp
            out[p, c + 2] = a2 / spp
            out[p, c + 3] = a3 / spp
        for c in range(quads, nc):
            acc = 0.0
            for s in range(spp):
                acc += block[s, c]
            out[p, c] = acc / spp


def lens_resolve(buf: np.ndarray, spp: int, u: np.ndarray, v: np.ndarray, region, clear: np.ndarray) -> np.ndarray:
    """Resolve of one lens region (Nilsson12 §8): per pixel, the mean of the samples whose lens position
    (``u``, ``v``) lies in the region's box window, in float64; the clear value where none does."""
    inside = (u >= region.u_lo) & (u <= region.u_hi) & (v >= region.v_lo) & (v <= region.v_hi)
    w = inside.reshape(-1, spp).astype(np.float64)
    num = np.einsum("ps,psc->pc", w, buf.reshape(-1, spp, buf.shape[1]).astype(np.float64))
    den = w.sum(axis=1)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, clear).astype(np.float32)


class Rop:
    """Functional model of the ROP and its multisample render targets.

    ``targets`` (``pipeline_sim.targets.Target``; None: one RGBA target cleared to ``clear_color``) take
    the shader's ``outputs`` (None: one RGBA "color"); ``tri_draw``: each triangle's draw index (None:
    all draw 0), of ``n_draws``. ``rows``: the image rows ``[r0, r1)`` of the first screen region
    (default: the whole frame, then the only region); ``samples``: that region's samples, needed to
    refresh z-cull's boxes and for lens resolves; ``keep_depth``: also keep the whole frame's per-sample
    depth (``frame_depth``) over several regions (with one region it is the depth buffer itself).
    """

    name = "rop"
    events = EVENTS
    event_meanings = EVENT_MEANINGS
    timing_dependent = TIMING_DEPENDENT

    def __init__(self, config, state, width: int, height: int, spp: int, clear_color, clear_depth: float, zcull=None,
                 samples=None, rows: tuple[int, int] | None = None, keep_depth: bool = True, targets=None,
                 outputs=None, tri_draw: np.ndarray | None = None, n_draws: int = 1):
        self.config = config
        self.width = width
        self.height = height
        self.spp = spp
        self.clear_depth = np.float32(clear_depth)
        self.func = DEPTH_FUNCS.index(state.depth_test)
        self.depth_write = state.depth_write
        self.zcull = zcull
        outputs = (ShaderOutput(),) if outputs is None else tuple(outputs)
        self.targets = default_targets(clear_color) if targets is None else tuple(targets)
        names = [o.name for o in outputs]
        offsets = np.cumsum([0] + [o.channels for o in outputs])
        self.channels = [outputs[names.index(t.source)].channels for t in self.targets]
        nt = len(self.targets)
        self.col0 = np.array([offsets[names.index(t.source)] for t in self.targets], np.int64)
        self.blend = np.zeros((nt, max(self.channels)), np.int64)
        for j, t in enumerate(self.targets):
            modes = t.blend if isinstance(t.blend, tuple) else (t.blend,) * self.channels[j]
            self.blend[j, :self.channels[j]] = [BLEND_MODES.index(state.blend if m is None else m) for m in modes]
        self.draw_ok = np.array([[t.draws is None or d in t.draws for d in range(n_draws)] for t in self.targets])
        # per target, what ``blend_kernel`` takes of it, chosen once: its first channel among the shader's
        # outputs, its blend modes, how many channels blend other than by replace, whether it is written
        # regardless of the depth test, whether it takes only some draws and which
        self.target_args = tuple((int(self.col0[j]), self.blend[j], int(np.count_nonzero(self.blend[j, :c])),
                                  t.depth == "always", not self.draw_ok[j].all(), self.draw_ok[j])
                                 for j, (t, c) in enumerate(zip(self.targets, self.channels)))
        # the common first target (replaced on every channel where the depth test passes, for every draw):
        # the depth test's kernel writes it in its own loop
        _, _, blended, every, some_draws, _ = self.target_args[0]
        self.copy_first = int(blended == 0 and not every and not some_draws)
        self.clears = [np.zeros(c, np.float32) if t.clear is None else np.asarray(t.clear, np.float32)
                       for t, c in zip(self.targets, self.channels)]
        # without a triangle -> draw table or with one draw, every sample is of draw 0
        self.tri_draw = _NO_TRIANGLES if tri_draw is None else tri_draw
        self.by_draw = tri_draw is not None and n_draws > 1
        self.queries = np.zeros(n_draws, np.int64)
        rows = (0, height) if rows is None else tuple(rows)
        self.one_region = rows == (0, height)
        # per target: its images (box: one; lens: one per view; none: its frame of per-sample data over
        # several regions); ``image``: the first target's box-resolved image, whatever its resolve
        self.images = {}
        self.frame_samples = {}
        for j, t in enumerate(self.targets):
            n_images = {"box": 1, "lens": len(t.views), "none": 0}[t.resolve]
            self.images[t.name] = [np.empty((height, width, self.channels[j]), np.float32) for _ in range(n_images)]
            for img in self.images[t.name]:
                img[:] = self.clears[j]
            if t.resolve == "none" and not self.one_region:  # (a region no sample reaches keeps the clear)
                self.frame_samples[t.name] = np.empty((width * height * spp, self.channels[j]), np.float32)
                self.frame_samples[t.name].view(np.dtype((np.void, self.clears[j].nbytes))).fill(
                    self.clears[j].tobytes())
        first = self.targets[0]
        if first.resolve == "box":
            self.image = self.images[first.name][0]
        else:
            self.image = np.empty((height, width, self.channels[0]), np.float32)
            self.image[:] = self.clears[0]
        self.frame_depth = (np.full(width * height * spp, clear_depth, np.float32)
                            if keep_depth and not self.one_region else None)
        self._store = None  # (depth, the targets' buffers) of the largest region so far
        self._open(rows, samples)

    @property
    def needs_samples(self) -> bool:
        """Whether the ROP needs each region's samples besides z-cull's refresh: for a lens resolve."""
        return any(t.resolve == "lens" for t in self.targets)

    @property
    def color(self) -> np.ndarray:
        """The first target's multisample buffer (samples, channels) of the current region."""
        return self.buffers[0]

    def _open(self, rows: tuple[int, int], samples) -> None:
        """Cleared buffers for image rows ``rows``, whose samples are ``samples``: views of the buffers of
        the largest region so far (a region's are resolved or copied out before the next one opens, and
        memory a process touches for the first time costs far more than clearing it again)."""
        r0, r1 = rows
        n = (r1 - r0) * self.width * self.spp
        self.rows = tuple(rows)
        self.pix0 = r0 * self.width
        if self._store is None or len(self._store[0]) < n:
            self._store = (np.empty(n, np.float32),) + tuple(np.empty((n, c), np.float32) for c in self.channels)
        self.depth = self._store[0][:n]
        self.depth.fill(self.clear_depth)
        self.buffers = tuple(b[:n] for b in self._store[1:])
        for buf, clear in zip(self.buffers, self.clears):
            # as one element the size of a row: numpy fills that as it fills a scalar, several times
            # faster than it broadcasts a row
            buf.view(np.dtype((np.void, clear.nbytes))).fill(clear.tobytes())
        self.samples = samples

    def _resolve_region(self) -> None:
        """Resolve the current region of each target into its images, or keep its samples (and its depth
        when asked)."""
        r0, r1 = self.rows
        lo, hi = self.pix0 * self.spp, r1 * self.width * self.spp
        for j, t in enumerate(self.targets):
            buf = self.buffers[j]
            if t.resolve == "box" or j == 0:
                img = self.images[t.name][0] if t.resolve == "box" else self.image
                resolve_kernel(buf, self.spp, img[r0:r1].reshape(-1, buf.shape[1]))
            if t.resolve == "lens":
                if self.samples is None:
                    raise ValueError(f"rows {r0}-{r1}: a lens resolve needs the region's samples")
                for view, img in zip(t.views, self.images[t.name]):
                    img[r0:r1] = lens_resolve(buf, self.spp, self.samples.u, self.samples.v, view,
                                              self.clears[j]).reshape(r1 - r0, self.width, -1)
            if t.name in self.frame_samples:
                self.frame_samples[t.name][lo:hi] = buf
        if self.frame_depth is not None:
            self.frame_depth[lo:hi] = self.depth

    def open_region(self, rows: tuple[int, int], samples=None) -> None:
        """Move on to the next screen region, image rows ``rows`` (its ``samples``
        refresh z-cull's boxes and weight lens resolves): the current one is resolved into the images and
        its buffers are cleared for the next one. The current region's rows again: only its ``samples``
        are handed over (the pipeline may hand the first region's when its first batch comes)."""
        if tuple(rows) == self.rows:
            self.samples = samples
            return
        self._resolve_region()
        self._open(rows, samples)

    def run(self, batch: dict[str, np.ndarray]) -> tuple[tuple | None, np.ndarray, np.ndarray, np.ndarray]:
        """Depth-test and blend a batch (of samples of the current region). Returns its z-cull refresh
        request (for ``refresh_zcull``; None without z-cull), arithmetic, events and traffic (bytes read,
        written)."""
        ops = np.zeros(N_OPS, np.int64)
        events = np.zeros(len(EVENTS), np.int64)
        traffic = np.zeros(2, np.int64)
        n = len(batch["pix"])
        prior = np.empty(n, np.float32)
        first = self.copy_first  # the targets from ``first`` on are blended after the depth test
        passed = np.empty(n, np.bool_) if len(self.buffers) > first else _NOT_KEPT
        by_draw = self.by_draw and "tri" in batch  # records without triangles: all of draw 0
        pix, sidx, tri = batch["pix"], batch["sidx"], batch["tri"] if by_draw else _NO_TRIANGLES
        rop_kernel(pix, sidx, batch["z"], tri, batch["color"], batch["noread"], self.spp, self.pix0, self.func,
                   self.depth_write, self.depth, self.tri_draw, by_draw, self.queries, passed, prior, self.buffers[0],
                   self.target_args[0][0], first == 1, ops, events, traffic)
        for buf, args in zip(self.buffers[first:], self.target_args[first:]):
            blend_kernel(pix, sidx, tri, batch["color"], passed, self.spp, self.pix0, self.tri_draw, by_draw, buf,
                         *args, ops, traffic)
        request = (batch["pix"], batch["sidx"], prior) if self.zcull is not None else None
        return request, ops, events, traffic

    def refresh_zcull(self, requests: list[tuple], publish: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
        """Refresh z-cull's boxes for the samples of ``requests`` (from ``run``, of the current
        screen region, in order) from the depth buffer as it is now; z-cull's test sees them at once,
        or, without ``publish``, at its ``publish_refresh``. Returns the ROP's work for
        it: arithmetic (one compare per replaced depth checked against its box's zmax and per
        sample rescanned), events (tiles refreshed and rescanned) and the depth bytes read."""
        if len(requests) == 1:
            pix, sidx, prior = requests[0]
        else:
            pix, sidx, prior = (np.concatenate([r[k] for r in requests]) for k in range(3))
        work = self.zcull.refresh(pix, sidx, prior, self.samples, self.depth, publish)
        ops = np.zeros(N_OPS, np.int64)
        ops[OP_CMP] = work[RF_CHECKS] + work[RF_READ]
        events = np.zeros(len(EVENTS), np.int64)
        events[EV_REFRESH_TILES] = work[RF_TILES]
        events[EV_REFRESH_SCANS] = work[RF_SCANS]
        return ops, events, int(work[RF_READ]) * DEPTH_BYTES

    def resolve(self) -> np.ndarray:
        """Resolve the last region; returns the first target's box-filtered image, the mean of each pixel's
        samples, (H, W, channels) float32 (the ROP's own image, not a copy: a frame's image can be
        gigabytes). Every target's images are then in ``images``, its kept samples in ``sample_data``."""
        self._resolve_region()
        return self.image

    def sample_data(self) -> dict[str, np.ndarray]:
        """After ``resolve``: the per-sample data of each target resolved "none", (H, W, spp, channels)."""
        out = {}
        for j, t in enumerate(self.targets):
            if t.resolve == "none":
                buf = self.buffers[j] if self.one_region else self.frame_samples[t.name]
                out[t.name] = buf.reshape(self.height, self.width, self.spp, -1)
        return out

    def depth_samples(self) -> np.ndarray | None:
        """The frame's per-sample depth, (H, W, spp), after ``resolve``; None
        when the frame spans several regions and ``keep_depth`` was off."""
        d = self.depth if self.one_region else self.frame_depth
        return None if d is None else d.reshape(self.height, self.width, self.spp)
