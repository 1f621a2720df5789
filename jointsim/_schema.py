"""Typed, validating conversion of nested TOML tables into frozen dataclasses.

A scene section is a frozen dataclass whose fields carry :func:`spec` metadata
(bounds, choices, unit, documentation).  :func:`build` walks a raw ``dict``
(as parsed from TOML), checks every key against the dataclass, converts values
to the annotated types and raises :class:`SceneError` naming the scene file
and the dotted key on the first problem.  Unknown keys are errors, with a
"did you mean" suggestion.

Supported annotations: ``float``, ``int``, ``bool``, ``str``, ``Optional[T]``,
``tuple[T, ...]`` (from TOML arrays), nested dataclasses, and
``tuple[Dataclass, ...]`` (arrays of tables).  A field may declare a
``coerce`` callable that turns a shorthand (a bare number, say) into the
table form before conversion.
"""
from __future__ import annotations

import dataclasses
import difflib
import math
import typing
from pathlib import Path
from typing import Any, Callable


class SceneError(ValueError):
    """A scene file is invalid.

    Parameters
    ----------
    file : str
        The scene file (as given by the user).
    key : str
        Dotted key path, for example ``joint.mu`` or ``model.contacts[0].t_dof``.
    message : str
        What is wrong, phrased to follow the key.
    """

    def __init__(self, file: str, key: str, message: str):
        self.file = str(file)
        self.key = key
        self.message = message
        where = f"{self.file}: {key}" if key else self.file
        super().__init__(f"{where} {message}")


def spec(
    default: Any = dataclasses.MISSING,
    *,
    doc: str = "",
    unit: str = "",
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    choices: tuple | None = None,
    path: bool = False,
    coerce: Callable[[Any], Any] | None = None,
    default_factory: Callable[[], Any] | None = None,
):
    """Declare a scene field with its validation rules.

    Parameters
    ----------
    default : object, optional
        Default value; a field without one is required.
    doc, unit : str
        Documentation and physical unit, used by the README key table.
    ge, gt, le, lt : float, optional
        Bounds applied to numbers (element-wise for tuples).
    choices : tuple, optional
        Allowed values.
    path : bool
        The value is a file path relative to the scene file and must exist.
    coerce : callable, optional
        Applied to the raw TOML value before type conversion.
    """
    meta = dict(doc=doc, unit=unit, ge=ge, gt=gt, le=le, lt=lt,
                choices=choices, path=path, coerce=coerce)
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


class Context:
    """Where a value came from: the scene file name and its directory."""

    def __init__(self, file: str, base_dir: Path):
        self.file = file
        self.base_dir = base_dir

    def error(self, key: str, message: str) -> SceneError:
        return SceneError(self.file, key, message)


_TYPE_NAMES = {float: "a number", int: "an integer", bool: "true or false",
               str: "a string"}


def _describe(value: Any) -> str:
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if isinstance(value, (int, float)):
        return f"{value!r} (a number)"
    if isinstance(value, str):
        return f"{value!r} (a string)"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    return repr(value)


def suggest(name: str, known: list[str]) -> list[str]:
    """Known names that ``name`` was probably meant to be (case-insensitive first)."""
    same = [k for k in known if k.lower() == name.lower()]
    return same or difflib.get_close_matches(name, known, n=1)


