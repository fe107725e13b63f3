"""What the units share with the framework: the one module of ``pipeline_sim`` that ``units/`` imports.

* The arithmetic classes and the common counters every unit declares
  (docs/pipeline.md §4); ``pipeline_sim.counters`` accumulates and tabulates them.
* The ROP's depth functions and blend modes (docs/pipeline.md §2.7), in the
  order of its kernel's codes; ``pipeline_sim.config`` checks settings against them.
* The shader input layout (docs/pipeline.md §2.6): one row of the shading
  unit's ``inputs`` array per name of ``INPUTS``; ``pipeline_sim.shaders``
  offers it to the shaders, a workload's own too.
* The declarations of a pass's render targets, shader outputs, lens
  regions and append buffer, which the ROP and the shading unit read
  (``pipeline_sim.targets`` documents and checks them).

Everything else of the framework (configuration, scenes, sampling, screen
regions, rendering, the SimPy plumbing) depends on the units, not the other
way: the pipeline hands a unit what it needs. This module imports nothing of
the project (``tests/test_layering.py``).
"""

from dataclasses import dataclass

# Arithmetic classes, in the order kernels write them (indices 0..4).
OP_ADD, OP_MUL, OP_MADD, OP_RCP, OP_CMP = range(5)
ARITHMETIC = ("add", "mul", "madd", "rcp", "compare")
N_OPS = len(ARITHMETIC)
#: the counters every unit has, before its own events, and what each counts
COMMON_MEANINGS = {
    "records_in": "records the unit received (triangles, tiles or samples, per its input)",
    "records_out": "records it passed on",
    **{op: f"`{op}` operations of its arithmetic" for op in ARITHMETIC},
    "bytes_read": "bytes it read from memory",
    "bytes_written": "bytes it wrote to memory",
}
COMMON = tuple(COMMON_MEANINGS)

DEPTH_FUNCS = ("less", "lequal", "greater", "gequal", "equal", "always", "never")
BLEND_MODES = ("replace", "add", "min", "max")

INPUTS = (
    "px", "py", "pz",  # world position of the shading point
    "nx", "ny", "nz",  # world normal (unit)
    "r", "g", "b",  # interpolated vertex color
    "t", "u", "v",  # shading time and lens position
    "x", "y",  # screen position in pixels (row 0 at the top)
    "depth",  # z/w of the sample (standard) or of the pixel centre (conservative: z^ midpoint)
    "material", "object", "triangle",
    "t_lo", "t_hi", "u_lo", "u_hi", "v_lo", "v_hi", "z_lo", "z_hi",  # conservative mode only
    # per-sample shading only (else -1): the sample's index within its pixel, and the index of its (u, v, t)
    # in the pass's fixed tuple set (the interleave pattern's tuples; a sample table's rows sorted by t, so
    # the sample index; -1 for other patterns)
    "sample", "tuple",
)
N_INPUTS = len(INPUTS)
(IN_PX, IN_PY, IN_PZ, IN_NX, IN_NY, IN_NZ, IN_R, IN_G, IN_B, IN_T, IN_U, IN_V, IN_X, IN_Y, IN_DEPTH,
 IN_MATERIAL, IN_OBJECT, IN_TRIANGLE, IN_T_LO, IN_T_HI, IN_U_LO, IN_U_HI, IN_V_LO, IN_V_HI, IN_Z_LO,
 IN_Z_HI, IN_SAMPLE, IN_TUPLE) = range(N_INPUTS)


# The parts of a pass the ROP and the shading unit run (documented in pipeline_sim.targets)
RESOLVES = ("box", "lens", "none")
DEPTH_RULES = ("test", "always")  # written where the pass's depth test passes / regardless of it


@dataclass(frozen=True)
class ShaderOutput:
    """One named output of a pass's shader: ``channels`` float32 values per shading point."""

    name: str = "color"
    channels: int = 4


@dataclass(frozen=True)
class LensRegion:
    """A view of a lens resolve: the samples whose lens position lies in [u_lo, u_hi] x [v_lo, v_hi]
    (a box window, weight 1 inside and 0 outside; Nilsson12 §8)."""

    u_lo: float = -1.0
    u_hi: float = 1.0
    v_lo: float = -1.0
    v_hi: float = 1.0


@dataclass(frozen=True)
class Target:
    """A float multisample render target of a pass (docs/pipeline.md §2.7).

    ``source``: the shader output it takes (as many channels as it has);
    ``blend``: None for the pass state's blend, one mode for every channel,
    or one mode per channel; ``clear``: its clear value per channel (None:
    zeros); ``depth``: "test" (written where the depth test passes) or
    "always" (every fragment that reaches the ROP); ``draws``: the indices
    of the draws that write it (None: all); ``resolve``: "box", "lens"
    (one image per region of ``views``) or "none" (per-sample data kept).
    """

    name: str = "color"
    source: str = "color"
    blend: str | tuple[str, ...] | None = None
    clear: tuple[float, ...] | None = None
    depth: str = "test"
    draws: tuple[int, ...] | None = None
    resolve: str = "box"
    views: tuple[LensRegion, ...] = ()


@dataclass(frozen=True)
class AppendBuffer:
    """Records the shader appends (``pipeline_sim.shaders.append_record``): at most ``capacity``
    records of ``len(fields)`` float32 values."""

    fields: tuple[str, ...] = ("x", "y", "u", "v", "t")
    capacity: int = 1024


def default_targets(clear_color) -> tuple[Target, ...]:
    """The target of a pass that names none: one RGBA target cleared to ``clear_color``, the state's blend
    and a box resolve."""
    return (Target(clear=tuple(float(c) for c in clear_color)),)
