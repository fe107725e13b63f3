"""Architecture configuration: plain dataclasses loaded from TOML.

Every unit owns one section. Values are typed and checked when the
configuration is built (``load_arch``); unknown names are errors that suggest
the nearest known name. ``--set section.key=value`` overrides use the same
dotted paths.

Every setting declares what it can change (:data:`EFFECTS`), from most to
least: ``image`` (it defines the picture: depth test, blending, clip planes,
backface culling), ``accuracy`` (it trades image error for cost: sample
pattern, shading mode and cache, pipeline mode; with a declared reference
value where one exists), ``counters`` (the functional counters only, never
the image: tile size, culling algorithm, z-cull boxes) or ``cycles`` (the
cost model only: throughputs, latencies, batch sizes, queue depth; these
can still move the counters that depend on timing, docs/pipeline.md §4).
The accuracy reference of a sweep (:func:`reference_arch`) and the groups
of algorithms ``compare`` expects the same image from (those whose
``accuracy`` settings agree) are derived from these declarations.
"""

from __future__ import annotations

import dataclasses
import functools
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from pipeline_sim.definitions import BLEND_MODES, DEPTH_FUNCS
from pipeline_sim.errors import UserError, did_you_mean, read_input_text, unknown_key_error
from pipeline_sim.sampling import PATTERNS
from pipeline_sim.settings import ACCURACY, COUNTERS, CYCLES, EFFECTS, IMAGE, setting  # noqa: F401 (re-exported)

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
# an architecture names a generated pattern; a sample table comes with a pass
SAMPLE_PATTERNS = tuple(p for p in PATTERNS if p != "table")


@dataclass
class PipelineConfig:
    """Global pipeline settings: mode, batching and channel depth."""

    mode: str = setting("standard", ACCURACY, reference="standard")
    triangles_per_batch: int = setting(64, CYCLES)
    tiles_per_batch: int = setting(512, CYCLES)
    samples_per_batch: int = setting(65536, CYCLES)
    queue_depth: int = setting(4, CYCLES)
    clock_ghz: float = setting(1.0, CYCLES)
    specialize: bool = setting(True, COUNTERS)
    sample_pattern: str = setting("net", ACCURACY, reference="net")
    interleave_tuples: int = setting(64, ACCURACY)
    region_samples: int = setting(1 << 22, COUNTERS)

    def validate(self, where: str) -> None:
        _choice(where, "mode", self.mode, ("standard", "conservative"))
        for name in ("triangles_per_batch", "tiles_per_batch", "samples_per_batch", "queue_depth"):
            _at_least(where, name, getattr(self, name), 1)
        _at_least(where, "region_samples", self.region_samples, 0)
        _positive(where, "clock_ghz", self.clock_ghz)
        _choice(where, "sample_pattern", self.sample_pattern, SAMPLE_PATTERNS)
        _at_least(where, "interleave_tuples", self.interleave_tuples, 1, 64)   # one bit each in a tile's mask


@dataclass
class UnitTiming:
    """Cost model shared by every unit: items per cycle per instance, latency, instances."""

    throughput: float = setting(1.0, CYCLES)
    latency: int = setting(10, CYCLES)
    instances: int = setting(1, CYCLES)

    def validate(self, where: str) -> None:
        _positive(where, "throughput", self.throughput)
        _at_least(where, "latency", self.latency, 0)
        _at_least(where, "instances", self.instances, 1)


@dataclass
class TriangleSetupConfig(UnitTiming):
    throughput: float = 0.5
    latency: int = 30
    backface_culling: bool = setting(False, IMAGE)

    def validate(self, where: str) -> None:
        super().validate(where)


@dataclass
class TileTraverserConfig(UnitTiming):
    throughput: float = 2.0
    latency: int = 4
    tile_size: int = setting(4, COUNTERS)
    coarse_factor: int = setting(4, COUNTERS)

    def validate(self, where: str) -> None:
        super().validate(where)
        if self.tile_size < 1 or self.tile_size > 128 or self.tile_size & (self.tile_size - 1):
            raise UserError(f"{where}.tile_size: must be a power of two from 1 to 128, got {self.tile_size}")
        _at_least(where, "coarse_factor", self.coarse_factor, 1)


