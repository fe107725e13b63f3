"""Architecture configuration (pipeline_sim/config.py): defaults, --set, --arch, errors.

Expected values come from the shipped TOML read here with tomllib, from
literal TOML/Python values, and from hand-written expectations of the error
messages (section and key named, one line).
"""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pandas as pd
import pytest

from pipeline_sim.config import (BLEND_MODES, DEFAULT_ARCH_PATH, DEPTH_FUNCS, SECTION_NAMES, ArchConfig,
                                 apply_overrides, arch_from_dict, load_arch, parse_override)
from pipeline_sim.errors import UserError


def shipped():
    with open(DEFAULT_ARCH_PATH, "rb") as fh:
        return tomllib.load(fh)


def test_defaults_load_and_match_shipped_file():
    arch = load_arch()
    assert isinstance(arch, ArchConfig)
    data = shipped()
    d = arch.to_dict()
    assert set(data) == set(SECTION_NAMES) == set(d)
    for section, values in data.items():
        assert set(values) == set(d[section]), section  # the file documents every key
        for key, value in values.items():
            got = d[section][key]
            assert got == value and type(got) is type(value), f"{section}.{key}: {got!r} != {value!r}"


def test_dataclass_defaults_equal_shipped_defaults():
    """The code defaults (used when a key is absent) are the documented ones."""
    assert ArchConfig().to_dict() == shipped()


def test_every_default_round_trips_through_dict():
    arch = load_arch()
    again = arch_from_dict(arch.to_dict())
    assert again == arch
    # and each value individually, set through --set to its own value
    for section, values in arch.to_dict().items():
        for key, value in values.items():
            lit = ("true" if value else "false") if isinstance(value, bool) else (
                f'"{value}"' if isinstance(value, str) else repr(value))
            assert apply_overrides(arch, [f"{section}.{key}={lit}"]) == arch, (section, key)


@pytest.mark.parametrize("text,expect", [
    ("tile_traverser.tile_size=16", ("tile_traverser", "tile_size", 16)),
    ("shading.shading_rate=0.5", ("shading", "shading_rate", 0.5)),
    ("shading.shading_rate=2", ("shading", "shading_rate", 2)),
    ("zcull.enabled=false", ("zcull", "enabled", False)),
    ("zcull.enabled=true", ("zcull", "enabled", True)),
    ("rop.depth_test=lequal", ("rop", "depth_test", "lequal")),
    ('rop.depth_test="gequal"', ("rop", "depth_test", "gequal")),
    (" rop.blend = max ", ("rop", "blend", "max")),
    ("pipeline.clock_ghz=1e-1", ("pipeline", "clock_ghz", 0.1)),
    ("shading.cache_entries=-3", ("shading", "cache_entries", -3)),
])
def test_parse_override_values(text, expect):
    got = parse_override(text)
    assert got == expect
    assert type(got[2]) is type(expect[2])


def test_overrides_apply_with_types():
    arch = load_arch(overrides=["tile_traverser.tile_size=16", "shading.shading_rate=2",
                                "zcull.enabled=false", "rop.depth_test=greater", "rop.blend=add",
                                "shading.replacement=fifo", "pipeline.queue_depth=1",
                                "tile_test.throughput=3"])
    assert arch.tile_traverser.tile_size == 16
    assert arch.shading.shading_rate == 2.0 and isinstance(arch.shading.shading_rate, float)
    assert arch.tile_test.throughput == 3.0 and isinstance(arch.tile_test.throughput, float)
    assert arch.zcull.enabled is False
    assert (arch.rop.depth_test, arch.rop.blend, arch.shading.replacement) == ("greater", "add", "fifo")
    assert arch.pipeline.queue_depth == 1
    # untouched keys keep the shipped defaults
    data = shipped()
    assert arch.shading.cache_entries == data["shading"]["cache_entries"]
    assert arch.rop.latency == data["rop"]["latency"]
    # the last of two overrides of one key wins
    assert load_arch(overrides=["rop.blend=add", "rop.blend=min"]).rop.blend == "min"


