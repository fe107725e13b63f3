"""The hardware an architecture file describes, and the settings of a run across its three kinds.

An architecture file holds only hardware: units' throughput, latency and
instances, tile size, the culling algorithm and its options, cache
geometry, z-cull boxes, bandwidth, queue depth, clock. What a pass asks of
it (mode, depth and blend, clip planes, backface culling, sample pattern,
shading mode) is the pass state (``pipeline_sim.pass_state``, a scene's
``[pass]`` table), and how the simulator runs it (batch sizes, screen
regions) the simulation options (``pipeline_sim.simulation``, a scene's
``[simulation]`` table). ``--set`` takes all three by their dotted paths:
``SECTION.KEY`` for hardware, ``pass.KEY`` (``pass.clip.KEY``) and
``simulation.KEY``; :func:`apply_settings` routes each. A setting that has
moved out of the architecture file is refused with one line saying where it
goes now (:data:`MOVED`).

Every setting declares what it can change (``pipeline_sim.settings``); the
accuracy reference of a sweep (:func:`reference_setup`) and the groups of
algorithms ``compare`` expects the same image from (:func:`settings_of`)
are derived from these declarations across all three kinds. Types, ranges,
choices and unknown keys are validated by pydantic from the fields'
annotations (``pipeline_sim.schema``).
"""

from __future__ import annotations

import dataclasses
import functools
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import tomli_w

from pipeline_sim import schema
from pipeline_sim.errors import UserError, read_input_text
from pipeline_sim.pass_state import PassState
from pipeline_sim.settings import (ACCURACY, COUNTERS, CYCLES, EFFECTS, FORBID, IMAGE, SPEED, Flag, Rate,  # noqa: F401
                                   count, setting)
from pipeline_sim.simulation import SimOptions

if TYPE_CHECKING:
    from pipeline_sim.scene import Scene

DEFAULT_ARCH_PATH = Path(__file__).with_name("data") / "default_arch.toml"

# bbox: every tile of the moving, defocused bounds and every sample of the
# triangle's time span (the baseline of Wu13 and Munkberg11); hierarchical: the tile
# tests of Munkberg11 §4 (moving box, linearized or quadratic edges) and lens bounds;
# hull: the convex hull of the six projected vertices (McGuire10,
# Wu13 §3.2); dual_space: lens bounds, then time bounds over the whole lens
# range (Laine11, Wu13 §2); two_stage: lens bounds, then time bounds
# linear in the lens coordinate (Wu13 §3.3-3.4); interleave_uvt: one 2D
# raster per (u, v, t) tuple of a fixed set (Fatahalian09)
TILE_TEST_ALGORITHMS = ("hierarchical", "bbox", "hull", "dual_space", "two_stage", "interleave_uvt")
EDGE_SOLVERS = ("linearized", "quadratic")
Count = count(1)
Latency = count(0)


@dataclass
class PipelineConfig:
    """The machine's global settings: channel depth, clock, specialization."""

    __pydantic_config__ = FORBID

    queue_depth: Count = setting(4, CYCLES, "capacity of every channel: this many batches of the default size, "
                                 "counted in records (so a batch size changes only the timing granularity)")
    clock_ghz: Rate = setting(1.0, CYCLES, "only used to print simulated time")
    specialize: Flag = setting(True, COUNTERS, "pay only for the dimensions each triangle uses (2D, xyt, xyuv, "
                               "xyuvt); false runs every test as 5D: same image, more arithmetic")


@dataclass
class UnitTiming:
    """Cost model shared by every unit: items per cycle per instance, latency, instances."""

    __pydantic_config__ = FORBID

    throughput: Rate = setting(1.0, CYCLES, "items per cycle per instance")
    latency: Latency = setting(10, CYCLES, "cycles")
    instances: Count = setting(1, CYCLES, "parallel instances")


@dataclass
class TriangleSetupConfig(UnitTiming):
    throughput: Rate = 0.5
    latency: Latency = 30


