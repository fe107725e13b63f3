"""The records that flow between the units, declared once: typed structures of arrays.

A record type is a list of fields, each with its name, dtype, per-record
shape and the unit that adds it (docs/pipeline.md §2). The units build their
batches from these declarations (``RecordType.allocate``) and the tests check
every batch a unit produces against them (``RecordType.problems``).

* ``TRIANGLE``: the per-triangle table triangle setup writes and the later
  units read (docs/pipeline.md §2.1), indexed by triangle id; a namedtuple of
  arrays (``RecordType.table``), so a numba kernel takes it as one argument.
* ``TILE``: a (triangle, tile) record: the tile traverser's ids (§2.2), the
  tile test's conservative intervals (§2.3), z-cull's no-read flag (§2.4).
* ``SAMPLE``: a covered sample out of the sample tester (§2.5).
* ``FRAGMENT``: a shaded sample: the fields of shading's output the ROP reads (§2.6-2.7).
* ``APPEND``: a record a shader appends to an append buffer (declaration
  only: no unit writes one yet).

A culling algorithm's own fields (the convex hull of a triangle, two-stage
time lines, a tuple mask) are declared by its module as records of their
own (``TRIANGLE_EXT``, ``TILE_EXT``) beside the base ones, which
``RecordType.extend`` joins; the culling registry (``units.culling``) lists them.
Between units a batch stays a dict of arrays keyed by field name
(``batch["tri"]``). This module imports only numpy (``tests/test_layering.py``).
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Field:
    """One field of a record: ``shape`` is per record (the array is ``(n, *shape)``)."""

    name: str
    dtype: type
    shape: tuple[int, ...] = ()
    by: str = ""  # the unit (or culling algorithm) that adds it
    doc: str = ""


class RecordType:
    """A structure-of-arrays record: its fields in order, and the arrays they make."""

    def __init__(self, name: str, fields: tuple[Field, ...], module: str):
        names = [f.name for f in fields]
        if len(set(names)) != len(names):
            raise ValueError(f"record {name}: a field name repeats in {names}")
        self.name = name
        self.fields = tuple(fields)
        # numba's on-disk cache finds a namedtuple type by module and name: ``module`` binds
        # ``name`` to ``tuple_class`` (a kernel taking it otherwise recompiles in every process)
        self.tuple_class = namedtuple(name, names, module=module)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)

    def extend(self, name: str, fields: tuple[Field, ...], module: str) -> "RecordType":
        """This record with ``fields`` appended (a culling algorithm's own)."""
        return RecordType(name, self.fields + tuple(fields), module)

    def added_by(self, *units: str) -> tuple[str, ...]:
        """The names of the fields the given units add, in order."""
        return tuple(f.name for f in self.fields if f.by in units)

    def allocate(self, n: int, fill: bool = True) -> dict[str, np.ndarray]:
        """Arrays for ``n`` records, zeroed unless not ``fill``."""
        new = np.zeros if fill else np.empty
        return {f.name: new((n, *f.shape), f.dtype) for f in self.fields}

    def table(self, n: int, fill: bool = True) -> tuple:
        """A namedtuple of arrays for ``n`` records (zeroed unless not ``fill``): what a kernel takes
        as one argument."""
        return self.tuple_class(**self.allocate(n, fill))

    def problems(self, batch: dict[str, np.ndarray]) -> list[str]:
        """How a batch differs from the declaration: missing or extra names, wrong
        dtypes or per-record shapes, unequal lengths; empty when it matches."""
        out = []
        missing = [k for k in self.names if k not in batch]
        extra = [k for k in batch if k not in self.names]
        if missing:
            out.append(f"{self.name}: missing {missing}")
        if extra:
            out.append(f"{self.name}: undeclared {extra}")
        lengths = {len(a) for a in batch.values()}
        if len(lengths) > 1:
            out.append(f"{self.name}: fields of unequal lengths {sorted(lengths)}")
        for f in self.fields:
            a = batch.get(f.name)
            if a is not None and (a.dtype != np.dtype(f.dtype) or a.shape[1:] != f.shape):
                out.append(f"{self.name}.{f.name}: {a.dtype}{list(a.shape[1:])}, declared "
                           f"{np.dtype(f.dtype)}{list(f.shape)}")
        return out


def _fields(by: str, dtype: type, shape: tuple[int, ...], *names_docs: tuple[str, str]) -> tuple[Field, ...]:
    return tuple(Field(name, dtype, shape, by, doc) for name, doc in names_docs)


f64, f32 = np.float64, np.float32
SETUP = "triangle_setup"
TRIANGLE = RecordType("TriangleTable", (
    *_fields(SETUP, f64, (3, 4), ("p0", "pixel-space 2DH (X, Y, Z, W) of each vertex at t=0, normalised"),
             ("dp", "its change to t=1")),
    *_fields(SETUP, f64, (3, 2), ("l0", "lens shift (LX, LY) of each vertex at t=0"), ("dl", "its change to t=1")),
    *_fields(SETUP, f32, (3, 4), ("p0_32", "float32 p0, for the sample tester"), ("dp_32", "float32 dp")),
    *_fields(SETUP, f32, (3, 2), ("l0_32", "float32 l0"), ("dl_32", "float32 dl")),
    Field("t_span", f64, (2,), SETUP, "[ts, te]: when the triangle can be in the frustum"),
    Field("bounds", np.int32, (4,), SETUP, "screen bounds px0, px1, py0, py1 (exclusive ends)"),
    Field("facing", np.int8, (), SETUP, "+1 always front, -1 always back, 0 mixed"),
    Field("flags", np.int8, (), SETUP, "FLAG_* bits: lens live, w > 0, edge test valid, moving, plane"),
    Field("edge_f", f64, (3, 3), SETUP, "f (t^2 coefficient) of each edge, facing-normalized"),
    Field("edge_h", f64, (3, 3), SETUP, "h of each edge, facing-normalized"),
    Field("edge_gamma", f64, (3,), SETUP, "upper slope bound Gamma per edge"),
    Field("edge_g", f64, (3, 3), SETUP, "facing-normalized g of each edge"),
    Field("edge_fg", f64, (3, 3), SETUP, "facing-normalized f + g of each edge"),
    Field("edge_abs", f64, (3, 3), SETUP, "sum of the absolute products behind f, g, h: their float32 rounding"),
    Field("ref", f32, (3, 3), SETUP, "X, Y, W seen by the shading cache's reference camera (the pass's shading view)"),
    Field("edge_eps", f32, (), SETUP, "error bound of a float32 edge-function value"),
    Field("plane_n", f64, (2, 3), SETUP, "normals of the triangle's plane at t=0 and t=1 (X, Y, W)"),
    Field("plane_d", f64, (2, 2, 2), SETUP, "[normal, side, (d0, v)] moving planes"),
), __name__)

IDS = ("tri", "tx", "ty")
INTERVALS = ("t_lo", "t_hi", "u_lo", "u_hi", "v_lo", "v_hi", "z_lo", "z_hi")
TILE = RecordType("TileRecord", (
    Field("tri", np.int32, (), "tile_traverser", "triangle id"),
    *_fields("tile_traverser", np.int32, (), ("tx", "tile column"), ("ty", "tile row")),
    *_fields("tile_test", f64, (), ("t_lo", "t^"), ("t_hi", "t^"), ("u_lo", "u^"), ("u_hi", "u^"),
             ("v_lo", "v^"), ("v_hi", "v^"), ("z_lo", "z^ (z/w)"), ("z_hi", "z^ (z/w)")),
    Field("noread", np.bool_, (), "zcull", "z-cull: every sample passes the depth test, skip the depth read "
          "(False until z-cull runs)"),
), __name__)

SAMPLE = RecordType("SampleRecord", (
    Field("tri", np.int32, (), "sample_tester", "triangle id"),
    Field("pix", np.int32, (), "sample_tester", "pixel, row-major over the frame"),
    Field("sidx", np.int32, (), "sample_tester", "sample index within the pixel"),
    Field("z", f32, (), "sample_tester", "z/w of the sample, clamped to z^"),
    *_fields("sample_tester", f32, (), ("b0", "perspective-correct barycentric"), ("b1", "barycentric"),
             ("b2", "barycentric")),
    Field("noread", np.bool_, (), "sample_tester", "the tile's z-cull no-read flag"),
), __name__)

FRAGMENT = RecordType("Fragment", (
    *(f for f in SAMPLE.fields if f.name in ("tri", "pix", "sidx", "z", "noread")),
    Field("color", f32, (4,), "shading", "the shader's RGBA output"),
), __name__)

APPEND = RecordType("AppendRecord", (
    *_fields("shading", f32, (), ("x", "sample x in pixels"), ("y", "sample y in pixels"), ("u", "lens u"),
             ("v", "lens v"), ("t", "time")),
    Field("values", f32, (4,), "shading", "the values the shader appends"),
), __name__)
TILE_IDS = RecordType("TileIds", tuple(f for f in TILE.fields if f.name in IDS), __name__)

TriangleTable = TRIANGLE.tuple_class
TileRecord = TILE.tuple_class
SampleRecord = SAMPLE.tuple_class
Fragment = FRAGMENT.tuple_class
AppendRecord = APPEND.tuple_class
TileIds = TILE_IDS.tuple_class
