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
import types
import typing
from typing import Any, Literal

from pydantic import TypeAdapter, ValidationError
from pydantic.fields import FieldInfo

from pipeline_sim.errors import UserError, did_you_mean, printable, unknown_key_error

_UNKNOWN = ("unexpected_keyword_argument", "extra_forbidden")
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


def required(annotation: Any) -> Any:
    """``X`` of an optional ``X | None`` (constraints kept); any other annotation as it is."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return next(a for a in typing.get_args(annotation) if a is not type(None))
    return annotation


def plain(annotation: Any) -> Any:
    """``annotation`` without its constraints, and ``X`` of an optional ``X | None``."""
    return _unwrap(required(_unwrap(annotation)))


def _step(annotation: Any, part: str | int) -> Any:
    """The annotation of ``part`` (a field name or a list index) inside a value of ``annotation``."""
    annotation = plain(annotation)
    if isinstance(part, int):
        args = typing.get_args(annotation)
        return args[0] if typing.get_origin(annotation) in (list, tuple) and args else None
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        return typing.get_type_hints(annotation, include_extras=True).get(part)
    args = typing.get_args(annotation)  # dict[str, X]: every key's value is an X
    return args[1] if typing.get_origin(annotation) is dict and len(args) == 2 else None


def _annotation(cls: type, loc: tuple[str | int, ...]) -> Any:
    """The annotation reached from the dataclass ``cls`` through ``loc`` (field names and list indices)."""
    annotation: Any = cls
    for part in loc:
        if annotation is None:
            return None
        annotation = _step(annotation, part)
    return annotation


def _class_at(cls: type, loc: tuple[str | int, ...]) -> type | None:
    """The settings dataclass reached from ``cls`` through ``loc``."""
    found = plain(_annotation(cls, loc))
    return found if isinstance(found, type) and dataclasses.is_dataclass(found) else None


def key_path(loc: tuple[str | int, ...]) -> str:
    """A key's place as messages show it: ``objects[2].open.rotate``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _doc(cls: type, loc: tuple[str | int, ...]) -> str:
    owner = _class_at(cls, loc[:-1])
    if owner is None or isinstance(loc[-1], int):
        return ""
    f = next((f for f in dataclasses.fields(owner) if f.name == loc[-1]), None)
    return f.metadata.get("doc", "") if f is not None else ""


def field_constraints(annotation: Any) -> dict[str, Any]:
    """``base`` (the Python type), ``choices`` (a Literal's), the bounds ``ge``, ``gt``, ``le``, ``lt`` and
    a list's ``min_length`` and ``max_length`` of a field annotation."""
    out: dict[str, Any] = {}
    args = typing.get_args(annotation) if typing.get_origin(annotation) is typing.Annotated else (annotation,)
    base = args[0] if args else annotation
    if typing.get_origin(base) is Literal:
        out["choices"] = tuple(typing.get_args(base))
        base = str
    out["base"] = base
    for meta in args[1:]:
        for m in (meta.metadata if isinstance(meta, FieldInfo) else [meta]):
            for bound in ("ge", "gt", "le", "lt", "min_length", "max_length"):
                if getattr(m, bound, None) is not None:
                    out[bound] = getattr(m, bound)
    return out


def range_text(c: dict[str, Any]) -> str:
    """The range of a number's constraints, as messages say it."""
    if "ge" in c and "le" in c:
        return f"from {c['ge']:g} to {c['le']:g}"
    low = f"{'[' if 'ge' in c else '('}{c.get('ge', c.get('gt', '-inf')):g}" if "ge" in c or "gt" in c else None
    high = f"{c.get('le', c.get('lt', 'inf')):g}{']' if 'le' in c else ')'}" if "le" in c or "lt" in c else None
    if low and high:
        return f"in {low}, {high}"
    if low:
        return f"{'>=' if 'ge' in c else '>'} {low[1:]}"
    return f"{'<=' if 'le' in c else '<'} {high[:-1]}"


def _items(cls: type, loc: tuple[str | int, ...]) -> str:
    """What a list at ``loc`` holds, as messages say it: ``3 numbers``, ``an array of tables``, ``a list``."""
    annotation = _annotation(cls, loc)
    c = field_constraints(required(annotation))
    item = plain(_step(annotation, 0)) if annotation is not None else None
    if isinstance(item, type) and dataclasses.is_dataclass(item):
        return f"an array of tables ([[{loc[-1]}]])"
    noun = "numbers" if item is float else "items"
    if c.get("min_length") is not None and c.get("min_length") == c.get("max_length"):
        return f"{c['min_length']} {noun}"
    return "a list"