def _convert_scalar(tp: type, value: Any, key: str, ctx: Context) -> Any:
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ctx.error(key, f"must be a number, got {_describe(value)}")
        v = float(value)
        if not math.isfinite(v):
            raise ctx.error(key, f"must be finite, got {v}")
        return v
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ctx.error(key, f"must be an integer, got {_describe(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ctx.error(key, f"must be true or false, got {_describe(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ctx.error(key, f"must be a string, got {_describe(value)}")
        return value
    raise TypeError(f"unsupported scene type {tp!r} at {key}")  # programming error


def _check_rules(value: Any, meta: dict, key: str, ctx: Context) -> None:
    items = value if isinstance(value, tuple) else (value,)
    for v in items:
        if isinstance(v, tuple):
            _check_rules(v, meta, key, ctx)
            continue
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if meta.get("ge") is not None and not v >= meta["ge"]:
                raise ctx.error(key, f"must be >= {meta['ge']:g}, got {v:g}")
            if meta.get("gt") is not None and not v > meta["gt"]:
                raise ctx.error(key, f"must be > {meta['gt']:g}, got {v:g}")
            if meta.get("le") is not None and not v <= meta["le"]:
                raise ctx.error(key, f"must be <= {meta['le']:g}, got {v:g}")
            if meta.get("lt") is not None and not v < meta["lt"]:
                raise ctx.error(key, f"must be < {meta['lt']:g}, got {v:g}")
        if meta.get("choices") is not None and v not in meta["choices"]:
            options = ", ".join(repr(c) for c in meta["choices"])
            raise ctx.error(key, f"must be one of {options}, got {v!r}")
    if meta.get("path") and isinstance(value, str):
        p = (ctx.base_dir / value)
        if not p.exists():
            raise ctx.error(key, f"names a file that does not exist: {value!r} "
                                 f"(looked for {p})")
        if value and p.is_dir():
            raise ctx.error(key, f"names a directory, not a file: {value!r} (looked for {p})")


def convert(tp: Any, value: Any, key: str, ctx: Context) -> Any:
    """Convert a raw TOML value to the annotated type ``tp``."""
    origin = typing.get_origin(tp)
    if origin is typing.Union or (origin is not None and str(origin) == "<class 'types.UnionType'>"):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        if len(args) == 1:
            return convert(args[0], value, key, ctx)
        errors = []
        for a in args:
            try:
                return convert(a, value, key, ctx)
            except SceneError as exc:
                errors.append(exc)
        raise errors[0]
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ctx.error(key, f"must be an array, got {_describe(value)}")
        inner = args[0]
        return tuple(convert(inner, v, f"{key}[{i}]", ctx) for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ctx.error(key, f"must be a table, got {_describe(value)}")
        return build(tp, value, key, ctx)
    return _convert_scalar(tp, value, key, ctx)


def build(cls: type, data: dict, prefix: str, ctx: Context) -> Any:
    """Build dataclass ``cls`` from table ``data``; ``prefix`` is its dotted key."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    key_of = (lambda name: f"{prefix}.{name}") if prefix else (lambda name: name)
    for name in data:
        if name not in fields:
            close = suggest(name, list(fields))
            hint = f" (did you mean {key_of(close[0])!r}?)" if close else ""
            known = ", ".join(sorted(fields))
            raise ctx.error(key_of(name), f"is not a known key{hint}; known keys here: {known}")
    kwargs = {}
    for name, f in fields.items():
        key = key_of(name)
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ctx.error(key, "is required but missing")
            continue
        raw = data[name]
        meta = dict(f.metadata)
        if meta.get("coerce") is not None:
            raw = meta["coerce"](raw)
        value = convert(hints[name], raw, key, ctx)
        _check_rules(value, meta, key, ctx)
        kwargs[name] = value
    obj = cls(**kwargs)
    check = getattr(obj, "check", None)
    if check is not None:
        for bad_key, message in check():
            raise ctx.error(key_of(bad_key) if bad_key else prefix, message)
    return obj


def to_plain(obj: Any) -> Any:
    """Dataclass -> nested dict/list/scalars, suitable for TOML output."""
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            if not f.init:
                continue
            v = getattr(obj, f.name)
            if v is None:
                continue
            out[f.name] = to_plain(v)
        return out
    if isinstance(obj, (tuple, list)):
        return [to_plain(v) for v in obj]
    return obj


def field_docs(cls: type, prefix: str = "", leaves: tuple = ()) -> list[tuple[str, str, str, str]]:
    """Rows (key, default, unit, doc) for every field, for the README.

    Nested dataclasses are expanded, except the types in ``leaves``, which
    are documented on their own.
    """
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        key = f"{prefix}.{f.name}" if prefix else f.name
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp) and tp not in leaves:
            rows.extend(field_docs(tp, key, leaves))
            continue
        if f.default is not dataclasses.MISSING:
            default = repr(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            default = repr(f.default_factory())
        else:
            default = "(required)"
        rows.append((key, default, f.metadata.get("unit", ""), f.metadata.get("doc", "")))
    return rows