@dataclass
class TileTraverserConfig(UnitTiming):
    throughput: Rate = 2.0
    latency: Latency = 4
    tile_size: count(1, 128) = setting(4, COUNTERS, "pixels, a power of two")
    coarse_factor: Count = setting(4, COUNTERS, "a coarse tile is coarse_factor x coarse_factor tiles")

    def check(self, where: str) -> None:
        if self.tile_size & (self.tile_size - 1):
            raise UserError(f"{where}.tile_size: must be a power of two from 1 to 128, got {self.tile_size}")


@dataclass
class TileTestConfig(UnitTiming):
    throughput: Rate = 1.0
    latency: Latency = 12
    instances: Count = 2
    algorithm: Literal[TILE_TEST_ALGORITHMS] = setting(
        "hierarchical", COUNTERS, "`hierarchical` (Munkberg11 §4 tile tests), `bbox` (every sample in the bounds), "
        "`hull` (McGuire10), `dual_space` (Laine11), `two_stage` (Wu13 §3.3-3.4) or `interleave_uvt` "
        "(Fatahalian09; needs pass.sample_pattern = \"interleave\")")
    edge_test: Flag = setting(True, COUNTERS, "hierarchical: the moving-edge test (Munkberg11 §4.2)")
    edge_solver: Literal[EDGE_SOLVERS] = setting(
        "linearized", COUNTERS, "`linearized` (Munkberg11 eq. 8-9) or `quadratic`: the edge equations solved per "
        "tile (Gribel10 §4.1)")
    gamma: Literal["triangle", "tile"] = setting("triangle", COUNTERS, "the edge slope bound per triangle or "
                                                 "recomputed per tile")
    lens_bounds: Flag = setting(True, COUNTERS, "hierarchical: lens intervals u^, v^ per tile")


@dataclass
class ZCullConfig(UnitTiming):
    throughput: Rate = 2.0
    latency: Latency = 6
    enabled: Flag = setting(True, COUNTERS, "z-cull on")
    time_slices: Count = setting(4, COUNTERS, "zmin/zmax boxes per tile: time_slices x lens_boxes^2, at most 255")
    lens_boxes: Count = setting(2, COUNTERS, "lens boxes per axis")

    def check(self, where: str) -> None:
        if self.time_slices * self.lens_boxes**2 > 255:
            raise UserError(f"{where}: time_slices * lens_boxes^2 must be at most 255")


@dataclass
class SampleTesterConfig(UnitTiming):
    throughput: Rate = 16.0
    latency: Latency = 8
    instances: Count = 2


@dataclass
class ShadingConfig(UnitTiming):
    throughput: Rate = 8.0
    latency: Latency = 40
    cache_entries: Count = setting(1024, ACCURACY, "shading-cache entries, a multiple of cache_ways")
    cache_ways: Count = setting(8, ACCURACY, "shading-cache associativity")
    replacement: Literal["lru", "fifo"] = setting("lru", ACCURACY, "shading-cache replacement")
    shader_cycles: Rate = setting(32.0, CYCLES, "cycles of one shader execution on one core")
    cores: Count = setting(32, CYCLES, "shader cores")

    def check(self, where: str) -> None:
        if self.cache_entries % self.cache_ways:
            raise UserError(f"{where}: cache_entries ({self.cache_entries}) must be a multiple of "
                            f"cache_ways ({self.cache_ways})")


@dataclass
class RopConfig(UnitTiming):
    throughput: Rate = 16.0
    latency: Latency = 20
    bandwidth: Rate = setting(64.0, CYCLES, "bytes per cycle to the multisample buffers (depth tests, blends, "
                              "z-cull refresh scans)")