@dataclass
class TileTestConfig(UnitTiming):
    throughput: float = 1.0
    latency: int = 12
    instances: int = 2
    algorithm: str = setting("hierarchical", COUNTERS)
    edge_test: bool = setting(True, COUNTERS)
    edge_solver: str = setting("linearized", COUNTERS)
    gamma: str = setting("triangle", COUNTERS)
    lens_bounds: bool = setting(True, COUNTERS)
    # axis-aligned user clip planes on t, u and v (Nilsson12 §2): samples outside are never covered
    clip_t_lo: float = setting(0.0, IMAGE)
    clip_t_hi: float = setting(1.0, IMAGE)
    clip_u_lo: float = setting(-1.0, IMAGE)
    clip_u_hi: float = setting(1.0, IMAGE)
    clip_v_lo: float = setting(-1.0, IMAGE)
    clip_v_hi: float = setting(1.0, IMAGE)

    def validate(self, where: str) -> None:
        super().validate(where)
        _choice(where, "algorithm", self.algorithm, TILE_TEST_ALGORITHMS)
        _choice(where, "gamma", self.gamma, ("triangle", "tile"))
        _choice(where, "edge_solver", self.edge_solver, EDGE_SOLVERS)
        for axis, lo, hi in (("t", 0.0, 1.0), ("u", -1.0, 1.0), ("v", -1.0, 1.0)):
            a = getattr(self, f"clip_{axis}_lo")
            b = getattr(self, f"clip_{axis}_hi")
            if not (lo <= a <= b <= hi):
                raise UserError(f"{where}.clip_{axis}_lo/clip_{axis}_hi: need {lo} <= lo <= hi <= {hi}, "
                                f"got [{a}, {b}]")

    @property
    def clips(self) -> np.ndarray:
        """(t_lo, t_hi, u_lo, u_hi, v_lo, v_hi) of the user clip planes."""
        return np.array([self.clip_t_lo, self.clip_t_hi, self.clip_u_lo, self.clip_u_hi, self.clip_v_lo,
                         self.clip_v_hi])


@dataclass
class ZCullConfig(UnitTiming):
    throughput: float = 2.0
    latency: int = 6
    enabled: bool = setting(True, COUNTERS)
    time_slices: int = setting(4, COUNTERS)
    lens_boxes: int = setting(2, COUNTERS)

    def validate(self, where: str) -> None:
        super().validate(where)
        _at_least(where, "time_slices", self.time_slices, 1)
        _at_least(where, "lens_boxes", self.lens_boxes, 1)
        if self.time_slices * self.lens_boxes**2 > 255:
            raise UserError(f"{where}: time_slices * lens_boxes^2 must be at most 255")


@dataclass
class SampleTesterConfig(UnitTiming):
    throughput: float = 16.0
    latency: int = 8
    instances: int = 2


@dataclass
class ShadingConfig(UnitTiming):
    throughput: float = 8.0
    latency: int = 40
    mode: str = setting("cache", ACCURACY, reference="per_sample")
    cache_entries: int = setting(1024, ACCURACY)
    cache_ways: int = setting(8, ACCURACY)
    replacement: str = setting("lru", ACCURACY)
    shading_rate: float = setting(1.0, ACCURACY)
    shader_cycles: float = setting(32.0, CYCLES)
    cores: int = setting(32, CYCLES)

    def validate(self, where: str) -> None:
        super().validate(where)
        _choice(where, "mode", self.mode, ("cache", "per_sample"))
        _choice(where, "replacement", self.replacement, ("lru", "fifo"))
        _at_least(where, "cache_entries", self.cache_entries, 1)
        _at_least(where, "cache_ways", self.cache_ways, 1)
        if self.cache_entries % self.cache_ways:
            raise UserError(
                f"{where}: cache_entries ({self.cache_entries}) must be a multiple of "
                f"cache_ways ({self.cache_ways})"
            )
        # a shading-grid cell from 1/64 of a pixel to 1024 pixels: the grid's cell index stays an int64
        _positive(where, "shading_rate", self.shading_rate, 1 / 64, 1024.0)
        _positive(where, "shader_cycles", self.shader_cycles)
        _at_least(where, "cores", self.cores, 1)


