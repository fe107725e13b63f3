"""Workloads: a TOML file names a kind, and the kind is a program over render passes.

A workload file names its kind with a top-level ``kind = "..."``; a file
without one is the kind ``scene`` (today's scene files, one standard pass).
A kind is a :class:`Workload` subclass: it reads its file, builds its passes
(:class:`pipeline_sim.render.RenderPass`), runs them through
:meth:`Workload.run_passes` and computes its derived results
(:class:`WorkloadResult`). ``pipeline-sim run``, ``check``, ``compare`` and
``sweep`` take any kind (docs/workloads.md).

Kinds are found in two places: the ``scene`` kind here, and the applications
under ``workloads/apps/<name>/``: each a package whose module defines
``WORKLOAD`` (its :class:`Workload` subclass), with the package's TOML files
and meshes beside it; the folder name is the kind's name. :func:`register`
adds a kind by hand (tests, notebooks).

Nothing here imports the kernels: a file is loaded and checked before any
numba module is imported; :meth:`Workload.run` imports them.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import importlib
import json
import pkgutil
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar

import numpy as np
import pandas as pd

from pipeline_sim import schema
from pipeline_sim.config import ArchConfig
from pipeline_sim.errors import UserError, did_you_mean, read_input_text

#: The kind of a file that names none.
DEFAULT_KIND = "scene"
#: The package whose subpackages are the application kinds.
APPS_PACKAGE = "workloads.apps"
#: Image settings a command may override (``--spp``, ``--seed``, a sweep's ``image.*`` keys).
IMAGE_KEYS = ("width", "height", "spp", "seed")

Progress = Callable[[int, int], None] | None


@dataclass
class WorkloadResult:
    """What a workload's run gives: every pass's result in run order, its derived results
    (JSON-able: ``results.json``), its tables (one CSV file each), its arrays (one .npy file each), its
    figures (one PNG file each) and its images (linear RGB(A), (H, W, 3) or (H, W, 4), each written as
    ``images/<name>.npy`` and ``.png``: e.g. the views of a lens resolve, a collision view's overlaps)."""

    passes: dict[str, Any]  # pass name -> pipeline_sim.render.PassResult, in run order
    results: dict[str, Any] = field(default_factory=dict)
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)  # name -> array, written as <name>.npy
    figures: dict[str, Any] = field(default_factory=dict)  # name -> matplotlib figure, written as <name>.png
    images: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def final(self):
        """The last pass's result (its image is the workload's image in summaries)."""
        return next(reversed(self.passes.values()))

    def total(self):
        """The passes as one :class:`~pipeline_sim.render.PassResult`: the final image, every
        counter summed over the passes, their cycles and wall times added (passes run one after
        the other). A one-pass workload's total is its pass."""
        if len(self.passes) == 1:
            return self.final
        from pipeline_sim.pipeline import TimingResult

        results = list(self.passes.values())
        counters = pd.concat([r.counters for r in results], ignore_index=True)
        counters = (counters.groupby(["unit", "counter"], sort=False, as_index=False)
                    .agg(value=("value", "sum"), timing_dependent=("timing_dependent", "any")))
        frame = sum(r.timing.frame_cycles for r in results)
        units = pd.concat([r.timing.units for r in results], ignore_index=True)
        units = units.groupby("unit", sort=False, as_index=False)[["busy", "starved", "blocked", "batches"]].sum()
        units["utilization"] = units.busy / frame if frame else 0.0
        queues = pd.concat([r.timing.queues.assign(channel=f"{name}:" + r.timing.queues.channel)
                            for name, r in self.passes.items()], ignore_index=True)
        timing = TimingResult(frame, units, queues, {}, {})
        last = self.final
        return dataclasses.replace(
            last, name="total", counters=counters, timing=timing, wall_time=sum(r.wall_time for r in results),
            dimensions={k: any(r.dimensions[k] for r in results) for k in last.dimensions},
            units_used=list(dict.fromkeys(u for r in results for u in r.units_used)), depth=None, samples=None)


