"""The generated parts of the format references and the counter glossary.

The settings tables of docs/architecture-format.md (the hardware),
docs/scene-format.md (a pass's state and the simulation options) and
docs/sweep-format.md (every setting path a sweep may vary), the table of
what each setting can change, and docs/counters.md (each unit's counters,
what they count and whether timing can move them) are written here from the
settings' declarations (types, ranges, choices, defaults, effects and
one-line docs: ``pipeline_sim.settings``) and the counters' declarations
(each unit's ``event_meanings`` and ``timing_dependent``, the common
counters' ``pipeline_sim.definitions.COMMON_MEANINGS``). Each generated
block sits between ``<!-- BEGIN generated: NAME -->`` and ``<!-- END generated: NAME -->``;
``make docs`` (``python -m pipeline_sim.docgen``) rewrites them and
``tests/test_docs.py`` fails when one is stale.
"""

from __future__ import annotations

import dataclasses
import re
import sys
import typing
from pathlib import Path

from pipeline_sim import schema
from pipeline_sim.config import PASS, SIMULATION, ArchConfig, declarations, setting_effects
from pipeline_sim.counters import counter_meanings
from pipeline_sim.pass_state import PassState
from pipeline_sim.settings import EFFECTS
from pipeline_sim.simulation import SimOptions
from pipeline_sim.sweep import ReferenceTable, SweepTable

ROOT = Path(__file__).resolve().parent.parent

EFFECT_MEANINGS = {
    "image": "defines the picture",
    "accuracy": "trades image error for cost (the reference value in brackets)",
    "counters": "the functional counters, never the image",
    "cycles": "the cost model only; they can still move the counters declared timing-dependent, z-cull's and "
              "those after it ([pipeline.md §4](pipeline.md#4-what-is-counted)), unless z-cull is refreshed in "
              "submission order, as `compare` does",
    "speed": "only the simulator's wall time: images, counters and cycles stay identical",
}


def _type_text(annotation: typing.Any) -> str:
    annotation = schema.required(annotation)
    base = schema.plain(annotation)
    if base is typing.Any:
        return "see its meaning"
    if typing.get_origin(base) is list:
        c = schema.field_constraints(annotation)
        n = c.get("min_length")
        return (f"{n} x " if n is not None and n == c.get("max_length") else "list of ") + \
            _type_text(typing.get_args(base)[0])
    if typing.get_origin(base) is dict or dataclasses.is_dataclass(base):
        return "table"
    c = schema.field_constraints(annotation)
    if "choices" in c:
        return "one of " + ", ".join(f"`{x}`" for x in c["choices"])
    name = {"int": "integer", "float": "number", "bool": "true or false", "str": "string"}[c["base"].__name__]
    if "ge" in c and "le" in c:
        return f"{name}, {c['ge']:g} to {c['le']:g}"
    if any(b in c for b in ("ge", "gt", "le", "lt")):
        return f"{name}, {schema.range_text(c)}"
    return name


def _value(v: typing.Any) -> str:
    if isinstance(v, list):
        return ", ".join(_value(x) for x in v)
    return f"`{str(v).lower() if isinstance(v, bool) else v}`"


def settings_table(obj: typing.Any, prefix: str = "") -> str:
    """One row per setting of the settings dataclass ``obj``: key, type and range, default, effect, meaning."""
    rows = ["| key | type | default | effect | meaning |", "|---|---|---|---|---|"]

    def walk(o: typing.Any, path: str) -> None:
        hints = typing.get_type_hints(type(o), include_extras=True)
        decl = declarations(o)
        for f in dataclasses.fields(o):
            value = getattr(o, f.name)
            if dataclasses.is_dataclass(value):
                walk(value, f"{path}{f.name}.")
                continue
            d = decl[f.name]
            effect = d["effect"] + (f" (reference `{d['reference']}`)" if d["reference"] is not None else "")
            rows.append(f"| `{prefix}{path}{f.name}` | {_type_text(hints[f.name])} | {_value(value)} | {effect} | "
                        f"{d['doc']} |")

    walk(obj, "")
    return "\n".join(rows)


