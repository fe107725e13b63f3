"""One schema for every input file's settings, validated by pydantic.

The hardware (``pipeline_sim.config.ArchConfig``), a pass's state
(``pipeline_sim.pass_state.PassState``) and the simulation options
(``pipeline_sim.simulation.SimOptions``) are dataclasses whose fields carry
their types and ranges as annotations (``pipeline_sim.settings``): pydantic
checks an input table against them (types without coercion, ranges, choices,
unknown keys), and :func:`build` turns its first complaint into the one-line
:class:`~pipeline_sim.errors.UserError` the tool shows: the file, the key,
what is wrong, and the nearest known name for a misspelt key or value. The
same annotations give the JSON Schema (:func:`json_schema`) from which the
format references in docs/ are generated (``pipeline_sim.docgen``).
Rules between keys (a cache's entries a multiple of its ways, clip planes in
order) are each dataclass's ``check`` method, run after pydantic's.
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from typing import Any, Literal

from pydantic import TypeAdapter, ValidationError
from pydantic.fields import FieldInfo

from pipeline_sim.errors import UserError, did_you_mean, unknown_key_error

_EXPECTED = {"int": "an integer", "float": "a number", "bool": "true or false", "str": "a string"}


@functools.cache
def adapter(cls: type) -> TypeAdapter:
    return TypeAdapter(cls)


def json_schema(cls: type) -> dict[str, Any]:
    """The JSON Schema of a settings dataclass (its fields' types, ranges, choices and defaults)."""
    return adapter(cls).json_schema()


def shown(value: Any) -> str:
    """A value as an error message shows it: short, on one line."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int) and len(str(abs(value))) > 20:
        return f"an integer of {len(str(abs(value)))} digits"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _unwrap(annotation: Any) -> Any:
    return typing.get_args(annotation)[0] if typing.get_origin(annotation) is typing.Annotated else annotation


def _class_at(cls: type, names: tuple[str, ...]) -> type | None:
    """The settings dataclass reached from ``cls`` through the fields ``names``."""
    for name in names:
        hints = typing.get_type_hints(cls, include_extras=True) if dataclasses.is_dataclass(cls) else {}
        if name not in hints:
            return None
        cls = _unwrap(hints[name])
    return cls if isinstance(cls, type) and dataclasses.is_dataclass(cls) else None


def _annotation(cls: type, loc: tuple[str, ...]) -> Any:
    owner = _class_at(cls, loc[:-1])
    return typing.get_type_hints(owner, include_extras=True).get(loc[-1]) if owner is not None else None


def field_constraints(annotation: Any) -> dict[str, Any]:
    """``base`` (the Python type), ``choices`` (a Literal's), ``ge`` and ``le`` of a field annotation."""
    out: dict[str, Any] = {}
    args = typing.get_args(annotation) if typing.get_origin(annotation) is typing.Annotated else (annotation,)
    base = args[0] if args else annotation
    if typing.get_origin(base) is Literal:
        out["choices"] = tuple(typing.get_args(base))
        base = str
    out["base"] = base
    for meta in args[1:]:
        for m in (meta.metadata if isinstance(meta, FieldInfo) else [meta]):
            for bound in ("ge", "le"):
                if hasattr(m, bound):
                    out[bound] = getattr(m, bound)
    return out


def _message(cls: type, err: dict[str, Any], where: str, prefix: tuple[str, ...]) -> UserError:
    loc = tuple(str(p) for p in err["loc"])
    path = ".".join(prefix + loc)
    table = ".".join(prefix + loc[:-1])
    kind, value = err["type"], err.get("input")
    if kind in ("unexpected_keyword_argument", "extra_forbidden"):
        owner = _class_at(cls, loc[:-1])
        known = [f.name for f in dataclasses.fields(owner)] if owner is not None else []
        return unknown_key_error(f"{where}: [{table}]" if table else where, loc[-1], known)
    if kind in ("dataclass_type", "dataclass_exact_type", "dataclass_args_type", "model_type"):
        return UserError(f"{where}: [{path}] must be a table, got {shown(value)}")
    c = field_constraints(_annotation(cls, loc))
    if "choices" in c:
        choices = c["choices"]
        return UserError(f"{where}: {path}: {shown(value) if not isinstance(value, str) else repr(value)} is not one "
                         f"of {', '.join(choices)}{did_you_mean(str(value), choices)}")
    if kind.endswith("_type") or kind.endswith("_parsing") or isinstance(value, bool):
        expected = _EXPECTED.get(getattr(c.get("base"), "__name__", ""), "another type")
        if expected == "a number" and isinstance(value, int) and not isinstance(value, bool):
            expected = "a finite number"
        return UserError(f"{where}: {path}: expected {expected}, got {shown(value)}")
    if "ge" in c or "le" in c:
        return UserError(f"{where}: {path}: must be from {c.get('ge', '-inf'):g} to {c.get('le', 'inf'):g}, "
                         f"got {shown(value)}")
    return UserError(f"{where}: {path}: {err['msg']}, got {shown(value)}")


def build(cls: type, data: Any, where: str, prefix: tuple[str, ...] = ()) -> Any:
    """Validate ``data`` (a parsed TOML table) as the dataclass ``cls`` and run its ``check``; a problem
    is one :class:`UserError` naming ``where`` and the key's dotted path (after ``prefix``)."""
    if not isinstance(data, dict):
        label = f"[{'.'.join(prefix)}]" if prefix else "the file"
        raise UserError(f"{where}: {label} must be a table, got {shown(data)}")
    try:
        obj = adapter(cls).validate_python(data)
    except ValidationError as exc:
        raise _message(cls, exc.errors()[0], where, prefix) from None
    check(obj, where, prefix)
    return obj


def check(obj: Any, where: str, prefix: tuple[str, ...] = ()) -> None:
    """Run the rules between keys of ``obj`` and of every settings dataclass it holds."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            check(value, where, prefix + (f.name,))
    rule = getattr(obj, "check", None)
    if rule is not None:
        rule(f"{where}: {'.'.join(prefix)}" if prefix else where)


def merged(base: Any, data: dict[str, Any]) -> dict[str, Any]:
    """``base`` (a settings dataclass) as a fresh dict with the tables of ``data`` laid over it, key by key."""
    def lay(out: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
        for key, value in over.items():
            if isinstance(out.get(key), dict) and isinstance(value, dict):
                lay(out[key], value)
            else:
                out[key] = value
        return out

    return lay(dataclasses.asdict(base), data)