def test_load_arch_does_not_mutate_base():
    base = load_arch()
    before = base.to_dict()
    apply_overrides(base, ["rop.blend=add", "tile_traverser.tile_size=32"])
    arch_from_dict({"zcull": {"enabled": False}}, base=base)
    assert base.to_dict() == before


def _expect_error(overrides, *fragments):
    with pytest.raises(UserError) as info:
        load_arch(overrides=overrides)
    msg = str(info.value)
    assert "\n" not in msg, msg
    for f in fragments:
        assert f in msg, f"{f!r} not in {msg!r}"
    return msg


def test_unknown_section():
    msg = _expect_error(["zcul.enabled=true"], "zcul", "did you mean 'zcull'")
    assert "--set" in msg


def test_unknown_key_with_suggestion():
    _expect_error(["zcull.enable=true"], "zcull", "'enable'", "did you mean 'enabled'")
    _expect_error(["shading.cache_entrys=8"], "shading", "cache_entrys", "did you mean 'cache_entries'")


def test_unknown_key_without_close_match_lists_known_keys():
    msg = _expect_error(["rop.qqqqq=1"], "rop", "qqqqq", "known keys")
    assert "did you mean" not in msg
    assert "depth_test" in msg


@pytest.mark.parametrize("text,section,key", [
    ("zcull.enabled=1", "zcull", "enabled"),
    ("zcull.enabled=yes", "zcull", "enabled"),
    ("tile_traverser.tile_size=8.0", "tile_traverser", "tile_size"),
    ("tile_traverser.tile_size=true", "tile_traverser", "tile_size"),
    ("shading.shading_rate=fast", "shading", "shading_rate"),
    ("shading.shading_rate=true", "shading", "shading_rate"),
    ("rop.depth_test=1", "rop", "depth_test"),
    ("rop.depth_test=false", "rop", "depth_test"),
    ("pipeline.queue_depth=[1, 2]", "pipeline", "queue_depth"),
])
def test_wrong_type(text, section, key):
    _expect_error([text], f"{section}.{key}")


@pytest.mark.parametrize("size", [0, 3, 6, 12, 100, 256, -8])
def test_tile_size_must_be_power_of_two(size):
    _expect_error([f"tile_traverser.tile_size={size}"], "tile_traverser", "tile_size")


@pytest.mark.parametrize("size", [1, 2, 4, 8, 16, 32, 64, 128])
def test_tile_size_powers_of_two_accepted(size):
    assert load_arch(overrides=[f"tile_traverser.tile_size={size}"]).tile_traverser.tile_size == size


def test_cache_entries_multiple_of_ways():
    _expect_error(["shading.cache_entries=100"], "shading", "cache_entries", "cache_ways")
    _expect_error(["shading.cache_ways=3"], "shading", "cache_entries", "cache_ways")
    ok = load_arch(overrides=["shading.cache_entries=96", "shading.cache_ways=3"])
    assert (ok.shading.cache_entries, ok.shading.cache_ways) == (96, 3)


@pytest.mark.parametrize("text,section,key", [
    ("rop.depth_test=lesser", "rop", "depth_test"),
    ("rop.blend=multiply", "rop", "blend"),
    ("shading.mode=cached", "shading", "mode"),
    ("shading.replacement=random", "shading", "replacement"),
    ("pipeline.mode=fast", "pipeline", "mode"),
])
def test_bad_enum(text, section, key):
    msg = _expect_error([text], f"{section}.{key}")
    assert "is not one of" in msg


def test_bad_enum_suggests_and_lists_choices():
    msg = _expect_error(["rop.depth_test=lesser"], "did you mean 'less'")
    for f in DEPTH_FUNCS:
        assert f in msg
    msg = _expect_error(["rop.blend=ad"], "rop.blend")
    for b in BLEND_MODES:
        assert b in msg


