"""What a run would refuse, refused before it starts: one validation for every command.

``check``, ``run`` and ``compare`` call :func:`validate_run` right after the
scene (with its pass state and simulation options) and the architecture are
loaded, and a sweep calls :func:`check_point` for every point while its file is read: all of it before a numba kernel is
loaded or compiled, so ``check`` accepts exactly what ``run`` runs, and a
refusal is one line (a :class:`~pipeline_sim.errors.UserError`) within a
second or two. Checked:

* the samples: the sample pattern's rule on spp (a power of two for ``net``,
  ``sobol`` and ``net5``; at most, and a divisor of, ``pass.interleave_tuples``
  for ``interleave``), and the rules between the hardware and the pass state
  (:func:`pipeline_sim.config.check_compatible`); the image limits themselves are the scene loader's
  (:func:`pipeline_sim.scene.check_image_value`), applied to overrides too;
* the geometry: :func:`~pipeline_sim.draw.build_draw` (the scene has
  triangles; coordinates stay within the float32 range the pipeline
  computes in);
* memory: :func:`estimate_memory`, an upper bound of what the run adds to
  the process from its settings alone, against :func:`available_memory`.

The memory a run takes is the sum of terms, each from the settings: the
per-triangle tables (the draw and triangle setup's constants); the samples
and multisample buffers of one screen region (``simulation.region_samples``
caps them); the work in flight between units (a triangle batch's tiles, a
tile batch's covered samples); z-cull's boxes over the whole frame and its
refresh state for a region's pixels; the shading cache; the resolved image
with the files written from it; and a constant for compiling the kernels and
drawing the report's figures. The per-item sizes are the arrays' own
(:data:`BYTES`), with the transient copies a step holds while it replaces
one array by another; ``tests/test_preflight.py`` checks the estimate
against the peak resident memory of real runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline_sim.config import ArchConfig, check_compatible
from pipeline_sim.errors import UserError
from pipeline_sim.pass_state import PassState
from pipeline_sim.regions import plan_regions, row_step
from pipeline_sim.sampling import check_spp
from pipeline_sim.simulation import SimOptions

if TYPE_CHECKING:
    from pipeline_sim.draw import Draw
    from pipeline_sim.scene import Scene

GIB = 1 << 30

#: Bytes per item of each term of :func:`estimate_memory`.
BYTES = {
    # the draw (clip vertices at t=0 and t=1, lens shifts, world positions and
    # normals, colours: ~480 B) and triangle setup's table (~1.1 KB), with
    # the binning's triangle lists
    "triangle": 2000,
    # a sample (x, y, u, v, t float32 and a tuple index) in the three most
    # recent regions' sample sets (3 x 21 B), the sample tester's tile-major
    # copies of the current region and of the next, made ahead (2 x 21 B),
    # the ROP's depth and colour, twice while one replaces the other
    # (2 x 20 B), and z-cull's box of the sample and its place among its
    # pixel's samples grouped by box, for the ROP's region and two made ahead
    # of it (3 x 3 B)
    "region_sample": 3 * 21 + 2 * 21 + 2 * 20 + 3 * 3,
    # a pixel of a region and z-cull box: where the box's samples start among
    # the pixel's, for the ROP's region and two made ahead (3 x int32), and
    # the ROP's refresh state, the box's largest depth at the pixel and a flag
    "region_pixel_box": 3 * 4 + 4 + 1,
    # a tile record out of the tile traverser (triangle, x, y: 3 x int32)
    "tile_record": 12,
    # a covered-sample record out of the sample tester (triangle, pixel,
    # sample, depth, three barycentrics, noread: 29 B), in arrays the tester
    # grows as it writes them (twice while one grows into the other)
    "sample_record": 2 * 29,
    # a shaded sample's RGBA colour (float32), of a batch shaded ahead
    "shaded_sample": 16,
    # a tile of the frame in z-cull: zmin, zmax and the ROP's refreshed zmax
    # per (t, u, v) box (float32 each, boxes counted below), and its refresh
    # state (9 B)
    "zcull_box": 3 * 4,
    "zcull_tile": 9,
    # a shading-cache entry: tag, stamp (int64), request (int32), RGBA float32
    "cache_entry": 8 + 8 + 4 + 16,
    # a pixel: the ROP's resolved float32 RGBA image, and the 8-bit sRGB
    # copies of the files written from it (the PNG's array and its image,
    # the report's embedded PNG and its base64 text) and their encoders'
    # buffers
    "pixel": 16 + 16,
}
#: Compiling the kernels (on a machine's first run; loading them from the
#: cache takes less), SimPy's traces, pandas tables and the report's figures.
#: Measured (VmHWM): a 640x360, 20k-triangle run at 16 spp added 529 MB
#: compiling every kernel from an empty cache, 319 MB loading them.
FIXED_BYTES = 256 << 20


@dataclass(frozen=True)
class MemoryEstimate:
    """An upper bound of the bytes a run adds to the process, by term."""

    parts: dict[str, int]

    @property
    def total(self) -> int:
        return sum(self.parts.values())

    def describe(self) -> str:
        """The three largest terms, e.g. ``image 8.0 GiB, z-cull 2.1 GiB, region samples 0.7 GiB``."""
        big = sorted(self.parts.items(), key=lambda kv: -kv[1])[:3]
        return ", ".join(f"{name} {_gib(v)}" for name, v in big)


def _gib(n: float) -> str:
    return f"{n / GIB:.1f} GiB" if n >= GIB / 10 else f"{n / (1 << 20):.0f} MiB"


def estimate_memory(width: int, height: int, spp: int, triangles: int, arch: ArchConfig,
                    state: PassState = PassState(), sim: SimOptions = SimOptions(), *,
                    images: int = 1) -> MemoryEstimate:
    """An upper bound of the memory a run of these settings adds to the process,
    holding ``images`` resolved images at once (``compare`` keeps one per algorithm)."""
    conservative = state.conservative
    ts = 1 if conservative else arch.tile_traverser.tile_size
    spp = 1 if conservative else spp
    cached = state.shading_mode == "cache" and not conservative
    step = row_step(ts, arch.tile_traverser.coarse_factor, state.shading_rate if cached else None)
    plan = plan_regions(width, height, spp, sim.region_samples, step)
    rows = min(plan.rows, height)
    region_samples = rows * width * spp
    region_tiles = math.ceil(rows / ts) * math.ceil(width / ts)
    # in flight: one triangle batch's tile records, each of its triangles
    # reaching at most every tile of the region; one tile batch's covered
    # samples, at most its tiles' samples and at most a region's, and as many
    # more as the sample tester may have tested ahead (simulation.run_ahead);
    # the colours of the sample batches shading may have shaded ahead
    tiles = min(sim.triangles_per_batch, max(triangles, 1)) * region_tiles * BYTES["tile_record"]
    samples = ((1 + sim.run_ahead) * min(sim.tiles_per_batch * ts * ts * spp, region_samples)
               * BYTES["sample_record"]
               + sim.run_ahead * min(sim.samples_per_batch, region_samples) * BYTES["shaded_sample"])
    # z-cull's boxes cover the whole frame, as many per tile as motion and a
    # lens may need (the estimate does not know yet whether the draw has them)
    boxes = arch.zcull.time_slices * arch.zcull.lens_boxes**2
    frame_tiles = math.ceil(height / ts) * math.ceil(width / ts)
    parts = {
        "triangles": triangles * BYTES["triangle"],
        "region samples": region_samples * BYTES["region_sample"],
        "in flight": tiles + samples,
        "z-cull": frame_tiles * (boxes * BYTES["zcull_box"] + BYTES["zcull_tile"])
        + rows * width * (boxes + 1) * BYTES["region_pixel_box"],
        "shading cache": arch.shading.cache_entries * BYTES["cache_entry"],  # allocated in every mode
        "image": images * width * height * BYTES["pixel"],
        "kernels and reports": FIXED_BYTES,
    }
    return MemoryEstimate(parts)


def _cgroup_room() -> list[int]:
    """What the memory cgroups this process is in leave it (v2 ``memory.max``, v1
    ``memory.limit_in_bytes``), found through /proc/self/cgroup."""
    room = []
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return room
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controllers == "":            # v2: one unified hierarchy
            base, files = Path("/sys/fs/cgroup") / path.lstrip("/"), ("memory.max", "memory.current")
        elif "memory" in controllers.split(","):
            base, files = (Path("/sys/fs/cgroup/memory") / path.lstrip("/"),
                           ("memory.limit_in_bytes", "memory.usage_in_bytes"))
        else:
            continue
        for folder in (base, *base.parents):   # the limit may be set on a parent group
            try:
                limit = (folder / files[0]).read_text().strip()
                used = int((folder / files[1]).read_text())
            except (OSError, ValueError):
                continue
            if limit != "max" and int(limit) < 1 << 62:
                room.append(int(limit) - used)
            if folder == Path("/sys/fs/cgroup") or folder == Path("/sys/fs/cgroup/memory"):
                break
    return room


def available_memory() -> int:
    """Bytes this process may still take: the system's available memory, or less when a memory
    cgroup (v1 or v2) or the process's address-space limit (``ulimit -v``) leaves less."""
    import resource

    import psutil

    room = [psutil.virtual_memory().available, *_cgroup_room()]
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        room.append(soft - psutil.Process().memory_info().vms)
    return max(0, min(room))


