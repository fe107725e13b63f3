"""Architecture configuration: plain dataclasses loaded from TOML.

Every unit owns one section. Values are typed and checked when the
configuration is built (``load_arch``); unknown names are errors that suggest
the nearest known name. ``--set section.key=value`` overrides use the same
dotted paths.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from pipeline_sim.errors import UserError, did_you_mean, unknown_key_error
from pipeline_sim.sampling import PATTERNS

DEFAULT_ARCH_PATH = Path(__file__).with_name("data") / "default_arch.toml"

DEPTH_FUNCS = ("less", "lequal", "greater", "gequal", "equal", "always", "never")
BLEND_MODES = ("replace", "add", "min", "max")
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

    mode: str = "standard"
    triangles_per_batch: int = 64
    tiles_per_batch: int = 512
    samples_per_batch: int = 65536
    queue_depth: int = 4
    clock_ghz: float = 1.0
    specialize: bool = True
    sample_pattern: str = "net"
    interleave_tuples: int = 64
    region_samples: int = 1 << 22

    def validate(self, where: str) -> None:
        _choice(where, "mode", self.mode, ("standard", "conservative"))
        for name in ("triangles_per_batch", "tiles_per_batch", "samples_per_batch", "queue_depth"):
            _at_least(where, name, getattr(self, name), 1)
        _at_least(where, "region_samples", self.region_samples, 0)
        _positive(where, "clock_ghz", self.clock_ghz)
        _choice(where, "sample_pattern", self.sample_pattern, SAMPLE_PATTERNS)
        if not 1 <= self.interleave_tuples <= 64:
            raise UserError(f"{where}.interleave_tuples: must be from 1 to 64 (one bit each in a tile's "
                            f"tuple mask), got {self.interleave_tuples}")


@dataclass
class UnitTiming:
    """Cost model shared by every unit: items per cycle per instance, latency, instances."""

    throughput: float = 1.0
    latency: int = 10
    instances: int = 1

    def validate(self, where: str) -> None:
        _positive(where, "throughput", self.throughput)
        _at_least(where, "latency", self.latency, 0)
        _at_least(where, "instances", self.instances, 1)


@dataclass
class TriangleSetupConfig(UnitTiming):
    throughput: float = 0.5
    latency: int = 30
    backface_culling: bool = False

    def validate(self, where: str) -> None:
        super().validate(where)


@dataclass
class TileTraverserConfig(UnitTiming):
    throughput: float = 2.0
    latency: int = 4
    tile_size: int = 4
    coarse_factor: int = 4

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
    algorithm: str = "hierarchical"
    edge_test: bool = True
    edge_solver: str = "linearized"
    gamma: str = "triangle"
    lens_bounds: bool = True
    # axis-aligned user clip planes on t, u and v (Nilsson12 §2): samples outside are never covered
    clip_t_lo: float = 0.0
    clip_t_hi: float = 1.0
    clip_u_lo: float = -1.0
    clip_u_hi: float = 1.0
    clip_v_lo: float = -1.0
    clip_v_hi: float = 1.0

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
    enabled: bool = True
    time_slices: int = 4
    lens_boxes: int = 2

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
    mode: str = "cache"
    cache_entries: int = 1024
    cache_ways: int = 8
    replacement: str = "lru"
    shading_rate: float = 1.0
    shader_cycles: float = 32.0
    cores: int = 32

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
        _positive(where, "shading_rate", self.shading_rate)
        _positive(where, "shader_cycles", self.shader_cycles)
        _at_least(where, "cores", self.cores, 1)


@dataclass
class RopConfig(UnitTiming):
    throughput: float = 16.0
    latency: int = 20
    depth_test: str = "less"
    depth_write: bool = True
    blend: str = "replace"
    bandwidth: float = 64.0

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


def _choice(where: str, name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise UserError(
            f"{where}.{name}: '{value}' is not one of {', '.join(choices)}"
            f"{did_you_mean(str(value), choices)}"
        )


def _positive(where: str, name: str, value: float) -> None:
    if not value > 0 or value != value or value == float("inf"):
        raise UserError(f"{where}.{name}: must be a positive finite number, got {value}")


def _at_least(where: str, name: str, value: int, low: int) -> None:
    if value < low:
        raise UserError(f"{where}.{name}: must be at least {low}, got {value}")


def _coerce(where: str, key: str, value: Any, default: Any) -> Any:
    """Check ``value`` against the type of the field default; ints widen to float."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise UserError(f"{where}.{key}: expected true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise UserError(f"{where}.{key}: expected an integer, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UserError(f"{where}.{key}: expected a number, got {value!r}")
        return float(value)
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
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise UserError(f"{path}: architecture file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{path.name}: malformed TOML: {exc}") from None