@pytest.mark.parametrize("text,section,key", [
    ("rop.throughput=0", "rop", "throughput"),
    ("rop.throughput=-1.5", "rop", "throughput"),
    ("rop.bandwidth=nan", "rop", "bandwidth"),
    ("shading.shading_rate=inf", "shading", "shading_rate"),
    ("zcull.latency=-1", "zcull", "latency"),
    ("tile_test.instances=0", "tile_test", "instances"),
    ("pipeline.queue_depth=0", "pipeline", "queue_depth"),
    ("pipeline.triangles_per_batch=0", "pipeline", "triangles_per_batch"),
    ("zcull.time_slices=0", "zcull", "time_slices"),
])
def test_range_errors(text, section, key):
    _expect_error([text], f"{section}.{key}")


def test_zcull_box_budget():
    _expect_error(["zcull.time_slices=64", "zcull.lens_boxes=2"], "zcull", "time_slices", "lens_boxes")
    arch = load_arch(overrides=["zcull.time_slices=63", "zcull.lens_boxes=2"])  # 252 boxes
    assert arch.zcull.time_slices * arch.zcull.lens_boxes ** 2 == 252


@pytest.mark.parametrize("text", ["noequals", "a=1", "a.b.c=1", ".b=1", "a.=1"])
def test_malformed_set(text):
    with pytest.raises(UserError) as info:
        parse_override(text)
    assert "\n" not in str(info.value) and "section.key=value" in str(info.value)


def test_arch_file_applied_over_defaults(tmp_path):
    f = tmp_path / "my_arch.toml"
    f.write_text("[rop]\nblend = \"max\"\nthroughput = 4\n\n[shading]\ncache_entries = 64\n"
                 "cache_ways = 4\n[zcull]\nenabled = false\n")
    arch = load_arch(f)
    assert arch.rop.blend == "max" and arch.rop.throughput == 4.0
    assert (arch.shading.cache_entries, arch.shading.cache_ways) == (64, 4)
    assert arch.zcull.enabled is False
    expect = shipped()
    expect["rop"].update(blend="max", throughput=4.0)
    expect["shading"].update(cache_entries=64, cache_ways=4)
    expect["zcull"]["enabled"] = False
    assert arch.to_dict() == expect
    # --set applies on top of the file
    arch2 = load_arch(f, overrides=["rop.blend=min", "shading.cache_entries=128"])
    assert arch2.rop.blend == "min" and arch2.rop.throughput == 4.0
    assert (arch2.shading.cache_entries, arch2.shading.cache_ways) == (128, 4)


def test_arch_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad_arch.toml"
    bad.write_text("[rop]\ndepth_tst = \"less\"\n")
    with pytest.raises(UserError) as info:
        load_arch(bad)
    msg = str(info.value)
    assert "bad_arch.toml" in msg and "rop" in msg and "depth_tst" in msg and "depth_test" in msg
    assert "\n" not in msg
    notable = tmp_path / "nt.toml"
    notable.write_text("rop = 3\n")
    with pytest.raises(UserError, match="rop"):
        load_arch(notable)
    broken = tmp_path / "broken.toml"
    broken.write_text("[rop\n")
    with pytest.raises(UserError, match="broken.toml"):
        load_arch(broken)
    with pytest.raises(UserError, match="not found"):
        load_arch(tmp_path / "missing.toml")
    garbage = tmp_path / "garbage.toml"
    garbage.write_bytes(b"\xff\xfe\x00 not text")
    with pytest.raises(UserError, match="garbage.toml: not a TOML file: not UTF-8"):
        load_arch(garbage)
    with pytest.raises(UserError, match="is a folder"):
        load_arch(tmp_path)


def test_replace_keeps_sections():
    arch = load_arch()
    new = arch.replace(rop=dataclasses.replace(arch.rop, blend="add"))
    assert new.rop.blend == "add" and arch.rop.blend == "replace"
    assert new.shading == arch.shading


