"""The Python API: run render passes through the simulated pipeline.

    from pipeline_sim import load_scene, load_arch, render_scene
    result = render_scene(load_scene("workloads/scenes/default.toml"), load_arch())
    result.image        # (H, W, 4) float32 linear RGBA, row 0 at the top
    result.counters     # tidy DataFrame: unit, counter, value
    result.timing.units # busy / starved / blocked cycles per unit

A workload with several passes builds ``RenderPass`` objects itself: each
has one or several draws (each with its own clip planes and occlusion query),
render targets with their blends and resolves, shader outputs, an append
buffer, and textures, which may name an earlier pass's images, per-sample
data or depth (``run_passes``; ``pipeline_sim.targets``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd

from pipeline_sim.config import ArchConfig
from pipeline_sim.counters import CounterSet, counters_frame
from pipeline_sim.draw import QUERY_MODES, Draw, build_draw, merge_draws
from pipeline_sim.errors import UserError
from pipeline_sim.pass_state import PassState
from pipeline_sim.pipeline import Stage, TimingResult, chunks, count_records, cycles_for, run_in_order, simulate
from pipeline_sim.regions import (RegionBatch, RegionCursor, RegionPlan, RegionSamples, bin_triangles, plan_regions,
                                  region_step, row_step)
from pipeline_sim.sampling import make_samples
from pipeline_sim.shaders import standard_params, standard_shader
from pipeline_sim.simulation import SimOptions
from pipeline_sim.targets import AppendBuffer, AppendResult, ShaderOutput, Target, check_targets
from units import culling
from units.rop import Rop
from units.sample_tester import (EV_2D, EV_PIXELS, TEST_OPS_MADD, TEST_OPS_MUL, SampleTester,
                                 TileMajorLayouts)
from units.shading_cache import MAX_CACHED_TRIANGLES, Shading
from units.tile_test import TileTest
from units.tile_traverser import TileTraverser
from units.triangle_setup import TriangleSetup
from units.zcull import ZCull

#: When z-cull sees the ROP's refreshes (``RenderPass.zcull_refresh``): "timed", at the simulated
#: time the ROP takes each batch, as hardware would (what z-cull culls then moves with queue depths,
#: throughputs and batch sizes); "ordered", in submission order: each triangle batch goes through
#: every unit before the next, and z-cull sees the refreshes of every earlier triangle batch and
#: none of its own, so no counter depends on timing (docs/pipeline.md §4).
ZCULL_REFRESH = ("timed", "ordered")

UNIT_ORDER = ("triangle_setup", "tile_traverser", "tile_test", "zcull", "sample_tester", "shading", "rop")
# what each unit's input channel carries
INPUT_KIND = {"triangle_setup": "triangles", "tile_traverser": "triangles", "tile_test": "tiles", "zcull": "tiles",
              "sample_tester": "tiles", "shading": "samples", "rop": "samples"}

# sample-tester work per test of each dimension (2D, xyt, xyuv, xyuvt), relative to a 5D test
TEST_WEIGHTS = np.array([(a + m) / (TEST_OPS_MADD[3] + TEST_OPS_MUL[3]) for a, m in zip(TEST_OPS_MADD, TEST_OPS_MUL)])

# bytes moved per record, for the memory-traffic counters
SETUP_BYTES_IN = 3 * 2 * (16 + 8)  # three vertices, two times, clip xyzw + lens shift
SETUP_BYTES_OUT = 3 * 4 * 4 * 2 + 3 * 2 * 4 * 2 + 64
TILE_RECORD_BYTES = 12
INTERVAL_BYTES = 32
SAMPLE_RECORD_BYTES = 28


@dataclass
class RenderPass:
    """One pass: its draws, the architecture, its state, sampling, the shader to run, the targets it writes
    and the simulation options.

    ``draw``: one draw or several, run in submission order, each with its own clip planes
    (``Draw.clip``) and query; ``outputs``: the shader's named outputs; ``targets``: the render targets
    (None: one RGBA target cleared to ``clear_color``, the state's blend, box resolve); ``append``: an
    append buffer the shader may write; ``textures``: arrays (H, W, layers) or names of an earlier
    pass's results (``run_passes``), handed to the shader as a tuple in this order.
    """

    draw: Draw | Sequence[Draw]
    arch: ArchConfig
    spp: int
    state: PassState = field(default_factory=PassState)
    seed: int = 0
    name: str = "main"
    shader: Callable = standard_shader
    params: np.ndarray = field(default_factory=lambda: np.zeros(8, np.float32))
    textures: tuple[np.ndarray | str, ...] = ()
    outputs: tuple[ShaderOutput, ...] = (ShaderOutput(),)
    targets: tuple[Target, ...] | None = None
    append: AppendBuffer | None = None
    clear_color: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    clear_depth: float = 1.0
    sample_table: np.ndarray | None = None  # given: the pass samples it (pattern "table")
    # the table's (x, y, t) rotated per pixel (Cranley-Patterson; its (u, v) kept: a lens region keeps its samples)
    scramble_table: bool = False
    zcull_refresh: str = "timed"  # one of ZCULL_REFRESH
    simulation: SimOptions = field(default_factory=SimOptions)


@dataclass
class PassResult:
    """Image, counters and timing of one pass."""

    name: str
    image: np.ndarray
    counters: pd.DataFrame
    timing: TimingResult
    wall_time: float
    dimensions: dict[str, bool]
    units_used: list[str]
    depth: np.ndarray | None  # (H, W, spp); None over several regions unless kept
    samples: Any  # the SampleSet of a one-region frame, else None
    regions: RegionPlan | None = None
    region_samples_made: int = 1  # sample sets generated (a region dropped and needed again counts twice)
    # per target: its images (box: one; lens: one per view; none: none)
    images: dict[str, list[np.ndarray]] = field(default_factory=dict)
    sample_data: dict[str, np.ndarray] = field(default_factory=dict)  # per target resolved "none": (H, W, spp, C)
    append: AppendResult | None = None
    queries: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # per draw: samples passing depth
    # per draw asking an interval query (Draw.query): its answer and work (units.zcull.ZCull.query_answer)
    interval_queries: dict[int, dict[str, bool | int]] = field(default_factory=dict)

    def counter(self, unit: str, name: str) -> int:
        c = self.counters
        v = c[(c.unit == unit) & (c.counter == name)].value
        return int(v.iloc[0]) if len(v) else 0

    @property
    def region_info(self) -> dict[str, int]:
        """How the frame was cut into screen regions (for run.json and summaries)."""
        plan = self.regions
        return {"count": plan.count if plan else 1, "rows": plan.rows if plan else 0,
                "sample_sets_made": self.region_samples_made}

    @property
    def ste(self) -> float:
        """Sample test efficiency: covered / tested samples (Wu13 §1.1)."""
        tested = self.counter("sample_tester", "samples_tested")
        return self.counter("sample_tester", "samples_covered") / tested if tested else float("nan")


def run_pass(p: RenderPass, *, textures: dict[str, np.ndarray] | None = None,
             progress: Callable[[int, int], None] | None = None, keep_depth: bool = False) -> PassResult:
    """Simulate one pass and return its image, counters and timing.

    A frame of more than ``simulation.region_samples`` samples is rendered in
    screen regions (``pipeline_sim.regions``); then its per-sample depth is
    kept only with ``keep_depth``.
    """
    start = time.perf_counter()
    arch = p.arch
    state = p.state
    where = f"pass {p.name}"
    draws = [p.draw] if isinstance(p.draw, Draw) else list(p.draw)
    draw, tri_draw = merge_draws(draws, where)
    # each draw's clip planes (Nilsson12 §2), set on the tile test per batch: a batch holds one draw's triangles
    planes = [d.clip or state.clip for d in draws]
    clips = [c.as_array() for c in planes]
    check_targets(where, p.targets or (Target(),), p.outputs, len(draws), p.append)
    conservative = state.conservative
    ts = 1 if conservative else arch.tile_traverser.tile_size
    # a pass samples time (the lens) when a draw moves (is defocused) or clips it: a static prism cut by clip
    # planes in t is a volume of xyt (Nilsson12 §5)
    motion = draw.has_motion or any(c.cuts_time for c in planes)
    lens = draw.has_lens or any(c.cuts_lens for c in planes)
    shader_textures = _pass_textures(p, textures or {})
    append = None if p.append is None else (np.zeros((p.append.capacity, len(p.append.fields)), np.float32),
                                            np.zeros(1, np.int64))
    if p.zcull_refresh not in ZCULL_REFRESH:
        raise UserError(f"pass {p.name}: zcull_refresh '{p.zcull_refresh}' is not one of {', '.join(ZCULL_REFRESH)}")
    ordered = p.zcull_refresh == "ordered"
    spp = 1 if conservative else p.spp
    pattern = "table" if p.sample_table is not None else state.sample_pattern

    def made(rows: tuple[int, int]):
        return make_samples(draw.width, draw.height, spp, p.seed, lens=lens, motion=motion, pattern=pattern,
                            table=p.sample_table, scramble_table=p.scramble_table,
                            interleave_tuples=state.interleave_tuples, rows=rows)

    cached_shading = state.shading_mode == "cache" and not conservative
    step = row_step(ts, arch.tile_traverser.coarse_factor, state.shading_rate if cached_shading else None)
    plan = plan_regions(draw.width, draw.height, spp, p.simulation.region_samples, step)
    # a region's samples are made when a unit first needs them (a region with triangles may get no batch:
    # the default scene's top one), and each next region's while the one before runs, with the sample
    # tester's layout of them and z-cull's grouping of them by box for the ROP's refreshes (a conservative
    # pass tests no samples; a set the tester asks for is laid out with it, on both cores, before the next
    # one is started; one another unit asked for first is laid out by the tester on its first batch there;
    # a set not made ahead is grouped by the ROP's refreshes, tile by tile); the pattern's shared (u, v, t)
    # tuples (Interleave UVT) and the check of a sample table come with a set of no rows
    layouts = TileMajorLayouts(ts)

    def prepare(s, waited_for: bool = False):
        s = layouts.prepare(s, waited_for)
        return zcull.groups.prepare(s) if zcull.active and not waited_for else s

    samples = RegionSamples(plan, made, prepare=None if conservative else prepare)
    tuples = made((0, 0)).tuples
    algorithm = culling.algorithm(arch.tile_test.algorithm)
    if algorithm.NEEDS_TUPLES and tuples is None:
        raise UserError(f"pass {p.name}: tile_test.algorithm = '{algorithm.NAME}' needs the 'interleave' sample "
                        f"pattern, not '{pattern}'")

    setup = TriangleSetup(arch.triangle_setup, draw, ts, state.backface_culling, culling=algorithm,
                          shading_view=state.shading_view, keep_degenerate=conservative)
    # the hierarchical tests of Munkberg11 start at coarse tiles; the others cover
    # their bounding geometry flat, as Wu13 does
    traverser = TileTraverser(arch.tile_traverser, setup.table, ts, draw.width, draw.height,
                              coarse_test=algorithm.COARSE_TEST)
    tile_test = TileTest(arch.tile_test, setup.table, ts, draw.width, draw.height, draw.depth_w,
                         clips[0], tuples=tuples, extension=setup.extension,
                         exact_time=conservative and state.time_intervals == "exact")
    spec = arch.pipeline.specialize
    zcull = ZCull(arch.zcull, state.depth_test, ts, draw.width, draw.height, p.clear_depth,
                  motion or not spec, lens or not spec)
    if conservative:
        zcull.active = False
    interval = [i for i, d in enumerate(draws) if d.query != "samples"]
    for i in interval:
        if draws[i].query not in QUERY_MODES:
            raise UserError(f"{where}: draw {i}: query '{draws[i].query}' is not one of {', '.join(QUERY_MODES)}")
        if not zcull.active:
            raise UserError(f"{where}: draw {i} asks an interval query, which needs z-cull: zcull.enabled, "
                            "depth test less or lequal, standard mode")
    tester = SampleTester(arch.sample_tester, setup.table, None, ts, state.backface_culling, spec, layouts)
    if cached_shading and draw.n > MAX_CACHED_TRIANGLES:
        raise UserError(f"{where}: the shading cache keys at most {MAX_CACHED_TRIANGLES:,} triangles and the pass "
                        f"draws {draw.n:,}: set pass.shading_mode = \"per_sample\"")
    shading = Shading(arch.shading, state.shading_mode, state.shading_rate, draw, setup.table, None, p.shader,
                      p.params, shader_textures, conservative, sum(o.channels for o in p.outputs), append,
                      shading_view=state.shading_view)
    # the ROP reads a region's samples to refresh z-cull and for lens resolves (which need the first
    # region's even when no batch reaches it)
    lens_resolve = any(t.resolve == "lens" for t in p.targets or ())
    rop_samples = zcull.active or lens_resolve
    rop = Rop(arch.rop, state, draw.width, draw.height, spp, p.clear_color, p.clear_depth,
              zcull if zcull.active else None, samples.region(0) if lens_resolve else None, rows=plan.bounds(0),
              keep_depth=keep_depth, targets=p.targets, outputs=p.outputs, tri_draw=tri_draw, n_draws=len(draws))
    # each unit that holds a region's samples or buffers is handed them as its batches move on: the
    # sample tester, shading and the ROP (which needs samples only to refresh z-cull and for lens
    # resolves, and starts with region 0's buffers) take a region's samples with its first batch
    tester_at = RegionCursor(lambda r: tester.use_samples(samples.region(r, prepared=True)))
    shading_at = RegionCursor(lambda r: shading.use_samples(samples.region(r)))
    rop_at = RegionCursor(lambda r: rop.open_region(plan.bounds(r), samples.region(r) if rop_samples else None))
    cs = {u.name: CounterSet(u.name, u.events, u.timing_dependent)
          for u in (setup, traverser, tile_test, zcull, tester, shading, rop)}
    pcfg, sim = arch.pipeline, p.simulation
    done = [0]
    set_up = np.zeros(draw.n, np.bool_)  # per triangle: set up (in an earlier region's batch or this one)
    presetup = plan.count > 1  # several regions: triangles are set up before binning
    kept = np.zeros(draw.n, np.bool_)  # and survived setup

    def step_setup(batch: RegionBatch):
        # a triangle is set up once, in the first region it reaches; later
        # regions fetch its setup results from the bin at no cost
        ids = batch.records
        new = ids[~set_up[ids]]
        if len(new):
            set_up[new] = True
            c = cs["triangle_setup"]
            if presetup:  # set up before binning: its arithmetic and events are counted there
                n_out = int(kept[new].sum())
            else:
                out, ops, ev = setup.run(new)
                kept[out] = True
                n_out = len(out)
                c.add_ops(ops), c.add_events(ev)
            count_records(c, len(new), n_out)
            c.add("bytes_read", len(new) * SETUP_BYTES_IN)
            c.add("bytes_written", n_out * SETUP_BYTES_OUT)
            done[0] += len(new)
            if progress is not None:
                progress(done[0], draw.n)
        survivors = ids[kept[ids]]
        cfg = arch.triangle_setup
        return ([RegionBatch(batch.region, survivors)] if len(survivors) else []), cycles_for(
            len(new), cfg.throughput, cfg.instances)

    def step_traverse(batch: RegionBatch):
        ids = batch.records
        out, ops, ev = traverser.run(ids, plan.bounds(batch.region))
        c = cs["tile_traverser"]
        n = len(out["tri"])
        c.add_ops(ops), c.add_events(ev), count_records(c, len(ids), n)
        c.add("bytes_written", n * TILE_RECORD_BYTES)
        cfg = arch.tile_traverser
        return ([RegionBatch(batch.region, part) for part in chunks(out, sim.tiles_per_batch)],
                cycles_for(ev[0] + n, cfg.throughput, cfg.instances))

    def step_tile_test(tiles):
        if len(tiles["tri"]):
            tile_test.clips = clips[tri_draw[tiles["tri"][0]]]
        out, ops, ev = tile_test.run(tiles)
        c = cs["tile_test"]
        n_in = len(tiles["tri"])
        c.add_ops(ops), c.add_events(ev), count_records(c, n_in, len(out["tri"]))
        c.add("bytes_read", n_in * TILE_RECORD_BYTES)
        c.add("bytes_written", len(out["tri"]) * (TILE_RECORD_BYTES + INTERVAL_BYTES))
        cfg = arch.tile_test
        return ([out] if len(out["tri"]) else []), cycles_for(n_in, cfg.throughput, cfg.instances)

    def step_zcull(tiles):
        d = int(tri_draw[tiles["tri"][0]]) if interval and len(tiles["tri"]) else -1
        out, ops, ev = zcull.run(tiles, d if d in interval else None)
        c = cs["zcull"]
        n_in = len(tiles["tri"])
        c.add_ops(ops), c.add_events(ev), count_records(c, n_in, len(out["tri"]))
        c.add("bytes_read", int(ev[2]) * 8)
        cfg = arch.zcull
        return ([out] if len(out["tri"]) else []), cycles_for(n_in, cfg.throughput, cfg.instances)

    def step_sample_test(tiles):
        out, ops, ev = tester.run(tiles)
        c = cs["sample_tester"]
        n = len(out["tri"])
        c.add_ops(ops), c.add_events(ev), count_records(c, len(tiles["tri"]), n)
        c.add("bytes_read", int(ev[2]) * 20)
        c.add("bytes_written", n * SAMPLE_RECORD_BYTES)
        cfg = arch.sample_tester
        # throughput counts 5D tests; a test of fewer dimensions takes its share
        # of a 5D test's arithmetic, a visited pixel one slot (its range lookup)
        work = float(np.dot(ev[EV_2D:EV_2D + 4], TEST_WEIGHTS)) + ev[EV_PIXELS]
        return chunks(out, sim.samples_per_batch), cycles_for(work, cfg.throughput, cfg.instances)

    def step_shade(batch):
        out, ops, ev = shading.run(batch)
        c = cs["shading"]
        n = len(batch["tri"])
        c.add_ops(ops), c.add_events(ev), count_records(c, n, n)
        c.add("bytes_written", n * 16)
        cfg = arch.shading
        cyc = cycles_for(ev[4] * cfg.shader_cycles, float(cfg.cores), 1)
        if shading.cached:  # per-sample and conservative shading bypass the cache
            cyc = max(cyc, cycles_for(ev[0], cfg.throughput, cfg.instances))
        return [out], cyc

    pending = []  # ordered: the refresh requests of the current triangle batch

    def refresh(requests, publish: bool = True) -> float:
        """The ROP's refresh of z-cull's boxes, the one path between them: its depth reads and
        comparisons are the ROP's counters, and its reads take the ROP's bandwidth after the batch's
        own traffic (the scan reads what the batch wrote). Returns its cycles. Without ``publish``,
        z-cull sees it when the ROP stage settles the step (the step may run ahead)."""
        ops, ev, nbytes = rop.refresh_zcull(requests, publish)
        c = cs["rop"]
        c.add_ops(ops), c.add_events(ev), c.add("bytes_read", nbytes)
        return cycles_for(nbytes, arch.rop.bandwidth, 1)

    def step_rop(batch):
        request, ops, ev, traffic = rop.run(batch)
        c = cs["rop"]
        n = len(batch["pix"])
        c.add_ops(ops), c.add_events(ev), count_records(c, n, int(ev[3]))
        c.add("bytes_read", int(traffic[0]))
        c.add("bytes_written", int(traffic[1]))
        cfg = arch.rop
        cyc = max(cycles_for(n, cfg.throughput, cfg.instances), cycles_for(traffic.sum(), cfg.bandwidth, 1))
        if request is not None:
            if ordered:
                pending.append(request)
            else:
                cyc += refresh([request], publish=False)
        return [], cyc

    def after_triangle_batch() -> float:
        """Ordered refresh: once a triangle batch has gone through, z-cull sees what it wrote."""
        if not pending:
            return 0.0
        cyc = refresh(pending)
        pending.clear()
        return cyc

    # batches carry their region from the bins on; the steps after the traverser run on records
    stage_defs = [
        ("triangle_setup", step_setup, arch.triangle_setup.latency),
        ("tile_traverser", step_traverse, arch.tile_traverser.latency),
        ("tile_test", region_step(step_tile_test), arch.tile_test.latency),
        ("zcull", region_step(step_zcull), arch.zcull.latency),
        ("sample_tester", region_step(step_sample_test, tester_at), arch.sample_tester.latency),
        # conservative shading reads no samples
        ("shading", region_step(step_shade, None if conservative else shading_at), arch.shading.latency),
        ("rop", region_step(step_rop, rop_at), arch.rop.latency),
    ]
    bypassed = set()
    if not zcull.active:
        bypassed.add("zcull")
    if conservative:
        bypassed.add("sample_tester")
    # steps that depend only on their batch and the unit's earlier steps may run ahead of the simulation
    # (pipeline.py): the tile test's (its batch's clip planes are set in its step), and the sample tester's,
    # shading's (whose cache only its own steps change, in order) and the ROP's (whose buffers only its own
    # steps change; z-cull sees its refreshes when the simulation reaches them) in the region whose samples
    # or buffers they hold (a cursor moves to the next region when the simulation brings it that region's
    # first batch)
    ahead = {"tile_test": lambda batch: True, "sample_tester": lambda batch: batch.region == tester_at.region,
             "shading": (lambda batch: True) if conservative else lambda batch: batch.region == shading_at.region,
             "rop": lambda batch: batch.region == rop_at.region}
    # the ROP's timed refresh of z-cull is published when the simulation reaches the step that made it
    settle = {"rop": zcull.publish_refresh} if zcull.active and not ordered else {}
    stages = [Stage(name, fn, lat, ahead=ahead.get(name), settle=settle.get(name))
              for name, fn, lat in stage_defs if name not in bypassed]
    ids = np.arange(draw.n, dtype=np.int64)
    if presetup:
        # binning needs each triangle's screen bounds: the functional setup
        # runs here, once per triangle (setup is per triangle, so its counters
        # do not depend on the grouping); the simulated setup stage then
        # takes each triangle's results in its first region and its cycles
        c = cs["triangle_setup"]
        for i in range(0, draw.n, 1 << 16):
            out, ops, ev = setup.run(ids[i : i + (1 << 16)])
            kept[out] = True
            c.add_ops(ops), c.add_events(ev)
    bins = bin_triangles(setup.table.bounds, ids, plan)
    samples.will_visit([r for r, b in enumerate(bins) if len(b)])
    try:
        tpb = sim.triangles_per_batch
        # a batch never spans two draws (each has its own clip planes)
        tri_batches = [RegionBatch(r, part[i : i + tpb]) for r, b in enumerate(bins)
                       for part in np.split(b, np.flatnonzero(np.diff(tri_draw[b])) + 1)
                       for i in range(0, len(part), tpb)]
        # FIFOs hold queue_depth batches of the shipped default size, counted in
        # records: a batch size then sets only the granularity of the timing
        default = SimOptions()
        per_kind = {"triangles": default.triangles_per_batch, "tiles": default.tiles_per_batch,
                    "samples": default.samples_per_batch}
        capacities = [pcfg.queue_depth * per_kind[INPUT_KIND[st.name]] for st in stages]
        if ordered:
            stages = run_in_order(stages, tri_batches, after_triangle_batch)
        timing = simulate(stages, tri_batches, pcfg.queue_depth, capacities, run_ahead=sim.run_ahead,
                          run_ahead_min_seconds=sim.run_ahead_min_us * 1e-6)
        image = rop.resolve()
        depth = rop.depth_samples()
        one_set = samples.region(0) if plan.count == 1 else None
    finally:
        samples.close()
    appended = None
    if append is not None:
        records, count = append
        appended = AppendResult(p.append.fields, records[:min(int(count[0]), len(records))],
                                max(int(count[0]) - len(records), 0))
        if not np.all(np.isfinite(appended.records)):
            raise UserError(f"{where}: the shader appended a value that is not finite")
    wall = time.perf_counter() - start
    counters = counters_frame([cs[name] for name in UNIT_ORDER], timing=zcull.active and not ordered)
    return PassResult(
        name=p.name, image=image, counters=counters, timing=timing, wall_time=wall,
        dimensions={"motion": motion, "lens": lens}, units_used=[s.name for s in stages],
        depth=depth, samples=one_set, regions=plan, region_samples_made=samples.made,
        images=rop.images, sample_data=rop.sample_data(), append=appended, queries=rop.queries,
        interval_queries={i: zcull.query_answer(i) for i in interval},
    )


def _pass_textures(p: RenderPass, named: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """The textures ``p`` names, as the shader takes them: float32 (H, W, layers) arrays, in order."""
    out = []
    for tex in p.textures:
        if isinstance(tex, str):
            if tex not in named:
                raise UserError(f"pass {p.name}: texture '{tex}' names no result of an earlier pass "
                                "(run the passes with run_passes)")
            tex = named[tex]
        tex = np.asarray(tex, np.float32)
        if tex.ndim == 2:
            tex = tex[:, :, None]
        if tex.ndim != 3 or 0 in tex.shape:
            raise UserError(f"pass {p.name}: a texture must be a non-empty (H, W, layers) array, not {tex.shape}")
        out.append(np.ascontiguousarray(tex))
    return tuple(out)


def pass_textures(result: PassResult) -> dict[str, np.ndarray]:
    """The names a later pass's ``textures`` may give for the results of pass ``result``:

    * ``"<pass>"``: its image (the first target's box resolve);
    * ``"<pass>.<target>"``: a target's box image, or its per-sample data (resolve "none"):
      (H, W, spp * channels), layer ``s * channels + c`` for channel ``c`` of sample ``s``;
    * ``"<pass>.<target>.<k>"``: view ``k`` of a target's lens resolve;
    * ``"<pass>.depth"``: its per-sample depth as a texture array, (H, W, spp), one layer per sample
      index (with a sample table whose sample ``k`` is the tuple ``k`` of every pixel, one per tuple).
    """
    n = result.name
    out = {n: result.image}
    for target, images in result.images.items():
        if len(images) == 1:
            out[f"{n}.{target}"] = images[0]
        for k, img in enumerate(images):
            out[f"{n}.{target}.{k}"] = img
    for target, data in result.sample_data.items():
        out[f"{n}.{target}"] = data.reshape(data.shape[0], data.shape[1], -1)
    if result.depth is not None:
        out[f"{n}.depth"] = result.depth
    return out


def run_passes(passes: list[RenderPass], progress=None) -> dict[str, PassResult]:
    """Run passes in order; a pass's ``textures`` may name an earlier pass's results (``pass_textures``).
    A pass whose depth a later pass names keeps it over several screen regions."""
    results: dict[str, PassResult] = {}
    named: dict[str, np.ndarray] = {}
    wanted = {tex for p in passes for tex in p.textures if isinstance(tex, str)}
    for p in passes:
        results[p.name] = run_pass(p, textures=named, progress=progress, keep_depth=f"{p.name}.depth" in wanted)
        named.update(pass_textures(results[p.name]))
    return results


def scene_pass(scene, arch: ArchConfig, **overrides) -> RenderPass:
    """The standard single pass of a scene: its draw (built here unless ``draw`` is given), light,
    background, pass state and simulation options."""
    bg = tuple(float(c) for c in scene.background) + (1.0,)
    if overrides.get("draw") is None:
        overrides["draw"] = build_draw(scene)
    kw: dict[str, Any] = dict(arch=arch, spp=scene.image.spp, seed=scene.image.seed,
                              params=standard_params(scene.light), clear_color=bg, state=scene.pass_state,
                              simulation=scene.simulation)
    kw.update(overrides)
    return RenderPass(**kw)


def render_scene(scene, arch: ArchConfig, progress=None, keep_depth: bool = False, **overrides) -> PassResult:
    """Render a scene in one standard pass."""
    return run_pass(scene_pass(scene, arch, **overrides), progress=progress, keep_depth=keep_depth)
