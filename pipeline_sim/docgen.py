"""The generated parts of the format references and the counter glossary.

The settings tables of docs/architecture-format.md (the hardware),
docs/scene-format.md (a pass's state and the simulation options) and
docs/sweep-format.md (every setting path a sweep may vary), the table of
what each setting can change, and docs/counters.md (each unit's counters,
what they count and whether timing can move them) are written here from the
settings' declarations (types, ranges, choices, defaults, effects and
one-line docs: ``pipeline_sim.settings``) and the units' counter
declarations (``events``, ``timing_dependent``; the common counters of
``pipeline_sim.definitions.COMMON``). Each generated block sits between
``<!-- BEGIN generated: NAME -->`` and ``<!-- END generated: NAME -->``;
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
from pipeline_sim.definitions import ARITHMETIC, COMMON
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
}

#: What each counter counts: the common ones, then each unit's events (every declared name has a line;
#: tests/test_docs.py checks it).
COUNTER_MEANINGS = {
    "records_in": "records the unit received (triangles, tiles or samples, per its input)",
    "records_out": "records it passed on",
    **{op: f"`{op}` operations of its arithmetic" for op in ARITHMETIC},
    "bytes_read": "bytes it read from memory",
    "bytes_written": "bytes it wrote to memory",
    "culled_frustum": "triangles outside the view frustum at every time and lens position",
    "culled_backface": "triangles facing away at every (t, u, v)",
    "degenerate": "triangles of zero area throughout",
    "crossing_w0": "triangles with a vertex path crossing w = 0",
    "moving": "triangles that move during the shutter",
    "defocused": "triangles with a lens shift",
    "mixed_facing": "triangles whose facing changes over (t, u, v)",
    "coarse_tiles_tested": "coarse tiles tested against a triangle's bounds",
    "coarse_tiles_rejected": "coarse tiles rejected",
    "tiles_emitted": "(triangle, tile) records emitted",
    "rejected_box": "tiles rejected by the moving-box test",
    "rejected_edge": "tiles rejected by the moving-edge test",
    "rejected_lens": "tiles rejected by the lens bounds",
    "accepted": "tiles passed on",
    "rejected_hull": "tiles rejected by the convex hull",
    "rejected_dual_time": "tiles rejected by dual-space time bounds",
    "rejected_two_stage": "tiles rejected by two-stage time bounds",
    "rejected_tuples": "tiles no (u, v, t) tuple of the set reaches",
    "tiles_culled": "tiles z-cull rejected as hidden",
    "tiles_no_depth_read": "tiles z-cull found in front of everything drawn (the ROP skips their depth reads)",
    "box_lookups": "z-cull box lookups",
    "samples_tested": "samples inside-tested",
    "samples_covered": "samples found covered",
    "samples_in_range": "samples within the tile's time and lens intervals",
    "pixels_visited": "pixels whose sample range was looked up",
    "tests_2d": "inside tests of static, focused triangles",
    "tests_3d_xyt": "inside tests in x, y, t",
    "tests_4d_xyuv": "inside tests in x, y, u, v",
    "tests_5d": "inside tests in all five dimensions",
    "lookups": "shading-cache lookups",
    "hits": "lookups that found their entry",
    "misses": "lookups that did not",
    "evictions": "entries evicted",
    "shader_executions": "shader executions",
    "depth_tests": "sample depth tests",
    "depth_passed": "samples that passed",
    "depth_reads_skipped": "depth reads skipped on z-cull's word",
    "samples_written": "samples written to the multisample buffers",
    "zcull_refresh_tiles": "tiles whose z-cull boxes were checked after a batch",
    "zcull_refresh_scans": "tiles rescanned to refresh their z-cull boxes",
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
    return "\n".join(rows)


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


def unit_counters() -> list[tuple[str, tuple[str, ...], tuple[str, ...]]]:
    """(unit, its events, its timing-dependent counters) in pipeline order, from the units' declarations."""
    from units.rop import Rop
    from units.sample_tester import SampleTester
    from units.shading_cache import Shading
    from units.tile_test import TileTest
    from units.tile_traverser import TileTraverser
    from units.triangle_setup import TriangleSetup
    from units.zcull import ZCull

    return [(u.name, tuple(u.events), tuple(u.timing_dependent))
            for u in (TriangleSetup, TileTraverser, TileTest, ZCull, SampleTester, Shading, Rop)]


def counter_glossary() -> str:
    """One row per (unit, counter): what it counts and whether timing can move it."""
    rows = ["| unit | counter | counts | timing can move it |", "|---|---|---|---|"]
    for unit, events, timed in unit_counters():
        rows += [f"| `{unit}` | `{c}` | {COUNTER_MEANINGS[c]} | {'yes' if c in timed else 'no'} |"
                 for c in (*COMMON, *events)]
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
