"""Scene files: a TOML description of the image, camera, light and objects.

A scene file is TOML, validated against its schema (the ``*Table`` and
``*Object`` dataclasses below, through ``pipeline_sim.schema``; the rules
between keys are code). Every problem in it is reported as a one-line
:class:`~pipeline_sim.errors.UserError` naming the file and the key path,
for example ``scene.toml: objects[2].open.rotate: expected 3 numbers, got 2``.
Unknown keys are errors at every level (with the nearest known name
suggested), numbers must be finite (TOML's ``nan`` and ``inf`` are refused),
and integers must be written as integers (``320``, not ``320.0``).

Coordinates are right-handed with y up, as in OpenGL: the camera looks down
its -z axis. Colours are linear RGB (components from 0 to ``MAX_RADIANCE``
= 1e8; values above 1 are allowed). Angles are in degrees. Time t runs over
the shutter from 0 (open) to 1 (close); everything that moves, moves
linearly per vertex in world space between its shutter-open and
shutter-close positions. Every vertex's world position, clip coordinate and
lens shift must lie within +-``MAX_COORDINATE`` = 2^126 (half the float32
range), as must a point light's position: with these bounds every value the
pipeline shades, tests and stores is finite.

Format
------

.. code-block:: toml

    [image]                      # required
    width = 320                  # pixels, > 0 (required)
    height = 180                 # pixels, > 0 (required)
    spp = 16                     # samples per pixel, > 0 (required)
    seed = 1                     # sample-pattern seed, >= 0 (default 0)

    [camera]                     # required
    projection = "perspective"   # "perspective" (default) or "orthographic"
    eye = [0.0, 1.5, 6.0]        # required; at shutter open
    look_at = [0.0, 0.5, 0.0]    # required; at shutter open
    up = [0.0, 1.0, 0.0]         # default [0, 1, 0]; need not be orthogonal
    fov_y = 40.0                 # vertical field of view in degrees, in (0, 180);
                                 # perspective only; required unless `frustum`
    near = 0.1                   # required, > 0
    far = 100.0                  # required, > near
    # frustum = [-0.05, 0.03, -0.02, 0.04]
    #     optional [left, right, bottom, top], left < right, bottom < top.
    #     Perspective: the window on the near plane (glFrustum), for
    #     asymmetric off-centre frusta; overrides fov_y. Orthographic: the
    #     view-volume extents (glOrtho); overrides ortho_height. The image
    #     aspect ratio is not applied to an explicit frustum.
    # ortho_height = 4.0         # orthographic only: full height of the view
    #                            # volume in world units (default 2);
    #                            # width = height * image aspect
    # eye_close = [0.5, 1.5, 6.0]      # optional camera motion: eye and
    # look_at_close = [0.5, 0.5, 0.0]  # look_at at shutter close (default:
    #                                  # the shutter-open values)

    [camera.lens]                # optional thin lens; perspective cameras only
    radius = 0.08                # required, >= 0, world units (0 = pinhole)
    focus_distance = 6.0         # > 0, world units along the view direction;
                                 # default: distance from eye to look_at

    [background]                 # optional
    color = [0.05, 0.05, 0.08]   # default [0, 0, 0]

    [light]                      # optional; default: a white directional light
    type = "directional"         # "directional" (default) or "point"
    direction = [-0.4, -1.0, -0.3]  # directional only: from the light toward
                                 # the scene, normalized on load
                                 # (default [-0.3, -1.0, -0.5])
    # position = [2.0, 4.0, 3.0] # point only, required
    color = [1.0, 1.0, 1.0]      # default [1, 1, 1]
    intensity = 1.0              # 0 to 1e8, default 1
    ambient = 0.15               # 0 to 1e8, default 0.1

    [[objects]]                  # zero or more
    name = "ball"                # optional, unique; default "object<i>" (i from 0)
    primitive = "sphere"         # a built-in shape (parameters below) -- or --
    # mesh = "../meshes/x.obj"   # a mesh file, relative to the scene file
    radius = 0.5                 # primitive parameters (see below)
    material = "lambert"         # "lambert" (default) or "flat" (unlit)
    color = [0.8, 0.2, 0.2]      # default [0.8, 0.8, 0.8]
    use_vertex_colors = false    # use the mesh file's vertex colours when it
                                 # has them (default false)

    [objects.open]               # optional transform at shutter open:
    translate = [0.0, 0.5, 0.0]  # scale, then rotate (degrees about x, then
    rotate = [0.0, 0.0, 0.0]     # y, then z), then translate
    scale = 1.0                  # number or [sx, sy, sz], components > 0

    [objects.close]              # optional transform at shutter close; each
    translate = [0.6, 0.5, 0.0]  # key missing here takes its `open` value

    [pass]                       # optional: the pass state (pipeline_sim.pass_state),
    depth_test = "less"          # every key of PassState, defaults as shown in
    shading_mode = "cache"       # docs/scene-format.md
    [pass.clip]                  # optional user clip planes
    t_hi = 1.0

    [simulation]                 # optional: batch sizes and screen regions
    region_samples = 4194304     # (pipeline_sim.simulation.SimOptions)

Exactly one of ``primitive`` and ``mesh`` is required. Primitives, all
centred on the object-space origin, with their parameters and defaults:

- ``sphere``: ``radius = 1``, ``subdivisions = 3`` (icosphere; 20*4^n
  triangles, n <= 7).
- ``box``: ``size = [1, 1, 1]`` (number or [x, y, z]).
- ``plane``: ``size = [1, 1]`` (number or [x, z]) in the xz plane at y = 0,
  facing +y; ``subdivisions = 0`` gives 2 triangles, n gives an
  (n+1) x (n+1) grid of quads (2 (n+1)^2 triangles).
- ``torus``: ``major_radius = 1``, ``minor_radius = 0.25`` (< major),
  ``major_sections = 32``, ``minor_sections = 16``; the ring lies in the xz
  plane (axis y).
- ``cylinder``: ``radius = 0.5``, ``height = 1``, ``sections = 32``; axis y,
  from y = -height/2 to +height/2, capped.

Mesh files (OBJ, PLY, STL, OFF, glTF/GLB) are read with trimesh; a glTF
scene is flattened into one mesh with its node transforms applied. Normals
in the file are used when present; otherwise vertices are merged by
position (unless the file has vertex colours) and smooth vertex normals are
computed. Vertex colours (8-bit, taken as linear values / 255) are used
only with ``use_vertex_colors = true`` (parts of a file without them, and
files without them, get the object's ``color``); textures and materials in
the file are ignored. Triangles keep the file's winding: counter-clockwise
is front (a mirroring glTF node transform reverses it, as glTF specifies).
A file that is not valid in its format is refused on one line saying what
is wrong with it (not UTF-8 text, a binary header whose sizes do not match
the file, malformed JSON, an OFF line that is not a vertex or a face).
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import dataclasses
import hashlib
import json
import logging
import math
import re
import tomllib
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np

from pydantic import Field, Strict

from . import schema
from .config import pass_state_from, sim_options_from
from .errors import UserError, printable, read_input_text, unknown_key_error
from .pass_state import PassState
from .settings import FORBID, Flag, count, number
from .simulation import SimOptions

__all__ = [
    "ImageSettings",
    "Lens",
    "Camera",
    "Light",
    "SceneObject",
    "Scene",
    "load_scene",
    "parse_scene",
    "PRIMITIVES",
    "MATERIALS",
    "MESH_FORMATS",
]

MATERIALS = ("flat", "lambert")
PRIMITIVES = ("sphere", "box", "plane", "torus", "cylinder")
PROJECTIONS = ("perspective", "orthographic")
LIGHT_TYPES = ("directional", "point")
MESH_FORMATS = (".obj", ".ply", ".stl", ".off", ".gltf", ".glb")

DEFAULT_LIGHT_DIRECTION = (-0.3, -1.0, -0.5)
DEFAULT_OBJECT_COLOR = (0.8, 0.8, 0.8)

#: Largest width, height and samples per pixel of an image.
IMAGE_LIMITS = {"width": 16384, "height": 16384, "spp": 16384}

#: Largest colour component (objects, background, light), light intensity and
#: ambient term. The standard shader (``pipeline_sim.shaders``) computes, in
#: float32, colour * (ambient + light colour * intensity * max(n.l, 0) *
#: attenuation) with attenuation = 1 / max(d^2, 1e-12) <= 1e12: with each
#: factor at most 1e8 that is at most 1e8 * (1e8 + 1e8 * 1e8 * 1e12) ~ 1e36,
#: below the largest finite float32 (3.4e38), so no shaded value overflows.
MAX_RADIANCE = 1e8

#: Largest magnitude of a coordinate the pipeline computes with (a light
#: position; a vertex's world position, clip coordinate or lens shift, checked
#: by ``pipeline_sim.draw.build_draw``): 2^126, half the float32 range, so the
#: difference of two such coordinates (an edge, a light vector) stays finite.
MAX_COORDINATE = 2.0**126


def _readonly(a: Any, dtype: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    arr = np.array(a, dtype=dtype, copy=True)
    if arr.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(arr.shape, shape)
    ):
        raise ValueError(f"expected an array of shape {shape}, got {arr.shape}")
    arr.setflags(write=False)
    return arr


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _lerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """(1-t) a + t b, exactly a at t=0 or when a == b, exactly b at t=1."""
    if t == 0.0 or np.array_equal(a, b):
        return a
    if t == 1.0:
        return b
    return (1.0 - t) * a + t * b


# --------------------------------------------------------------------------
# Public data model


@dataclass(frozen=True)
class ImageSettings:
    """Output image size, samples per pixel and sample-pattern seed."""

    width: int
    height: int
    spp: int
    seed: int = 0

    @property
    def aspect(self) -> float:
        """Width / height."""
        return self.width / self.height


@dataclass(frozen=True)
class Lens:
    """Thin lens: aperture radius and focus distance, both in world units."""

    radius: float
    focus_distance: float


@dataclass(frozen=True, eq=False)
class Camera:
    """A perspective or orthographic camera, optionally moving and with a lens.

    ``eye``/``look_at`` are at shutter open (t=0), ``eye_close``/
    ``look_at_close`` at shutter close (t=1); in between they move linearly.
    ``up`` is fixed. Arrays are read-only float64 (3,).

    ``fov_y`` (degrees) is the vertical field of view of a perspective
    camera; with an explicit ``frustum`` it is the frustum's vertical angle
    (informational; the frustum is what is used), and 0.0 for orthographic
    cameras. ``ortho_height`` is only used by orthographic cameras without a
    ``frustum``. A ``lens`` with radius 0 behaves as a pinhole.
    """

    projection: str
    eye: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    eye_close: np.ndarray
    look_at_close: np.ndarray
    fov_y: float
    near: float
    far: float
    frustum: tuple[float, float, float, float] | None = None
    ortho_height: float = 2.0
    lens: Lens | None = None

    def __post_init__(self) -> None:
        for name in ("eye", "look_at", "up", "eye_close", "look_at_close"):
            object.__setattr__(self, name, _readonly(getattr(self, name), np.float64, (3,)))
        if self.projection not in PROJECTIONS:
            raise ValueError(f"projection must be one of {PROJECTIONS}, got {self.projection!r}")
        if self.frustum is not None:
            object.__setattr__(self, "frustum", tuple(float(x) for x in self.frustum))

    @property
    def moving(self) -> bool:
        """True when the eye or look-at point moves during the shutter."""
        return not (
            np.array_equal(self.eye, self.eye_close)
            and np.array_equal(self.look_at, self.look_at_close)
        )

    def eye_at(self, t: float) -> np.ndarray:
        """Eye position at shutter time t (linear between open and close)."""
        return _lerp(self.eye, self.eye_close, t)

    def look_at_at(self, t: float) -> np.ndarray:
        """Look-at point at shutter time t (linear between open and close)."""
        return _lerp(self.look_at, self.look_at_close, t)

    def view_matrix(self, t: float = 0.0) -> np.ndarray:
        """4x4 world->eye matrix (OpenGL gluLookAt) at shutter time t.

        t=0 is shutter open, t=1 shutter close; eye and look_at are
        interpolated linearly. The camera looks down its -z axis.
        """
        eye = self.eye_at(t)
        f = _normalize(self.look_at_at(t) - eye)
        s = _normalize(np.cross(f, self.up))
        u = np.cross(s, f)
        m = np.eye(4)
        m[0, :3] = s
        m[1, :3] = u
        m[2, :3] = -f
        m[:3, 3] = -m[:3, :3] @ eye
        return m

    def frustum_window(self, aspect: float) -> tuple[float, float, float, float]:
        """(left, right, bottom, top): the near-plane window (perspective)
        or the view-volume extents (orthographic) for this aspect ratio."""
        if self.frustum is not None:
            return self.frustum
        if self.projection == "perspective":
            top = self.near * math.tan(math.radians(self.fov_y) / 2.0)
        else:
            top = self.ortho_height / 2.0
        right = top * aspect
        return (-right, right, -top, top)

    def projection_matrix(self, aspect: float) -> np.ndarray:
        """4x4 eye->clip matrix: glFrustum / gluPerspective or glOrtho.

        ``aspect`` is image width / height; it is ignored when an explicit
        ``frustum`` is set. Perspective clip w = -z_eye. After the divide,
        the near plane maps to z_ndc = -1 and the far plane to +1.
        """
        l, r, b, t = self.frustum_window(aspect)
        n, f = self.near, self.far
        m = np.zeros((4, 4))
        if self.projection == "perspective":
            m[0, 0] = 2.0 * n / (r - l)
            m[0, 2] = (r + l) / (r - l)
            m[1, 1] = 2.0 * n / (t - b)
            m[1, 2] = (t + b) / (t - b)
            m[2, 2] = -(f + n) / (f - n)
            m[2, 3] = -2.0 * f * n / (f - n)
            m[3, 2] = -1.0
        else:
            m[0, 0] = 2.0 / (r - l)
            m[0, 3] = -(r + l) / (r - l)
            m[1, 1] = 2.0 / (t - b)
            m[1, 3] = -(t + b) / (t - b)
            m[2, 2] = -2.0 / (f - n)
            m[2, 3] = -(f + n) / (f - n)
            m[3, 3] = 1.0
        return m


@dataclass(frozen=True, eq=False)
class Light:
    """One light. ``direction`` (directional: unit vector from the light
    toward the scene) is zero for point lights; ``position`` (point) is zero
    for directional lights."""

    kind: str
    direction: np.ndarray
    position: np.ndarray
    color: np.ndarray
    intensity: float
    ambient: float

    def __post_init__(self) -> None:
        for name in ("direction", "position", "color"):
            object.__setattr__(self, name, _readonly(getattr(self, name), np.float64, (3,)))


@dataclass(frozen=True, eq=False)
class SceneObject:
    """A triangle mesh with its material and shutter-open/close transforms.

    Arrays are read-only: positions/normals float64 (V,3) in object space,
    faces int32 (F,3) counter-clockwise = front facing, colors float32 (V,3)
    linear RGB, transforms float64 4x4 object->world.
    """

    name: str
    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    material: str
    transform_open: np.ndarray
    transform_close: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "positions", _readonly(self.positions, np.float64, (None, 3)))
        nv = len(self.positions)
        object.__setattr__(self, "normals", _readonly(self.normals, np.float64, (nv, 3)))
        object.__setattr__(self, "faces", _readonly(self.faces, np.int32, (None, 3)))
        object.__setattr__(self, "colors", _readonly(self.colors, np.float32, (nv, 3)))
        for name in ("transform_open", "transform_close"):
            object.__setattr__(self, name, _readonly(getattr(self, name), np.float64, (4, 4)))

    @property
    def moving(self) -> bool:
        """True when the open and close transforms differ."""
        return not np.array_equal(self.transform_open, self.transform_close)

    @property
    def triangle_count(self) -> int:
        return len(self.faces)

    def world_positions(self, t: float) -> np.ndarray:
        """(V,3) float64 world-space positions at shutter time t in [0, 1].

        t=0 and t=1 apply the open/close transforms; in between the
        positions are interpolated linearly per vertex (not the transforms).
        """
        t = _check_time(t)
        p0 = self.positions @ self.transform_open[:3, :3].T + self.transform_open[:3, 3]
        if t == 0.0 or not self.moving:
            return p0
        p1 = self.positions @ self.transform_close[:3, :3].T + self.transform_close[:3, 3]
        if t == 1.0:
            return p1
        return (1.0 - t) * p0 + t * p1

    def world_normals(self, t: float) -> np.ndarray:
        """(V,3) float64 unit world-space normals at shutter time t in [0, 1]
        (inverse-transpose transformed, interpolated linearly, renormalized)."""
        t = _check_time(t)
        # inv(M) = inv(M D^-1) D^-1 with D the powers of two of M's column
        # magnitudes: M D^-1 is well conditioned for any scale (1e-300 or
        # 1e300 included), and n D^-1 is taken relative to the smallest power of
        # both matrices, one common factor, so the result is (inv(M)^T n^T)^T
        # times a power of two, exactly, and the interpolation is unchanged
        def powers(m: np.ndarray) -> np.ndarray:
            return np.frexp(np.abs(m[:3, :3]).max(axis=0))[1]

        low = min(powers(self.transform_open).min(), powers(self.transform_close).min())

        def at(m: np.ndarray) -> np.ndarray:
            e = powers(m)
            return np.ldexp(self.normals, low - e) @ np.linalg.inv(np.ldexp(m[:3, :3], -e))

        n = at(self.transform_open)
        if t != 0.0 and self.moving:
            n1 = at(self.transform_close)
            n = n1 if t == 1.0 else (1.0 - t) * n + t * n1
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return n / np.where(length > 0.0, length, 1.0)


def _check_time(t: float) -> float:
    t = float(t)
    if not 0.0 <= t <= 1.0:
        raise ValueError(f"shutter time must be in [0, 1], got {t}")
    return t


@dataclass(frozen=True, eq=False)
class Scene:
    """A loaded scene. ``digest`` is the sha256 (hex) of the scene file's
    bytes and the bytes of every mesh file it loads, in object order; it
    identifies the inputs and is not changed by :meth:`replace`."""

    image: ImageSettings
    camera: Camera
    light: Light
    background: np.ndarray
    objects: tuple[SceneObject, ...]
    path: Path | None = None
    digest: str = ""
    pass_state: PassState = field(default_factory=PassState)  # the [pass] table
    simulation: SimOptions = field(default_factory=SimOptions)  # the [simulation] table

    def __post_init__(self) -> None:
        object.__setattr__(self, "background", _readonly(self.background, np.float32, (3,)))
        object.__setattr__(self, "objects", tuple(self.objects))

    def replace(self, **changes: Any) -> "Scene":
        """A copy with some fields replaced (``dataclasses.replace``), e.g.
        ``scene.replace(image=dataclasses.replace(scene.image, spp=64))``."""
        return dataclasses.replace(self, **changes)

    @property
    def moving(self) -> bool:
        """True when the camera or any object moves during the shutter."""
        return self.camera.moving or any(o.moving for o in self.objects)

    @property
    def has_lens(self) -> bool:
        """True when the camera has a thin lens with a non-zero radius."""
        return self.camera.lens is not None and self.camera.lens.radius > 0.0

    @property
    def triangle_count(self) -> int:
        return sum(len(o.faces) for o in self.objects)


# --------------------------------------------------------------------------
# The scene file's schema: each table's keys with their types and ranges, validated by pydantic through
# pipeline_sim.schema (unknown keys with the nearest known name, types without coercion, finite numbers,
# ranges, required keys). The rules between keys (far beyond near, a camera's keys by its projection, a
# light's by its type, a primitive's parameters, degenerate views) are the parsers' below.

Finite = Annotated[float, Strict(), Field(allow_inf_nan=False)]
Positive = Annotated[float, Strict(), Field(gt=0.0, allow_inf_nan=False)]
Radiance = number(0.0, MAX_RADIANCE)  # a light intensity or ambient term: float32 shading stays finite


def _vector(n: int, item: Any = Finite) -> Any:
    return Annotated[list[item], Field(min_length=n, max_length=n)]


Vec3 = _vector(3)
Colour = _vector(3, Radiance)
#: A number or ``n`` numbers (a primitive's size, a scale): checked by :meth:`_Reader.number_or_numbers`.
NumberOrNumbers = Any



@dataclass
class ImageTable:
    __pydantic_config__ = FORBID
    width: count(1, IMAGE_LIMITS["width"]) = schema.key("pixels")
    height: count(1, IMAGE_LIMITS["height"]) = schema.key("pixels")
    spp: count(1, IMAGE_LIMITS["spp"]) = schema.key("samples per pixel")
    seed: count(0, 2**64 - 1) = schema.key("sample-pattern seed", default=0)


@dataclass
class LensTable:
    __pydantic_config__ = FORBID
    radius: Annotated[float, Strict(), Field(ge=0.0, allow_inf_nan=False)] = schema.key(
        "aperture radius, world units (0: a pinhole)")
    focus_distance: Positive | None = schema.key("world units along the view direction (default: eye to look_at)",
                                           default=None)


@dataclass
class CameraTable:
    __pydantic_config__ = FORBID
    eye: Vec3 = schema.key("at shutter open")
    look_at: Vec3 = schema.key("at shutter open")
    near: Positive = schema.key("near plane distance")
    far: Finite = schema.key("far plane distance, > near")
    projection: Literal[PROJECTIONS] = schema.key("the projection", default="perspective")
    up: Vec3 = schema.key("up direction, need not be orthogonal", default_factory=lambda: [0.0, 1.0, 0.0])
    fov_y: Annotated[float, Strict(), Field(gt=0.0, lt=180.0, allow_inf_nan=False)] | None = schema.key(
        "vertical field of view in degrees (perspective)", default=None)
    frustum: _vector(4) | None = schema.key("[left, right, bottom, top]", default=None)
    ortho_height: Positive | None = schema.key("orthographic: view volume height", default=None)
    eye_close: Vec3 | None = schema.key("eye at shutter close", default=None)
    look_at_close: Vec3 | None = schema.key("look_at at shutter close", default=None)
    lens: LensTable | None = schema.key("a thin lens (perspective)", default=None)


@dataclass
class BackgroundTable:
    __pydantic_config__ = FORBID
    color: Colour = schema.key("linear RGB", default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class LightTable:
    __pydantic_config__ = FORBID
    type: Literal[LIGHT_TYPES] = schema.key("the light's type", default="directional")
    direction: Vec3 | None = schema.key("directional: from the light toward the scene", default=None)
    position: Vec3 | None = schema.key("point: its position", default=None)
    color: Colour = schema.key("linear RGB", default_factory=lambda: [1.0, 1.0, 1.0])
    intensity: Radiance = schema.key("its intensity", default=1.0)
    ambient: Radiance = schema.key("the ambient term", default=0.1)


@dataclass
class TransformTable:
    __pydantic_config__ = FORBID
    translate: Vec3 | None = schema.key("translation", default=None)
    rotate: Vec3 | None = schema.key("degrees about x, then y, then z", default=None)
    scale: NumberOrNumbers = schema.key("a number or [sx, sy, sz], components > 0", default=None)


@dataclass
class ObjectTable:
    __pydantic_config__ = FORBID
    name: Annotated[str, Strict(), Field(min_length=1)] | None = schema.key("unique name", default=None)
    primitive: Literal[PRIMITIVES] | None = schema.key("a built-in shape", default=None)
    mesh: Annotated[str, Strict(), Field(min_length=1)] | None = schema.key("a mesh file, relative to the scene file",
                                                                       default=None)
    material: Literal[MATERIALS] = schema.key("the material", default="lambert")
    color: Colour = schema.key("linear RGB", default_factory=lambda: list(DEFAULT_OBJECT_COLOR))
    use_vertex_colors: Flag = schema.key("use the mesh file's vertex colours", default=False)
    open: TransformTable | None = schema.key("transform at shutter open", default=None)
    close: TransformTable | None = schema.key("transform at shutter close", default=None)


# --------------------------------------------------------------------------
# Validation helpers. `ctx` is the file name as shown to the user; `key` is
# the dotted key path inside the file.

_TOML_TYPE_NAMES = {
    bool: "boolean",
    int: "integer",
    float: "float",
    str: "string",
    list: "array",
    dict: "table",
}


def _type_name(v: Any) -> str:
    for t, name in _TOML_TYPE_NAMES.items():
        if type(v) is t:
            if t is str:
                return f"string {v!r}" if len(v) <= 40 else "string"
            if t in (int, float, bool):
                return f"{name} {str(v).lower() if t is bool else v}"
            return name
    return type(v).__name__


class _Reader:
    """The scene file's name (``ctx``) for messages, and the checks the schema leaves to code: a number
    or ``n`` numbers (a primitive's size, a scale)."""

    def __init__(self, ctx: str) -> None:
        self.ctx = ctx

    def error(self, key: str, message: str) -> UserError:
        where = f"{self.ctx}: {key}" if key else self.ctx
        return UserError(f"{where}: {message}")

    def number(self, v: Any, key: str) -> float:
        if type(v) not in (int, float):
            raise self.error(key, f"expected a number, got {_type_name(v)}")
        try:
            x = float(v)
        except OverflowError:   # an integer of hundreds of digits
            raise self.error(key, f"expected a finite number, got an integer of {len(str(abs(v)))} digits") from None
        if not math.isfinite(x):
            raise self.error(key, f"expected a finite number, got {v}")
        return x

    def number_or_numbers(self, v: Any, key: str, n: int) -> np.ndarray:
        if isinstance(v, list):
            if len(v) != n:
                raise self.error(key, f"expected {n} numbers, got {len(v)}")
            return np.array([self.number(x, f"{key}[{i}]") for i, x in enumerate(v)])
        if type(v) not in (int, float):
            raise self.error(key, f"expected a number or {n} numbers, got {_type_name(v)}")
        return np.full(n, self.number(v, key))


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:g}" for x in v) + "]"