def _message(cls: type, err: dict[str, Any], where: str, prefix: tuple[str | int, ...]) -> UserError:
    loc = tuple(err["loc"])
    path = key_path(prefix + loc)
    table = key_path(prefix + loc[:-1])
    kind, value = err["type"], err.get("input")
    if kind in _UNKNOWN:
        owner = _class_at(cls, loc[:-1])
        known = [f.name for f in dataclasses.fields(owner)] if owner is not None else []
        return unknown_key_error(f"{where}: [{table}]" if table else where, printable(str(loc[-1])), known)
    if kind == "missing" or kind == "missing_argument":
        doc = _doc(cls, loc)
        return UserError(f"{where}: {path}: missing required key{f' ({doc})' if doc else ''}")
    if kind in ("dataclass_type", "dataclass_exact_type", "dataclass_args_type", "model_type", "dict_type"):
        return UserError(f"{where}: [{path}] must be a table, got {shown(value)}")
    if kind in ("list_type", "tuple_type"):
        return UserError(f"{where}: {path}: expected {_items(cls, loc)}, got {shown(value)}")
    if kind in ("too_short", "string_too_short") and err["ctx"]["min_length"] == 1:
        return UserError(f"{where}: {path}: must not be empty")
    if kind in ("too_short", "too_long"):
        ctx = err["ctx"]
        expected = _items(cls, loc)
        if expected == "a list" or expected.startswith("an array"):
            expected = (f"at least {ctx['min_length']}" if kind == "too_short" else f"at most {ctx['max_length']}"
                        ) + " items"
        return UserError(f"{where}: {path}: expected {expected}, got {ctx['actual_length']}")
    if kind == "finite_number":
        return UserError(f"{where}: {path}: expected a finite number, got {shown(value)}")
    c = field_constraints(required(_annotation(cls, loc)))
    if "choices" in c:
        choices = c["choices"]
        return UserError(f"{where}: {path}: {shown(value) if not isinstance(value, str) else repr(value)} is not one "
                         f"of {', '.join(choices)}{did_you_mean(str(value), choices)}")
    if kind.endswith("_type") or kind.endswith("_parsing") or isinstance(value, bool):
        expected = _EXPECTED.get(getattr(c.get("base"), "__name__", ""), "another type")
        if expected == "a number" and isinstance(value, int) and not isinstance(value, bool):
            expected = "a finite number"
        return UserError(f"{where}: {path}: expected {expected}, got {shown(value)}")
    if any(b in c for b in ("ge", "gt", "le", "lt")):
        return UserError(f"{where}: {path}: must be {range_text(c)}, got {shown(value)}")
    return UserError(f"{where}: {path}: {err['msg']}, got {shown(value)}")


def build(cls: type, data: Any, where: str, prefix: tuple[str | int, ...] = ()) -> Any:
    """Validate ``data`` (a parsed TOML table) as the dataclass ``cls`` and run its ``check``; a problem
    is one :class:`UserError` naming ``where`` and the key's path (after ``prefix``, as :func:`key_path`)."""
    if not isinstance(data, dict):
        label = f"[{key_path(prefix)}]" if prefix else "the file"
        raise UserError(f"{where}: {label} must be a table, got {shown(data)}")
    try:
        obj = adapter(cls).validate_python(data)
    except ValidationError as exc:
        errors = exc.errors()
        # a misspelt key is also a missing one: name the misspelling, with the nearest known name
        first = next((e for e in errors if e["type"] in _UNKNOWN), errors[0])
        raise _message(cls, first, where, prefix) from None
    check(obj, where, prefix)
    return obj


def check(obj: Any, where: str, prefix: tuple[str | int, ...] = ()) -> None:
    """Run the rules between keys of ``obj`` and of every settings dataclass it holds (in its fields and
    in lists of them)."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            check(value, where, prefix + (f.name,))
        elif isinstance(value, list):
            for i, item in enumerate(value):
                if dataclasses.is_dataclass(item):
                    check(item, where, prefix + (f.name, i))
    rule = getattr(obj, "check", None)
    if rule is not None:
        rule(f"{where}: {key_path(prefix)}" if prefix else where)


def key(doc: str, **kwargs: Any) -> Any:
    """A key of an input file's table that is not a setting (a sweep's scene, a workload kind's keys):
    a dataclass field (``default=`` / ``default_factory=`` as ``dataclasses.field``; none: required)
    with the one line the generated references show for it."""
    return dataclasses.field(metadata={"doc": doc}, **kwargs)


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
