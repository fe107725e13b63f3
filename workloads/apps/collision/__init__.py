"""Continuous collision detection with conservative time-only rasterization (Nilsson12 §3).

Objects (meshes given inline, or generated icospheres and rounded boxes) move between shutter open
(t=0) and close (t=1), each vertex along a straight line from its place at t=0 to its place at t=1
(a rigid motion is given by its two end poses; between them the vertices are interpolated linearly,
the motion the pipeline rasterizes). For each pair of objects whose swept bounding boxes meet, up to
three orthographic passes look along x, then y, then z, in conservative mode (1x1 tiles, one shader
call per (triangle, pixel), Nilsson12 §2) with time as the only extra dimension. The viewport of a
pass encloses both objects' swept volumes, at ``resolution`` x ``resolution`` pixels. The
``interval_shader`` writes each (triangle, pixel)'s tz-box (t_lo, z_lo, t_hi, z_hi) from the tile
test's t^ and z^; one target per object keeps per pixel the union of its triangles' boxes (MIN on
the lower bounds, MAX on the upper, every fragment written, restricted to the object's draw).

A pair leaves the potentially colliding set (PCS) of a method at the first view with no pixel where
both objects' boxes overlap:

* ``tz_union``: in t and in z (Nilsson12 §3, Fig. 5 left);
* ``depth_only``: in z, whatever the times.

Two more methods test each fragment of the second object against the first object's union box at
its pixel, read as a texture: per view a pass draws the first object alone into its box target,
then a pass draws the second, whose shader sets per pixel a flag for each test a fragment fails to
separate (a "max" blended target, the query):

* ``tz_fragment``: the fragment's own tz-box overlaps the union box (Nilsson12 §3, Fig. 5 right,
  tighter than ``tz_union``);
* ``cullide``: the CULLIDE baseline of Govindaraju et al. 2003 on the swept volumes: the second
  object is "fully visible" in front of the first (every fragment's z_hi below the first object's
  nearest z_lo) or behind it (every z_lo beyond its farthest z_hi); the front and back directions of
  the three axes are its six tests, the depth pass and the reversed-test query of each direction
  sharing one pass each.

Each method stops at its own first separating view; its passes, shaded pixels and simulated cycles
are the ones it needed (methods that share a pass each count it). Each union view also gives an
image of the pixels where the boxes overlap in time, in depth, and in both (Nilsson12 Fig. 6).

With ``views = "scene"`` the many-object PCS is pruned view by view over all pairs at once: per axis
one pass draws every object still in a pair of some PCS and appends each fragment with its object
(a per-pixel object list); every pair met at a pixel gets the four tests from its objects' fragments
there (:func:`pair_tests`), three passes in all.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import re
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numba as nb
import numpy as np
import pandas as pd
import trimesh
from pydantic import Field, Strict
from scipy.spatial.transform import Rotation

from pipeline_sim.errors import UserError
from pipeline_sim.pass_state import PassState
from pipeline_sim.scene import MAX_COORDINATE, Positive, Vec3
from pipeline_sim.schema import key
from pipeline_sim.settings import FORBID, Text, count
from pipeline_sim.shaders import IN_OBJECT, IN_T_HI, IN_T_LO, IN_X, IN_Y, IN_Z_HI, IN_Z_LO, append_record, fetch
from pipeline_sim.workload import Workload, WorkloadResult

Face = Annotated[list[Annotated[int, Strict(), Field(ge=0)]], Field(min_length=3, max_length=3)]

AXES = "xyz"
METHODS = ("tz_union", "depth_only", "tz_fragment", "cullide")
#: The flags the fragment pass sets (its target's channels): the fragment's tz-box meets the union
#: box; its z_hi reaches the union's z_lo (not in front); its z_lo reaches the union's z_hi (not behind).
FLAGS = ("tz", "not_in_front", "not_behind")
#: An object's name: it names its pairs' passes ("<a>-<b>.<axis>") and their folders.
OBJECT_NAME = re.compile(r"[A-Za-z0-9_]+")
#: A target's clear value: the empty tz-box (t_lo > t_hi, z_lo > z_hi), finite.
EMPTY_BOX = (2.0, 2.0, -2.0, -2.0)
BOX_BLEND = ("min", "min", "max", "max")
#: The state of every pass: conservative, every fragment written, no depth kept.
CONSERVATIVE = PassState(mode="conservative", depth_test="always", depth_write=False)
#: Margin of a view around the swept volumes, as a share of their extent (keeps them inside the
#: clip volume, depth included).
MARGIN = 0.05


@dataclass
class ObjectSpec:
    """One ``[[objects]]`` entry."""

    __pydantic_config__ = FORBID
    shape: Literal["icosphere", "rounded_box", "mesh"] = key("the object's surface: a generated icosphere, a "
                                                            "generated rounded box, or the `vertices` and "
                                                            "`faces` given")
    name: Text = key("its name in the results (default: object<index>)", default="")
    size: Vec3 = key("half extents along x, y, z (icosphere: size[0] is the radius)",
                     default_factory=lambda: [0.5, 0.5, 0.5])
    subdivisions: count(0, 5) = key("icosphere: subdivisions of the icosahedron; rounded box: cells per "
                                    "face side minus one", default=2)
    slots: count(0, 4) = key("rounded box: slots cut into its top (+y) face, along x, side by side in z (a "
                             "toaster)", default=0)
    vertices: list[Vec3] = key("mesh: the vertices, in object space", default_factory=list)
    faces: list[Face] = key("mesh: triangles, three vertex indices each", default_factory=list)
    start: Vec3 = key("position of the object's origin at t=0", default_factory=lambda: [0.0, 0.0, 0.0])
    end: Vec3 | None = key("position at t=1 (default: start)", default=None)
    turn: Vec3 = key("rotation at t=1 relative to t=0, degrees about x, then y, then z (about the origin)",
                     default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class RandomSpec:
    """The ``[random]`` table: many generated moving icospheres and rounded boxes."""

    __pydantic_config__ = FORBID
    count: count(1, 10_000) = key("number of objects")
    seed: count(0) = key("random seed", default=0)
    extent: Positive = key("side of the cube the objects start in", default=10.0)
    radius: Positive = key("largest half extent of an object", default=0.4)
    travel: Positive = key("largest distance an object moves over the shutter", default=1.0)
    subdivisions: count(0, 3) = key("icosphere subdivisions / rounded-box cells", default=1)


@dataclass
class Settings:
    """The keys of a `collision` file besides `kind`."""

    __pydantic_config__ = FORBID
    resolution: count(1, 4096) = key("pixels along each side of every view", default=32)
    views: Literal["pair", "scene"] = key("`pair`: up to three views of each pair whose swept boxes meet, each "
                                          "enclosing the pair; `scene`: per axis one view of every object still "
                                          "in a pair of some PCS, the pairs pruned view by view", default="pair")
    objects: list[ObjectSpec] = key("the objects, each its own table", default_factory=list)
    random: RandomSpec | None = key("generated objects added after `objects`", default=None)


@dataclass
class Body:
    """A moving triangle mesh: vertices at t=0 and t=1 (V, 3) and faces (F, 3)."""

    name: str
    v0: np.ndarray
    v1: np.ndarray
    faces: np.ndarray

    def at(self, t: float) -> np.ndarray:
        """The vertices at time ``t`` (linear per vertex)."""
        return (1.0 - t) * self.v0 + t * self.v1

    def swept_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The bounding box of the swept volume (the vertices' paths are segments), widened by a few ulps:
        :meth:`at` rounds, and (1 - t) v0 + t v1 may lie an ulp outside [min, max]."""
        both = np.concatenate([self.v0, self.v1])
        lo, hi = both.min(axis=0), both.max(axis=0)
        pad = 8.0 * np.finfo(np.float64).eps * np.maximum(np.abs(lo), np.abs(hi))
        return lo - pad, hi + pad


