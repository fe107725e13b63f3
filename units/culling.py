"""The culling algorithms of the tile test, by name: one module each, behind one interface.

``tile_test.algorithm`` names one of ``ALGORITHMS`` (docs/culling.md). A
culling algorithm's module provides:

* ``NAME``: its name in ``tile_test.algorithm``;
* ``EVENT_MEANINGS``: its own tile-test events, name -> what it counts (the
  counter glossary's line), and ``EVENTS``, their names in that order; they
  follow the core ones (``units.tile_test_bounds.CORE_EVENTS``), placed by
  ``event_offset``;
* ``TRIANGLE_EXT``: the fields it adds to the triangle setup table, a
  ``pipeline_sim.records.RecordType`` (empty: ``NO_TRIANGLE_FIELDS``), and
  ``setup_extras(ids, table, extension, ops)``, triangle setup's part that fills
  them for the triangles that survived setup (None: nothing to fill);
* ``TILE_EXT``: the fields it adds to the tile records (``NO_TILE_FIELDS``: none);
* its per-record bound (numba functions of its module or of
  ``units.tile_test_bounds``), which ``units.tile_test.tile_test_kernel_for`` calls in
  the algorithm's branch of its record loop (code: its place in ``ALGORITHMS``). A
  kernel of its own per algorithm, with the record loop's shared start and z^ end
  as numba helpers, measured 1.25x (hierarchical) to 2x (bbox) slower: the loop stays one;
* ``SAMPLE_FILTER``: which of the sample tester's per-sample filters
  (``units.sample_tester.SAMPLE_FILTERS``) its tile-record extension feeds,
  by field name, or None;
* ``COARSE_TEST``: whether the tile traverser tests coarse tiles with the
  moving box first; ``NEEDS_TUPLES``: whether it needs the sample set's
  fixed (u, v, t) tuples.

Adding an algorithm is a module, a line here, its branch of the tile test
kernel, and its name among the choices of ``tile_test.algorithm``.
"""

from __future__ import annotations

from types import ModuleType

from units import (tile_test_bbox, tile_test_dual, tile_test_hierarchical, tile_test_hull, tile_test_interleave,
                   tile_test_two_stage)
from units.tile_test_bounds import CORE_EVENT_MEANINGS, CORE_EVENTS

ALGORITHMS: dict[str, ModuleType] = {m.NAME: m for m in (
    tile_test_hierarchical, tile_test_bbox, tile_test_hull, tile_test_dual, tile_test_two_stage,
    tile_test_interleave)}
INTERFACE = ("NAME", "EVENTS", "EVENT_MEANINGS", "TRIANGLE_EXT", "setup_extras", "TILE_EXT", "SAMPLE_FILTER", "COARSE_TEST",
             "NEEDS_TUPLES")

#: the tile test's events: the core ones, then each algorithm's own in the order of ``ALGORITHMS``
EVENTS = CORE_EVENTS + tuple(e for m in ALGORITHMS.values() for e in m.EVENTS)
#: what each of them counts, as the core and each algorithm's module declare it
EVENT_MEANINGS = {**CORE_EVENT_MEANINGS, **{e: s for m in ALGORITHMS.values() for e, s in m.EVENT_MEANINGS.items()}}


def algorithm(name: str) -> ModuleType:
    """The module of the culling algorithm ``name``."""
    try:
        return ALGORITHMS[name]
    except KeyError:
        raise ValueError(f"no culling algorithm '{name}' (known: {', '.join(ALGORITHMS)})") from None


def event_offset(name: str) -> int:
    """Where the algorithm's own events start in ``EVENTS``."""
    names = list(ALGORITHMS)
    return len(CORE_EVENTS) + sum(len(ALGORITHMS[k].EVENTS) for k in names[:names.index(name)])
