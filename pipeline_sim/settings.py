"""What a setting can change, and the value types every input file's settings are validated as.

Every hardware, pass-state and simulation setting is a dataclass field made
by :func:`setting`, which declares, from most to least, what it can change:
``image`` (it defines the picture: depth test, blending, clip planes,
backface culling), ``accuracy`` (it trades image error for cost: sample
pattern, shading mode and cache, pipeline mode; with a declared reference
value where one exists), ``counters`` (the functional counters only, never
the image: tile size, culling algorithm, z-cull boxes, screen regions) or
``cycles`` (the cost model only: throughputs, latencies, batch sizes, queue
depth; these can still move the counters that depend on timing,
docs/pipeline.md §4). Its annotation (one of the types below) is the
schema pydantic validates input files against (``pipeline_sim.schema``),
and its ``doc`` is the line the generated format references show.
"""

from __future__ import annotations

from dataclasses import field
from typing import Annotated, Any

from pydantic import ConfigDict, Field, Strict

IMAGE, ACCURACY, COUNTERS, CYCLES, SPEED = "image", "accuracy", "counters", "cycles", "speed"
#: What a setting can change, from most to least (``speed``: only how fast the simulator runs).
EFFECTS = (IMAGE, ACCURACY, COUNTERS, CYCLES, SPEED)

# The cost model's range: a rate or a cost from 1e-6 to 1e9 keeps every cycle count of a frame (at most
# about 1e10 items, each costing at most 1e9 cycles or 1e6 per unit of rate) far inside a float's exact
# integers, so timing, its CSV and JSON stay finite; counts up to 2^31 - 1 fit the kernels' int32 indices.
RATE_RANGE = (1e-6, 1e9)
MAX_COUNT = 2**31 - 1

#: Every settings dataclass's ``__pydantic_config__``: an unknown key is an error.
FORBID = ConfigDict(extra="forbid")
#: A rate or cost of the cost model (items per cycle, cycles, bytes per cycle).
Rate = Annotated[float, Strict(), Field(ge=RATE_RANGE[0], le=RATE_RANGE[1], allow_inf_nan=False)]
Flag = Annotated[bool, Strict()]
Text = Annotated[str, Strict()]


def count(low: int, high: int = MAX_COUNT) -> Any:
    """An integer from ``low`` to ``high``."""
    return Annotated[int, Strict(), Field(ge=low, le=high)]


def number(low: float, high: float) -> Any:
    """A finite number from ``low`` to ``high``."""
    return Annotated[float, Strict(), Field(ge=low, le=high, allow_inf_nan=False)]


def setting(default: Any, effect: str, doc: str = "", reference: Any = None) -> Any:
    """A configuration field with its declared effect (and, for ``accuracy``, the reference's value) and
    the one line the format references show for it."""
    assert effect in EFFECTS and (reference is None or effect == ACCURACY)
    return field(default=default, metadata={"effect": effect, "reference": reference, "doc": doc})