def slot_rects(half: np.ndarray, slots: int) -> list[tuple[float, float, float, float]]:
    """The openings (x0, x1, z0, z1) of ``slots`` toaster slots in the top face of a rounded box of half
    extents ``half``: along x, side by side in z, inside the face's flat part."""
    inner = half - 0.25 * float(np.min(half))
    width = 2.0 * inner[2] / (2 * slots + 1)  # slots and the walls between them share the flat width
    return [(-0.7 * inner[0], 0.7 * inner[0], -inner[2] + (2 * k + 1) * width, -inner[2] + (2 * k + 2) * width)
            for k in range(slots)]


def rounded_box(half: np.ndarray, cells: int, slots: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A box of half extents ``half`` with edges and corners rounded by a quarter of its smallest half
    extent: each face a grid of ``cells`` x ``cells`` squares, every point of the unit cube's surface
    moved to the nearest point of the inner box plus the rounding radius along the offset. With
    ``slots``, a toaster: the top (+y) face's grid also has the slots' edges, its cells inside a slot
    (:func:`slot_rects`) are left out, and each slot is a pit of four walls and a floor, 0.7 of the
    box's height deep (the walls meet the face's cells at their corners or along their sides)."""
    radius = 0.25 * float(np.min(half))
    inner = half - radius
    grids = [np.linspace(-1.0, 1.0, cells + 1)] * 3
    rects = slot_rects(half, slots)
    if rects:
        grids[0] = np.union1d(grids[0], [r[k] / half[0] for r in rects for k in (0, 1)])
        grids[2] = np.union1d(grids[2], [r[k] / half[2] for r in rects for k in (2, 3)])
    pts, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            a, b = (axis + 1) % 3, (axis + 2) % 3
            base = len(pts)
            for i in grids[a]:
                for j in grids[b]:
                    p = np.zeros(3)
                    p[axis], p[a], p[b] = sign, i, j
                    pts.append(p)
            n = len(grids[b])
            for i in range(len(grids[a]) - 1):
                for j in range(n - 1):
                    centre = np.zeros(3)  # the cell's centre, on the unit cube
                    centre[axis], centre[a], centre[b] = sign, grids[a][i:i + 2].mean(), grids[b][j:j + 2].mean()
                    if axis == 1 and sign > 0 and any(x0 < centre[0] * half[0] < x1 and z0 < centre[2] * half[2] < z1
                                                      for x0, x1, z0, z1 in rects):
                        continue
                    v = base + i * n + j
                    faces += [(v, v + n, v + n + 1), (v, v + n + 1, v + 1)]
    cube = np.array(pts) * half
    core = np.clip(cube, -inner, inner)
    offset = cube - core
    verts = [core + radius * offset / np.linalg.norm(offset, axis=1, keepdims=True)]
    for x0, x1, z0, z1 in rects:
        base = sum(len(v) for v in verts)
        top, bottom = half[1], half[1] - 1.4 * half[1]
        verts.append(np.array([[x, y, z] for y in (top, bottom) for x, z in ((x0, z0), (x1, z0), (x1, z1), (x0, z1))]))
        for k in range(4):  # the walls, then the floor
            m = (k + 1) % 4
            faces += [(base + k, base + m, base + 4 + m), (base + k, base + 4 + m, base + 4 + k)]
        faces += [(base + 4, base + 5, base + 6), (base + 4, base + 6, base + 7)]
    return np.concatenate(verts), np.array(faces, np.int64)


def make_body(spec: ObjectSpec, index: int, where: str) -> Body:
    """The moving mesh of ``spec`` (``where``: the file, for errors)."""
    name = spec.name or f"object{index}"
    at = f"{where}: objects[{index}] ('{name}')"
    if not OBJECT_NAME.fullmatch(name):
        raise UserError(f"{at}: name: use letters, digits and _ (it names the pair's passes)")
    half = np.asarray(spec.size, float)
    if spec.shape == "mesh":
        verts = np.asarray(spec.vertices, float).reshape(-1, 3)
        faces = np.asarray(spec.faces, np.int64).reshape(-1, 3)
        if len(faces) and faces.max() >= len(verts):
            raise UserError(f"{at}: faces index vertex {int(faces.max())}, but there are {len(verts)} vertices")
    elif np.any(half <= 0):
        raise UserError(f"{at}: size needs positive half extents, got {spec.size}")
    elif spec.shape == "icosphere":
        sphere = trimesh.creation.icosphere(subdivisions=spec.subdivisions, radius=half[0])
        verts, faces = np.asarray(sphere.vertices, float), np.asarray(sphere.faces, np.int64)
    else:
        verts, faces = rounded_box(half, spec.subdivisions + 1, spec.slots)
    if not len(faces):
        raise UserError(f"{at}: the object has no triangles")
    start = np.asarray(spec.start, float)
    end = start if spec.end is None else np.asarray(spec.end, float)
    turn = Rotation.from_euler("xyz", spec.turn, degrees=True).as_matrix()  # about x, then y, then z
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
        body = Body(name, verts + start, verts @ turn.T + end, faces)
    if not np.all(np.abs(np.concatenate([body.v0, body.v1])) <= MAX_COORDINATE):
        raise UserError(f"{at}: a vertex reaches beyond +-{MAX_COORDINATE:g} at t=0 or t=1")
    return body


def random_bodies(spec: RandomSpec, first: int) -> list[Body]:
    """``spec.count`` generated objects, numbered from ``first``: icospheres and rounded boxes at random
    places in a cube, each moving by a random translation and turn."""
    rng = np.random.default_rng(spec.seed)
    out = []
    for i in range(spec.count):
        size = list(rng.uniform(0.4, 1.0, 3) * spec.radius)
        start = list(rng.uniform(0.0, spec.extent, 3))
        step = rng.normal(size=3)
        end = list(np.asarray(start) + step / np.linalg.norm(step) * rng.uniform(0, spec.travel))
        shape = "icosphere" if rng.random() < 0.5 else "rounded_box"
        obj = ObjectSpec(shape=shape, name=f"r{i}", size=size, subdivisions=spec.subdivisions, start=start,
                         end=end, turn=list(rng.uniform(-45, 45, 3)))
        out.append(make_body(obj, first + i, "random"))
    return out


def view_draw(body: Body, axis: int, lo: np.ndarray, hi: np.ndarray, resolution: int):
    """``body``'s triangles in the orthographic view along ``axis`` whose clip volume [-1, 1]^3 maps the
    box [lo, hi]: image x and y along the next two axes, depth along ``axis``."""
    from pipeline_sim.draw import draw_from_clip

    order = [(axis + 1) % 3, (axis + 2) % 3, axis]

    def clip(v: np.ndarray) -> np.ndarray:
        xyz = (v[:, order] - lo[order]) / (hi[order] - lo[order]) * 2.0 - 1.0
        return np.concatenate([xyz, np.ones((len(v), 1))], axis=1)[body.faces]

    return draw_from_clip(clip(body.v0), clip(body.v1), width=resolution, height=resolution)


def view_box(*bodies: Body) -> tuple[np.ndarray, np.ndarray]:
    """The box the views of ``bodies`` (a pair, or the objects of a scene view) map to their clip volume:
    their swept volumes with a margin."""
    boxes = [b.swept_box() for b in bodies]
    lo, hi = np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)
    pad = MARGIN * max(float(np.max(hi - lo)), 1e-6)
    return lo - pad, hi + pad


def box_pass(a: Body, b: Body, axis: int, resolution: int, arch, name: str):
    """The conservative pass along ``axis`` writing the union tz-boxes of ``a`` (target "a", draw 0)
    and ``b`` (target "b", draw 1) per pixel (Nilsson12 §3)."""
    from pipeline_sim.render import RenderPass
    from pipeline_sim.shaders import interval_shader
    from pipeline_sim.targets import ShaderOutput, Target

    lo, hi = view_box(a, b)
    targets = tuple(Target(t, source="box", blend=BOX_BLEND, clear=EMPTY_BOX, depth="always", draws=(d,))
                    for d, t in enumerate("ab"))
    return RenderPass(draw=[view_draw(a, axis, lo, hi, resolution), view_draw(b, axis, lo, hi, resolution)],
                      arch=arch, spp=1, name=name, state=CONSERVATIVE,
                      shader=interval_shader, outputs=(ShaderOutput("box", 4),), targets=targets)


@nb.njit(cache=True, nogil=True)
def fragment_shader(inputs, params, textures, out, append):
    """Each (triangle, pixel) tz-box of the second object against the first object's union box at the
    pixel (``textures[0]``, t_lo, z_lo, t_hi, z_hi): Nilsson12 §3, Fig. 5 right, and the CULLIDE
    depth tests (Govindaraju et al. 2003) on conservative depths; writes the ``FLAGS``, 1 or 0."""
    box = textures[0]
    for i in range(inputs.shape[1]):
        x, y = inputs[IN_X, i], inputs[IN_Y, i]
        t_lo, z_lo, t_hi, z_hi = fetch(box, x, y, 0), fetch(box, x, y, 1), fetch(box, x, y, 2), fetch(box, x, y, 3)
        meet_t = max(t_lo, inputs[IN_T_LO, i]) <= min(t_hi, inputs[IN_T_HI, i])
        meet_z = max(z_lo, inputs[IN_Z_LO, i]) <= min(z_hi, inputs[IN_Z_HI, i])
        out[i, 0] = 1.0 if meet_t and meet_z else 0.0
        out[i, 1] = 1.0 if inputs[IN_Z_HI, i] >= z_lo else 0.0
        out[i, 2] = 1.0 if inputs[IN_Z_LO, i] <= z_hi else 0.0


def object_pass(a: Body, b: Body, axis: int, resolution: int, arch, name: str):
    """The conservative pass along ``axis`` (the view of the pair ``a``, ``b``) drawing ``a`` alone
    into its union tz-box target "a"."""
    from pipeline_sim.render import RenderPass
    from pipeline_sim.shaders import interval_shader
    from pipeline_sim.targets import ShaderOutput, Target

    lo, hi = view_box(a, b)
    return RenderPass(draw=view_draw(a, axis, lo, hi, resolution), arch=arch, spp=1, name=name, state=CONSERVATIVE,
                      shader=interval_shader, outputs=(ShaderOutput("box", 4),),
                      targets=(Target("a", source="box", blend=BOX_BLEND, clear=EMPTY_BOX, depth="always"),))


def fragment_pass(a: Body, b: Body, axis: int, resolution: int, arch, name: str, box_a: np.ndarray):
    """The conservative pass along ``axis`` drawing ``b``, each fragment tested against ``box_a``
    (``a``'s union boxes from :func:`object_pass`); target "flags" holds per pixel the max of the
    fragments' ``FLAGS``."""
    from pipeline_sim.render import RenderPass
    from pipeline_sim.targets import ShaderOutput, Target

    lo, hi = view_box(a, b)
    return RenderPass(draw=view_draw(b, axis, lo, hi, resolution), arch=arch, spp=1, name=name, state=CONSERVATIVE,
                      shader=fragment_shader, textures=(box_a.astype(np.float32),),
                      outputs=(ShaderOutput("flags", len(FLAGS)),),
                      targets=(Target("flags", source="flags", blend="max", clear=(0.0,) * len(FLAGS),
                                      depth="always"),))


#: The fields of a scene view's fragment records (its append buffer).
FRAGMENT_FIELDS = ("object", "x", "y", "t_lo", "z_lo", "t_hi", "z_hi")


@nb.njit(cache=True, nogil=True)
def fragment_record_shader(inputs, params, textures, out, append):
    """Conservative mode: writes each (triangle, pixel)'s tz-box (t_lo, z_lo, t_hi, z_hi) of the tile
    test (Nilsson12 §3) and appends it with the triangle's object and the pixel (``FRAGMENT_FIELDS``):
    a scene view's per-pixel object list."""
    record = np.empty(len(FRAGMENT_FIELDS), np.float32)
    for i in range(inputs.shape[1]):
        out[i, 0], out[i, 1] = inputs[IN_T_LO, i], inputs[IN_Z_LO, i]
        out[i, 2], out[i, 3] = inputs[IN_T_HI, i], inputs[IN_Z_HI, i]
        record[0], record[1], record[2] = inputs[IN_OBJECT, i], inputs[IN_X, i], inputs[IN_Y, i]
        for c in range(4):
            record[3 + c] = out[i, c]
        append_record(append, record)


def scene_pass(bodies: list[Body], ids: list[int], axis: int, resolution: int, arch, name: str):
    """The conservative pass along ``axis`` drawing the objects ``ids`` of ``bodies`` in one view that
    encloses their swept volumes: each fragment appended with its object (``FRAGMENT_FIELDS``), the
    union of all their tz-boxes in target "box". The append buffer holds one record per (triangle,
    pixel) of each triangle's swept screen bounds, more than conservative rasterization can shade."""
    from pipeline_sim.draw import merge_draws
    from pipeline_sim.render import RenderPass
    from pipeline_sim.targets import AppendBuffer, ShaderOutput, Target

    lo, hi = view_box(*(bodies[i] for i in ids))
    parts = [view_draw(bodies[i], axis, lo, hi, resolution) for i in ids]
    draw, _ = merge_draws(parts, name)
    draw = dataclasses.replace(draw, object_id=np.repeat(np.asarray(ids, np.int32), [d.n for d in parts]))
    # every vertex at t=0 and t=1 in pixels: a triangle's fragments lie in their bounds, widened by a pixel
    xy = np.concatenate([draw.q[..., :2], draw.r[..., :2]], axis=1)
    span = np.clip(np.ceil((xy.max(axis=1) - xy.min(axis=1)) / 2.0 * resolution) + 3, 1, resolution)
    return RenderPass(draw=draw, arch=arch, spp=1, name=name, state=CONSERVATIVE, shader=fragment_record_shader,
                      outputs=(ShaderOutput("box", 4),),
                      targets=(Target("box", source="box", blend=BOX_BLEND, clear=EMPTY_BOX, depth="always"),),
                      append=AppendBuffer(fields=FRAGMENT_FIELDS, capacity=int(np.prod(span, axis=1).sum())))


@nb.njit(cache=True)
def _pair_flags(obj, start, end, union, boxes, pixel, n_objects):
    """Per (pixel, pair of objects there), the tests of :func:`pair_tests`; rows (a * n_objects + b,
    tz, z, tz_fragment, not_in_front, not_behind) with a < b, b's fragments tested against a's union box."""
    out = []
    g = 0
    while g < len(obj):
        h = g
        while h < len(obj) and pixel[h] == pixel[g]:
            h += 1
        for i in range(g, h):
            for j in range(i + 1, h):  # obj[i] < obj[j]: the groups of a pixel are sorted by object
                a, b = union[i], union[j]
                meet_t = max(a[0], b[0]) <= min(a[2], b[2])
                meet_z = max(a[1], b[1]) <= min(a[3], b[3])
                frag = False
                for f in range(start[j], end[j]):
                    fr = boxes[f]
                    if max(a[0], fr[0]) <= min(a[2], fr[2]) and max(a[1], fr[1]) <= min(a[3], fr[3]):
                        frag = True
                        break
                out.append((obj[i] * n_objects + obj[j], meet_t and meet_z, meet_z, frag, b[3] >= a[1],
                            b[1] <= a[3]))
        g = h
    return out


def pair_tests(records: np.ndarray, resolution: int, n_objects: int) -> dict[int, np.ndarray]:
    """From a scene view's fragment records, per pair of objects met at a pixel (key a * n_objects + b,
    a < b), whether some pixel has their union boxes overlapping in t and z (``tz_union``), in z
    (``depth_only``), a fragment of b overlapping a's union box (``tz_fragment``), and the CULLIDE flags
    of :func:`fragment_shader` (``cullide``: both set at some pixels); the same tests as the pair views."""
    obj = records[:, 0].astype(np.int64)
    pixel = np.floor(records[:, 2]).astype(np.int64) * resolution + np.floor(records[:, 1]).astype(np.int64)
    order = np.lexsort((obj, pixel))
    obj, pixel, boxes = obj[order], pixel[order], records[order, 3:].astype(np.float64)
    first = np.flatnonzero(np.r_[True, (obj[1:] != obj[:-1]) | (pixel[1:] != pixel[:-1])])
    union = np.concatenate([np.minimum.reduceat(boxes[:, :2], first), np.maximum.reduceat(boxes[:, 2:], first)],
                           axis=1) if len(first) else np.zeros((0, 4))
    end = np.r_[first[1:], len(obj)]
    rows = np.array(_pair_flags(obj[first], first, end, union, boxes, pixel[first], n_objects), np.int64)
    if not len(rows):
        return {}
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    keys, at = np.unique(rows[:, 0], return_index=True)
    any_set = np.maximum.reduceat(rows[:, 1:], at)
    kept = np.column_stack([any_set[:, :3], any_set[:, 3] & any_set[:, 4]]).astype(bool)
    return dict(zip(keys.tolist(), kept))


def overlaps(box_a: np.ndarray, box_b: np.ndarray) -> dict[str, np.ndarray]:
    """Per pixel, whether two union tz-box images (H, W, 4: t_lo, z_lo, t_hi, z_hi) overlap in t, in z
    and in both (empty boxes overlap nothing)."""
    def meet(c: int) -> np.ndarray:
        return np.maximum(box_a[..., c], box_b[..., c]) <= np.minimum(box_a[..., c + 2], box_b[..., c + 2])

    t, z = meet(0), meet(1)
    return {"t": t, "z": z, "tz": t & z}


def overlap_image(over: dict[str, np.ndarray]) -> np.ndarray:
    """A view's overlaps (:func:`overlaps`) in three colours, as Nilsson12 Fig. 6 draws them: red where
    the union boxes overlap in time, blue where in depth, so purple where in both; (H, W, 3) float32."""
    image = np.zeros(over["t"].shape + (3,), np.float32)
    image[..., 0] = over["t"]
    image[..., 2] = over["z"]
    return image


def swept_boxes_meet(a: Body, b: Body) -> bool:
    """Whether the bounding boxes of two swept volumes meet (pairs that do not are never drawn)."""
    (lo_a, hi_a), (lo_b, hi_b) = a.swept_box(), b.swept_box()
    return bool(np.all(lo_a <= hi_b) and np.all(lo_b <= hi_a))


class Collision(Workload):
    """The kind ``collision``: the PCS of every pair of moving objects by each of the four methods, in
    views per pair or in views of the whole scene."""

    file_schema = Settings
    #: how the views are laid out (`Settings.views`); a workload built in code keeps the pair views
    views = "pair"

    @classmethod
    def load(cls, path, data: Settings, arch, image: dict[str, int]) -> "Collision":
        if image:
            raise UserError(f"{path}: a collision workload has no image settings ({', '.join(image)}); "
                            "set its resolution in the file")
        self = cls(path, arch)
        self.resolution = data.resolution
        self.views = data.views
        self.bodies = [make_body(o, i, str(path)) for i, o in enumerate(data.objects)]
        if data.random is not None:
            self.bodies += random_bodies(data.random, len(self.bodies))
        names = [b.name for b in self.bodies]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise UserError(f"{path}: objects: names must be distinct, '{twice[0]}' is given twice")
        if len(self.bodies) < 2:
            raise UserError(f"{path}: objects: a collision workload needs at least two objects, "
                            f"got {len(self.bodies)}")
        return self

    def check(self, variants=None, *, reference_spp=None) -> str:
        n = sum(len(b.faces) for b in self.bodies)
        return (f"{len(self.bodies)} objects, {n} triangles, {self.views} views of {self.resolution}x{self.resolution} "
                "pixels")

    def run(self, progress=None) -> WorkloadResult:
        """Every pair whose swept boxes meet through the views of each method, pass by pass."""
        self.passes: dict[str, Any] = {}
        self.progress = progress
        self.cost = {m: {"passes": 0, "pixels_shaded": 0, "cycles": 0.0} for m in METHODS}
        self.rows: dict[str, list[dict[str, Any]]] = {"union_views": [], "fragment_views": [], "scene_views": []}
        self.images: dict[str, np.ndarray] = {}
        pcs: dict[str, list[list[str]]] = {m: [] for m in METHODS}
        pairs = list(itertools.combinations(range(len(self.bodies)), 2))
        candidates = [(i, j) for i, j in pairs if swept_boxes_meet(self.bodies[i], self.bodies[j])]
        if not candidates:  # a run has a pass: one view of every object, charged to no method
            ids = list(range(len(self.bodies)))
            p = scene_pass(self.bodies, ids, 0, self.resolution, self.arch, "scene.x")
            self.passes[p.name] = self.run_passes([p], progress)[p.name]
            kept_pairs = {m: [] for m in METHODS}
        elif self.views == "scene":
            kept_pairs = self._scene_views(candidates)
        else:
            kept_pairs = {m: [] for m in METHODS}
            for i, j in candidates:
                kept = {**self._union_views(self.bodies[i], self.bodies[j]),
                        **self._fragment_views(self.bodies[i], self.bodies[j])}
                for m in METHODS:
                    if kept[m]:
                        kept_pairs[m].append((i, j))
        for m in METHODS:
            pcs[m] = [[self.bodies[i].name, self.bodies[j].name] for i, j in kept_pairs[m]]
        results = {
            "objects": len(self.bodies), "pairs": len(pairs), "swept_box_pairs": len(candidates),
            "resolution": self.resolution, "views": self.views,
            "methods": {m: {"pcs_size": len(pcs[m]), "pcs": pcs[m], **self.cost[m]} for m in METHODS},
        }
        tables = {k: pd.DataFrame(v) for k, v in self.rows.items() if v}
        return WorkloadResult(self.passes, results=results, tables=tables, images=self.images)

    def _view(self, p, methods: list[str]):
        """Run pass ``p``, its cost charged to ``methods``."""
        res = self.run_passes([p], self.progress)[p.name]
        self.passes[p.name] = res
        for m in methods:
            self.cost[m]["passes"] += 1
            self.cost[m]["pixels_shaded"] += res.counter("shading", "shader_executions")
            self.cost[m]["cycles"] += res.timing.frame_cycles
        return res

    def _scene_views(self, candidates: list[tuple[int, int]]) -> dict[str, list[tuple[int, int]]]:
        """All four methods on one pass per axis, over every object still in a pair of some method's
        PCS, in a view enclosing those objects (so it narrows as pairs leave): the pairs each method
        keeps. The pass appends every fragment with its object; per pixel the objects' union boxes and
        fragments give each method's test for every pair met there (:func:`pair_tests`)."""
        alive = {m: set(candidates) for m in METHODS}
        n = len(self.bodies)
        for axis in range(3):
            live = set().union(*alive.values())
            if not live:
                break
            ids = sorted({i for pair in live for i in pair})
            methods = [m for m in METHODS if alive[m]]
            res = self._view(scene_pass(self.bodies, ids, axis, self.resolution, self.arch, f"scene.{AXES[axis]}"),
                             methods)
            if res.append.overflow:
                raise RuntimeError(f"scene.{AXES[axis]}: {res.append.overflow} fragments beyond the append buffer")
            met = pair_tests(res.append.records, self.resolution, n)
            for c, m in enumerate(METHODS):
                alive[m] = {(i, j) for i, j in alive[m] if met.get(i * n + j, np.zeros(4, bool))[c]}
            self.rows["scene_views"].append({
                "axis": AXES[axis], "objects": len(ids), "pairs_tested": len(live),
                "fragments": len(res.append.records), "pixels_shaded": res.counter("shading", "shader_executions"),
                "cycles": res.timing.frame_cycles, **{f"pcs_{m}": len(alive[m]) for m in METHODS}})
        return {m: sorted(alive[m]) for m in METHODS}

    def _union_views(self, a: Body, b: Body) -> dict[str, bool]:
        """``tz_union`` and ``depth_only``: one pass per view, until both have separated the pair;
        whether each keeps it."""
        kept = {"tz_union": True, "depth_only": True}
        pair = f"{a.name}-{b.name}"
        for axis in range(3):
            if not any(kept.values()):
                break
            res = self._view(box_pass(a, b, axis, self.resolution, self.arch, f"{pair}.{AXES[axis]}"),
                             [m for m in kept if kept[m]])
            over = overlaps(res.images["a"][0], res.images["b"][0])
            self.images[f"{pair}.{AXES[axis]}"] = overlap_image(over)
            self.rows["union_views"].append({
                "pair": pair, "axis": AXES[axis], "pixels_shaded": res.counter("shading", "shader_executions"),
                "cycles": res.timing.frame_cycles, **{f"pixels_{k}": int(v.sum()) for k, v in over.items()}})
            for m, layer in (("tz_union", "tz"), ("depth_only", "z")):
                kept[m] = kept[m] and bool(over[layer].any())
        return kept

    def _fragment_views(self, a: Body, b: Body) -> dict[str, bool]:
        """``tz_fragment`` and ``cullide``: per view a pass drawing ``a``'s union boxes and a pass
        testing ``b``'s fragments against them, until both have separated the pair."""
        kept = {"tz_fragment": True, "cullide": True}
        pair = f"{a.name}-{b.name}"
        for axis in range(3):
            if not any(kept.values()):
                break
            methods = [m for m in kept if kept[m]]
            first = self._view(object_pass(a, b, axis, self.resolution, self.arch, f"{pair}.{AXES[axis]}.a"),
                               methods)
            res = self._view(fragment_pass(a, b, axis, self.resolution, self.arch, f"{pair}.{AXES[axis]}.b",
                                           first.images["a"][0]), methods)
            flags = res.images["flags"][0] > 0.5
            self.rows["fragment_views"].append({
                "pair": pair, "axis": AXES[axis],
                "pixels_shaded": sum(r.counter("shading", "shader_executions") for r in (first, res)),
                "cycles": first.timing.frame_cycles + res.timing.frame_cycles,
                **{f"pixels_{k}": int(flags[..., c].sum()) for c, k in enumerate(FLAGS)}})
            kept["tz_fragment"] = kept["tz_fragment"] and bool(flags[..., 0].any())
            kept["cullide"] = kept["cullide"] and bool(flags[..., 1].any() and flags[..., 2].any())
        return kept

    def resolved(self) -> dict[str, Any]:
        return {**super().resolved(), "resolution": self.resolution, "views": self.views,
                "objects": [{"name": b.name, "vertices": len(b.v0), "triangles": len(b.faces)} for b in self.bodies]}

    @property
    def digest(self) -> str:
        h = hashlib.sha256(json.dumps([self.resolution, self.views]).encode())
        for b in self.bodies:
            for arr in (b.v0, b.v1, b.faces):
                h.update(np.ascontiguousarray(arr).tobytes())
        return h.hexdigest()


WORKLOAD = Collision