# --------------------------------------------------------------------------
# Primitives. Each builder returns (positions, normals, faces) with
# counter-clockwise outward-facing triangles.


_Mesh = tuple[np.ndarray, np.ndarray, np.ndarray]


def _sphere(radius: float, subdivisions: int) -> _Mesh:
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    unit = np.asarray(m.vertices, dtype=np.float64)
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    return unit * radius, unit, np.asarray(m.faces)


def _box(size: np.ndarray) -> _Mesh:
    half = np.asarray(size, dtype=np.float64) / 2.0
    axes = np.eye(3)
    positions, normals, faces = [], [], []
    for axis in range(3):
        u_axis, v_axis = (axis + 1) % 3, (axis + 2) % 3  # e_u x e_v = e_axis
        for sign in (1.0, -1.0):
            n = axes[axis] * sign
            u = axes[u_axis] * sign  # flip u so that u x v = n for both signs
            v = axes[v_axis]
            base = len(positions)
            for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                positions.append((n + su * u + sv * v) * half)
                normals.append(n)
            faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.array(positions), np.array(normals), np.array(faces)


def _plane(size: np.ndarray, subdivisions: int) -> _Mesh:
    k = subdivisions + 2  # vertices per side
    xs = np.linspace(-size[0] / 2.0, size[0] / 2.0, k)
    zs = np.linspace(-size[1] / 2.0, size[1] / 2.0, k)
    gx, gz = np.meshgrid(xs, zs, indexing="ij")  # [i, j] -> (x_i, z_j)
    positions = np.stack([gx.ravel(), np.zeros(k * k), gz.ravel()], axis=1)
    normals = np.tile([0.0, 1.0, 0.0], (k * k, 1))
    i, j = np.meshgrid(np.arange(k - 1), np.arange(k - 1), indexing="ij")
    a = (i * k + j).ravel()  # (x_i, z_j)
    b = a + 1  # (x_i, z_j+1)
    c = a + k  # (x_i+1, z_j)
    d = c + 1  # (x_i+1, z_j+1)
    # (+z) x (+x) = +y, so (a, b, c) is counter-clockwise seen from +y.
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([c, b, d], 1)])
    return positions, normals, faces


