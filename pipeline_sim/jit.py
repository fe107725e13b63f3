"""Compiling (or loading from numba's cache) every kernel before a run, on two cores when the cache is cold.

All kernels use ``cache=True``: the first run on a machine compiles them
(tens of seconds), later runs load them from ``__pycache__`` (or
``NUMBA_CACHE_DIR``) in milliseconds. ``warm_up`` runs a tiny draw through
every path of the pipeline (``warm_pass``) so that the cost shows up, timed,
before the real run rather than inside it.

numba compiles one kernel at a time in a process, so on a cold cache
``warm_up`` splits the work in two groups of units of about equal compile
time: ``WORKER_UNITS`` (the sample tester, whose kernel is the largest, and
z-cull's refresh) are compiled by a worker process into the on-disk cache while this
process compiles ``PARENT_UNITS``; once the worker has exited, ``warm_pass``
loads its kernels from the cache. Each unit's warmer (``warm_units``) calls
the unit's own ``run`` on a tiny synthetic batch built from the record
declarations (``pipeline_sim.records``), so that every kernel gets the
argument types of a real pass (a mismatch would compile a second
specialization in ``warm_pass``: ``tests/test_jit.py`` checks there is none).

The worker starts at the first real compile (numba's ``numba:compile`` event
fires on a cache miss only), so a cached ``warm_up`` starts no process. This
process never starts a kernel of the worker's group before the worker is done,
so no kernel is compiled twice. The worker is an optimization only: if it
cannot start or fails, ``warm_pass`` compiles what is missing here; it exits
with this process (it watches its stdin) and is killed if ``warm_up`` is
interrupted.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from numba.core import event

_WARM = False

#: the kernels the worker process compiles on a cold cache, by unit (``WARMERS``): the sample tester's and
#: z-cull's refresh, about half the compile time (measured: 15.7 of 32 s) once its start is counted
WORKER_UNITS = ("sample_tester", "zcull_refresh")
#: seconds ``warm_up`` waits for the worker at most (it takes tens of seconds; a hung one is killed and
#: its kernels compiled here)
WORKER_TIMEOUT_S = 900.0
#: the units this process compiles meanwhile
PARENT_UNITS = ("sampling", "triangle_setup", "tile_traverser", "tile_test", "zcull", "shading", "rop")
# what a worker runs: the worker group's warmers, imported from the directory given as its argument
_WORKER_CODE = "import sys; sys.path.insert(0, sys.argv[1]); from pipeline_sim.jit import worker_main; worker_main()"


def warm_up() -> float:
    """Compile or load all kernels; return the seconds it took (0 if already warm)."""
    global _WARM
    if _WARM:
        return 0.0
    start = time.perf_counter()
    worker = Worker()
    try:
        with worker.starting_on_compile():
            warm_units(PARENT_UNITS, tolerant=True)
        worker.wait(WORKER_TIMEOUT_S)
    finally:
        worker.stop()
    warm_pass()
    _WARM = True
    return time.perf_counter() - start


def warm_pass() -> None:
    """A tiny draw through every path of the pipeline: the default pass, per-sample shading and
    conservative mode."""
    from pipeline_sim.config import load_arch
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.render import RenderPass, run_pass

    for state in (PassState(), PassState(shading_mode="per_sample"), PassState(mode="conservative")):
        run_pass(RenderPass(draw=_tiny_draw(), arch=load_arch(), state=state, spp=4, seed=0))


def _tiny_draw():
    """Two triangles, one moving and defocused, 16 x 16 pixels."""
    from pipeline_sim.draw import draw_from_clip

    q = np.array([[[-0.5, -0.5, 0.2, 1.0], [0.6, -0.4, 0.3, 1.2], [0.0, 0.7, 0.1, 0.9]]])
    r = q + np.array([0.3, 0.1, 0.0, 0.0])
    lens = np.full((1, 3, 2), 0.05)
    return draw_from_clip(np.concatenate([q, q]), np.concatenate([r, q]), np.concatenate([lens, lens]),
                          np.concatenate([lens, lens]), width=16, height=16)


class Worker:
    """The process that compiles ``WORKER_UNITS`` into numba's cache, started at most once."""

    def __init__(self) -> None:
        self.process: subprocess.Popen | None = None
        self._started = False

    def start(self) -> None:
        """Start the worker (once; a failure to start leaves none)."""
        if self._started:
            return
        self._started = True
        try:
            self.process = subprocess.Popen(worker_command(), env=worker_env(), stdin=subprocess.PIPE,
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        except (OSError, ValueError, TypeError):  # (TypeError: no sys.executable)
            self.process = None

    def starting_on_compile(self) -> Any:
        """A context in which numba's first real compile (not a cache load) starts the worker."""
        worker = self

        class _Listener(event.Listener):
            def on_start(self, ev: event.Event) -> None:
                worker.start()

            def on_end(self, ev: event.Event) -> None:
                pass

        return event.install_listener("numba:compile", _Listener())

    def wait(self, timeout: float) -> None:
        """Wait for the worker to exit, at most ``timeout`` seconds (whether it succeeded does not matter:
        what it did not compile, ``warm_pass`` compiles; ``stop`` kills a worker still running)."""
        if self.process is not None:
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                pass

    def stop(self) -> None:
        """Kill the worker if it still runs, and close its stdin."""
        p = self.process
        if p is not None:
            if p.poll() is None:
                p.kill()
                p.wait()
            if p.stdin is not None:
                p.stdin.close()


def worker_command() -> list[str]:
    """The worker's command line: this interpreter, running ``worker_main`` of this very package (numba's
    cache is keyed by each kernel's source file): the directory holding ``pipeline_sim`` and ``units`` goes
    first on its path, before its working directory."""
    return [sys.executable, "-c", _WORKER_CODE, str(Path(__file__).resolve().parent.parent)]


def worker_env() -> dict[str, str]:
    """This process's environment, with numba's cache directory as set here."""
    import numba

    env = dict(os.environ)
    if numba.config.CACHE_DIR:
        env["NUMBA_CACHE_DIR"] = numba.config.CACHE_DIR
    return env


def worker_main() -> None:
    """The worker: compile ``WORKER_UNITS`` into the cache; exit at once if the parent goes away."""
    threading.Thread(target=_exit_at_eof, daemon=True).start()
    warm_units(WORKER_UNITS)


def _exit_at_eof() -> None:
    """Read stdin to its end (the parent never writes: its end closes when it exits), then exit. (Raw reads:
    a daemon thread blocked in a buffered read would abort the interpreter's shutdown.)"""
    while os.read(0, 4096):
        pass
    os._exit(1)


@dataclass
class _Tiny:
    """What the warmers share: the shipped architecture, a default pass state, the tiny draw, its
    triangle setup (whose table is zeros until it runs) and synthetic samples of one tile."""

    arch: Any
    state: Any
    draw: Any
    setup: Any
    samples: Any
    algorithm: Any

    @property
    def tile_size(self) -> int:
        return self.arch.tile_traverser.tile_size

    def tiles(self) -> dict[str, np.ndarray]:
        """One tile record as z-cull and the sample tester take it (with the culling algorithm's fields)."""
        from pipeline_sim.records import TILE

        return {**TILE.allocate(1), **self.algorithm.TILE_EXT.allocate(1)}


def _tiny() -> _Tiny:
    from pipeline_sim.config import load_arch
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.sampling import SampleSet
    from units import culling
    from units.triangle_setup import TriangleSetup

    arch = load_arch()
    state = PassState()
    draw = _tiny_draw()
    algorithm = culling.algorithm(arch.tile_test.algorithm)
    ts = arch.tile_traverser.tile_size
    setup = TriangleSetup(arch.triangle_setup, draw, ts, state.backface_culling, culling=algorithm,
                          shading_view=state.shading_view)
    spp = 4
    n = ts * ts * spp
    x, y, u, v, t = (np.zeros(n, np.float32) for _ in range(5))
    samples = SampleSet(x=x, y=y, u=u, v=v, t=t, spp=spp, width=ts, height=ts, lens=True, motion=True)
    return _Tiny(arch, state, draw, setup, samples, algorithm)


def _warm_sampling(w: _Tiny) -> None:
    from pipeline_sim.sampling import make_samples

    make_samples(w.draw.width, w.draw.height, 4, 0, lens=True, motion=True, pattern=w.state.sample_pattern,
                 rows=(0, w.draw.height))


def _warm_triangle_setup(w: _Tiny) -> None:
    w.setup.run(np.arange(w.draw.n, dtype=np.int64))


def _warm_tile_traverser(w: _Tiny) -> None:
    from units.tile_traverser import TileTraverser

    TileTraverser(w.arch.tile_traverser, w.setup.table, w.tile_size, w.draw.width, w.draw.height,
                  coarse_test=w.algorithm.COARSE_TEST).run(np.zeros(1, np.int64), (0, w.draw.height))


def _warm_tile_test(w: _Tiny) -> None:
    from pipeline_sim.records import TILE_IDS
    from units.tile_test import TileTest

    TileTest(w.arch.tile_test, w.setup.table, w.tile_size, w.draw.width, w.draw.height, w.draw.depth_w,
             w.state.clip.as_array(), tuples=None, extension=w.setup.extension).run(TILE_IDS.allocate(1))


def _zcull(w: _Tiny):
    from units.zcull import ZCull

    return ZCull(w.arch.zcull, w.state.depth_test, w.tile_size, w.tile_size, w.tile_size, 1.0)


def _warm_zcull(w: _Tiny) -> None:
    _zcull(w).run(w.tiles())


def _warm_zcull_refresh(w: _Tiny) -> None:
    from pipeline_sim.records import SAMPLE

    s = w.samples
    batch = SAMPLE.allocate(1)  # the ROP refreshes z-cull with the pixels and samples of its batch
    _zcull(w).refresh(batch["pix"], batch["sidx"], np.empty(1, np.float32), s, np.ones(len(s), np.float32))


def _warm_sample_tester(w: _Tiny) -> None:
    from units.sample_tester import SampleTester

    tester = SampleTester(w.arch.sample_tester, w.setup.table, w.samples, w.tile_size, w.state.backface_culling,
                          w.arch.pipeline.specialize)
    tester.run(w.tiles())


def _warm_shading(w: _Tiny) -> None:
    from pipeline_sim.records import SAMPLE, TILE, TRIANGLE
    from pipeline_sim.shaders import standard_shader
    from units.shading_cache import Shading

    # triangle 0 in front of the reference camera, and two samples at its vertex 0: the first misses the
    # cache, the second hits the entry it fills, so that the cache's requests are some of its rows (a
    # view of its request arrays, as in most batches of a real pass; all of them: per-sample shading)
    table = TRIANGLE.table(1)
    table.ref[0] = ((0.0, 0.0, 1.0), (1.0, 0.0, 1.0), (0.0, 1.0, 1.0))  # (X, Y, W) of each vertex
    batch = SAMPLE.allocate(2)
    batch["b0"][:] = 1.0
    for mode, conservative in (("cache", False), ("per_sample", False), ("cache", True)):
        shading = Shading(w.arch.shading, mode, w.state.shading_rate, w.draw, table, w.samples,
                          standard_shader, np.zeros(8, np.float32), (), conservative, 4,
                          shading_view=w.state.shading_view)
        shading.run(TILE.allocate(1) if conservative else batch)


def _warm_rop(w: _Tiny) -> None:
    from pipeline_sim.draw import merge_draws
    from pipeline_sim.records import FRAGMENT
    from units.rop import Rop

    _, tri_draw = merge_draws([w.draw], "warm-up")
    rop = Rop(w.arch.rop, w.state, w.draw.width, w.draw.height, w.samples.spp, (0.0, 0.0, 0.0, 1.0), 1.0,
              keep_depth=False, tri_draw=tri_draw)
    rop.run(FRAGMENT.allocate(1))
    rop.resolve()


#: each unit's warmer
WARMERS: dict[str, Callable[[_Tiny], None]] = {
    "sampling": _warm_sampling, "triangle_setup": _warm_triangle_setup, "tile_traverser": _warm_tile_traverser,
    "tile_test": _warm_tile_test, "zcull": _warm_zcull, "zcull_refresh": _warm_zcull_refresh,
    "sample_tester": _warm_sample_tester,
    "shading": _warm_shading, "rop": _warm_rop,
}


def warm_units(units: tuple[str, ...], tolerant: bool = False) -> None:
    """Compile (or load) the kernels of ``units`` (keys of ``WARMERS``) with the argument types of a real pass.
    ``tolerant``: a warmer that fails leaves the others to run (warming is an optimization only: ``warm_pass``
    compiles whatever is still missing)."""
    w = _tiny()
    for unit in units:
        try:
            WARMERS[unit](w)
        except Exception:  # noqa: BLE001
            if not tolerant:
                raise
