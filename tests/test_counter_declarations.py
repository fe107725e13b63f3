"""Every counter is declared with what it counts, where it is declared.

The common counters' meanings sit with ``pipeline_sim.definitions.COMMON``,
each unit's events' with its ``EVENTS`` (``EVENT_MEANINGS``), each culling
algorithm's with its module; docs/counters.md is generated from them alone.
The units are found here by importing every module of ``units/`` (not from
the generator's list), and the glossary is read back from the Markdown.
"""

import importlib
import inspect
import pkgutil

import pytest

import units
from pipeline_sim import docgen
from pipeline_sim.counters import counter_meanings
from pipeline_sim.definitions import COMMON, COMMON_MEANINGS


def all_units() -> list[type]:
    """Every class of ``units/`` that declares counters (a name, events and timing-dependent counters)."""
    found = {}
    for info in pkgutil.iter_modules(units.__path__):
        module = importlib.import_module(f"units.{info.name}")
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if cls.__module__ == module.__name__ and all(hasattr(cls, a) for a in ("name", "events",
                                                                                     "timing_dependent")):
                found[cls.name] = cls
    return list(found.values())


def test_the_pipeline_units_are_found():
    assert sorted(u.name for u in all_units()) == sorted(
        ["triangle_setup", "tile_traverser", "tile_test", "zcull", "sample_tester", "shading", "rop"])


def test_the_common_counters_declare_a_meaning():
    assert tuple(COMMON_MEANINGS) == COMMON
    assert all(isinstance(m, str) and m.strip() for m in COMMON_MEANINGS.values())


@pytest.mark.parametrize("unit", all_units(), ids=lambda u: u.name)
def test_each_unit_declares_a_meaning_for_each_of_its_events_and_no_other(unit):
    assert set(unit.event_meanings) == set(unit.events), unit.name
    assert all(isinstance(unit.event_meanings[e], str) and unit.event_meanings[e].strip() for e in unit.events)


def test_each_culling_algorithm_declares_its_events_meanings():
    from units import culling
    from units.tile_test import TileTest

    for name, m in culling.ALGORITHMS.items():
        assert m.EVENTS == tuple(m.EVENT_MEANINGS), name
        assert all(s.strip() for s in m.EVENT_MEANINGS.values()), name
        for e in m.EVENTS:  # the tile test states each as its module does
            assert TileTest.event_meanings[e] == m.EVENT_MEANINGS[e]


def test_a_counter_declared_without_a_meaning_fails_the_glossary(monkeypatch):
    from units.rop import Rop

    monkeypatch.setattr(Rop, "event_meanings", {k: v for k, v in Rop.event_meanings.items()
                                                if k != "samples_written"})
    with pytest.raises(ValueError, match="rop: .*samples_written"):
        docgen.counter_glossary()
    monkeypatch.setattr(Rop, "event_meanings", {**Rop.event_meanings, "samples_written": " "})
    with pytest.raises(ValueError, match="samples_written"):
        counter_meanings(Rop)


def test_the_glossary_states_each_declared_meaning(root):
    """Each row of docs/counters.md carries its unit's declared meaning (common ones included)."""
    declared = {(u.name, c): m for u in all_units() for c, m in {**COMMON_MEANINGS, **u.event_meanings}.items()
                if c in COMMON + tuple(u.events)}
    rows = {}
    for line in (root / "docs/counters.md").read_text().splitlines():
        if line.startswith("| `"):
            cells = [c.strip() for c in line.strip("|").split(" | ")]
            rows[(cells[0].strip("`"), cells[1].strip("`"))] = cells[2]
    assert rows == declared