def _torus(major_radius: float, minor_radius: float, major_sections: int, minor_sections: int) -> _Mesh:
    theta = 2.0 * np.pi * np.arange(major_sections) / major_sections  # around the y axis
    phi = 2.0 * np.pi * np.arange(minor_sections) / minor_sections  # around the tube
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    radial = np.stack([np.cos(th), np.zeros_like(th), -np.sin(th)], axis=-1)
    up = np.array([0.0, 1.0, 0.0])
    normals = np.cos(ph)[..., None] * radial + np.sin(ph)[..., None] * up
    positions = major_radius * radial + minor_radius * normals
    i, j = np.meshgrid(np.arange(major_sections), np.arange(minor_sections), indexing="ij")
    i1 = (i + 1) % major_sections
    j1 = (j + 1) % minor_sections
    a = (i * minor_sections + j).ravel()
    b = (i1 * minor_sections + j).ravel()
    c = (i1 * minor_sections + j1).ravel()
    d = (i * minor_sections + j1).ravel()
    # d(theta) x d(phi) points along the outward normal for this parametrization.
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return positions.reshape(-1, 3), normals.reshape(-1, 3), faces


def _cylinder(radius: float, height: float, sections: int) -> _Mesh:
    ang = 2.0 * np.pi * np.arange(sections) / sections
    radial = np.stack([np.cos(ang), np.zeros(sections), -np.sin(ang)], axis=1)  # CCW seen from +y
    h = height / 2.0
    up = np.array([0.0, 1.0, 0.0])
    ring_lo = radius * radial - h * up
    ring_hi = radius * radial + h * up
    k = np.arange(sections)
    k1 = (k + 1) % sections
    # side: vertices [0, s) bottom ring, [s, 2s) top ring
    side_faces = np.concatenate(
        [np.stack([k, k1, k1 + sections], 1), np.stack([k, k1 + sections, k + sections], 1)]
    )
    # top cap: centre at 2s, ring at 2s+1 ..; bottom cap: centre at 3s+1, ring after
    top_c = 2 * sections
    bot_c = 3 * sections + 1
    top_faces = np.stack([np.full(sections, top_c), top_c + 1 + k, top_c + 1 + k1], 1)
    bot_faces = np.stack([np.full(sections, bot_c), bot_c + 1 + k1, bot_c + 1 + k], 1)
    positions = np.concatenate([ring_lo, ring_hi, [h * up], ring_hi, [-h * up], ring_lo])
    normals = np.concatenate(
        [radial, radial, np.tile(up, (sections + 1, 1)), np.tile(-up, (sections + 1, 1))]
    )
    faces = np.concatenate([side_faces, top_faces, bot_faces])
    return positions, normals, faces