def effects_table() -> str:
    """The settings of each effect, hardware, pass state and simulation options alike."""
    by_effect: dict[str, list[str]] = {e: [] for e in EFFECTS}
    refs = {k: d["reference"] for k, d in {**declarations(ArchConfig()), **declarations(PassState(), PASS + "."),
                                            **declarations(SimOptions(), SIMULATION + ".")}.items()}
    for path, effect in setting_effects().items():
        by_effect[effect].append(f"`{path}`" + (f" (`{refs[path]}`)" if refs[path] is not None else ""))
    rows = ["| effect | meaning | settings |", "|---|---|---|"]
    rows += [f"| `{e}` | {EFFECT_MEANINGS[e]} | {', '.join(by_effect[e])} |" for e in EFFECTS]
    return "\n".join(rows)


def sweep_paths() -> str:
    """Every setting path a sweep may vary, grouped by where it goes."""
    paths = list(setting_effects())
    hardware = [p for p in paths if not p.startswith((PASS + ".", SIMULATION + "."))]
    groups = (("hardware (the architecture)", hardware),
              ("pass state (the scene's `[pass]`)", [p for p in paths if p.startswith(PASS + ".")]),
              ("simulation options (the scene's `[simulation]`)", [p for p in paths if p.startswith(SIMULATION + ".")]))
    rows = ["| kind | paths |", "|---|---|", "| image (the scene's `[image]`) | `image.width`, `image.height`, "
            "`image.spp`, `image.seed` |"]
    rows += [f"| {kind} | {', '.join(f'`{p}`' for p in ps)} |" for kind, ps in groups]
    rows.append("| the workload kind's own file ([workloads.md](workloads.md#registered-kinds)) | `workload.KEY`, "
                "e.g. " + ", ".join(f"`workload.{k}` ({kind})" for kind, k in _example_workload_keys()) + " |")
    return "\n".join(rows)


def _example_workload_keys() -> list[tuple[str, str]]:
    """(kind, key): the first key of a few registered kinds' files, for the table of sweep paths."""
    from pipeline_sim.workload import kind_of, kinds

    keys = []
    for name in kinds():
        file_schema = kind_of(name, "docgen").file_schema
        if file_schema is not None:
            keys.append((name, next(f.name for f in dataclasses.fields(file_schema))))
    return keys[:4]


def schema_table(cls: type, prefix: str = "", skip: tuple[str, ...] = ()) -> str:
    """One row per key of the file-schema dataclass ``cls`` (and of the tables it holds) but ``skip``:
    key, type, default, meaning (each field's ``doc``)."""
    rows = ["| key | type | default | meaning |", "|---|---|---|---|"]

    def walk(klass: type, path: str) -> None:
        hints = typing.get_type_hints(klass, include_extras=True)
        for f in dataclasses.fields(klass):
            if not path and f.name in skip:
                continue
            inner = schema.plain(hints[f.name])
            if dataclasses.is_dataclass(inner):
                walk(inner, f"{path}{f.name}.")
                continue
            if f.default is not dataclasses.MISSING:
                default = "none" if f.default is None else _value(list(f.default) if isinstance(f.default, tuple)
                                                                  else f.default)
            elif f.default_factory is not dataclasses.MISSING:
                made = f.default_factory()
                default = _value(made) if made or isinstance(made, (int, float)) else "empty"
            else:
                default = "required"
            rows.append(f"| `{prefix}{path}{f.name}` | {_type_text(hints[f.name])} | {default} | "
                        f"{f.metadata.get('doc', '')} |")

    walk(cls, "")
    return "\n".join(rows)


def scene_tables() -> str:
    """The scene file's tables and each primitive's parameters, from their schema."""
    from pipeline_sim import scene as S

    tables = [("image", S.ImageTable), ("camera", S.CameraTable), ("background", S.BackgroundTable),
              ("light", S.LightTable), ("[objects]", S.ObjectTable)]
    parts = [f"`[{name}]`:\n\n{schema_table(cls)}" for name, cls in tables]
    parts += [f"`primitive = \"{name}\"`, its parameters:\n\n{schema_table(cls, skip=S._OBJECT_KEYS)}"
              for name, cls in S._PRIMITIVE_TABLES.items()]
    return "\n\n".join(parts)


