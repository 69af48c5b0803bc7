"""Typed, documented parameters for stages and drivers.

A stage declares its parameters as a frozen dataclass whose fields use :func:`param`::

    @dataclass(frozen=True)
    class Params:
        voxel_mm: float = param(0.5, "finest voxel edge, mm", min=0.1)

:func:`build_params` turns a TOML table into that dataclass, checking names, types,
ranges and choices, and raising :class:`~inspector.errors.RecipeError` that names the
key. Nothing else in the program parses parameters.

Numbers are checked wherever they are, nested in lists and tables included: every float is
finite (TOML has ``nan`` and ``inf`` literals, and a NaN passes every ``<``/``>`` range
check: ``cluster_radius_mm = nan`` once let a notched part pass), declared bounds apply to
a number and to the numbers of a list, and an integer without a declared ``max`` must lie
within :data:`INT_BOUND` (``min_points = 9223372036854775807`` is a typo, not a choice).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from typing import Any, Literal, get_args, get_origin

from inspector.errors import RecipeError

__all__ = ["param", "build_params", "check_params", "describe_params", "NoParams", "INT_BOUND"]

#: Largest magnitude of an integer parameter without a declared ``max`` (and of integers
#: nested in lists and tables): counts, seeds and sizes reach compiled kernels, Open3D and
#: numpy as C ints, and no meaningful value comes near 2**31.
INT_BOUND = 2**31 - 1


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
            try:
                return float(value)
            except OverflowError:  # an integer beyond any float
                raise RecipeError(f"{where}: expected a finite number, got {value!r}") from None
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
        _check_numbers(v, key, f.metadata.get("min"), f.metadata.get("max"))
        values[name] = v
    try:
        return cls(**values)
    except ValueError as e:  # the dataclass's own checks (__post_init__), e.g. a bump's keys
        raise RecipeError(f"{where}: {e}") from None


def check_params(params: Any, where: str) -> None:
    """Check the numbers of a parameter dataclass built without :func:`build_params`
    (e.g. from command-line options) as :func:`build_params` checks a table's.

    Raises
    ------
    RecipeError
        Naming ``where.<field>``: a non-finite number, or one outside its bounds.
    """
    for f in dataclasses.fields(params):
        _check_numbers(getattr(params, f.name), f"{where}.{f.name}", f.metadata.get("min"), f.metadata.get("max"))


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_number(v: int | float, key: str, lo: float | None, hi: float | None) -> None:
    """One number: finite, within the declared bounds, an integer within INT_BOUND unless
    its bounds are declared (a declared bound wins, either way)."""
    if isinstance(v, float) and not math.isfinite(v):
        raise RecipeError(f"{key}: expected a finite number, got {v!r}")
    if lo is not None and v < lo:
        raise RecipeError(f"{key}: expected a value >= {lo}, got {v!r}")
    if hi is not None and v > hi:
        raise RecipeError(f"{key}: expected a value <= {hi}, got {v!r}")
    if isinstance(v, int):
        if hi is None and v > INT_BOUND:
            raise RecipeError(f"{key}: expected a value <= {INT_BOUND}, got {v!r}")
        if lo is None and v < -INT_BOUND:
            raise RecipeError(f"{key}: expected a value >= {-INT_BOUND}, got {v!r}")


def _check_numbers(value: Any, key: str, lo: float | None, hi: float | None) -> None:
    """Every number in ``value`` (a number, or lists and tables of any depth, walked without
    recursion); the declared bounds apply to the value and to the items of a list."""
    stack: list[tuple[Any, str, bool]] = [(value, key, True)]
    while stack:
        v, k, bounded = stack.pop()
        if _is_number(v):
            _check_number(v, k, lo if bounded else None, hi if bounded else None)
        elif isinstance(v, Mapping):
            stack.extend(reversed([(x, f"{k}.{name}", False) for name, x in v.items()]))  # first key first
        elif isinstance(v, (list, tuple)):
            stack.extend(reversed([(x, f"{k}[{i}]", bounded and k == key) for i, x in enumerate(v)]))


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
