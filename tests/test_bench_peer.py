"""The benchmark's accumulation-buffer peer (benchmarks/peer.py) renders what the project renders.

At one sample point (x, y, t, u, v), Mesa's llvmpipe drawing the project's own
draw must give the project's per-sample-shaded image, pixel for pixel but for
ties on an edge: an independent rasterizer checking the peer's vertex
motion, lens shift, sub-pixel offset and image orientation. Skipped without
moderngl (the optional ``bench`` dependency) or an EGL context.
"""

import dataclasses

import numpy as np
import pytest

pytest.importorskip("moderngl")

from benchmarks.convergence import scenes  # noqa: E402
from benchmarks.peer import open_peer  # noqa: E402
from pipeline_sim.config import load_arch  # noqa: E402
from pipeline_sim.render import run_pass, scene_pass  # noqa: E402


@pytest.fixture(scope="module")
def both():
    p = scene_pass(scenes(48, 27)["both"], load_arch())
    peer, why = open_peer(p)
    if peer is None:
        pytest.skip(why)
    yield p, peer
    peer.release()


@pytest.mark.parametrize("point", [(0.1, 0.8, 0.0, 0.7, -0.3), (0.9, 0.2, 0.9, -0.5, 0.6), (0.3, 0.6, 0.4, 0.0, 0.9)])
def test_peer_pass_is_the_projects_image_at_that_sample(both, point):
    p, peer = both
    x, y, t, u, v = point
    gl, _ = peer.render(np.array([point]))
    q = dataclasses.replace(p, spp=1, sample_table=np.array([[x, y, u, v, t]]),
                            state=p.state.replace(shading_mode="per_sample"))
    img = run_pass(q).image[..., :3].astype(np.float64)
    diff = np.abs(gl - img).max(axis=2)
    assert (diff > 1e-3).sum() <= 1
    assert img.std() > 0.05  # a scene, not an empty frame