class Workload:
    """A workload kind. A subclass reads its file in :meth:`load`, checks it in :meth:`check`,
    runs in :meth:`run` and tells what it ran in :meth:`resolved`.

    ``pass_options`` are :class:`~pipeline_sim.render.RenderPass` fields a command sets on every
    pass the workload runs (``compare`` sets ``zcull_refresh = "ordered"``); a kind runs its passes
    through :meth:`run_passes` so that they apply.
    """

    kind: ClassVar[str] = ""
    #: The kind's file schema, or None: a dataclass whose fields carry their types and ranges
    #: (``pipeline_sim.settings``) and a ``doc`` line in their metadata, under the config
    #: ``pipeline_sim.settings.FORBID``. :func:`read_workload` validates the file (less its ``kind``)
    #: against it through ``pipeline_sim.schema`` and hands :meth:`load` the instance as ``data``;
    #: docs/workloads.md lists every kind's keys from it (``pipeline_sim.docgen``).
    file_schema: ClassVar[type | None] = None
    #: A kind with a file schema: its file's settings as validated, with what a command changed
    #: (:meth:`from_settings`); :meth:`resolved` lists them and :attr:`digest` hashes them.
    settings_file: Any = None
    #: Per image setting the kind's file has no key for, what its refusal says instead of the default
    #: "set what it stands for in the file" (:meth:`from_settings`): why, and what to set.
    image_refusals: ClassVar[dict[str, str]] = {}

    def __init__(self, path: Path, arch: ArchConfig) -> None:
        self.path = Path(path)
        self.arch = arch
        self.pass_options: dict[str, Any] = {}
        self.settings: list[str] = []  # the ``pass.*`` and ``simulation.*`` settings of every pass
        self.states: list[Any] = []  # every pass run, as run (RenderPass), for run.json

    @classmethod
    def load(cls, path: Path, data: Any, arch: ArchConfig, image: dict[str, int]) -> "Workload":
        """Build the workload of file ``path`` (``data``: its parsed TOML, or the :attr:`file_schema`
        instance validated from it) on ``arch``. ``image``: image settings a command overrides (keys of
        :data:`IMAGE_KEYS`, already checked); a kind that has no such setting refuses them with one line.
        By default, for a kind with a file schema: :meth:`from_settings`."""
        if cls.file_schema is None:
            raise NotImplementedError(f"kind {cls.kind}: a kind without a file schema reads its file in load()")
        return cls.from_settings(path, data, arch, image)

    @classmethod
    def from_settings(cls, path: Path, data: Any, arch: ArchConfig, image: dict[str, Any]) -> "Workload":
        """The workload of a kind with a file schema whose image settings are keys of its file of the same
        names: ``data`` with ``image`` applied, kept as :attr:`settings_file`. An image setting its file
        has no key for is refused in one line (:attr:`image_refusals`)."""
        unknown = sorted(set(image) - {f.name for f in dataclasses.fields(data)})
        for name in unknown:
            if name in cls.image_refusals:
                raise UserError(f"{path}: --{name}: a {cls.kind} workload {cls.image_refusals[name]}")
        if unknown:
            raise UserError(f"{path}: a {cls.kind} workload has no image setting {', '.join(unknown)}; set what "
                            "it stands for in the file")
        self = cls(path, arch)
        self.settings_file = dataclasses.replace(data, **image)
        return self

    def check(self, variants: list["Workload"] | None = None, *, reference_spp: int | None = None) -> str:
        """Refuse (one line) what a run of each of ``variants`` (itself with other settings, from
        :meth:`with_settings`; default: itself alone) would refuse later, before any kernel loads;
        return a one-line summary."""
        return f"kind {self.kind}"

    def run(self, progress: Progress = None) -> WorkloadResult:
        """Build and run the passes; compute the derived results."""
        raise NotImplementedError

    def resolved(self) -> dict[str, Any]:
        """Everything the workload read, resolved (its own content, not only a digest): run.json's
        ``workload`` (with :attr:`digest` added): the kind, the file and its :attr:`settings_file`."""
        settings = {} if self.settings_file is None else {"settings": dataclasses.asdict(self.settings_file)}
        return {"kind": self.kind, "file": str(self.path), **settings}

    @property
    def digest(self) -> str:
        """A hash of the inputs, as a scene's digest: of the :attr:`settings_file` as resolved (the file's
        keys with what a command or a sweep point changed); empty for a kind without one."""
        if self.settings_file is None:
            return ""
        text = json.dumps(dataclasses.asdict(self.settings_file), sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()

    def reference_scene(self):
        """The scene an accuracy reference renders (a sweep's metrics, ``compare --reference-spp``),
        or None when the kind has no single image to measure."""
        return None

    def with_settings(self, overrides: list[str], where: str = "--set") -> "Workload":
        """The same workload with ``--set`` settings, nothing run: hardware ones on its architecture,
        ``pass.*`` and ``simulation.*`` ones on every pass it runs (``compare``: one per algorithm)."""
        from pipeline_sim.config import pass_settings

        other = self._unrun_copy()
        other.arch = pass_settings(overrides, self.arch, where=where)["arch"]  # checks them all, too
        other.settings = self.settings + [o for o in overrides if _is_pass_setting(o)]
        return other

    def _unrun_copy(self) -> "Workload":
        """A copy to change settings on: its own pass options and no passes run yet."""
        other = copy.copy(self)
        other.pass_options = dict(self.pass_options)
        other.states = []
        return other

    def accuracy_settings(self) -> tuple:
        """The ``accuracy`` settings it runs with (its hardware's, and its pass settings' over the
        defaults): runs whose ones agree sample the same scene the same way."""
        from pipeline_sim.config import pass_settings

        s = pass_settings(self.settings, self.arch)
        return _accuracy_key(s["arch"], s["state"], s["simulation"])

    def run_passes(self, passes: list[Any], progress: Progress = None) -> dict[str, Any]:
        """Run ``passes`` in order (a pass's ``textures`` may name earlier passes) with
        :attr:`pass_options` and :attr:`settings` applied to each; record them for run.json."""
        from pipeline_sim.config import pass_settings
        from pipeline_sim.render import run_passes

        def prepared(p):
            s = pass_settings(self.settings, p.arch, p.state, p.simulation) if self.settings else {}
            return dataclasses.replace(p, **self.pass_options, **{k: s[k] for k in ("state", "simulation") if s})

        passes = [prepared(p) for p in passes]
        self.states.extend(passes)
        return run_passes(passes, progress=progress)


def _accuracy_key(arch: ArchConfig, state: Any, simulation: Any) -> tuple:
    """The ``accuracy`` settings of a hardware, pass state and simulation options, sorted, as a key."""
    from pipeline_sim.config import settings_of
    from pipeline_sim.settings import ACCURACY

    return tuple(sorted(settings_of(arch, state, simulation, (ACCURACY,)).items()))


def _is_pass_setting(override: str) -> bool:
    """Whether a ``--set`` text sets the pass state or the simulation options (not the hardware)."""
    from pipeline_sim.config import PASS, SIMULATION, parse_override

    return parse_override(override)[0] in (PASS, SIMULATION)


def pass_state(p: Any) -> dict[str, Any]:
    """run.json's record of one pass as it ran: its state (field by field), sampling, clear values,
    z-cull refresh, shader, textures, outputs, targets, append buffer and draws."""
    draws = list(p.draw) if isinstance(p.draw, (list, tuple)) else [p.draw]
    return {
        "name": p.name, "spp": p.spp, "seed": p.seed,
        "state": dataclasses.asdict(p.state),
        "sample_pattern": "table" if p.sample_table is not None else p.state.sample_pattern,
        "sample_table": p.sample_table, "scramble_table": p.scramble_table,
        "clear_color": list(p.clear_color), "clear_depth": p.clear_depth, "zcull_refresh": p.zcull_refresh,
        "shader": getattr(p.shader, "__qualname__", None) or getattr(p.shader, "__name__", repr(p.shader)),
        "shader_module": getattr(p.shader, "__module__", None),
        "params": p.params,
        "textures": [t if isinstance(t, str) else f"array {list(np.shape(t))}" for t in p.textures],
        "outputs": [dataclasses.asdict(o) for o in p.outputs],
        "targets": None if p.targets is None else [dataclasses.asdict(t) for t in p.targets],
        "append": None if p.append is None else dataclasses.asdict(p.append),
        "draws": [{"triangles": d.n, "clip": None if d.clip is None else dataclasses.asdict(d.clip)} for d in draws],
        "width": draws[0].width, "height": draws[0].height,
    }


class SceneWorkload(Workload):
    """The kind ``scene``: a scene file rendered in one standard pass named ``main``
    (:func:`pipeline_sim.render.scene_pass`)."""

    kind = "scene"

    def __init__(self, path: Path, arch: ArchConfig, scene, data: dict[str, Any] | None) -> None:
        super().__init__(path, arch)
        self.scene = scene
        self.data = data
        self.draw = None

    @classmethod
    def load(cls, path: Path, data: dict[str, Any], arch: ArchConfig, image: dict[str, int]) -> "SceneWorkload":
        from pipeline_sim.scene import load_scene, parse_scene

        content = {k: v for k, v in data.items() if k != "kind"}
        if "kind" in data:  # named explicitly: parsed from the document
            scene = parse_scene(content, where=str(path), base_dir=Path(path).parent).replace(path=Path(path))
        else:  # the scene reader's own way, digest of the file's bytes and all
            scene = load_scene(path)
        if image:
            scene = scene.replace(image=dataclasses.replace(scene.image, **image))
        return cls(path, arch, scene, content)

    @classmethod
    def of_scene(cls, scene, arch: ArchConfig) -> "SceneWorkload":
        """The workload of an already loaded scene."""
        return cls(scene.path or Path("<scene>"), arch, scene, None)

    def with_settings(self, overrides: list[str], where: str = "--set") -> "SceneWorkload":
        from pipeline_sim.config import apply_settings

        other = self._unrun_copy()
        other.scene, other.arch = apply_settings(self.scene, self.arch, overrides, where)
        return other

    def accuracy_settings(self) -> tuple:
        return _accuracy_key(self.arch, self.scene.pass_state, self.scene.simulation)

    def check(self, variants: list["Workload"] | None = None, *, reference_spp: int | None = None) -> str:
        from pipeline_sim.preflight import validate_run

        runs = [(v.scene, v.arch) for v in (variants or [self])]
        self.draw = validate_run(runs, str(self.path), reference_spp=reference_spp)
        img = self.scene.image
        return (f"{len(self.scene.objects)} objects, {self.draw.n} triangles, {img.width}x{img.height} at "
                f"{img.spp} spp, motion={self.draw.has_motion}, lens={self.draw.has_lens}")

    def run(self, progress: Progress = None) -> WorkloadResult:
        from pipeline_sim.render import scene_pass

        return WorkloadResult(self.run_passes([scene_pass(self.scene, self.arch, draw=self.draw)], progress))

    def resolved(self) -> dict[str, Any]:
        img = self.scene.image
        content = None
        if self.data is not None:  # the document as read, with the commands' image settings
            content = {**self.data, "image": {**self.data.get("image", {}), **dataclasses.asdict(img)}}
        return {
            **super().resolved(), "scene": content,
            "image": dataclasses.asdict(img),
            "objects": [{"name": o.name, "triangles": o.triangle_count, "vertices": len(o.positions),
                         "material": o.material, "moving": o.moving} for o in self.scene.objects],
        }

    @property
    def digest(self) -> str:
        return self.scene.digest

    def reference_scene(self):
        return self.scene


_KINDS: dict[str, type[Workload]] = {SceneWorkload.kind: SceneWorkload}
_discovered = [False]


def register(cls: type[Workload], name: str | None = None) -> type[Workload]:
    """Register a workload kind under ``name`` (default: ``cls.kind``); usable as a decorator."""
    name = name or cls.kind
    if not name:
        raise ValueError(f"{cls.__name__}: a workload kind needs a name")
    cls.kind = name
    _KINDS[name] = cls
    return cls


def _discover() -> None:
    """Register every application under ``workloads/apps/``, once."""
    if _discovered[0]:
        return
    _discovered[0] = True
    try:
        apps = importlib.import_module(APPS_PACKAGE)
    except ModuleNotFoundError:
        return
    for info in pkgutil.iter_modules(apps.__path__):
        if info.ispkg and info.name not in _KINDS:
            module = importlib.import_module(f"{APPS_PACKAGE}.{info.name}")
            register(module.WORKLOAD, info.name)


def kinds() -> list[str]:
    """Every known kind's name, sorted."""
    _discover()
    return sorted(_KINDS)


def kind_of(name: str, where: str) -> type[Workload]:
    """The kind called ``name``, or a one-line error with the nearest name."""
    if name not in _KINDS:
        _discover()
    if name not in _KINDS:
        known = kinds()
        raise UserError(f"{where}: kind: unknown workload kind '{name}'{did_you_mean(name, known)}; "
                        f"known: {', '.join(known)}")
    return _KINDS[name]


def read_workload(path: str | Path, file_keys: dict[str, Any] | None = None) -> tuple[type[Workload], dict[str, Any]]:
    """The kind a workload file names and its parsed TOML, or, for a kind with a
    :attr:`Workload.file_schema`, the file (less its ``kind``) validated against it (one line naming
    the file and key, with the nearest known name). A file that cannot be read or is not TOML is
    reported as the scene reader reports it (the kind of a file without ``kind``).

    ``file_keys`` (a sweep's ``workload.KEY`` settings: dotted key -> value) replace keys of the
    file before it is validated; only a kind with a file schema has such keys."""
    from pipeline_sim.scene import load_scene

    p = Path(path)
    where = str(path)
    _, text = read_input_text(p, where, "scene")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        load_scene(p)  # raises its one-line error
        raise
    name = data.get("kind", DEFAULT_KIND)
    if not isinstance(name, str):
        raise UserError(f"{where}: kind: expected a string naming the workload kind, got {type(name).__name__}")
    cls = kind_of(name, where)
    if file_keys and cls.file_schema is None:
        raise UserError(f"{where}: workload.{next(iter(file_keys))}: a workload.KEY setting replaces a key of a "
                        f"kind's file, and the kind {name} has no file keys (vary its image.*, pass.*, "
                        "simulation.* or hardware settings)")
    for key, value in (file_keys or {}).items():
        _replace_key(data, key, value, where)
    if cls.file_schema is not None:
        return cls, schema.build(cls.file_schema, {k: v for k, v in data.items() if k != "kind"}, where)
    return cls, data


def _replace_key(data: dict[str, Any], key: str, value: Any, where: str) -> None:
    """Set the dotted ``key`` of a parsed TOML file to ``value`` (tables on the way made if missing)."""
    *tables, last = key.split(".")
    table = data
    for i, name in enumerate(tables):
        table = table.setdefault(name, {})
        if not isinstance(table, dict):
            raise UserError(f"{where}: workload.{key}: '{'.'.join(tables[:i + 1])}' is not a table of the file")
    table[last] = value


def load_workload(path: str | Path, arch: ArchConfig, image: dict[str, int] | None = None,
                  file_keys: dict[str, Any] | None = None) -> Workload:
    """Load the workload file ``path`` on ``arch`` (``image``: image settings overridden, checked by
    the caller; ``file_keys``: keys of the file replaced, see :func:`read_workload`), its file read and
    validated by :func:`read_workload`."""
    cls, data = read_workload(path, file_keys)
    return cls.load(Path(path), data, arch, dict(image or {}))


__all__ = ["APPS_PACKAGE", "DEFAULT_KIND", "IMAGE_KEYS", "SceneWorkload", "Workload", "WorkloadResult", "kind_of",
           "kinds", "load_workload", "pass_state", "read_workload", "register"]
