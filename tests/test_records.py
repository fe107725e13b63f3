"""Records declared once: every batch a unit produces on a real run matches its declaration
in ``pipeline_sim.records`` (names, dtypes, per-record shapes), for every culling algorithm."""

import dataclasses
import sys

import numpy as np
import pytest

from conftest import ROOT
from pipeline_sim.config import TILE_TEST_ALGORITHMS, apply_settings, load_arch
from pipeline_sim.records import APPEND, FRAGMENT, SAMPLE, TILE, TILE_IDS, TRIANGLE, Field, RecordType
from pipeline_sim.render import render_scene
from pipeline_sim.scene import load_scene
from units import culling, sample_tester, tile_test, tile_traverser, triangle_setup, zcull

RECORD_TYPES = (TRIANGLE, TILE, TILE_IDS, SAMPLE, FRAGMENT, APPEND)


def test_problems_names_each_difference():
    rt = RecordType("R", (Field("a", np.int32), Field("b", np.float32, (2,))), __name__)
    assert rt.problems({"a": np.zeros(3, np.int32), "b": np.zeros((3, 2), np.float32)}) == []
    assert rt.problems(rt.allocate(5)) == []
    assert rt.problems({"a": np.zeros(3, np.int64), "b": np.zeros((3, 2), np.float32)}) == [
        "R.a: int64[], declared int32[]"]
    assert rt.problems({"a": np.zeros(3, np.int32), "b": np.zeros((3, 3), np.float32)}) == [
        "R.b: float32[3], declared float32[2]"]
    assert rt.problems({"a": np.zeros(3, np.int32)}) == ["R: missing ['b']"]
    assert rt.problems({**rt.allocate(3), "c": np.zeros(3)}) == ["R: undeclared ['c']"]
    assert rt.problems({"a": np.zeros(3, np.int32), "b": np.zeros((4, 2), np.float32)}) == [
        "R: fields of unequal lengths [3, 4]"]


def test_a_field_name_repeats_no_more_than_once():
    with pytest.raises(ValueError, match="repeats"):
        RecordType("R", (Field("a", np.int32), Field("a", np.float32)), __name__)


@pytest.mark.parametrize("rt", RECORD_TYPES + tuple(r for m in culling.ALGORITHMS.values()
                                                    for r in (m.TRIANGLE_EXT, m.TILE_EXT)), ids=lambda r: r.name)
def test_each_record_tuple_is_found_by_module_and_name(rt):
    """numba's on-disk cache finds a namedtuple argument type by module and name: a record
    whose tuple class is not bound there makes every kernel taking it recompile per process."""
    cls = rt.tuple_class
    assert getattr(sys.modules[cls.__module__], cls.__name__) is cls
    assert cls._fields == rt.names


def test_the_units_are_built_from_the_declarations():
    """The units allocate from the records (no private key lists): their tables carry exactly the
    declared fields, and the tile test's intervals are the tile record's tile-test fields."""
    assert TILE.added_by("tile_traverser") == TILE_IDS.names == ("tri", "tx", "ty")
    assert TILE.added_by("tile_test") == ("t_lo", "t_hi", "u_lo", "u_hi", "v_lo", "v_hi", "z_lo", "z_hi")
    assert set(FRAGMENT.names) <= set(SAMPLE.names) | {"color"}


def _run(algorithm):
    """Render a small both-blurs scene with ``algorithm``; capture every unit's output."""
    scene = load_scene(ROOT / "workloads/scenes/compare/both_1x.toml")
    scene = dataclasses.replace(scene, image=dataclasses.replace(scene.image, width=96, height=64, spp=4))
    overrides = [f"tile_test.algorithm='{algorithm}'"]
    if culling.algorithm(algorithm).NEEDS_TUPLES:
        overrides.append("pass.sample_pattern='interleave'")
    seen = {}
    units = {"triangle_setup": triangle_setup.TriangleSetup, "tile_traverser": tile_traverser.TileTraverser,
             "tile_test": tile_test.TileTest, "zcull": zcull.ZCull, "sample_tester": sample_tester.SampleTester}
    originals = {name: cls.run for name, cls in units.items()}

    def capture(name):
        def run(self, *args, **kw):
            out = originals[name](self, *args, **kw)
            seen.setdefault(name, []).append((self, out[0]))
            return out
        return run

    try:
        for name, cls in units.items():
            cls.run = capture(name)
        render_scene(*apply_settings(scene, load_arch(), overrides))
    finally:
        for name, cls in units.items():
            cls.run = originals[name]
    return seen


@pytest.mark.parametrize("algorithm", TILE_TEST_ALGORITHMS)
def test_every_unit_batch_matches_its_declaration(algorithm):
    seen = _run(algorithm)
    alg = culling.algorithm(algorithm)
    tiles_out = TILE.extend("Tested", alg.TILE_EXT.fields, __name__)
    assert {"triangle_setup", "tile_traverser", "tile_test", "zcull", "sample_tester"} <= set(seen)
    setup = seen["triangle_setup"][0][0]
    for rt, table in ((TRIANGLE, setup.table), (alg.TRIANGLE_EXT, setup.extension)):
        if not rt.names:
            assert table is None
            continue
        assert rt.problems(table._asdict()) == []
        assert {len(a) for a in table} == {setup.draw.n}
    problems = {f"{unit} batch {i}": p
                for unit, rt in (("tile_traverser", TILE_IDS), ("tile_test", tiles_out), ("zcull", tiles_out),
                                 ("sample_tester", SAMPLE))
                for i, (_, batch) in enumerate(seen[unit]) if (p := rt.problems(batch))}
    assert not problems, problems
    # the run produced records through every unit (a test of empty batches only would prove little)
    assert sum(len(b["tri"]) for _, b in seen["sample_tester"]) > 1000
