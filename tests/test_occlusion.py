"""Occlusion queries (Nilsson12 §3; docs/passes.md, docs/occlusion.md).

* The interval-based query (z-cull's boxes, ``Draw.query = "interval"``) never answers "occluded" when a
  dense sample-based query over the same samples counts a passing sample: a hypothesis property test over
  random moving, defocused occluders and proxies, tile sizes, z-cull boxes and depth functions.
* It does answer "occluded" for a proxy behind a screen-filling occluder and "visible" at once for one in
  front of it (closed form: one record, one comparison).
* The sample-based count against a float64 brute force: every sample's coverage and depth from the
  triangles' vertices at the sample's (t, u, v), with a sequential depth test.
* The ``occlusion`` workload end to end through ``pipeline-sim run``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from pipeline_sim.config import pass_settings
from pipeline_sim.draw import draw_from_clip
from pipeline_sim.errors import UserError
from pipeline_sim.render import RenderPass, run_pass
from runs import ran_file, refused_file

W, H = 16, 12


def quad(x0, y0, x1, y1, z0, z1=None):
    """Two triangles covering [x0, x1] x [y0, y1] (NDC, w = 1), depth z0 at x0 and z1 at x1."""
    z1 = z0 if z1 is None else z1
    a, b, c, d = (x0, y0, z0), (x1, y0, z1), (x1, y1, z1), (x0, y1, z0)
    return np.array([[(*a, 1), (*b, 1), (*c, 1)], [(*a, 1), (*c, 1), (*d, 1)]], float)


def draw_of(q, shift=(0.0, 0.0, 0.0), lens=0.0, query="samples", width=W, height=H):
    """A draw of clip triangles ``q`` moving by ``shift`` (x, y, z) over the shutter, with a lens shift of
    ``lens`` (clip units per unit lens coordinate) at every vertex."""
    n = len(q)
    r = q + np.array([*shift, 0.0])
    lx = np.full((n, 3, 2), lens)
    return dataclasses.replace(draw_from_clip(q, r, lx, lx.copy(), width=width, height=height), query=query)


def run(draws, overrides=(), spp=4, seed=0):
    return run_pass(RenderPass(draw=draws, spp=spp, seed=seed, zcull_refresh="ordered",
                               **pass_settings(["pass.depth_write=true", *overrides])))


# --------------------------------------------------------------------------- closed forms
def test_hidden_proxy_is_occluded_and_visible_proxy_answers_at_once():
    occluder = draw_of(quad(-1.2, -1.2, 1.2, 1.2, 0.1), shift=(0.1, 0.0, 0.0), lens=0.02)
    hidden = draw_of(quad(-0.5, -0.5, 0.5, 0.5, 0.6), shift=(0.2, 0.1, 0.0), lens=0.05, query="interval")
    front = draw_of(quad(-0.5, -0.5, 0.5, 0.5, -0.5), shift=(0.2, 0.1, 0.0), lens=0.05, query="interval")
    res = run([occluder, hidden, front], spp=8)
    assert res.interval_queries[1]["visible"] is False
    assert res.interval_queries[1]["tiles"] > 1  # every record of the hidden proxy was compared
    assert res.interval_queries[2] == {"visible": True, "tiles": 1, "box_comparisons": 1}
    # the interval draws render nothing: only the occluder's samples reach the ROP
    assert res.queries.tolist() == [W * H * 8, 0, 0]


def test_time_slices_against_a_moving_occluder():
    """An occluder spanning x in [-0.9, 0.2] moves by +0.9 over the shutter. A proxy at x in [-0.5, -0.1]
    standing still is uncovered once the occluder's left edge passes -0.1 (t > 8/9): samples pass there,
    and the query, whatever its time slices, must say visible (though every tile of it is hidden in the
    first slices). A proxy at x in [-0.4, 0.0] moving with the
    occluder stays behind it at every time: no sample passes; with one time slice its tiles' boxes hold
    the depths of the whole shutter (where the occluder has gone, the far plane), so the query cannot tell;
    with eight, each record meets only the slices of its own times and the answer is occluded."""
    width, height = 64, 32
    occluder = draw_of(quad(-0.9, -0.8, 0.2, 0.8, 0.1), shift=(0.9, 0.0, 0.0), width=width, height=height)
    still = quad(-0.5, -0.5, -0.1, 0.5, 0.6)
    moving = quad(-0.4, -0.5, 0.0, 0.5, 0.6)
    for q, shift, passes in ((still, (0.0, 0.0, 0.0), True), (moving, (0.9, 0.0, 0.0), False)):
        samples = run([occluder, draw_of(q, shift, width=width, height=height)], spp=16)
        assert (samples.queries[1] > 0) == passes
        answers = [run([occluder, draw_of(q, shift, query="interval", width=width, height=height)],
                       [f"zcull.time_slices={nt}", "zcull.lens_boxes=1"], spp=16).interval_queries[1]["visible"]
                   for nt in (1, 8)]
        assert answers == ([True, True] if passes else [True, False])


def test_interval_query_needs_zcull():
    proxy = draw_of(quad(-0.5, -0.5, 0.5, 0.5, 0.6), query="interval")
    for overrides in (["zcull.enabled=false"], ["pass.depth_test=greater"]):
        with pytest.raises(UserError, match="interval query, which needs z-cull"):
            run([proxy], overrides)
    with pytest.raises(UserError, match="query 'intervals' is not one of samples, interval"):
        run([dataclasses.replace(proxy, query="intervals")])


# --------------------------------------------------------------------------- never a false "occluded"
@st.composite
def occlusion_case(draw):
    """A moving, defocused, tilted occluder (a quad) and a moving, defocused proxy (a triangle) near its
    depth, with the tile size, z-cull boxes and depth function."""
    x0, x1 = sorted(draw(st.tuples(st.floats(-1.2, 0.3), st.floats(-0.3, 1.2))))
    y0, y1 = sorted(draw(st.tuples(st.floats(-1.2, 0.3), st.floats(-0.3, 1.2))))
    z0, z1 = draw(st.floats(-0.2, 0.5)), draw(st.floats(-0.2, 0.5))
    occluder = (quad(x0, y0, max(x1, x0 + 0.2), max(y1, y0 + 0.2), z0, z1),
                draw(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.1, 0.1))),
                draw(st.floats(0.0, 0.1)))
    # mostly behind the occluder and within its reach: near its edges the answer is close
    cx, cy = x0 + (x1 - x0) * draw(st.floats(0.0, 1.0)), y0 + (y1 - y0) * draw(st.floats(0.0, 1.0))
    verts = [(cx + draw(st.floats(-0.3, 0.3)), cy + draw(st.floats(-0.3, 0.3)),
              draw(st.floats(max(z0, z1) - 0.1, 0.95)), 1.0) for _ in range(3)]
    proxy = (np.array([verts], float),
             draw(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.1, 0.1))),
             draw(st.floats(0.0, 0.1)))
    config = [f"tile_traverser.tile_size={draw(st.sampled_from([1, 2, 4, 8]))}",
              f"zcull.time_slices={draw(st.sampled_from([1, 2, 4, 8]))}",
              f"zcull.lens_boxes={draw(st.sampled_from([1, 2, 4]))}",
              f"pass.depth_test={draw(st.sampled_from(['less', 'lequal']))}"]
    return occluder, proxy, config, draw(st.integers(0, 3))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(occlusion_case())
def test_interval_query_never_occludes_what_a_dense_sample_query_sees(case):
    (oq, oshift, olens), (pq, pshift, plens), config, seed = case
    occluder = draw_of(oq, oshift, olens)
    dense = dict(overrides=config, spp=64, seed=seed)
    interval = run([occluder, draw_of(pq, pshift, plens, "interval")], **dense)
    samples = run([occluder, draw_of(pq, pshift, plens)], **dense)
    answer = interval.interval_queries[1]
    event("occluded" if not answer["visible"] else "visible, samples pass" if samples.queries[1] else
          "visible, no sample passes")
    assert answer["visible"] or samples.queries[1] == 0, (
        f"interval query answered occluded after {answer['tiles']} tiles, but {samples.queries[1]} samples pass")


# --------------------------------------------------------------------------- sample count vs brute force
def brute_force_passing(draws, samples, spp):
    """Per draw, its samples passing a LESS depth test with depth writes, draws and triangles in order: each
    sample's position from the triangles' vertices at its (t, u, v) (w = 1: affine), coverage by signed
    areas, depth by barycentric interpolation, in float64."""
    n = W * H * spp
    k = np.arange(n)
    pix = k // spp
    xs = (pix % W) + samples.x.astype(np.float64)
    ys = (pix // W) + samples.y.astype(np.float64)
    x_ndc, y_ndc = 2.0 * xs / W - 1.0, 1.0 - 2.0 * ys / H
    t, u, v = (getattr(samples, a).astype(np.float64) for a in ("t", "u", "v"))
    depth = np.ones(n)
    passed = []
    for d in draws:
        count = 0
        for i in range(d.n):
            # the vertices at each sample's (t, u, v): (n, 3, 4)
            p = (1.0 - t)[:, None, None] * d.q[i] + t[:, None, None] * d.r[i]
            p[..., 0] += u[:, None] * ((1.0 - t)[:, None] * d.lens_x[i, :, 0] + t[:, None] * d.lens_x[i, :, 1])
            p[..., 1] += v[:, None] * ((1.0 - t)[:, None] * d.lens_y[i, :, 0] + t[:, None] * d.lens_y[i, :, 1])
            a, b, c = p[:, 0], p[:, 1], p[:, 2]

            def edge(e0, e1):
                return (e1[:, 0] - e0[:, 0]) * (y_ndc - e0[:, 1]) - (e1[:, 1] - e0[:, 1]) * (x_ndc - e0[:, 0])

            w0, w1, w2 = edge(b, c), edge(c, a), edge(a, b)
            area = w0 + w1 + w2
            inside = (np.sign(w0) == np.sign(area)) & (np.sign(w1) == np.sign(area)) & \
                     (np.sign(w2) == np.sign(area)) & (area != 0)
            z = (w0 * a[:, 2] + w1 * b[:, 2] + w2 * c[:, 2]) / np.where(area != 0, area, 1.0)
            ok = inside & (z < depth)
            depth[ok] = z[ok]
            count += int(ok.sum())
        passed.append(count)
    return passed


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sample_query_counts_against_brute_force(seed):
    """An occluder tilted in depth and moving, then a proxy of two triangles at separate depths behind and
    partly beside it, moving and defocused: the pipeline's per-draw counts equal the brute force's."""
    rng = np.random.default_rng(seed)
    occluder = draw_of(quad(-0.6, -0.7, 0.4, 0.5, 0.05, 0.25), shift=(0.3, 0.1, 0.0), lens=0.03)
    near = [(*rng.uniform(-0.9, 0.9, 2), rng.uniform(0.4, 0.5), 1.0) for _ in range(3)]
    far = [(*rng.uniform(-0.9, 0.9, 2), rng.uniform(0.6, 0.8), 1.0) for _ in range(3)]
    proxy = draw_of(np.array([near, far], float), shift=(-0.2, 0.15, 0.0), lens=0.06)
    spp = 16
    res = run([occluder, proxy], spp=spp, seed=seed)
    want = brute_force_passing([occluder, proxy], res.samples, spp)
    assert res.queries.tolist() == want and 0 < want[1]


# --------------------------------------------------------------------------- the workload end to end
SMALL = """kind = "occlusion"
width = 32
height = 24
spp = 8
proxies = 8
tile_sizes = [4, 8]
time_slices = [1, 4]
lens_boxes = [1, 2]
"""


def test_occlusion_workload_end_to_end(tmp_path):
    out, results = ran_file(tmp_path, SMALL)
    queries = results["queries"]
    assert len(queries) == 8 and results["wrongly_occluded"] == 0
    for q in queries:
        assert q["samples"]["visible"] == (q["samples"]["passed"] > 0)
        assert q["interval"]["visible"] or not q["samples"]["visible"]
        assert q["interval"]["box_comparisons"] >= q["interval"]["tiles"] >= int(q["interval"]["visible"])
    assert results["truly_occluded"] == sum(not q["samples"]["visible"] for q in queries)
    import pandas as pd

    table = pd.read_csv(out / "occlusion_rate.csv")
    # the architecture's own configuration (tile 4, 4 slices, 2 lens boxes, one of the 8 swept) first
    configs = list(zip(table.tile_size, table.time_slices, table.lens_boxes))
    assert configs[0] == (4, 4, 2) and sorted(configs) == [(a, b, c) for a in (4, 8) for b in (1, 4) for c in (1, 2)]
    assert (table.boxes_per_tile == table.time_slices * table.lens_boxes ** 2).all()
    assert (table.wrongly_occluded == 0).all()
    assert (table.answered_occluded <= table.truly_occluded).all()
    assert sorted((out / "passes").iterdir())[0].name == "interval_ts4_t1_l1"


@pytest.mark.parametrize("text,message", [
    ("tile_size = [4]", "unknown key 'tile_size' (did you mean 'tile_sizes'?)"),
    ("tile_sizes = [3]", "tile_size"),
    ("time_slices = [64]\nlens_boxes = [4]", "at most 255"),
])
def test_occlusion_workload_bad_input_is_one_line(tmp_path, capsys, text, message):
    assert message in refused_file(tmp_path, capsys, "occlusion", text)


def test_cost_sweep_runs_a_tiny_version(root, tmp_path):
    """workloads/sweeps/occlusion_cost.toml on a tiny scene, narrowed to two points: each point's
    architecture and table have its configuration, its results are that configuration's row."""
    import pandas as pd

    from pipeline_sim.sweep import load_sweep, run_sweep

    shipped = (root / "workloads/sweeps/occlusion_cost.toml").read_text()
    text = (shipped.replace('"../apps/occlusion/occlusion.toml"', '"occlusion.toml"')
            .replace("= [4, 8, 16]", "= [8]").replace("= [[4], [8], [16]]", "= [[8]]")
            .replace("= [1, 4, 8]", "= [1, 4]").replace("= [[1], [4], [8]]", "= [[1], [4]]")
            .replace("= [1, 2]", "= [1]").replace("= [[1], [2]]", "= [[1]]"))
    (tmp_path / "occlusion.toml").write_text('kind = "occlusion"\nwidth = 16\nheight = 16\nspp = 1\nproxies = 3\n')
    (tmp_path / "sweep.toml").write_text(text)
    frame = run_sweep(load_sweep(tmp_path / "sweep.toml"), tmp_path / "out", executor="serial", progress=False)
    assert (frame.status == "ok").all() and len(frame) == 2
    points = pd.read_csv(tmp_path / "out" / "points.csv")
    for _, row in points.iterrows():
        table = pd.read_csv(tmp_path / "out" / "points" / row.point_id / "occlusion_rate.csv")
        assert len(table) == 1 and table.time_slices[0] == row["zcull.time_slices"]
        assert row["result.interval_cycles"] == table.frame_cycles[0]
        assert row["result.mean_box_comparisons"] == table.mean_box_comparisons[0]
        assert row["result.wrongly_occluded"] == 0
