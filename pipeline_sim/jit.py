"""Compiling (or loading from numba's cache) every kernel before a run.

All kernels use ``cache=True``: the first run on a machine compiles them
(tens of seconds), later runs load them from ``__pycache__`` in milliseconds.
``warm_up`` runs a tiny draw through every path of the pipeline so that the
cost shows up, timed, before the real run rather than inside it.
"""

from __future__ import annotations

import time

import numpy as np

_WARM = False


def warm_up() -> float:
    """Compile or load all kernels; return the seconds it took (0 if already warm)."""
    global _WARM
    if _WARM:
        return 0.0
    from pipeline_sim.config import load_arch
    from pipeline_sim.draw import draw_from_clip
    from pipeline_sim.pass_state import PassState
    from pipeline_sim.render import RenderPass, run_pass

    start = time.perf_counter()
    q = np.array([[[-0.5, -0.5, 0.2, 1.0], [0.6, -0.4, 0.3, 1.2], [0.0, 0.7, 0.1, 0.9]]])
    r = q + np.array([0.3, 0.1, 0.0, 0.0])
    lens = np.full((1, 3, 2), 0.05)
    draw = draw_from_clip(np.concatenate([q, q]), np.concatenate([r, q]), np.concatenate([lens, lens]),
                          np.concatenate([lens, lens]), width=16, height=16)
    for state in (PassState(), PassState(shading_mode="per_sample"), PassState(mode="conservative")):
        run_pass(RenderPass(draw=draw, arch=load_arch(), state=state, spp=4, seed=0))
    _WARM = True
    return time.perf_counter() - start
