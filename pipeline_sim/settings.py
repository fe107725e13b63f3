"""What a setting can change: the declaration every hardware and pass-state field carries.

From most to least: ``image`` (it defines the picture: depth test, blending,
clip planes, backface culling), ``accuracy`` (it trades image error for
cost: sample pattern, shading mode and cache, pipeline mode; with a
declared reference value where one exists), ``counters`` (the functional
counters only, never the image: tile size, culling algorithm, z-cull boxes)
or ``cycles`` (the cost model only: throughputs, latencies, batch sizes,
queue depth; these can still move the counters that depend on timing,
docs/pipeline.md §4).
"""

from __future__ import annotations

from dataclasses import field
from typing import Any

IMAGE, ACCURACY, COUNTERS, CYCLES = "image", "accuracy", "counters", "cycles"
#: What a setting can change, from most to least.
EFFECTS = (IMAGE, ACCURACY, COUNTERS, CYCLES)


def setting(default: Any, effect: str, reference: Any = None) -> Any:
    """A configuration field with its declared effect (and, for ``accuracy``, the reference's value)."""
    assert effect in EFFECTS and (reference is None or effect == ACCURACY)
    return field(default=default, metadata={"effect": effect, "reference": reference})
