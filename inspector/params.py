"""Typed, documented parameters for stages and drivers.

A stage declares its parameters as a frozen dataclass whose fields use :func:`param`::

    @dataclass(frozen=True)
    class Params:
        voxel_mm: float = param(0.5, "finest voxel edge, mm", min=0.1)

:func:`build_params` turns a TOML table into that dataclass, checking names, types,
ranges and choices, and raising :class:`~inspector.errors.RecipeError` that names the
key. Nothing else in the program parses parameters.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from typing import Any, Literal, get_args, get_origin

from inspector.errors import RecipeError

__all__ = ["param", "build_params", "describe_params", "NoParams"]


def param(
    default: Any,
    doc: str,
    *,
    min: float | None = None,  # noqa: A002 - reads naturally at the call site
    max: float | None = None,  # noqa: A002
) -> Any:
    """Declare one parameter: default value, one-line doc, optional numeric bounds."""
    kwargs: dict[str, Any] = {"metadata": {"doc": doc, "min": min, "max": max}}
    if isinstance(default, (list, dict, set)):
        raise TypeError("use a tuple for sequence defaults")
    return dataclasses.field(default=default, **kwargs)


@dataclasses.dataclass(frozen=True)
class NoParams:
    """A stage or driver without parameters."""


def _type_name(tp: Any) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return " | ".join(repr(a) for a in get_args(tp))
    if origin is tuple:
        args = get_args(tp)
        return f"list of {_type_name(args[0])}" if args else "list"
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " or ".join(_type_name(a) for a in get_args(tp))
    if tp is type(None):
        return "none"
    return getattr(tp, "__name__", str(tp))


def _coerce(value: Any, tp: Any, where: str) -> Any:
    """Check ``value`` against annotation ``tp``; return the converted value."""
    origin = get_origin(tp)
    if origin is Literal:
        if value in get_args(tp):
            return value
        raise RecipeError(f"{where}: expected one of {_type_name(tp)}, got {value!r}")
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        for arg in get_args(tp):
            try:
                return _coerce(value, arg, where)
            except RecipeError:
                continue
        raise RecipeError(f"{where}: expected {_type_name(tp)}, got {value!r}")
    if tp is type(None):
        if value is None:
            return None
        raise RecipeError(f"{where}: expected none, got {value!r}")
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise RecipeError(f"{where}: expected {_type_name(tp)}, got {value!r}")
        (item,) = get_args(tp)[:1] or (Any,)
        return tuple(_coerce(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    if tp is Any:
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif tp is str:
        if isinstance(value, str):
            return value
    else:
        if isinstance(value, tp):
            return value
    raise RecipeError(f"{where}: expected {_type_name(tp)}, got {value!r}")


def build_params(cls: type, table: Mapping[str, Any] | None, where: str) -> Any:
    """Validate ``table`` against the parameter dataclass ``cls``.

    Parameters
    ----------
    cls : type
        A frozen dataclass declared with :func:`param` fields.
    table : mapping or None
        Values from the recipe (or the command line).
    where : str
        Location prefix for messages, e.g. ``"recipe.toml: stages.carve.params"``.

    Raises
    ------
    RecipeError
        Unknown key, wrong type, out of range, or not one of the choices.
    """
    table = dict(table or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        known = ", ".join(sorted(fields)) or "none"
        raise RecipeError(f"{where}: unknown parameter {unknown[0]!r} (known: {known})")
    values: dict[str, Any] = {}
    for name, value in table.items():
        f = fields[name]
        key = f"{where}.{name}"
        v = _coerce(value, hints[name], key)
        lo, hi = f.metadata.get("min"), f.metadata.get("max")
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if lo is not None and v < lo:
                raise RecipeError(f"{key}: expected a value >= {lo}, got {v!r}")
            if hi is not None and v > hi:
                raise RecipeError(f"{key}: expected a value <= {hi}, got {v!r}")
        values[name] = v
    return cls(**values)


def describe_params(cls: type) -> list[dict[str, Any]]:
    """One dict per parameter: name, type, default, doc, bounds (for ``inspector plugins``)."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        out.append(
            {
                "name": f.name,
                "type": _type_name(hints[f.name]),
                "default": f.default,
                "doc": f.metadata.get("doc", ""),
                "min": f.metadata.get("min"),
                "max": f.metadata.get("max"),
            }
        )
    return out
