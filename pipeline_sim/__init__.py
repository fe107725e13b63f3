"""pipeline-sim: a simulator of a 5D stochastic rasterization GPU pipeline.

The public API::

    from pipeline_sim import load_scene, load_arch, render_scene
    scene = load_scene("workloads/scenes/default.toml")
    result = render_scene(scene, load_arch(overrides=["zcull.time_slices=8"]))
    result.image, result.counters, result.timing.units
"""

from pipeline_sim.config import ArchConfig, load_arch
from pipeline_sim.errors import UserError


def __getattr__(name):  # lazy: importing the package does not compile or import numba
    if name in ("load_scene", "parse_scene", "Scene"):
        from pipeline_sim import scene

        return getattr(scene, name)
    if name in ("render_scene", "run_pass", "run_passes", "RenderPass", "PassResult", "scene_pass"):
        from pipeline_sim import render

        return getattr(render, name)
    if name in ("build_draw", "draw_from_clip", "Draw"):
        from pipeline_sim import draw

        return getattr(draw, name)
    raise AttributeError(name)


__all__ = ["ArchConfig", "UserError", "load_arch", "load_scene", "parse_scene", "render_scene", "run_pass",
           "run_passes", "RenderPass", "PassResult", "scene_pass", "build_draw", "draw_from_clip", "Draw"]