@dataclass
class RopConfig(UnitTiming):
    throughput: float = 16.0
    latency: int = 20
    depth_test: str = setting("less", IMAGE)
    depth_write: bool = setting(True, IMAGE)
    blend: str = setting("replace", IMAGE)
    bandwidth: float = setting(64.0, CYCLES)

    def validate(self, where: str) -> None:
        super().validate(where)
        _choice(where, "depth_test", self.depth_test, DEPTH_FUNCS)
        _choice(where, "blend", self.blend, BLEND_MODES)
        _positive(where, "bandwidth", self.bandwidth)


@dataclass
class ArchConfig:
    """The whole architecture: one section per unit plus pipeline settings."""

    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    triangle_setup: TriangleSetupConfig = field(default_factory=TriangleSetupConfig)
    tile_traverser: TileTraverserConfig = field(default_factory=TileTraverserConfig)
    tile_test: TileTestConfig = field(default_factory=TileTestConfig)
    zcull: ZCullConfig = field(default_factory=ZCullConfig)
    sample_tester: SampleTesterConfig = field(default_factory=SampleTesterConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    rop: RopConfig = field(default_factory=RopConfig)

    def validate(self, where: str = "arch") -> "ArchConfig":
        for f in fields(self):
            getattr(self, f.name).validate(f"{where}: {f.name}")
        if self.tile_test.algorithm == "interleave_uvt" and self.pipeline.sample_pattern != "interleave":
            raise UserError(f"{where}: tile_test.algorithm = 'interleave_uvt' needs pipeline.sample_pattern = "
                            f"'interleave' (got '{self.pipeline.sample_pattern}')")
        # conservative mode rasterizes 1x1 tiles (Nilsson12 §2); the renderer applies
        # that without rewriting tile_size, so leaving the mode restores it
        return self

    def to_dict(self) -> dict[str, dict[str, Any]]:
        return dataclasses.asdict(self)

    def replace(self, **sections: Any) -> "ArchConfig":
        return dataclasses.replace(self, **sections)


SECTION_NAMES = tuple(f.name for f in fields(ArchConfig))


def _declaration(section_type: type, name: str) -> dict[str, Any]:
    """The metadata of a setting, from the nearest class that declares it (a unit's own
    default for ``throughput`` keeps :class:`UnitTiming`'s declaration)."""
    for cls in section_type.__mro__:
        f = getattr(cls, "__dataclass_fields__", {}).get(name)
        if f is not None and "effect" in f.metadata:
            return dict(f.metadata)
    raise AssertionError(f"{section_type.__name__}.{name} declares no effect")


@functools.cache
def setting_effects() -> dict[str, str]:
    """``"section.key"`` -> the declared effect, for every architecture setting."""
    arch = ArchConfig()
    return {f"{name}.{f.name}": _declaration(type(getattr(arch, name)), f.name)["effect"]
            for name in SECTION_NAMES for f in fields(getattr(arch, name))}


def settings_of(arch: "ArchConfig", effects: tuple[str, ...]) -> dict[str, Any]:
    """The values of the settings of ``arch`` whose declared effect is among ``effects``."""
    out = {}
    for path, effect in setting_effects().items():
        if effect in effects:
            section, key = path.split(".")
            out[path] = getattr(getattr(arch, section), key)
    return out


def reference_arch(arch: "ArchConfig | None") -> "ArchConfig":
    """The architecture of an accuracy reference for ``arch``: its ``image`` settings kept, each
    ``accuracy`` setting at its declared reference value (else the shipped default), and the
    ``counters`` and ``cycles`` settings, which cannot change the image, at the shipped defaults."""
    shipped = load_arch()
    if arch is None:
        arch = shipped
    sections = {}
    for sec in fields(ArchConfig):
        mine, default = getattr(arch, sec.name), getattr(shipped, sec.name)
        values = {}
        for f in fields(mine):
            decl = _declaration(type(mine), f.name)
            if decl["effect"] == IMAGE:
                values[f.name] = getattr(mine, f.name)
            elif decl["effect"] == ACCURACY and decl["reference"] is not None:
                values[f.name] = decl["reference"]
            else:
                values[f.name] = getattr(default, f.name)
        sections[sec.name] = dataclasses.replace(default, **values)
    return ArchConfig(**sections).validate("reference arch")


def _choice(where: str, name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise UserError(
            f"{where}.{name}: '{value}' is not one of {', '.join(choices)}"
            f"{did_you_mean(str(value), choices)}"
        )


# The cost model's range: a rate or a cost from 1e-6 to 1e9 keeps every cycle count of a frame (at most
# about 1e10 items, each costing at most 1e9 cycles or 1e6 per unit of rate) far inside a float's exact
# integers, so timing, its CSV and JSON stay finite; counts up to 2^31 - 1 fit the kernels' int32 indices.
RATE_RANGE = (1e-6, 1e9)
MAX_COUNT = 2**31 - 1


def _positive(where: str, name: str, value: float, low: float = RATE_RANGE[0], high: float = RATE_RANGE[1]) -> None:
    if not low <= value <= high:   # NaN fails too
        raise UserError(f"{where}.{name}: must be from {low:g} to {high:g}, got {value}")


def _at_least(where: str, name: str, value: int, low: int, high: int = MAX_COUNT) -> None:
    if not low <= value <= high:
        raise UserError(f"{where}.{name}: must be from {low} to {high}, got {value}")


def _coerce(where: str, key: str, value: Any, default: Any) -> Any:
    """Check ``value`` against the type of the field default; ints widen to float."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise UserError(f"{where}.{key}: expected true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise UserError(f"{where}.{key}: expected an integer, got {value!r}")
        if not -2**63 <= value < 2**63:
            raise UserError(f"{where}.{key}: expected a 64-bit integer, got one of {len(str(abs(value)))} digits")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UserError(f"{where}.{key}: expected a number, got {value!r}")
        try:
            return float(value)
        except OverflowError:   # an integer of hundreds of digits
            raise UserError(f"{where}.{key}: expected a finite number, got an integer of "
                            f"{len(str(abs(value)))} digits") from None
    if isinstance(default, str):
        if not isinstance(value, str):
            raise UserError(f"{where}.{key}: expected a string, got {value!r}")
        return value
    raise AssertionError(f"unsupported field type for {key}")


def arch_from_dict(data: dict[str, Any], where: str = "arch", base: ArchConfig | None = None) -> ArchConfig:
    """Build a validated ``ArchConfig`` from nested dicts, on top of ``base``."""
    arch = dataclasses.replace(base) if base is not None else ArchConfig()
    sections = {name: dataclasses.replace(getattr(arch, name)) for name in SECTION_NAMES}
    for section, values in data.items():
        if section not in sections:
            raise unknown_key_error(where, section, SECTION_NAMES)
        if not isinstance(values, dict):
            raise UserError(f"{where}: [{section}] must be a table")
        obj = sections[section]
        known = {f.name: f for f in fields(obj)}
        for key, value in values.items():
            if key not in known:
                raise unknown_key_error(f"{where}: [{section}]", key, known)
            setattr(obj, key, _coerce(f"{where}: {section}", key, value, getattr(obj, key)))
    return ArchConfig(**sections).validate(where)


def load_arch(path: str | Path | None = None, overrides: list[str] | None = None) -> ArchConfig:
    """Load the shipped default, then ``path`` (if given), then ``--set`` overrides."""
    arch = arch_from_dict(_read_toml(DEFAULT_ARCH_PATH), where=DEFAULT_ARCH_PATH.name)
    if path is not None:
        p = Path(path)
        arch = arch_from_dict(_read_toml(p), where=p.name, base=arch)
    if overrides:
        arch = apply_overrides(arch, overrides)
    return arch


def parse_override(text: str) -> tuple[str, str, Any]:
    """Split ``section.key=value``; the value is read as a TOML literal, else a string."""
    if "=" not in text:
        raise UserError(f"--set {text}: expected section.key=value")
    path, raw = text.split("=", 1)
    parts = path.strip().split(".")
    if len(parts) != 2 or not all(parts):
        raise UserError(f"--set {text}: expected section.key=value, e.g. tile_traverser.tile_size=16")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return parts[0], parts[1], value


def apply_overrides(arch: ArchConfig, overrides: list[str]) -> ArchConfig:
    """Apply ``--set`` overrides, each a dotted ``section.key=value``."""
    data: dict[str, dict[str, Any]] = {}
    for text in overrides:
        section, key, value = parse_override(text)
        data.setdefault(section, {})[key] = value
    return arch_from_dict(data, where="--set", base=arch)


def _read_toml(path: Path) -> dict[str, Any]:
    _, text = read_input_text(path, path.name, "architecture")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{path.name}: malformed TOML: {exc}") from None