@dataclass
class ArchConfig:
    """The hardware: one section per unit plus the pipeline's global settings."""

    __pydantic_config__ = FORBID

    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    triangle_setup: TriangleSetupConfig = field(default_factory=TriangleSetupConfig)
    tile_traverser: TileTraverserConfig = field(default_factory=TileTraverserConfig)
    tile_test: TileTestConfig = field(default_factory=TileTestConfig)
    zcull: ZCullConfig = field(default_factory=ZCullConfig)
    sample_tester: SampleTesterConfig = field(default_factory=SampleTesterConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    rop: RopConfig = field(default_factory=RopConfig)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        return dataclasses.asdict(self)

    def replace(self, **sections: Any) -> "ArchConfig":
        return dataclasses.replace(self, **sections)


SECTION_NAMES = tuple(f.name for f in fields(ArchConfig))
#: The ``--set`` and sweep prefixes of the settings that are not hardware.
PASS, SIMULATION = "pass", "simulation"

#: Settings an architecture file held before the pass state and the simulation options moved out:
#: old ``section.key`` -> its path now.
MOVED = {
    "pipeline.mode": "pass.mode", "pipeline.sample_pattern": "pass.sample_pattern",
    "pipeline.interleave_tuples": "pass.interleave_tuples", "triangle_setup.backface_culling": "pass.backface_culling",
    **{f"tile_test.clip_{a}_{e}": f"pass.clip.{a}_{e}" for a in "tuv" for e in ("lo", "hi")},
    "rop.depth_test": "pass.depth_test", "rop.depth_write": "pass.depth_write", "rop.blend": "pass.blend",
    "shading.mode": "pass.shading_mode", "shading.shading_rate": "pass.shading_rate",
    **{f"pipeline.{k}": f"simulation.{k}" for k in ("triangles_per_batch", "tiles_per_batch", "samples_per_batch",
                                                     "region_samples")},
}


def is_toml_value(value: Any, lists: bool = False) -> bool:
    """Whether ``value`` is a TOML scalar (a number, boolean or string), or with ``lists`` also a list of them."""
    scalars = (bool, int, float, str)
    return isinstance(value, scalars) or (lists and isinstance(value, list) and all(isinstance(v, scalars)
                                                                                    for v in value))


def literal(value: Any) -> str:
    """``value`` written as a TOML literal (the right-hand side of ``--set``; a list of scalars, a
    workload file key's value), by tomli_w."""
    if not is_toml_value(value, lists=True):
        raise TypeError(f"not a TOML scalar: {value!r}")
    return tomli_w.dumps({"v": value}).split("=", 1)[1].strip()


def moved_error(where: str, old: str, value: Any = None, *, varied: bool = False) -> UserError:
    """The one line for a setting of ``MOVED``: what it is now and exactly where it goes."""
    new = MOVED[old]
    section, key = old.split(".")
    table, name = new.rsplit(".", 1)
    what = "pass state" if new.startswith(PASS + ".") else "a simulation option"
    shown = "..." if value is None or not isinstance(value, (bool, int, float, str)) else literal(value)
    if varied:
        return UserError(f"{where}: {old} is {what} now: name it \"{new}\" instead")
    return UserError(f"{where}: [{section}] {key} is {what} now: set it in the scene's [{table}] table "
                     f"({name} = {shown}) or with --set {new}={shown}")


def _hardware_from(data: Any, where: str, base: ArchConfig) -> ArchConfig:
    if isinstance(data, dict):
        for section, values in data.items():
            for key, value in (values.items() if isinstance(values, dict) else ()):
                if f"{section}.{key}" in MOVED:
                    raise moved_error(where, f"{section}.{key}", value)
    return schema.build(ArchConfig, schema.merged(base, data) if isinstance(data, dict) else data, where)


def arch_from_dict(data: dict[str, Any], where: str = "arch", base: ArchConfig | None = None) -> ArchConfig:
    """Build a validated ``ArchConfig`` from nested dicts, on top of ``base``."""
    return _hardware_from(data, where, base if base is not None else ArchConfig())


def load_arch(path: str | Path | None = None, overrides: list[str] | None = None) -> ArchConfig:
    """Load the shipped default, then ``path`` (if given), then hardware ``--set`` overrides."""
    arch = arch_from_dict(_read_toml(DEFAULT_ARCH_PATH), where=DEFAULT_ARCH_PATH.name)
    if path is not None:
        p = Path(path)
        arch = arch_from_dict(_read_toml(p), where=p.name, base=arch)
    if overrides:
        arch = apply_overrides(arch, overrides)
    return arch


def parse_override(text: str) -> tuple[str, str, Any]:
    """Split ``section.key=value`` (``pass.clip.key=value`` for a clip plane) into (section, key, value);
    the value is read as a TOML literal, else a string. The key of a clip plane is ``clip.KEY``."""
    if "=" not in text:
        raise UserError(f"--set {text}: expected section.key=value")
    path, raw = text.split("=", 1)
    parts = path.strip().split(".")
    nested = len(parts) == 3 and parts[:2] == [PASS, "clip"]
    if not (len(parts) == 2 or nested) or not all(parts):
        raise UserError(f"--set {text}: expected section.key=value, e.g. tile_traverser.tile_size=16")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return parts[0], ".".join(parts[1:]), value


def _nest(values: dict[str, Any]) -> dict[str, Any]:
    """``{"clip.t_hi": 0.3}`` -> ``{"clip": {"t_hi": 0.3}}``."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        *tables, name = key.split(".")
        node = out
        for t in tables:
            node = node.setdefault(t, {})
        node[name] = value
    return out


def _grouped(overrides: list[str], where: str) -> dict[str, dict[str, Any]]:
    data: dict[str, dict[str, Any]] = {}
    for text in overrides:
        section, key, value = parse_override(text)
        if f"{section}.{key}" in MOVED:
            raise moved_error(where, f"{section}.{key}", value)
        data.setdefault(section, {})[key] = value
    return data


def apply_overrides(arch: ArchConfig, overrides: list[str]) -> ArchConfig:
    """Apply hardware ``--set`` overrides, each a dotted ``section.key=value``."""
    data = _grouped(overrides, "--set")
    for other in (PASS, SIMULATION):
        if other in data:
            raise UserError(f"--set {other}.{next(iter(data[other]))}: not hardware; pass it with the scene "
                            "(pipeline_sim.config.apply_settings)")
    return arch_from_dict(data, where="--set", base=arch)


def pass_state_from(data: Any, where: str, base: PassState | None = None) -> PassState:
    """A validated :class:`PassState`: ``data`` (a ``[pass]`` table) over ``base``."""
    base = base if base is not None else PassState()
    return schema.build(PassState, schema.merged(base, data) if isinstance(data, dict) else data, where, (PASS,))


def sim_options_from(data: Any, where: str, base: SimOptions | None = None) -> SimOptions:
    """Validated :class:`SimOptions`: ``data`` (a ``[simulation]`` table) over ``base``."""
    base = base if base is not None else SimOptions()
    return schema.build(SimOptions, schema.merged(base, data) if isinstance(data, dict) else data, where,
                        (SIMULATION,))


def pass_settings(overrides: list[str], arch: ArchConfig | None = None, state: PassState | None = None,
                  simulation: SimOptions | None = None, where: str = "--set") -> dict[str, Any]:
    """``arch``, ``state`` and ``simulation`` (default: the shipped ones) with ``--set`` overrides of every
    kind applied, as the keyword arguments of a ``RenderPass``: hardware ones to ``arch``, ``pass.*`` to the
    pass state and ``simulation.*`` to the simulation options."""
    data = _grouped(list(overrides), where)
    state = state if state is not None else PassState()
    simulation = simulation if simulation is not None else SimOptions()
    if PASS in data:
        state = pass_state_from(_nest(data.pop(PASS)), where, state)
    if SIMULATION in data:
        simulation = sim_options_from(data.pop(SIMULATION), where, simulation)
    if arch is None:
        arch = load_arch()
    if data:
        arch = arch_from_dict(data, where=where, base=arch)
    return {"arch": arch, "state": state, "simulation": simulation}


def apply_settings(scene: "Scene", arch: ArchConfig, overrides: list[str], where: str = "--set"
                   ) -> tuple["Scene", ArchConfig]:
    """Apply ``--set`` overrides of every kind (:func:`pass_settings`) to ``arch`` and to the scene's pass
    state and simulation options."""
    s = pass_settings(overrides, arch, scene.pass_state, scene.simulation, where)
    return scene.replace(pass_state=s["state"], simulation=s["simulation"]), s["arch"]


def check_compatible(arch: ArchConfig, state: PassState, where: str) -> None:
    """The rules between the hardware and a pass's state."""
    if arch.tile_test.algorithm == "interleave_uvt" and state.sample_pattern != "interleave":
        raise UserError(f"{where}: tile_test.algorithm = 'interleave_uvt' needs pass.sample_pattern = "
                        f"'interleave' (got '{state.sample_pattern}')")


# --- what each setting can change -------------------------------------------------------------------

def _declaration(cls: type, name: str) -> dict[str, Any]:
    """The metadata of a setting, from the nearest class that declares it (a unit's own
    default for ``throughput`` keeps :class:`UnitTiming`'s declaration)."""
    for klass in cls.__mro__:
        f = getattr(klass, "__dataclass_fields__", {}).get(name)
        if f is not None and "effect" in f.metadata:
            return dict(f.metadata)
    raise AssertionError(f"{cls.__name__}.{name} declares no effect")


def declarations(obj: Any, prefix: str = "") -> dict[str, dict[str, Any]]:
    """``"path"`` -> the declaration (effect, reference, doc, value) of every setting of the settings
    dataclass ``obj`` and the ones it holds, by dotted path under ``prefix``."""
    out = {}
    for f in fields(obj):
        value = getattr(obj, f.name)
        path = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            out.update(declarations(value, path + "."))
        else:
            out[path] = {**_declaration(type(obj), f.name), "value": value}
    return out


def _all_declarations(arch: ArchConfig, state: PassState, sim: SimOptions) -> dict[str, dict[str, Any]]:
    return {**declarations(arch), **declarations(state, PASS + "."), **declarations(sim, SIMULATION + ".")}


@functools.cache
def setting_effects() -> dict[str, str]:
    """``"path"`` -> the declared effect, for every hardware (``section.key``), pass-state
    (``pass.key``, ``pass.clip.key``) and simulation (``simulation.key``) setting."""
    return {k: d["effect"] for k, d in _all_declarations(ArchConfig(), PassState(), SimOptions()).items()}


def settings_of(arch: ArchConfig, state: PassState, sim: SimOptions, effects: tuple[str, ...]) -> dict[str, Any]:
    """The values of the settings whose declared effect is among ``effects``, by path."""
    return {k: d["value"] for k, d in _all_declarations(arch, state, sim).items() if d["effect"] in effects}


def _reference_of(obj: Any, shipped: Any) -> Any:
    """``obj`` with its ``image`` settings kept, each ``accuracy`` setting at its declared reference value
    (else ``shipped``'s) and every other setting at ``shipped``'s."""
    values = {}
    for f in fields(obj):
        mine, default = getattr(obj, f.name), getattr(shipped, f.name)
        if dataclasses.is_dataclass(mine):
            values[f.name] = _reference_of(mine, default)
            continue
        decl = _declaration(type(obj), f.name)
        if decl["effect"] == IMAGE:
            values[f.name] = mine
        elif decl["effect"] == ACCURACY and decl["reference"] is not None:
            values[f.name] = decl["reference"]
        else:
            values[f.name] = default
    return dataclasses.replace(shipped, **values)


def reference_setup(arch: ArchConfig | None, state: PassState | None) -> tuple[ArchConfig, PassState, SimOptions]:
    """The hardware, pass state and simulation options of an accuracy reference for a run of ``arch`` and
    ``state``: the settings declared to define the image kept, each ``accuracy`` setting at its declared
    reference value (else the shipped default), and the ``counters`` and ``cycles`` settings, which cannot
    change the image, at the shipped defaults."""
    shipped = load_arch()
    ref_arch = _reference_of(arch if arch is not None else shipped, shipped)
    ref_state = _reference_of(state if state is not None else PassState(), PassState())
    return ref_arch, ref_state, SimOptions()


def _read_toml(path: Path) -> dict[str, Any]:
    _, text = read_input_text(path, path.name, "architecture")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{path.name}: malformed TOML: {exc}") from None