@dataclass
class SphereObject(ObjectTable):
    radius: Positive = schema.key("radius", default=1.0)
    subdivisions: count(0, 7) = schema.key("icosphere subdivisions: 20*4^n triangles", default=3)


@dataclass
class BoxObject(ObjectTable):
    size: NumberOrNumbers = schema.key("a number or [x, y, z], > 0", default=(1.0, 1.0, 1.0))


@dataclass
class PlaneObject(ObjectTable):
    size: NumberOrNumbers = schema.key("a number or [x, z], > 0", default=(1.0, 1.0))
    subdivisions: count(0, 1023) = schema.key("n: an (n+1) x (n+1) grid of quads", default=0)


@dataclass
class TorusObject(ObjectTable):
    major_radius: Positive = schema.key("ring radius", default=1.0)
    minor_radius: Positive = schema.key("tube radius, < major_radius", default=0.25)
    major_sections: count(3, 4096) = schema.key("sections around the ring", default=32)
    minor_sections: count(3, 4096) = schema.key("sections around the tube", default=16)


@dataclass
class CylinderObject(ObjectTable):
    radius: Positive = schema.key("radius", default=0.5)
    height: Positive = schema.key("height", default=1.0)
    sections: count(3, 65536) = schema.key("sections around the axis", default=32)


#: Each primitive's object table: the object's keys and the primitive's parameters.
_PRIMITIVE_TABLES: dict[str, type[ObjectTable]] = {
    "sphere": SphereObject, "box": BoxObject, "plane": PlaneObject, "torus": TorusObject, "cylinder": CylinderObject,
}
_OBJECT_KEYS = tuple(f.name for f in dataclasses.fields(ObjectTable))
#: Each primitive's parameter names.
_PRIMITIVE_PARAMS: dict[str, tuple[str, ...]] = {
    name: tuple(f.name for f in dataclasses.fields(t) if f.name not in _OBJECT_KEYS)
    for name, t in _PRIMITIVE_TABLES.items()
}

_PRIMITIVE_BUILDERS: dict[str, Callable[..., _Mesh]] = {
    "sphere": _sphere,
    "box": _box,
    "plane": _plane,
    "torus": _torus,
    "cylinder": _cylinder,
}

def _primitive_mesh(r: _Reader, obj: ObjectTable, key: str, primitive: str) -> _Mesh:
    params: dict[str, Any] = {}
    for name in _PRIMITIVE_PARAMS[primitive]:
        v = getattr(obj, name)
        if name == "size":  # a number or one per axis
            v = r.number_or_numbers(list(v) if isinstance(v, tuple) else v, f"{key}.{name}",
                                    3 if primitive == "box" else 2)
            if np.any(v <= 0.0):
                raise r.error(f"{key}.{name}", f"must be > 0, got {_fmt(v)}")
        params[name] = v
    if primitive == "torus" and params["minor_radius"] >= params["major_radius"]:
        raise r.error(
            f"{key}.minor_radius",
            f"must be < major_radius ({params['major_radius']:g}), got {params['minor_radius']:g}",
        )
    return _PRIMITIVE_BUILDERS[primitive](**params)


# --------------------------------------------------------------------------
# Mesh files


@dataclass
class _LoadedMesh:
    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None
    data: bytes


def _gltf_buffer_bytes(path: Path) -> bytes:
    """Bytes of the external buffers a .gltf file references (for the digest)."""
    if path.suffix.lower() != ".gltf":
        return b""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        uris = [b.get("uri") for b in doc.get("buffers", []) if isinstance(b, dict)]
    except (ValueError, AttributeError):
        return b""  # trimesh reports the broken file
    out = b""
    for uri in uris:
        if isinstance(uri, str) and not uri.startswith("data:"):
            extra = path.parent / uri
            if extra.is_file():
                out += len(uri).to_bytes(8, "little") + uri.encode() + extra.read_bytes()
    return out


_FORMAT_NAMES = {".obj": "OBJ", ".ply": "PLY", ".stl": "STL", ".off": "OFF", ".gltf": "glTF", ".glb": "GLB"}
_STL_HEADER = 84  # binary STL: 80-byte header, uint32 triangle count, then 50 bytes a triangle
_STL_TRIANGLE = 50


