"""What the units share with the framework: the one module of ``pipeline_sim`` that ``units/`` imports.

* The arithmetic classes and the common counters every unit declares
  (docs/pipeline.md §4); ``pipeline_sim.counters`` accumulates and tabulates them.
* The ROP's depth functions and blend modes (docs/pipeline.md §2.7), in the
  order of its kernel's codes; ``pipeline_sim.config`` checks settings against them.
* The shader input layout (docs/pipeline.md §2.6): one row of the shading
  unit's ``inputs`` array per name of ``INPUTS``; ``pipeline_sim.shaders``
  offers it to the shaders, a workload's own too.

Everything else of the framework (configuration, scenes, sampling, screen
regions, rendering, the SimPy plumbing) depends on the units, not the other
way: the pipeline hands a unit what it needs. This module imports nothing of
the project (``tests/test_layering.py``).
"""

# Arithmetic classes, in the order kernels write them (indices 0..4).
OP_ADD, OP_MUL, OP_MADD, OP_RCP, OP_CMP = range(5)
ARITHMETIC = ("add", "mul", "madd", "rcp", "compare")
N_OPS = len(ARITHMETIC)
COMMON = ("records_in", "records_out", *ARITHMETIC, "bytes_read", "bytes_written")

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
)
N_INPUTS = len(INPUTS)
(IN_PX, IN_PY, IN_PZ, IN_NX, IN_NY, IN_NZ, IN_R, IN_G, IN_B, IN_T, IN_U, IN_V, IN_X, IN_Y, IN_DEPTH,
 IN_MATERIAL, IN_OBJECT, IN_TRIANGLE, IN_T_LO, IN_T_HI, IN_U_LO, IN_U_HI, IN_V_LO, IN_V_HI, IN_Z_LO,
 IN_Z_HI) = range(N_INPUTS)