def check_samples(spp: int, state: PassState, where: str) -> None:
    """The sample pattern's rule on ``spp`` (not applied in conservative mode,
    which takes one sample per pixel)."""
    if not state.conservative:
        check_spp(state.sample_pattern, spp, state.interleave_tuples, where)


def check_memory(estimate: MemoryEstimate, where: str, what: str) -> None:
    """Refuse a run whose estimate exceeds the available memory."""
    have = available_memory()
    if estimate.total > have:
        raise UserError(f"{where}: {what} needs about {_gib(estimate.total)} of memory ({estimate.describe()}), "
                        f"more than the {_gib(have)} available")


def check_point(scene: Scene, arch: ArchConfig, where: str, *, images: int = 1,
                reference_spp: int | None = None) -> None:
    """Everything but the geometry: the hardware against the pass state, the samples and the memory of a
    run of ``scene``'s image settings, pass state and simulation options with ``arch`` holding ``images``
    resolved images (and of its reference rendered at ``reference_spp``, if given)."""
    from pipeline_sim.config import reference_setup

    img = scene.image
    check_compatible(arch, scene.pass_state, where)
    check_samples(img.spp, scene.pass_state, where)
    runs = [(img.spp, (arch, scene.pass_state, scene.simulation),
             f"a {img.width}x{img.height} frame at {img.spp} spp")]
    if reference_spp is not None:
        runs.append((reference_spp, reference_setup(arch, scene.pass_state), f"the reference at {reference_spp} spp"))
    for spp, setup, what in runs:
        estimate = estimate_memory(img.width, img.height, spp, scene.triangle_count, *setup, images=images)
        check_memory(estimate, where, f"{what} of {scene.triangle_count:,} triangles")


def validate_run(runs: Sequence[tuple[Scene, ArchConfig]], where: str, *,
                 reference_spp: int | None = None) -> Draw:
    """Refuse (a :class:`UserError` naming ``where``) what each of ``runs`` (a scene with its pass state
    and simulation options, and the hardware; one per render: ``compare`` has one per algorithm) would
    refuse later; return the draw they render (the first's: the runs share the scene's geometry)."""
    from pipeline_sim.draw import build_draw

    images = len(runs) + (reference_spp is not None)
    for i, (scene, arch) in enumerate(runs):
        check_point(scene, arch, where, images=images, reference_spp=reference_spp if i == 0 else None)
    return build_draw(runs[0][0])


__all__ = ["BYTES", "FIXED_BYTES", "MemoryEstimate", "available_memory", "check_memory", "check_point",
           "check_samples", "estimate_memory", "validate_run"]
