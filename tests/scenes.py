"""Small scene files for tests: one camera layout, the objects each test needs."""

from __future__ import annotations


def moving_sphere(subdivisions: int = 1) -> str:
    """A sphere moving from x = -0.3 to x = 0.3 during the shutter."""
    return ('[[objects]]\nprimitive = "sphere"\nradius = 0.7\n'
            f"subdivisions = {subdivisions}\n[objects.open]\ntranslate = [-0.3, 0.5, 0.0]\n"
            "[objects.close]\ntranslate = [0.3, 0.5, 0.0]\n")


def mesh_object(path: str) -> str:
    """One object read from the mesh file ``path`` (relative to the scene file)."""
    return f'[[objects]]\nmesh = "{path}"\n'


def scene_toml(objects: str, *, width: int = 48, height: int = 32, spp: int = 4, seed: int | None = None,
               eye_y: float = 0.5, lens_radius: float | None = None) -> str:
    """A scene file: ``width`` x ``height`` at ``spp``, a 45-degree camera 4 units from the origin at
    height ``eye_y`` (a thin lens of ``lens_radius`` focused at 4 if given), then ``objects``."""
    lines = ["[image]", f"width = {width}", f"height = {height}", f"spp = {spp}"]
    if seed is not None:
        lines.append(f"seed = {seed}")
    lines += ["[camera]", f"eye = [0.0, {eye_y}, 4.0]", f"look_at = [0.0, {eye_y}, 0.0]", "fov_y = 45.0",
              "near = 0.1", "far = 20.0"]
    if lens_radius is not None:
        lines += ["[camera.lens]", f"radius = {lens_radius}", "focus_distance = 4.0"]
    return "\n".join(lines) + "\n" + objects