def workload_kinds() -> str:
    """Every registered workload kind with the keys of its file (from its ``file_schema``)."""
    from pipeline_sim.workload import kind_of, kinds

    parts = []
    for name in kinds():
        cls = kind_of(name, "docgen")
        if cls.file_schema is None:
            what = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
            what = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", what).replace("``", "`")
            parts.append(f"### `{name}`\n\n{what} Its file is checked by the kind's own reader.")
        else:
            parts.append(f"### `{name}`\n\n{schema_table(cls.file_schema)}")
    return "\n\n".join(parts)


def unit_counters() -> list[tuple[str, dict[str, str], tuple[str, ...]]]:
    """(unit, each counter with what it counts, its timing-dependent counters) in pipeline order, from the
    units' declarations."""
    from units.rop import Rop
    from units.sample_tester import SampleTester
    from units.shading_cache import Shading
    from units.tile_test import TileTest
    from units.tile_traverser import TileTraverser
    from units.triangle_setup import TriangleSetup
    from units.zcull import ZCull

    return [(u.name, counter_meanings(u), tuple(u.timing_dependent))
            for u in (TriangleSetup, TileTraverser, TileTest, ZCull, SampleTester, Shading, Rop)]


def counter_glossary() -> str:
    """One row per (unit, counter): what it counts and whether timing can move it."""
    rows = ["| unit | counter | counts | timing can move it |", "|---|---|---|---|"]
    for unit, meanings, timed in unit_counters():
        rows += [f"| `{unit}` | `{c}` | {m} | {'yes' if c in timed else 'no'} |" for c, m in meanings.items()]
    return "\n".join(rows)


#: file -> {block name: its generator}
BLOCKS = {
    "docs/architecture-format.md": {"hardware settings": lambda: settings_table(ArchConfig()),
                                    "effects": effects_table},
    "docs/scene-format.md": {"scene tables": scene_tables,
                             "pass settings": lambda: settings_table(PassState(), PASS + "."),
                             "simulation settings": lambda: settings_table(SimOptions(), SIMULATION + ".")},
    "docs/sweep-format.md": {"sweep tables": lambda: "\n\n".join(
                                 f"`[{name}]`:\n\n{schema_table(cls)}" for name, cls in
                                 (("sweep", SweepTable), ("reference", ReferenceTable))),
                             "sweep paths": sweep_paths},
    "docs/workloads.md": {"workload kinds": workload_kinds},
    "docs/counters.md": {"counter glossary": counter_glossary},
}


def _block(name: str) -> re.Pattern:
    return re.compile(rf"(<!-- BEGIN generated: {re.escape(name)} -->\n).*?(<!-- END generated: {re.escape(name)} -->)",
                      re.S)


def regenerate(text: str, blocks: dict[str, typing.Callable[[], str]], where: str) -> str:
    """``text`` with each named block's content replaced by its generator's output."""
    for name, make in blocks.items():
        pattern = _block(name)
        if not pattern.search(text):
            raise AssertionError(f"{where}: no generated block '{name}'")
        body = make()
        text = pattern.sub(lambda m: m.group(1) + body + "\n" + m.group(2), text)
    return text


def stale(root: Path = ROOT) -> list[str]:
    """The files whose generated blocks differ from what the declarations give now."""
    return [f for f, blocks in BLOCKS.items()
            if regenerate((root / f).read_text(), blocks, f) != (root / f).read_text()]


def main(argv: list[str] | None = None) -> int:
    """Rewrite every generated block (``--check``: only report the stale files, exit 1 if any)."""
    argv = sys.argv[1:] if argv is None else argv
    if "--check" in argv:
        bad = stale()
        for f in bad:
            print(f"{f}: generated blocks are stale (run `make docs`)")
        return 1 if bad else 0
    for f, blocks in BLOCKS.items():
        path = ROOT / f
        path.write_text(regenerate(path.read_text(), blocks, f))
    return 0


if __name__ == "__main__":
    sys.exit(main())