def _utf8_problem(data: bytes) -> str | None:
    """Why ``data`` is not text (UTF-8 without NUL bytes), or None."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        return f"not UTF-8 text at byte {e.start} (0x{data[e.start]:02x})"
    if "\0" in text:
        return f"not text: a NUL byte at byte {data.index(0)}"
    return None


def _stl_problem(data: bytes) -> str | None:
    if len(data) >= _STL_HEADER:
        count = int.from_bytes(data[80:84], "little")
        if len(data) == _STL_HEADER + _STL_TRIANGLE * count:
            return None
        binary = (f"its header gives {count} triangles, {_STL_HEADER + _STL_TRIANGLE * count} bytes, "
                  f"but the file has {len(data)}")
    else:
        binary = f"{len(data)} bytes, shorter than the {_STL_HEADER}-byte header"
    text = _utf8_problem(data) or (None if data.lstrip()[:5].lower() == b"solid" else "does not start with 'solid'")
    return None if text is None else f"neither binary STL ({binary}) nor ASCII STL: {text}"


def _ply_problem(data: bytes) -> str | None:
    if not (data.startswith(b"ply\n") or data.startswith(b"ply\r\n")):
        return "does not start with the line 'ply'"
    end = data.find(b"end_header")
    if end < 0:
        return "no 'end_header' line"
    problem = _utf8_problem(data[:end])
    if problem is not None:
        return f"the header is {problem}"
    header = [line.split() for line in data[:end].decode("utf-8").splitlines()]
    if not any(words[:2] == ["format", "ascii"] for words in header):
        return None  # a binary body: trimesh checks its length against the counts
    elements: list[tuple[str, int]] = []
    for words in header:
        if words[:1] == ["element"]:
            if len(words) != 3 or not (words[2].isascii() and words[2].isdigit()):   # int() takes no '³'
                return f"header line 'element {' '.join(words[1:])}': expected a name and a count"
            elements.append((words[1], int(words[2])))
    body_start = data.find(b"\n", end)
    body = data[body_start + 1:] if body_start >= 0 else b""
    problem = _utf8_problem(body)
    if problem is not None:
        return f"the ASCII body is {problem}"
    rows = sum(1 for line in body.decode("utf-8").splitlines() if line.strip())
    need = sum(n for _, n in elements)
    if rows < need:
        counts = ", ".join(f"{n} {name}" for name, n in elements)
        return f"its header gives {counts} elements, {need} lines, but the body has {rows}"
    return None


def _obj_problem(data: bytes) -> str | None:
    """Text, and face indices that name an existing vertex (1-based; a negative
    index counts back from the last vertex read so far; 0 is no index)."""
    problem = _utf8_problem(data)
    if problem is not None:
        return problem
    lines = data.decode("utf-8").splitlines()
    kinds = ("v", "vt", "vn")
    total = {k: 0 for k in kinds}
    for line in lines:
        words = line.split(None, 1)
        if words and words[0] in total:
            total[words[0]] += 1
    seen = {k: 0 for k in kinds}
    for n, line in enumerate(lines, 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if words[0] in seen:
            seen[words[0]] += 1
            continue
        if words[0] != "f":
            continue
        for word in words[1:]:
            for kind, part in zip(kinds, word.split("/")):
                if not part:
                    continue
                try:
                    i = int(part)
                except ValueError:
                    return f"line {n}: face vertex '{printable(word)}' is not of the form i, i/t, i//n or i/t/n"
                if i == 0:
                    return f"line {n}: face vertex '{word}' uses index 0 (OBJ indices start at 1)"
                if i < 0 and -i > seen[kind]:
                    return (f"line {n}: face vertex '{word}' counts back {-i} from the {seen[kind]} "
                            f"'{kind}' lines before it")
                if i > total[kind]:
                    return f"line {n}: face vertex '{word}' names '{kind}' {i}, but the file has {total[kind]}"
    return None


def _glb_problem(data: bytes, folder: Path) -> str | None:
    if len(data) < 12 or data[:4] != b"glTF":
        return "does not start with the 12-byte GLB header (magic 'glTF')"
    version = int.from_bytes(data[4:8], "little")
    length = int.from_bytes(data[8:12], "little")
    if version != 2:
        return f"GLB version {version}, only version 2 is supported"
    if length != len(data):
        return f"its header gives a length of {length} bytes but the file has {len(data)}"
    chunk = int.from_bytes(data[12:16], "little")
    if data[16:20] != b"JSON" or 20 + chunk > len(data):
        return "the header is not followed by a whole JSON chunk"
    rest = 20 + chunk
    binary = None
    if rest < len(data):
        size = int.from_bytes(data[rest:rest + 4], "little")
        if len(data) < rest + 8 or data[rest + 4:rest + 8] != b"BIN\0" or rest + 8 + size > len(data):
            return f"the JSON chunk is followed by {len(data) - rest} bytes that are not a whole BIN chunk"
        binary = data[rest + 8:rest + 8 + size]
    problem = _gltf_problem(data[20:rest], folder, binary, glb=True)
    return None if problem is None else f"its JSON chunk: {problem}"


# glTF accessors: bytes a component, components an element
_GLTF_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_GLTF_TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


class _GltfError(Exception):
    """What is wrong in a glTF document, in its own terms."""


def _gltf_index(value: Any, what: str, table: list, target: str) -> int:
    """``value`` as an index into the document's ``target`` array."""
    if type(value) is not int or not 0 <= value < len(table):
        raise _GltfError(f"{what} is {_gltf_shown(value)}, not an index into {target} (which has {len(table)})")
    return value


def _gltf_shown(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:40] + "..."


def _gltf_count(item: dict, key: str, what: str, default: int | None = None) -> int:
    """``item[key]`` as a non-negative integer (``default`` if absent and allowed)."""
    value = item.get(key, default)
    if type(value) is not int or value < 0:
        raise _GltfError(f"{what} {key} is {_gltf_shown(value) if key in item else 'missing'}, "
                         "expected a non-negative integer")
    return value


def _gltf_buffer_length(i: int, buffer: dict, folder: Path, binary: bytes | None, glb: bool) -> int:
    """The bytes of buffer ``i`` that exist: a data URI's decoded length, an
    external file's size or (buffer 0 of a GLB without a URI) the BIN chunk's."""
    uri = buffer.get("uri")
    if uri is None:
        if not (glb and i == 0):
            raise _GltfError(f"buffer {i} has no uri")
        if binary is None:
            raise _GltfError("buffer 0 refers to the BIN chunk, but the file has none")
        return len(binary)
    if not isinstance(uri, str):
        raise _GltfError(f"buffer {i} uri is {_gltf_shown(uri)}, not a string")
    if uri.startswith("data:"):
        head, comma, payload = uri.partition(",")
        if not comma or not head.endswith(";base64"):
            raise _GltfError(f"buffer {i} data URI is not base64 ('data:...;base64,...')")
        try:
            return len(base64.b64decode(payload, validate=True))
        except binascii.Error as e:
            raise _GltfError(f"buffer {i} data URI is not valid base64 ({e})") from None
    path = folder / uri   # as written, as the mesh loader and the scene digest take it
    if not path.is_file():
        raise _GltfError(f"buffer {i} file '{uri}' not found (resolved to '{path}')")
    return path.stat().st_size


