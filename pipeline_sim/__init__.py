"""pipeline-sim: a simulator of a 5D stochastic rasterization GPU pipeline.

The public API::

    from pipeline_sim import load_scene, load_arch, render_scene
    scene = load_scene("workloads/scenes/default.toml")
    result = render_scene(scene, load_arch(overrides=["zcull.time_slices=8"]))
    result.image, result.counters, result.timing.units
"""

import importlib

# name -> module: imported on first use, so that importing the package (as every unit does, for
# pipeline_sim.definitions) imports nothing else of it, and does not compile or import numba
_LAZY = {name: module for module, names in (
    ("config", ("ArchConfig", "load_arch", "apply_settings", "pass_settings")),
    ("pass_state", ("PassState", "ClipPlanes")),
    ("simulation", ("SimOptions",)),
    ("errors", ("UserError",)),
    ("scene", ("load_scene", "parse_scene", "Scene")),
    ("render", ("render_scene", "run_pass", "run_passes", "RenderPass", "PassResult", "scene_pass")),
    ("draw", ("build_draw", "draw_from_clip", "Draw")),
) for name in names}


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(name)
    return getattr(importlib.import_module(f"pipeline_sim.{_LAZY[name]}"), name)


__all__ = list(_LAZY)