def test_leaving_conservative_mode_restores_tile_size(tmp_path):
    f = tmp_path / "cons.toml"
    f.write_text('[pipeline]\nmode = "conservative"\n')
    arch = load_arch(f, overrides=["pipeline.mode=standard"])
    assert arch.pipeline.mode == "standard"
    assert arch.tile_traverser.tile_size == shipped()["tile_traverser"]["tile_size"]


# --- what each setting declares it can change -----------------------------------

def _alternative(path: str, value):
    """A valid value other than the default, for every setting."""
    special = {"pipeline.mode": "conservative", "pipeline.sample_pattern": "sobol", "pipeline.interleave_tuples": 32,
               "pipeline.region_samples": 4096, "tile_test.algorithm": "bbox", "tile_test.edge_solver": "quadratic",
               "tile_test.gamma": "tile", "tile_test.clip_t_hi": 0.5, "tile_test.clip_t_lo": 0.5,
               "tile_test.clip_u_lo": 0.0, "tile_test.clip_u_hi": 0.0, "tile_test.clip_v_lo": 0.0,
               "tile_test.clip_v_hi": 0.0, "tile_traverser.tile_size": 16, "tile_traverser.coarse_factor": 2,
               "zcull.lens_boxes": 3, "shading.mode": "per_sample", "shading.replacement": "fifo",
               "rop.depth_test": "greater", "rop.blend": "add", "shading.cache_ways": 4}
    if path in special:
        return special[path]
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return max(1, value // 2) if value > 1 else 3
    if isinstance(value, float):
        return value * 0.5
    raise AssertionError(f"no alternative for {path} = {value!r}")


def test_every_setting_declares_what_it_can_change():
    from pipeline_sim.config import EFFECTS, setting_effects

    effects = setting_effects()
    arch = load_arch()
    listed = {f"{s}.{f.name}" for s in SECTION_NAMES for f in dataclasses.fields(getattr(arch, s))}
    assert set(effects) == listed and set(effects.values()) <= set(EFFECTS)
    # every setting's alternative value is valid on its own
    for path in effects:
        section, key = path.split(".")
        value = _alternative(path, getattr(getattr(arch, section), key))
        apply_overrides(arch, [_override(path, value)])


@pytest.fixture(scope="module")
def blurred_scene(root):
    from pipeline_sim.scene import load_scene

    s = load_scene(root / "workloads/scenes/default.toml")
    return s.replace(image=dataclasses.replace(s.image, width=48, height=27, spp=4))


def _override(path, value):
    from pipeline_sim.sweep import toml_literal

    return f"{path}={toml_literal(value)}"


def test_settings_declared_not_to_change_the_image_do_not(blurred_scene):
    """Measured, not assumed: every `counters` and `cycles` setting, moved off its default, leaves the image
    bit-identical; with z-cull (the one path from timing back to the work) off, every `cycles` setting leaves
    every counter identical too."""
    from pipeline_sim.config import COUNTERS, CYCLES, setting_effects
    from pipeline_sim.render import render_scene

    base = load_arch()
    reference = render_scene(blurred_scene, base)
    no_zcull = load_arch(overrides=["zcull.enabled=false"])
    reference_counters = render_scene(blurred_scene, no_zcull).counters
    checked = 0
    for path, effect in setting_effects().items():
        if effect not in (COUNTERS, CYCLES):
            continue
        section, key = path.split(".")
        change = _override(path, _alternative(path, getattr(getattr(base, section), key)))
        image = render_scene(blurred_scene, apply_overrides(base, [change])).image
        assert np.array_equal(image, reference.image), path
        if effect == CYCLES:
            counters = render_scene(blurred_scene, apply_overrides(no_zcull, [change])).counters
            pd.testing.assert_frame_equal(counters, reference_counters, obj=path)
        checked += 1
    assert checked >= 35


def test_reference_arch_follows_the_declarations():
    from pipeline_sim.config import IMAGE, reference_arch, settings_of, setting_effects

    user = load_arch(overrides=["tile_test.clip_t_hi=0.3", "rop.depth_test='lequal'", "shading.mode='cache'",
                                "pipeline.sample_pattern='interleave'", "tile_test.algorithm='interleave_uvt'",
                                "zcull.time_slices=8", "rop.throughput=3.0"])
    ref = reference_arch(user)
    assert settings_of(ref, (IMAGE,)) == settings_of(user, (IMAGE,))
    assert (ref.shading.mode, ref.pipeline.sample_pattern, ref.pipeline.mode) == ("per_sample", "net", "standard")
    shipped = load_arch()
    for path, effect in setting_effects().items():
        if effect in ("counters", "cycles"):
            section, key = path.split(".")
            assert getattr(getattr(ref, section), key) == getattr(getattr(shipped, section), key), path


def test_the_docs_table_of_effects_matches_the_declarations(root):
    from pipeline_sim.config import setting_effects

    text = (root / "docs/architecture-format.md").read_text()
    rows = {line.split("|")[1].strip(" `"): line.split("|")[3] for line in text.splitlines()
            if line.startswith("| `") and line.split("|")[1].strip(" `") in ("image", "accuracy", "counters", "cycles")}
    assert len(rows) == 4
    for path, effect in setting_effects().items():
        if path.split(".")[1] in ("throughput", "latency", "instances"):
            assert "every unit's `throughput`, `latency` and `instances`" in rows["cycles"]
            continue
        listed_in = [e for e, cell in rows.items() if f"`{path}`" in cell]
        assert listed_in == [effect], (path, listed_in)


@pytest.mark.parametrize("value", ["1e-308", "1e308", "1" + "0" * 400, "-1", "nan"])
def test_every_numeric_setting_is_bounded_so_the_cost_model_stays_finite(value):
    """Each number an architecture takes is refused in one line outside its range (a throughput of 1e-308
    made the frame's cycles infinite, and the run died writing run.json after the whole simulation)."""
    arch = load_arch()
    for section in SECTION_NAMES:
        for f in dataclasses.fields(getattr(arch, section)):
            default = getattr(getattr(arch, section), f.name)
            if isinstance(default, bool) or not isinstance(default, (int, float)):
                continue
            if isinstance(default, int) and value in ("1e-308", "1e308", "nan"):
                continue   # not an integer: refused for its type already
            if f.name.startswith("clip_") and value in ("1e-308", "-1"):
                continue   # a clip plane may sit anywhere in [0, 1] or [-1, 1]
            with pytest.raises(UserError) as info:
                apply_overrides(arch, [f"{section}.{f.name}={value}"])
            assert "\n" not in str(info.value) and f.name in str(info.value)
            assert len(str(info.value)) < 300


def test_the_cost_model_range_keeps_frame_cycles_finite(root):
    """At the ends of the range the simulation's timing is finite (and so is every file written from it)."""
    import math

    from pipeline_sim.render import render_scene
    from pipeline_sim.scene import load_scene

    s = load_scene(root / "workloads/scenes/default.toml")
    s = s.replace(image=dataclasses.replace(s.image, width=32, height=18, spp=1))
    slow = [f"{u}.throughput=1e-6" for u in ("triangle_setup", "tile_traverser", "tile_test", "zcull",
                                              "sample_tester", "shading", "rop")]
    slow += ["shading.shader_cycles=1e9", "rop.bandwidth=1e-6", f"rop.latency={2**31 - 1}"]
    result = render_scene(s, load_arch(overrides=slow))
    assert math.isfinite(result.timing.frame_cycles) and result.timing.frame_cycles > 1e9
    assert np.isfinite(result.timing.units[["busy", "starved", "blocked"]].to_numpy(float)).all()
