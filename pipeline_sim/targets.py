"""The parts a render pass is assembled from besides its draws: render targets, resolves, the append buffer.

A pass (``pipeline_sim.render.RenderPass``) writes one or more float
multisample render targets (docs/pipeline.md §2.7). Each ``Target`` takes
one named output of the shader (``ShaderOutput``), blends it per channel
(replace, add, min or max: e.g. MIN on the lower and MAX on the upper
bounds of a tz-box, Nilsson12 §3), starts from its own clear value, is
written where the pass's depth test passes or regardless of it, and may be
restricted to some of the pass's draws (one target per object). Its resolve
is a box filter over each pixel's samples, one image per lens region
(``LensRegion``: each sample weighted by the region's box window on its
lens position (u, v); regions may overlap: stereo and multi-view,
Nilsson12 §8), or none (the per-sample data kept for a later pass).

The ``AppendBuffer`` holds records the shader appends (Nilsson12 §5: the
rasterizer as a sampler): ``capacity`` records of ``fields`` float32 values,
kept in the order the shader appended them; appends beyond the capacity are
counted, never written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# declared beside the record definitions, which the ROP reads them from (tests/test_layering.py)
from pipeline_sim.definitions import (BLEND_MODES, DEPTH_RULES, RESOLVES, AppendBuffer, LensRegion, ShaderOutput,
                                      Target)
from pipeline_sim.errors import UserError

@dataclass
class AppendResult:
    """An append buffer after its pass: the ``records`` kept (count, fields), in the order they were
    appended, and ``overflow``, the appends refused for want of capacity."""

    fields: tuple[str, ...]
    records: np.ndarray  # (kept, len(fields)) float32
    overflow: int


__all__ = ["AppendBuffer", "AppendResult", "LensRegion", "ShaderOutput", "Target", "check_targets"]


def check_targets(where: str, targets: tuple[Target, ...], outputs: tuple[ShaderOutput, ...], n_draws: int,
                  append: AppendBuffer | None) -> None:
    """Refuse a target, output or append buffer a pass cannot run, naming it (``where``: the pass)."""
    if not targets:
        raise UserError(f"{where}: a pass needs at least one target")
    names = [o.name for o in outputs]
    if len(set(names)) != len(names) or any(o.channels < 1 for o in outputs):
        raise UserError(f"{where}: shader outputs need distinct names and at least one channel each")
    if len({t.name for t in targets}) != len(targets):
        raise UserError(f"{where}: target names must be distinct")
    for t in targets:
        at = f"{where}: target '{t.name}'"
        if t.source not in names:
            raise UserError(f"{at}: source '{t.source}' is not a shader output ({', '.join(names)})")
        channels = outputs[names.index(t.source)].channels
        modes = (t.blend,) * channels if t.blend is None or isinstance(t.blend, str) else tuple(t.blend)
        if len(modes) != channels or any(m is not None and m not in BLEND_MODES for m in modes):
            raise UserError(f"{at}: blend must be one of {', '.join(BLEND_MODES)}, or one per channel "
                            f"({channels})")
        if t.clear is not None and (len(t.clear) != channels or not all(math.isfinite(c) for c in t.clear)):
            raise UserError(f"{at}: clear needs {channels} finite values")
        if t.depth not in DEPTH_RULES:
            raise UserError(f"{at}: depth '{t.depth}' is not one of {', '.join(DEPTH_RULES)}")
        if t.draws is not None and any(not 0 <= d < n_draws for d in t.draws):
            raise UserError(f"{at}: draws {list(t.draws)} must index the pass's {n_draws} draw(s)")
        if t.resolve not in RESOLVES:
            raise UserError(f"{at}: resolve '{t.resolve}' is not one of {', '.join(RESOLVES)}")
        if (t.resolve == "lens") != bool(t.views):
            raise UserError(f"{at}: views are given with resolve 'lens', and only then")
    if append is not None and (append.capacity < 0 or not append.fields):
        raise UserError(f"{where}: the append buffer needs at least one field and a capacity >= 0")
