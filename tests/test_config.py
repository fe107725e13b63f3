"""Settings (pipeline_sim/config.py): the hardware's defaults, --set, --arch, the pass state and
simulation options, the migration of moved keys, errors, and what each setting declares it can change.

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

from pipeline_sim.config import (DEFAULT_ARCH_PATH, MOVED, SECTION_NAMES, ArchConfig, apply_overrides,
                                 arch_from_dict, load_arch, parse_override, pass_settings)
from pipeline_sim.definitions import BLEND_MODES, DEPTH_FUNCS
from pipeline_sim.errors import UserError
from pipeline_sim.pass_state import PassState
from pipeline_sim.simulation import SimOptions


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
    ("pass.shading_rate=0.5", ("pass", "shading_rate", 0.5)),
    ("pass.shading_rate=2", ("pass", "shading_rate", 2)),
    ("pass.clip.t_hi=0.3", ("pass", "clip.t_hi", 0.3)),
    ("simulation.region_samples=0", ("simulation", "region_samples", 0)),
    ("zcull.enabled=false", ("zcull", "enabled", False)),
    ("zcull.enabled=true", ("zcull", "enabled", True)),
    ("pass.depth_test=lequal", ("pass", "depth_test", "lequal")),
    ('pass.depth_test="gequal"', ("pass", "depth_test", "gequal")),
    (" pass.blend = max ", ("pass", "blend", "max")),
    ("pipeline.clock_ghz=1e-1", ("pipeline", "clock_ghz", 0.1)),
    ("shading.cache_entries=-3", ("shading", "cache_entries", -3)),
])
def test_parse_override_values(text, expect):
    got = parse_override(text)
    assert got == expect
    assert type(got[2]) is type(expect[2])


def test_overrides_apply_with_types():
    s = pass_settings(["tile_traverser.tile_size=16", "pass.shading_rate=2", "zcull.enabled=false",
                       "pass.depth_test=greater", "pass.blend=add", "shading.replacement=fifo",
                       "pipeline.queue_depth=1", "tile_test.throughput=3", "pass.clip.t_hi=0.5",
                       "simulation.tiles_per_batch=7"])
    arch, state, sim = s["arch"], s["state"], s["simulation"]
    assert arch.tile_traverser.tile_size == 16
    assert state.shading_rate == 2.0 and isinstance(state.shading_rate, float)
    assert arch.tile_test.throughput == 3.0 and isinstance(arch.tile_test.throughput, float)
    assert arch.zcull.enabled is False
    assert (state.depth_test, state.blend, arch.shading.replacement) == ("greater", "add", "fifo")
    assert arch.pipeline.queue_depth == 1
    assert state.clip.t_hi == 0.5 and state.clip.t_lo == 0.0 and sim.tiles_per_batch == 7
    assert state.replace(shading_rate=1.0, depth_test="less", blend="replace", clip=PassState().clip) == PassState()
    # untouched keys keep the shipped defaults
    data = shipped()
    assert arch.shading.cache_entries == data["shading"]["cache_entries"]
    assert arch.rop.latency == data["rop"]["latency"]
    # the last of two overrides of one key wins
    assert pass_settings(["pass.blend=add", "pass.blend=min"])["state"].blend == "min"
    assert load_arch(overrides=["rop.latency=3", "rop.latency=4"]).rop.latency == 4


def test_load_arch_does_not_mutate_base():
    base = load_arch()
    before = base.to_dict()
    apply_overrides(base, ["rop.bandwidth=3", "tile_traverser.tile_size=32"])
    pass_settings(["zcull.lens_boxes=1"], arch=base)
    arch_from_dict({"zcull": {"enabled": False}}, base=base)
    assert base.to_dict() == before


def _expect_error(overrides, *fragments):
    with pytest.raises(UserError) as info:
        pass_settings(overrides)
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
    assert "bandwidth" in msg
    msg = _expect_error(["pass.qqqqq=1"], "pass", "qqqqq", "known keys")
    assert "did you mean" not in msg and "depth_test" in msg
    _expect_error(["pass.clip.t_high=0.5"], "[pass.clip]", "t_high", "did you mean 't_hi'")
    _expect_error(["simulation.region_sample=0"], "[simulation]", "did you mean 'region_samples'")


@pytest.mark.parametrize("text,section,key", [
    ("zcull.enabled=1", "zcull", "enabled"),
    ("zcull.enabled=yes", "zcull", "enabled"),
    ("tile_traverser.tile_size=8.0", "tile_traverser", "tile_size"),
    ("tile_traverser.tile_size=true", "tile_traverser", "tile_size"),
    ("pass.shading_rate=fast", "pass", "shading_rate"),
    ("pass.shading_rate=true", "pass", "shading_rate"),
    ("pass.depth_test=1", "pass", "depth_test"),
    ("pass.depth_test=false", "pass", "depth_test"),
    ("pass.clip.t_hi=true", "pass", "clip.t_hi"),
    ("simulation.region_samples=1.5", "simulation", "region_samples"),
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
    ("pass.depth_test=lesser", "pass", "depth_test"),
    ("pass.blend=multiply", "pass", "blend"),
    ("pass.shading_mode=cached", "pass", "shading_mode"),
    ("shading.replacement=random", "shading", "replacement"),
    ("pass.mode=fast", "pass", "mode"),
    ("tile_test.algorithm=box", "tile_test", "algorithm"),
])
def test_bad_enum(text, section, key):
    msg = _expect_error([text], f"{section}.{key}")
    assert "is not one of" in msg


def test_bad_enum_suggests_and_lists_choices():
    msg = _expect_error(["pass.depth_test=lesser"], "did you mean 'less'")
    for f in DEPTH_FUNCS:
        assert f in msg
    msg = _expect_error(["pass.blend=ad"], "pass.blend")
    for b in BLEND_MODES:
        assert b in msg


@pytest.mark.parametrize("text,section,key", [
    ("rop.throughput=0", "rop", "throughput"),
    ("rop.throughput=-1.5", "rop", "throughput"),
    ("rop.bandwidth=nan", "rop", "bandwidth"),
    ("pass.shading_rate=inf", "pass", "shading_rate"),
    ("pass.shading_rate=0.001", "pass", "shading_rate"),
    ("pass.interleave_tuples=65", "pass", "interleave_tuples"),
    ("pass.clip.t_hi=1.5", "pass", "clip.t_hi"),
    ("pass.clip.u_lo=-2", "pass", "clip.u_lo"),
    ("simulation.region_samples=-1", "simulation", "region_samples"),
    ("zcull.latency=-1", "zcull", "latency"),
    ("tile_test.instances=0", "tile_test", "instances"),
    ("pipeline.queue_depth=0", "pipeline", "queue_depth"),
    ("simulation.triangles_per_batch=0", "simulation", "triangles_per_batch"),
    ("zcull.time_slices=0", "zcull", "time_slices"),
])
def test_range_errors(text, section, key):
    _expect_error([text], f"{section}.{key}")


def test_zcull_box_budget():
    _expect_error(["zcull.time_slices=64", "zcull.lens_boxes=2"], "zcull", "time_slices", "lens_boxes")
    arch = load_arch(overrides=["zcull.time_slices=63", "zcull.lens_boxes=2"])  # 252 boxes
    assert arch.zcull.time_slices * arch.zcull.lens_boxes ** 2 == 252


def test_clip_planes_in_order():
    _expect_error(["pass.clip.t_lo=0.6", "pass.clip.t_hi=0.4"], "pass.clip", "t_lo", "t_hi", "[0.6, 0.4]")
    clip = pass_settings(["pass.clip.v_lo=0.2", "pass.clip.v_hi=0.2"])["state"].clip
    assert (clip.v_lo, clip.v_hi) == (0.2, 0.2)


@pytest.mark.parametrize("text", ["noequals", "a=1", "a.b.c=1", ".b=1", "a.=1", "pass.clip.t.hi=1", "rop.clip.t_hi=1"])
def test_malformed_set(text):
    with pytest.raises(UserError) as info:
        parse_override(text)
    assert "\n" not in str(info.value) and "section.key=value" in str(info.value)


def test_arch_file_applied_over_defaults(tmp_path):
    f = tmp_path / "my_arch.toml"
    f.write_text("[rop]\nbandwidth = 8\nthroughput = 4\n\n[shading]\ncache_entries = 64\n"
                 "cache_ways = 4\n[zcull]\nenabled = false\n")
    arch = load_arch(f)
    assert arch.rop.bandwidth == 8.0 and arch.rop.throughput == 4.0
    assert (arch.shading.cache_entries, arch.shading.cache_ways) == (64, 4)
    assert arch.zcull.enabled is False
    expect = shipped()
    expect["rop"].update(bandwidth=8.0, throughput=4.0)
    expect["shading"].update(cache_entries=64, cache_ways=4)
    expect["zcull"]["enabled"] = False
    assert arch.to_dict() == expect
    # --set applies on top of the file
    arch2 = load_arch(f, overrides=["rop.bandwidth=2", "shading.cache_entries=128"])
    assert arch2.rop.bandwidth == 2.0 and arch2.rop.throughput == 4.0
    assert (arch2.shading.cache_entries, arch2.shading.cache_ways) == (128, 4)


def test_arch_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad_arch.toml"
    bad.write_text("[rop]\nbandwith = 1.0\n")
    with pytest.raises(UserError) as info:
        load_arch(bad)
    msg = str(info.value)
    assert "bad_arch.toml" in msg and "rop" in msg and "bandwith" in msg and "did you mean 'bandwidth'" in msg
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
    new = arch.replace(rop=dataclasses.replace(arch.rop, bandwidth=2.0))
    assert new.rop.bandwidth == 2.0 and arch.rop.bandwidth == 64.0
    assert new.shading == arch.shading


# --- the settings that moved out of the architecture file -----------------------

# hand-written: where each old key goes now (the scene's table, its key there, the --set path)
WHERE_NOW = {
    "pipeline.mode": ("[pass]", "mode", "pass.mode"),
    "pipeline.sample_pattern": ("[pass]", "sample_pattern", "pass.sample_pattern"),
    "pipeline.interleave_tuples": ("[pass]", "interleave_tuples", "pass.interleave_tuples"),
    "triangle_setup.backface_culling": ("[pass]", "backface_culling", "pass.backface_culling"),
    "rop.depth_test": ("[pass]", "depth_test", "pass.depth_test"),
    "rop.depth_write": ("[pass]", "depth_write", "pass.depth_write"),
    "rop.blend": ("[pass]", "blend", "pass.blend"),
    "shading.mode": ("[pass]", "shading_mode", "pass.shading_mode"),
    "shading.shading_rate": ("[pass]", "shading_rate", "pass.shading_rate"),
    **{f"tile_test.clip_{a}_{e}": ("[pass.clip]", f"{a}_{e}", f"pass.clip.{a}_{e}")
       for a in "tuv" for e in ("lo", "hi")},
    **{f"pipeline.{k}": ("[simulation]", k, f"simulation.{k}")
       for k in ("triangles_per_batch", "tiles_per_batch", "samples_per_batch", "region_samples")},
}
OLD_VALUES = {"pipeline.mode": "conservative", "pipeline.sample_pattern": "sobol", "rop.depth_test": "always",
              "rop.blend": "add", "shading.mode": "per_sample", "rop.depth_write": False,
              "triangle_setup.backface_culling": True}


@pytest.mark.parametrize("old", sorted(WHERE_NOW))
def test_a_moved_key_in_an_architecture_file_says_where_it_goes_now(tmp_path, old):
    assert set(MOVED) == set(WHERE_NOW)
    section, key = old.split(".")
    value = OLD_VALUES.get(old, 0.5 if "clip" in old else 32)
    f = tmp_path / "arch.toml"
    literal = '"' + value + '"' if isinstance(value, str) else str(value).lower()
    f.write_text(f"[{section}]\n{key} = {literal}\n")
    table, name, path = WHERE_NOW[old]
    kind = "a simulation option" if table == "[simulation]" else "pass state"
    expect = (f"arch.toml: [{section}] {key} is {kind} now: set it in the scene's {table} table "
              f"({name} = {literal}) or with --set {path}={literal}")
    with pytest.raises(UserError) as info:
        load_arch(f)
    assert str(info.value) == expect
    with pytest.raises(UserError) as info:
        pass_settings([f"{old}={literal}"])
    assert str(info.value) == expect.replace("arch.toml:", "--set:", 1)
    # and where it says, it is taken
    s = pass_settings([f"{path}={literal}"])
    owner = s["simulation"] if table == "[simulation]" else s["state"]
    got = getattr(owner.clip, name) if table == "[pass.clip]" else getattr(owner, name)
    assert got == value


def test_scene_pass_and_simulation_tables(tmp_path, root):
    from pipeline_sim.scene import load_scene

    text = (root / "workloads/scenes/static.toml").read_text()
    f = tmp_path / "s.toml"
    f.write_text(text + '\n[pass]\ndepth_test = "always"\nshading_mode = "per_sample"\n[pass.clip]\nt_hi = 0.3\n'
                 "\n[simulation]\nregion_samples = 0\n")
    scene = load_scene(f)
    assert scene.pass_state == PassState(depth_test="always", shading_mode="per_sample",
                                         clip=dataclasses.replace(PassState().clip, t_hi=0.3))
    assert scene.simulation == SimOptions(region_samples=0)
    assert load_scene(root / "workloads/scenes/static.toml").pass_state == PassState()
    f.write_text(text + '\n[pass]\ndepth_tst = "always"\n')
    with pytest.raises(UserError, match=r"s.toml: \[pass\]: unknown key 'depth_tst' \(did you mean 'depth_test'\?\)"):
        load_scene(f)
    f.write_text(text + '\n[pass.clip]\nt_hi = 2.0\n')
    with pytest.raises(UserError, match=r"s.toml: pass.clip.t_hi: must be from 0 to 1, got 2.0"):
        load_scene(f)
    f.write_text('pass = 3\n' + text)
    with pytest.raises(UserError, match=r"s.toml: \[pass\] must be a table, got 3"):
        load_scene(f)


# --- what each setting declares it can change -----------------------------------

def _alternative(path: str, value):
    """A valid value other than the default, for every setting."""
    special = {"pass.mode": "conservative", "pass.time_intervals": "exact", "pass.sample_pattern": "sobol",
               "pass.interleave_tuples": 32,
               "simulation.region_samples": 4096, "simulation.run_ahead": 0, "tile_test.algorithm": "bbox",
               "tile_test.edge_solver": "quadratic",
               "tile_test.gamma": "tile", "pass.clip.t_hi": 0.5, "pass.clip.t_lo": 0.5,
               "pass.clip.u_lo": 0.0, "pass.clip.u_hi": 0.0, "pass.clip.v_lo": 0.0,
               "pass.clip.v_hi": 0.0, "tile_traverser.tile_size": 16, "tile_traverser.coarse_factor": 2,
               "zcull.lens_boxes": 3, "pass.shading_mode": "per_sample", "shading.replacement": "fifo",
               "pass.depth_test": "greater", "pass.blend": "add", "shading.cache_ways": 4}
    if path in special:
        return special[path]
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return max(1, value // 2) if value > 1 else 3
    if isinstance(value, float):
        return value * 0.5
    raise AssertionError(f"no alternative for {path} = {value!r}")


def _paths(obj, prefix=""):
    """Every setting of a settings dataclass by dotted path, with its value (walked here, not by config)."""
    out = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        out.update(_paths(v, f"{prefix}{f.name}.") if dataclasses.is_dataclass(v) else {f"{prefix}{f.name}": v})
    return out


def _all_paths():
    return {**_paths(load_arch()), **_paths(PassState(), "pass."), **_paths(SimOptions(), "simulation.")}


def test_every_setting_declares_what_it_can_change():
    from pipeline_sim.config import EFFECTS, setting_effects

    effects = setting_effects()
    listed = _all_paths()
    assert set(effects) == set(listed) and set(effects.values()) <= set(EFFECTS)
    assert len([p for p in listed if p.startswith("pass.")]) == 19 and "simulation.region_samples" in listed
    # every setting's alternative value is valid on its own
    for path, value in listed.items():
        pass_settings([_override(path, _alternative(path, value))])


@pytest.fixture(scope="module")
def blurred_scene(root):
    from pipeline_sim.scene import load_scene

    s = load_scene(root / "workloads/scenes/default.toml")
    return s.replace(image=dataclasses.replace(s.image, width=48, height=27, spp=4))


def _override(path, value):
    from pipeline_sim.config import literal

    return f"{path}={literal(value)}"


def test_settings_declared_not_to_change_the_image_do_not(blurred_scene):
    """Measured, not assumed: every `counters`, `cycles` and `speed` setting (hardware or simulation option),
    moved off its default, leaves the image bit-identical; with z-cull (the one path from timing back to the
    work) off, every `cycles` setting leaves every counter identical too, and a `speed` setting leaves every
    counter and cycle identical even with z-cull on."""
    from pipeline_sim.config import COUNTERS, CYCLES, SPEED, setting_effects
    from pipeline_sim.render import render_scene

    reference = render_scene(blurred_scene, **pass_settings([]))
    reference_counters = render_scene(blurred_scene, **pass_settings(["zcull.enabled=false"])).counters
    values = _all_paths()
    checked = 0
    for path, effect in setting_effects().items():
        if effect not in (COUNTERS, CYCLES, SPEED):
            continue
        change = _override(path, _alternative(path, values[path]))
        result = render_scene(blurred_scene, **pass_settings([change]))
        assert np.array_equal(result.image, reference.image), path
        if effect == SPEED:
            pd.testing.assert_frame_equal(result.counters, reference.counters, obj=path)
            pd.testing.assert_frame_equal(result.timing.units, reference.timing.units, obj=path)
        if effect == CYCLES:
            counters = render_scene(blurred_scene, **pass_settings(["zcull.enabled=false", change])).counters
            pd.testing.assert_frame_equal(counters, reference_counters, obj=path)
        checked += 1
    assert checked >= 35


def test_reference_setup_follows_the_declarations():
    from pipeline_sim.config import IMAGE, reference_setup, setting_effects, settings_of

    s = pass_settings(["pass.clip.t_hi=0.3", "pass.depth_test='lequal'", "pass.shading_mode='cache'",
                       "pass.sample_pattern='interleave'", "tile_test.algorithm='interleave_uvt'",
                       "zcull.time_slices=8", "rop.throughput=3.0", "simulation.region_samples=0",
                       "shading.cache_entries=64"])
    ref = reference_setup(s["arch"], s["state"])
    user_values = settings_of(s["arch"], s["state"], s["simulation"], ("image",))
    assert settings_of(*ref, (IMAGE,)) == user_values
    assert ref[1].clip.t_hi == 0.3 and ref[1].depth_test == "lequal"
    assert (ref[1].shading_mode, ref[1].sample_pattern, ref[1].mode) == ("per_sample", "net", "standard")
    shipped = _all_paths()
    got = {**_paths(ref[0]), **_paths(ref[1], "pass."), **_paths(ref[2], "simulation.")}
    for path, effect in setting_effects().items():
        if effect in ("counters", "cycles") or path == "shading.cache_entries":
            assert got[path] == shipped[path], path


@pytest.mark.parametrize("value", ["1e-308", "1e308", "1" + "0" * 400, "-1", "nan"])
def test_every_numeric_setting_is_bounded_so_the_cost_model_stays_finite(value):
    """Each number a setting takes is refused in one line outside its range (a throughput of 1e-308
    made the frame's cycles infinite, and the run died writing run.json after the whole simulation)."""
    for path, default in _all_paths().items():
        if isinstance(default, bool) or not isinstance(default, (int, float)):
            continue
        if isinstance(default, int) and value in ("1e-308", "1e308", "nan"):
            continue   # not an integer: refused for its type already
        # a time (a clip plane's, the shading view's) may sit anywhere in [0, 1], a lens coordinate in [-1, 1]
        time = ".clip.t_" in path or path == "pass.shading_t"
        lens = any(k in path for k in (".clip.u_", ".clip.v_", "pass.shading_u", "pass.shading_v"))
        if value == "1e-308" and (time or lens) or value == "-1" and lens:
            continue
        with pytest.raises(UserError) as info:
            pass_settings([f"{path}={value}"])
        assert "\n" not in str(info.value) and path.rsplit(".", 1)[1] in str(info.value)
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