def _gltf_structure(doc: dict, folder: Path, binary: bytes | None, glb: bool) -> None:
    """Check what the mesh loader reads of a glTF document: the types of the
    top-level members, each index between them and each byte range."""
    if not isinstance(doc.get("asset"), dict):
        raise _GltfError(f"'asset' is {_gltf_shown(doc.get('asset'))}, not an object")
    arrays = {}
    for name in ("scenes", "nodes", "meshes", "accessors", "bufferViews", "buffers", "materials", "textures",
                 "images", "samplers"):
        value = doc.get(name, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise _GltfError(f"'{name}' is not an array of objects")
        arrays[name] = value
    if "scene" in doc:
        _gltf_index(doc["scene"], "'scene'", arrays["scenes"], "scenes")
    node_lists = [(f"scene {i}", "nodes", "a node of", s) for i, s in enumerate(arrays["scenes"])]
    node_lists += [(f"node {i}", "children", "a child of", n) for i, n in enumerate(arrays["nodes"])]
    for owner, key, role, obj in node_lists:
        refs = obj.get(key, [])
        if not isinstance(refs, list):
            raise _GltfError(f"{owner} {key} is not an array")
        for n in refs:
            _gltf_index(n, f"{role} {owner}", arrays["nodes"], "nodes")
    for i, node in enumerate(arrays["nodes"]):
        if "mesh" in node:
            _gltf_index(node["mesh"], f"node {i} mesh", arrays["meshes"], "meshes")
        for key, size in (("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)):
            value = node.get(key, [0.0] * size)
            if (not isinstance(value, list) or len(value) != size
                    or not all(type(x) in (int, float) for x in value)):
                raise _GltfError(f"node {i} {key} is {_gltf_shown(value)}, not {size} numbers")
    accessors = set()
    for i, mesh in enumerate(arrays["meshes"]):
        primitives = mesh.get("primitives")
        if not isinstance(primitives, list) or not all(isinstance(p, dict) for p in primitives):
            raise _GltfError(f"mesh {i} primitives is not an array of objects")
        for j, prim in enumerate(primitives):
            what = f"mesh {i} primitive {j}"
            attributes = prim.get("attributes")
            if not isinstance(attributes, dict):
                raise _GltfError(f"{what} attributes is not an object")
            for name, a in attributes.items():
                accessors.add(_gltf_index(a, f"{what} attribute {name}", arrays["accessors"], "accessors"))
            if "indices" in prim:
                accessors.add(_gltf_index(prim["indices"], f"{what} indices", arrays["accessors"], "accessors"))
            if "material" in prim:
                _gltf_index(prim["material"], f"{what} material", arrays["materials"], "materials")
            if type(prim.get("mode", 4)) is not int:
                raise _GltfError(f"{what} mode is {_gltf_shown(prim['mode'])}, not an integer")
    lengths = [_gltf_buffer_length(i, b, folder, binary, glb) for i, b in enumerate(arrays["buffers"])]
    views = []
    for i, view in enumerate(arrays["bufferViews"]):
        b = _gltf_index(view.get("buffer"), f"bufferView {i} buffer", arrays["buffers"], "buffers")
        start = _gltf_count(view, "byteOffset", f"bufferView {i}", 0)
        length = _gltf_count(view, "byteLength", f"bufferView {i}")
        declared = _gltf_count(arrays["buffers"][b], "byteLength", f"buffer {b}")
        if declared > lengths[b]:
            raise _GltfError(f"buffer {b} byteLength is {declared}, but its data has {lengths[b]} bytes")
        if start + length > declared:
            raise _GltfError(f"bufferView {i} spans bytes {start}-{start + length} of buffer {b}, which has {declared}")
        stride = view.get("byteStride")
        if stride is not None and (type(stride) is not int or stride <= 0):
            raise _GltfError(f"bufferView {i} byteStride is {_gltf_shown(stride)}, expected a positive integer")
        views.append((length, stride))
    for i in sorted(accessors):
        a = arrays["accessors"][i]
        count = _gltf_count(a, "count", f"accessor {i}")
        if a.get("componentType") not in _GLTF_COMPONENT_BYTES or isinstance(a.get("componentType"), bool):
            raise _GltfError(f"accessor {i} componentType is {_gltf_shown(a.get('componentType'))}, "
                             f"expected one of {sorted(_GLTF_COMPONENT_BYTES)}")
        if a.get("type") not in _GLTF_TYPE_COMPONENTS:
            raise _GltfError(f"accessor {i} type is {_gltf_shown(a.get('type'))}, "
                             f"expected one of {', '.join(_GLTF_TYPE_COMPONENTS)}")
        if "bufferView" not in a:
            continue  # zeros (or sparse values)
        v = _gltf_index(a["bufferView"], f"accessor {i} bufferView", arrays["bufferViews"], "bufferViews")
        start = _gltf_count(a, "byteOffset", f"accessor {i}", 0)
        element = _GLTF_COMPONENT_BYTES[a["componentType"]] * _GLTF_TYPE_COMPONENTS[a["type"]]
        length, stride = views[v]
        end = start + ((count - 1) * (stride or element) + element if count else 0)
        if end > length:
            raise _GltfError(f"accessor {i} reads bytes {start}-{end} of bufferView {v}, which has {length}")


def _gltf_problem(data: bytes, folder: Path, binary: bytes | None = None, glb: bool = False) -> str | None:
    problem = _utf8_problem(data)
    if problem is not None:
        return problem
    try:
        doc = json.loads(data.decode("utf-8"))
    except json.JSONDecodeError as e:
        return f"not JSON (line {e.lineno}, column {e.colno}: {e.msg})"
    if not isinstance(doc, dict) or "asset" not in doc:
        return "the JSON is not a glTF document (no 'asset' object)"
    try:
        _gltf_structure(doc, folder, binary, glb)
    except _GltfError as e:
        return str(e)
    return None


def _off_problem(data: bytes) -> str | None:
    """The OFF layout: 'OFF' (or 'COFF'), the vertex and face counts, then
    that many vertex lines (x y z ...) and face lines (k i1 .. ik ...)."""
    problem = _utf8_problem(data)
    if problem is not None:
        return problem
    lines = [(n, line.split("#", 1)[0].split()) for n, line in enumerate(data.decode("utf-8").splitlines(), 1)]
    lines = [(n, words) for n, words in lines if words]
    if not lines or lines[0][1][0] not in ("OFF", "COFF"):
        return "does not start with 'OFF'"
    lines[0] = (lines[0][0], lines[0][1][1:])  # the counts may follow the keyword on its line
    if not lines[0][1]:
        del lines[0]

    def shown(words: list[str]) -> str:
        text = " ".join(words)
        return f"'{text}'" if len(text) <= 40 else f"'{text[:40]}...'"

    def numbers(words: list[str], kind: type) -> bool:
        try:
            for w in words:
                kind(w)
        except ValueError:
            return False
        return True

    if not lines or len(lines[0][1]) < 2 or not numbers(lines[0][1][:2], int):
        return "no vertex and face counts after 'OFF'" if not lines else (
            f"line {lines[0][0]}: expected the vertex and face counts, got {shown(lines[0][1])}")
    nv, nf = (int(w) for w in lines[0][1][:2])
    body = lines[1:]
    if nv < 0 or nf < 0 or len(body) < nv + nf:
        return f"the counts give {nv} vertices and {nf} faces, but {len(body)} lines follow"
    for n, words in body[:nv]:
        if len(words) < 3 or not numbers(words[:3], float):
            return f"line {n}: expected a vertex (three numbers), got {shown(words)}"
    for n, words in body[nv:nv + nf]:
        k = int(words[0]) if numbers(words[:1], int) else 0
        if k < 3 or len(words) <= k or not numbers(words[1:k + 1], int):
            return f"line {n}: expected a face (a count k >= 3 and k vertex indices), got {shown(words)}"
    return None


# a format's own check of a file's bytes, before trimesh parses it: trimesh
# decodes text it cannot read as UTF-8 with an optional dependency (not
# installed), and its errors on garbage rarely say what is wrong
# (given the file's bytes and its folder, where a .gltf's buffers are)
_FORMAT_PROBLEM: dict[str, Callable[[bytes, Path], str | None]] = {
    ".obj": lambda data, folder: _obj_problem(data), ".off": lambda data, folder: _off_problem(data),
    ".stl": lambda data, folder: _stl_problem(data), ".ply": lambda data, folder: _ply_problem(data),
    ".glb": _glb_problem, ".gltf": _gltf_problem,
}


@contextlib.contextmanager
def _quiet_parser() -> Iterator[None]:
    """Silence what trimesh reports on its own while it parses a bad file (numpy
    floating-point warnings, Python warnings, log messages to stderr): the
    loader reports the problem itself, on one line."""
    logger = logging.getLogger("trimesh")
    was = logger.disabled
    logger.disabled = True
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.disabled = was


def _parse_error_detail(e: Exception) -> str:
    """One line saying what a mesh parser's exception found wrong."""
    if isinstance(e, KeyError) and e.args:
        return f"missing entry {e.args[0]!r}"
    if isinstance(e, UnicodeDecodeError):
        return f"not UTF-8 text at byte {e.start}"
    text = str(e).strip()
    first = text.splitlines()[0] if text else ""
    return f"{type(e).__name__}: {first}" if first else type(e).__name__


def _load_mesh_file(r: _Reader, key: str, written: str, resolved: Path) -> _LoadedMesh:
    import trimesh

    shown = printable(f"'{written}' (resolved to '{resolved}')")
    if not resolved.exists():
        raise r.error(key, f"mesh file not found: {shown}")
    if not resolved.is_file():
        raise r.error(key, f"mesh path is not a file: {shown}")
    suffix = resolved.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise r.error(
            key, f"unsupported mesh format '{suffix or resolved.name}' for {shown}; expected one of: {', '.join(MESH_FORMATS)}"
        )
    try:
        raw = resolved.read_bytes()
        data = raw + _gltf_buffer_bytes(resolved)
    except OSError as e:
        raise r.error(key, f"cannot read mesh file {shown}: {e.strerror or e}") from None
    invalid = f"not a valid {_FORMAT_NAMES[suffix]} file {shown}"
    problem = _FORMAT_PROBLEM[suffix](raw, resolved.parent)
    if problem is not None:
        raise r.error(key, f"{invalid}: {printable(problem)}")
    try:
        with _quiet_parser():
            loaded = trimesh.load_scene(str(resolved), process=False)
        parts = [
            (np.asarray(loaded.graph[node][0], dtype=np.float64), loaded.geometry[name])
            for node in loaded.graph.nodes_geometry
            for name in [loaded.graph[node][1]]
            if isinstance(loaded.geometry.get(name), trimesh.Trimesh)
        ]
    except Exception as e:  # trimesh raises many kinds on bad files
        raise r.error(key, f"{invalid}: {printable(_parse_error_detail(e))}") from None

    positions, normals, faces, colors = [], [], [], []
    offset = 0
    for transform, part in parts:
        if len(part.faces) == 0:
            continue
        with _quiet_parser():  # huge or degenerate triangles: _mesh_part keeps their normals finite
            p, n, f, c = _mesh_part(r, key, shown, part, transform)
        positions.append(p)
        normals.append(n)
        faces.append(f + offset)
        colors.append(c)
        offset += len(p)
    if not faces:
        raise r.error(key, f"mesh file has no triangles: {shown}")
    if offset >= 2**31:
        raise r.error(key, f"mesh file has too many vertices: {shown}")
    has_colors = any(c is not None for c in colors)
    return _LoadedMesh(
        positions=np.concatenate(positions),
        normals=np.concatenate(normals),
        faces=np.concatenate(faces).astype(np.int32),
        # parts without vertex colours get NaN rows, filled with the object's colour
        vertex_colors=np.concatenate(
            [c if c is not None else np.full((len(p), 3), np.nan, np.float32) for p, c in zip(positions, colors)]
        )
        if has_colors
        else None,
        data=data,
    )


def _mesh_part(
    r: _Reader, key: str, shown: str, mesh: Any, transform: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """One trimesh geometry placed by its scene-graph transform:
    (positions, unit normals, faces, vertex colours or None)."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    finite = np.all(np.isfinite(vertices), axis=1)
    if not np.all(finite):
        bad = int(np.flatnonzero(~finite)[0])
        raise r.error(key, f"mesh file has non-finite vertex coordinates (vertex {bad}): {shown}")
    faces = np.asarray(mesh.faces)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise r.error(key, f"mesh file has face indices out of range: {shown}")

    file_normals = mesh._cache["vertex_normals"]  # normals read from the file, if any
    has_normals = file_normals is not None and np.shape(file_normals) == vertices.shape
    if has_normals and not np.all(np.isfinite(file_normals)):
        raise r.error(key, f"mesh file has non-finite vertex normals: {shown}")
    has_colors = mesh.visual.kind == "vertex"
    if not has_normals and not has_colors:
        # vertices merged where their positions are equal, so that smooth
        # normals can be computed (trimesh's merge_vertices rounds through
        # int64, which overflows for coordinates beyond about 1e10)
        unique, inverse = np.unique(vertices + 0.0, axis=0, return_inverse=True)  # + 0.0: -0.0 is 0.0
        mesh = type(mesh)(unique, inverse.reshape(-1)[faces], process=False)
    mesh.remove_unreferenced_vertices()
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    normals = np.array(mesh.vertex_normals, dtype=np.float64)
    colors = None
    if has_colors:
        colors = np.asarray(mesh.visual.vertex_colors)[:, :3].astype(np.float32) / 255.0

    linear = transform[:3, :3]
    if not np.allclose(transform, np.eye(4)):
        vertices = vertices @ linear.T + transform[:3, 3]
        if not np.all(np.isfinite(vertices)):
            raise r.error(key, f"mesh file's node transforms give non-finite coordinates: {shown}")
        det = np.linalg.det(linear)
        if abs(det) < 1e-300:
            raise r.error(key, f"mesh file has a singular node transform: {shown}")
        normals = normals @ np.linalg.inv(linear)
        if det < 0.0:  # a mirroring node transform reverses the winding (as glTF specifies)
            faces = faces[:, ::-1]
    length = np.linalg.norm(normals, axis=1)
    zero = ~((length > 1e-12) & (length < np.inf))
    normals[zero] = (0.0, 0.0, 1.0)  # vertices used only by degenerate triangles (or overflowing normals)
    normals /= np.where(zero, 1.0, length)[:, None]
    return vertices, normals, faces, colors


# --------------------------------------------------------------------------
# Sections


def check_image_value(name: str, value: Any, where: str) -> int:
    """``value`` as the image setting ``name`` (width, height, spp or seed):
    an integer, > 0 and at most ``IMAGE_LIMITS[name]`` (a seed: in [0, 2^64)).
    Otherwise a :class:`UserError` naming ``where`` (a scene key, a command-line
    option or a sweep setting): the scene file and every override of it
    pass this one check."""
    if type(value) is not int:
        raise UserError(f"{where}: expected an integer, got {_type_name(value)}")
    if name == "seed":
        if not 0 <= value < 2**64:
            raise UserError(f"{where}: must be in [0, 2^64), got {value}")
    elif value <= 0:
        raise UserError(f"{where}: must be > 0, got {value}")
    elif value > IMAGE_LIMITS[name]:
        raise UserError(f"{where}: must be <= {IMAGE_LIMITS[name]}, got {value}")
    return value


def _section(r: _Reader, cls: type, data: dict, name: str, required: bool = False) -> Any:
    """The table ``name`` of the scene document validated as ``cls`` (its defaults when absent)."""
    if name not in data:
        if required:
            raise r.error(name, f"missing required table [{name}]")
        return cls()
    return schema.build(cls, data[name], r.ctx, (name,))


def _parse_image(r: _Reader, data: dict) -> ImageSettings:
    return ImageSettings(**dataclasses.asdict(_section(r, ImageTable, data, "image", required=True)))


def _crosses_zero(a: np.ndarray, b: np.ndarray) -> bool:
    """True if the segment (1-t) a + t b, t in [0, 1], passes (nearly) through 0."""
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-9 or nb < 1e-9:
        return True
    if np.dot(a, b) > 0.0:
        return False
    return np.linalg.norm(np.cross(a, b)) <= 1e-9 * na * nb


def _parse_camera(r: _Reader, data: dict) -> Camera:
    cam = _section(r, CameraTable, data, "camera", required=True)
    projection = cam.projection
    eye, look_at, up = np.array(cam.eye), np.array(cam.look_at), np.array(cam.up)
    eye_close = np.array(cam.eye_close) if cam.eye_close is not None else eye
    look_at_close = np.array(cam.look_at_close) if cam.look_at_close is not None else look_at
    if np.linalg.norm(up) < 1e-12:
        raise r.error("camera.up", "must not be the zero vector")
    up_unit = up / np.linalg.norm(up)
    d0, d1 = look_at - eye, look_at_close - eye_close
    for d, when, keys in ((d0, "", "eye/look_at"), (d1, " at shutter close", "eye_close/look_at_close")):
        if np.linalg.norm(d) < 1e-12 * max(1.0, np.linalg.norm(eye), np.linalg.norm(look_at)):
            raise r.error("camera", f"degenerate view: look_at equals eye{when} ({keys} = {_fmt(eye if not when else eye_close)})")
        if np.linalg.norm(np.cross(d / np.linalg.norm(d), up_unit)) < 1e-6:
            raise r.error("camera.up", f"up {_fmt(up)} is parallel to the view direction {_fmt(d)}{when}")
    if _crosses_zero(d0, d1):
        raise r.error("camera", "degenerate view: eye and look_at coincide during the shutter")
    if _crosses_zero(np.cross(d0, up_unit), np.cross(d1, up_unit)):
        raise r.error("camera.up", f"up {_fmt(up)} becomes parallel to the view direction during the shutter")

    near, far = cam.near, cam.far
    if far <= near:
        raise r.error("camera.far", f"must be > near ({near:g}), got {far:g}")

    frustum = None
    if cam.frustum is not None:
        fr = np.array(cam.frustum)
        if not fr[0] < fr[1]:
            raise r.error("camera.frustum", f"left must be < right, got {_fmt(fr)}")
        if not fr[2] < fr[3]:
            raise r.error("camera.frustum", f"bottom must be < top, got {_fmt(fr)}")
        frustum = (float(fr[0]), float(fr[1]), float(fr[2]), float(fr[3]))

    ortho_height = 2.0
    fov_y = 0.0
    lens = None
    if projection == "perspective":
        if cam.ortho_height is not None:
            raise r.error("camera.ortho_height", "applies only to orthographic cameras; use fov_y or frustum")
        if cam.fov_y is not None:
            fov_y = cam.fov_y
        elif frustum is None:
            raise r.error("camera.fov_y", "missing required key (or give camera.frustum)")
        if frustum is not None:
            fov_y = math.degrees(math.atan2(frustum[3], near) - math.atan2(frustum[2], near))
        if cam.lens is not None:
            focus = cam.lens.focus_distance
            lens = Lens(radius=cam.lens.radius,
                        focus_distance=float(np.linalg.norm(d0)) if focus is None else focus)
    else:
        if cam.fov_y is not None:
            raise r.error("camera.fov_y", "applies only to perspective cameras; use ortho_height or frustum")
        if cam.lens is not None:
            raise r.error("camera.lens", "a thin lens needs a perspective camera, but projection is 'orthographic'")
        if cam.ortho_height is not None:
            ortho_height = cam.ortho_height
    return Camera(
        projection=projection,
        eye=eye,
        look_at=look_at,
        up=up,
        eye_close=eye_close,
        look_at_close=look_at_close,
        fov_y=fov_y,
        near=near,
        far=far,
        frustum=frustum,
        ortho_height=ortho_height,
        lens=lens,
    )


def _parse_background(r: _Reader, data: dict) -> np.ndarray:
    return np.array(_section(r, BackgroundTable, data, "background").color)


def _parse_light(r: _Reader, data: dict) -> Light:
    light = _section(r, LightTable, data, "light")
    direction = np.zeros(3)
    position = np.zeros(3)
    if light.type == "directional":
        if light.position is not None:
            raise r.error("light.position", "applies only to point lights; use direction")
        direction = np.array(light.direction if light.direction is not None else DEFAULT_LIGHT_DIRECTION)
        if not np.any(direction):
            raise r.error("light.direction", "must not be the zero vector")
        direction = np.ldexp(direction, -math.frexp(np.abs(direction).max())[1])  # exact; 1e300 and 1e-320 in range
        direction = direction / np.linalg.norm(direction)
    else:
        if light.direction is not None:
            raise r.error("light.direction", "applies only to directional lights; use position")
        if light.position is None:
            raise r.error("light.position", "missing required key for a point light")
        position = np.array(light.position)
        if np.any(np.abs(position) > MAX_COORDINATE):
            raise r.error("light.position", f"coordinates must be within +-{MAX_COORDINATE:g} (half the float32 "
                          f"range), got {_fmt(position)}")
    return Light(kind=light.type, direction=direction, position=position, color=np.array(light.color),
                 intensity=light.intensity, ambient=light.ambient)


def _rotation(deg: np.ndarray) -> np.ndarray:
    """Rotation about x, then y, then z (angles in degrees): Rz @ Ry @ Rx."""
    ax, ay, az = np.radians(deg)
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _trs(translate: np.ndarray, rotate: np.ndarray, scale: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = _rotation(rotate) @ np.diag(scale)
    m[:3, 3] = translate
    return m


def _transform(r: _Reader, t: TransformTable | None, key: str, base: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``base`` with the keys the transform table ``t`` gives."""
    out = dict(base)
    if t is None:
        return out
    if t.translate is not None:
        out["translate"] = np.array(t.translate)
    if t.rotate is not None:
        out["rotate"] = np.array(t.rotate)
    if t.scale is not None:
        s = r.number_or_numbers(t.scale, f"{key}.scale", 3)
        if np.any(s <= 0.0):
            raise r.error(f"{key}.scale", f"must be > 0 (mirroring is not supported), got {_fmt(s)}")
        out["scale"] = s
    return out


def _parse_object(
    r: _Reader, value: Any, index: int, base_dir: Path, mesh_cache: dict[Path, _LoadedMesh]
) -> tuple[SceneObject, bytes | None]:
    key = f"objects[{index}]"
    primitive = value.get("primitive") if isinstance(value, dict) else None
    table = _PRIMITIVE_TABLES.get(primitive, ObjectTable) if isinstance(primitive, str) else ObjectTable
    if isinstance(value, dict) and (table is not ObjectTable or primitive is None):
        for k in value:  # a parameter of another primitive: say whose, and what this one takes
            owners = [name for name, params in _PRIMITIVE_PARAMS.items() if k in params]
            if owners and k not in _PRIMITIVE_PARAMS.get(primitive, ()):
                takes = (f"{primitive} takes: {', '.join(_PRIMITIVE_PARAMS[primitive])}" if primitive
                         else "a mesh object takes none")
                raise r.error(f"[{key}]", f"unknown key '{k}': it is a parameter of primitive {', '.join(owners)}; "
                              f"{takes}")
    obj = schema.build(table, value, r.ctx, ("objects", index))
    if obj.primitive is not None and obj.mesh is not None:
        raise r.error(key, "give either 'primitive' or 'mesh', not both")
    if obj.primitive is None and obj.mesh is None:
        raise r.error(
            key, f"missing required key 'primitive' ({', '.join(PRIMITIVES)}) or 'mesh' (a mesh file path)"
        )
    name = obj.name if obj.name is not None else f"object{index}"
    color = np.array(obj.color)

    identity = {"translate": np.zeros(3), "rotate": np.zeros(3), "scale": np.ones(3)}
    t_open = _transform(r, obj.open, f"{key}.open", identity)
    t_close = _transform(r, obj.close, f"{key}.close", t_open)

    data = None
    vertex_colors = None
    if obj.primitive is not None:
        positions, normals, faces = _primitive_mesh(r, obj, key, obj.primitive)
    else:
        resolved = (base_dir / obj.mesh).resolve()
        if resolved not in mesh_cache:
            mesh_cache[resolved] = _load_mesh_file(r, f"{key}.mesh", obj.mesh, resolved)
        loaded = mesh_cache[resolved]
        positions, normals, faces = loaded.positions, loaded.normals, loaded.faces
        vertex_colors = loaded.vertex_colors
        data = loaded.data
    if obj.use_vertex_colors and vertex_colors is not None:
        colors = np.where(np.isnan(vertex_colors), color.astype(np.float32), vertex_colors)
    else:
        colors = np.broadcast_to(color.astype(np.float32), (len(positions), 3))
    scene_object = SceneObject(
        name=name,
        positions=positions,
        normals=normals,
        faces=faces,
        colors=colors,
        material=obj.material,
        transform_open=_trs(**t_open),
        transform_close=_trs(**t_close),
    )
    return scene_object, data


def _parse_objects(r: _Reader, data: dict, base_dir: Path) -> tuple[tuple[SceneObject, ...], list[bytes]]:
    value = data.get("objects", [])
    if not isinstance(value, list):
        raise r.error("objects", f"expected an array of tables ([[objects]]), got {_type_name(value)}")
    objects: list[SceneObject] = []
    mesh_bytes: list[bytes] = []
    mesh_cache: dict[Path, _LoadedMesh] = {}
    seen: dict[str, int] = {}
    for i, item in enumerate(value):
        obj, data_bytes = _parse_object(r, item, i, base_dir, mesh_cache)
        if obj.name in seen:
            raise r.error(f"objects[{i}].name", f"duplicate name '{obj.name}' (also objects[{seen[obj.name]}])")
        seen[obj.name] = i
        objects.append(obj)
        if data_bytes is not None:
            mesh_bytes.append(data_bytes)
    return tuple(objects), mesh_bytes


_TOP_LEVEL_KEYS = ("image", "camera", "background", "light", "objects", "pass", "simulation")


def _parse(data: dict, where: str, base_dir: Path, source: bytes | None, path: Path | None) -> Scene:
    r = _Reader(where)
    if not isinstance(data, dict):
        raise UserError(f"{where}: expected a TOML table at the top level, got {_type_name(data)}")
    for k in data:
        if k not in _TOP_LEVEL_KEYS:
            raise unknown_key_error(where, printable(k), _TOP_LEVEL_KEYS)
    image = _parse_image(r, data)
    camera = _parse_camera(r, data)
    background = _parse_background(r, data)
    light = _parse_light(r, data)
    objects, mesh_bytes = _parse_objects(r, data, base_dir)
    pass_state = pass_state_from(data.get("pass", {}), where)
    simulation = sim_options_from(data.get("simulation", {}), where)

    h = hashlib.sha256()
    if source is None:
        source = json.dumps(data, sort_keys=True, default=repr).encode()
    for chunk in (source, *mesh_bytes):
        h.update(len(chunk).to_bytes(8, "little"))
        h.update(chunk)
    return Scene(
        image=image,
        camera=camera,
        light=light,
        background=background,
        objects=objects,
        path=path,
        digest=h.hexdigest(),
        pass_state=pass_state,
        simulation=simulation,
    )


def parse_scene(data: dict, *, where: str = "<scene>", base_dir: Path = Path(".")) -> Scene:
    """Build a :class:`Scene` from an already-parsed TOML document.

    ``where`` names the source in error messages; mesh paths are resolved
    against ``base_dir``. The digest covers a canonical JSON form of
    ``data`` and the bytes of every mesh file loaded.
    """
    return _parse(data, where, Path(base_dir), None, None)


_TOML_POS = re.compile(r"\s*\(at line (\d+), column (\d+)\)\s*$")
_TOML_END = re.compile(r"\s*\(at end of document\)\s*$")


def _toml_error(where: str, text: str, err: tomllib.TOMLDecodeError) -> UserError:
    msg = str(err).strip().splitlines()[0] if str(err).strip() else "syntax error"
    m = _TOML_POS.search(msg)
    if m:
        line, col = int(m.group(1)), int(m.group(2))
        msg = msg[: m.start()]
    elif _TOML_END.search(msg):
        lines = text.split("\n")
        line, col = len(lines), len(lines[-1]) + 1
        msg = _TOML_END.sub("", msg) + " at end of file"
    else:
        return UserError(f"{where}: invalid TOML: {msg}")
    return UserError(f"{where}: line {line}, column {col}: invalid TOML: {msg}")


def load_scene(path: str | Path) -> Scene:
    """Load and validate a TOML scene file (see the module docstring).

    Raises :class:`UserError` with one line naming the file and key path
    for any problem in the file or in the mesh files it references.
    """
    p = Path(path)
    where = str(path)
    source, text = read_input_text(p, where, "scene")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise _toml_error(where, text, e) from None
    return _parse(data, where, p.parent, source, p)
