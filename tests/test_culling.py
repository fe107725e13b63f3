"""The culling registry: every configured tile-test algorithm is one module behind one interface."""

import numpy as np
import pytest

from pipeline_sim.config import TILE_TEST_ALGORITHMS
from pipeline_sim.records import TILE, TRIANGLE, RecordType
from units import culling
from units.sample_tester import SAMPLE_FILTERS
from units.tile_test import ALGORITHM_CODES, EVENTS, TileTest
from units.tile_test_bounds import CORE_EVENTS


def test_every_configured_algorithm_has_a_module_and_no_other():
    assert tuple(culling.ALGORITHMS) == TILE_TEST_ALGORITHMS
    assert set(ALGORITHM_CODES) == set(TILE_TEST_ALGORITHMS)
    with pytest.raises(ValueError, match="no culling algorithm 'hul'"):
        culling.algorithm("hul")


@pytest.mark.parametrize("name", TILE_TEST_ALGORITHMS)
def test_each_module_provides_the_interface(name):
    m = culling.algorithm(name)
    assert m.__name__.startswith("units.tile_test_")
    assert [a for a in culling.INTERFACE if not hasattr(m, a)] == []
    assert m.NAME == name
    assert isinstance(m.TRIANGLE_EXT, RecordType) and isinstance(m.TILE_EXT, RecordType)
    # an extension adds fields of its own, named for the algorithm, never one of the base record's
    assert not set(m.TRIANGLE_EXT.names) & set(TRIANGLE.names)
    assert not set(m.TILE_EXT.names) & set(TILE.names)
    assert {f.by for f in m.TRIANGLE_EXT.fields + m.TILE_EXT.fields} <= {name}
    # fields to fill need a setup part that fills them, and none without
    assert (m.setup_extras is not None) == bool(m.TRIANGLE_EXT.names)
    assert m.setup_extras is None or callable(m.setup_extras)
    # a sample filter reads a field the algorithm adds to the tile records, one the sample tester knows
    assert (m.SAMPLE_FILTER is None) == (not m.TILE_EXT.names)
    assert m.SAMPLE_FILTER is None or (m.SAMPLE_FILTER in SAMPLE_FILTERS and m.SAMPLE_FILTER in m.TILE_EXT.names)
    assert isinstance(m.COARSE_TEST, bool) and isinstance(m.NEEDS_TUPLES, bool)
    assert all(isinstance(e, str) for e in m.EVENTS)


def test_the_events_are_the_core_ones_then_each_algorithms_own_once():
    assert EVENTS[:len(CORE_EVENTS)] == CORE_EVENTS and len(set(EVENTS)) == len(EVENTS)
    for name, m in culling.ALGORITHMS.items():
        k = culling.event_offset(name)
        assert EVENTS[k:k + len(m.EVENTS)] == m.EVENTS


def test_only_the_hierarchical_test_starts_at_coarse_tiles_and_only_interleave_needs_tuples():
    """What render.py once tested by name, now declared by the modules."""
    assert [n for n, m in culling.ALGORITHMS.items() if m.COARSE_TEST] == ["hierarchical"]
    assert [n for n, m in culling.ALGORITHMS.items() if m.NEEDS_TUPLES] == ["interleave_uvt"]


def test_the_tile_test_refuses_an_algorithm_without_the_setup_fields_it_declares():
    class Cfg:
        algorithm = "hull"
        clips = np.array([0.0, 1.0, -1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="hull needs triangle setup's"):
        TileTest(Cfg(), TRIANGLE.table(1), 4, 8, 8)
