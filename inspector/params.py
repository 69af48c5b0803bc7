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

Supported annotations (:data:`SUPPORTED`): ``bool``, ``int``, ``float``, ``str``,
``pathlib.Path`` (a string in the recipe; relative to the recipe's folder), choices
(``Literal["a", "b"]`` or an ``enum.Enum`` of str/int values), ``tuple[T, ...]``,
``tuple[T1, T2, ...]`` (that many items) and ``list[T]`` (both arrive as a tuple: parameters
are immutable), ``dict`` / ``dict[str, T]`` tables, ``T | None`` and unions of these, and
``Any``. :func:`check_param_class` refuses anything else when the plugin registers its stage
or driver, naming the field, as it refuses bounds on a field that holds no number, ``min >
max``, and a default that its own type or bounds refuse: a plugin's mistake is its author's
message at load time, never a recipe user's ``TypeError``.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any, Literal, get_args, get_origin

from inspector.errors import RecipeError

__all__ = ["param", "build_params", "check_params", "check_param_class", "describe_params", "NoParams", "INT_BOUND",
           "SUPPORTED"]

#: What :func:`check_param_class` accepts, in words (its refusals end with this).
SUPPORTED = ("bool, int, float, str, Path, Literal[...] or Enum choices, tuple[T, ...], tuple[T1, T2], list[T], "
             "dict[str, T], T | None, Any")

#: Largest magnitude of an integer parameter without a declared ``max`` (and of integers
#: nested in lists and tables): counts, seeds and sizes reach compiled kernels, Open3D and
#: numpy as C ints, and no meaningful value comes near 2**31.
INT_BOUND = 2**31 - 1


def param(
    default: Any,
    doc: str,
    *,
    min: float | None = None,
    max: float | None = None,
) -> Any:
    """Declare one parameter: default value, one-line doc, optional numeric bounds."""
    kwargs: dict[str, Any] = {"metadata": {"doc": doc, "min": min, "max": max}}
    if isinstance(default, (list, dict, set)):
        raise TypeError("use a tuple for sequence defaults")
    return dataclasses.field(default=default, **kwargs)


@dataclasses.dataclass(frozen=True)
class NoParams:
    """A stage or driver without parameters."""


def _is_union(tp: Any) -> bool:
    return get_origin(tp) in (typing.Union, types.UnionType)


def _is_enum(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, enum.Enum)


def _is_path(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, PurePath)


def _items(tp: Any) -> tuple[tuple[Any, ...], bool]:
    """(item types, variadic) of a tuple/list annotation: ``tuple[int, ...]`` -> ((int,), True)."""
    args = get_args(tp)
    if get_origin(tp) is list or tp in (list, tuple) or not args:
        return (args[0] if args else Any,), True
    if len(args) == 2 and args[1] is Ellipsis:
        return (args[0],), True
    if args == ((),):  # tuple[()]
        return (), False
    return args, False


def _type_name(tp: Any) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return " | ".join(repr(a) for a in get_args(tp))
    if _is_enum(tp):
        return " | ".join(repr(m.value) for m in tp)
    if origin in (tuple, list) or tp in (tuple, list):
        items, variadic = _items(tp)
        if variadic:
            return f"list of {_type_name(items[0])}" if items[0] is not Any else "list"
        return f"list of {len(items)}: " + ", ".join(_type_name(a) for a in items)
    if _is_union(tp):
        return " or ".join(_type_name(a) for a in get_args(tp))
    if tp is type(None):
        return "none"
    if _is_path(tp):
        return "path"
    if origin in (dict, Mapping) and get_args(tp):
        return f"table of {_type_name(get_args(tp)[1])}"
    return getattr(tp, "__name__", str(tp))


def _coerce(value: Any, tp: Any, where: str, base: Path | None = None) -> Any:
    """Check ``value`` against annotation ``tp``; return the converted value.

    ``base``: the folder a relative path is relative to (the recipe's), None: as given.
    """
    origin = get_origin(tp)
    if origin is Literal:
        if any(value == a and type(value) is type(a) or (_is_number(value) and _is_number(a) and value == a
                                                          and not isinstance(a, bool)) for a in get_args(tp)):
            return next(a for a in get_args(tp) if a == value)
        raise RecipeError(f"{where}: expected one of {_type_name(tp)}, got {value!r}")
    if _is_union(tp):
        for arg in get_args(tp):
            try:
                return _coerce(value, arg, where, base)
            except RecipeError:
                continue
        raise RecipeError(f"{where}: expected {_type_name(tp)}, got {value!r}")
    if tp is type(None):
        if value is None:
            return None
        raise RecipeError(f"{where}: expected none, got {value!r}")
    if origin in (tuple, list) or tp in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise RecipeError(f"{where}: expected {_type_name(tp)}, got {value!r}")
        items, variadic = _items(tp)
        if not variadic and len(value) != len(items):
            raise RecipeError(f"{where}: expected {len(items)} items, got {len(value)}")
        kinds = items * len(value) if variadic else items
        return tuple(_coerce(v, t, f"{where}[{i}]", base) for i, (v, t) in enumerate(zip(value, kinds)))
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise RecipeError(f"{where}: expected a table, got {value!r}")
        args = get_args(tp)
        if not args:
            return value
        return {str(k): _coerce(v, args[1], f"{where}.{k}", base) for k, v in value.items()}
    if tp is Any:
        return value
    if _is_enum(tp):
        if isinstance(value, tp):
            return value
        for m in tp:
            if m.value == value and type(m.value) is type(value):
                return m
        raise RecipeError(f"{where}: expected one of {_type_name(tp)}, got {value!r}")
    if _is_path(tp):
        if isinstance(value, PurePath) or (isinstance(value, str) and value and "\0" not in value):
            path = Path(value).expanduser()
            if base is not None and not path.is_absolute():
                path = base / path
            return tp(path)
        raise RecipeError(f"{where}: expected a path, got {value!r}")
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
    elif isinstance(tp, type):  # refused at registration (check_param_class); kept for safety
        if isinstance(value, tp):
            return value
    raise RecipeError(f"{where}: expected {_type_name(tp)}, got {value!r}")


def _unsupported(tp: Any) -> str | None:
    """Why annotation ``tp`` cannot come from a recipe, or None when it can."""
    origin = get_origin(tp)
    if tp in (bool, int, float, str, Any, type(None)) or _is_path(tp):
        return None
    if origin is Literal:
        bad = [a for a in get_args(tp) if not isinstance(a, (str, int, float, bool))]
        return f"choice {bad[0]!r} is not a str, int, float or bool" if bad else None
    if _is_enum(tp):
        bad = [m for m in tp if not isinstance(m.value, (str, int, float, bool))]
        return f"member {bad[0].name} has a value that is not a str, int, float or bool" if bad else None
    if _is_union(tp):
        return next((why for why in map(_unsupported, get_args(tp)) if why), None)
    if origin in (tuple, list) or tp in (tuple, list):
        items, _ = _items(tp)
        return next((why for why in map(_unsupported, items) if why), None)
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        args = get_args(tp)
        if args and args[0] is not str:
            return "table keys are strings"
        return _unsupported(args[1]) if args else None
    return f"{_type_repr(tp)} cannot come from a recipe"


def _holds_number(tp: Any) -> bool:
    """Whether a value of annotation ``tp`` can hold a number (bounds mean something)."""
    origin = get_origin(tp)
    if tp in (int, float, Any):
        return True
    if origin is Literal:
        return any(_is_number(a) for a in get_args(tp))
    if _is_enum(tp):
        return any(_is_number(m.value) for m in tp)
    if _is_union(tp):
        return any(map(_holds_number, get_args(tp)))
    if origin in (tuple, list) or tp in (tuple, list):
        return any(map(_holds_number, _items(tp)[0]))
    return False


def check_param_class(cls: Any) -> None:
    """Refuse a parameter class that recipes could not fill, when its plugin registers.

    Parameters
    ----------
    cls : type
        The ``params`` of a :class:`~inspector.registry.StageSpec` or
        :class:`~inspector.registry.DriverSpec`.

    Raises
    ------
    TypeError
        Naming the field: not a frozen dataclass, an annotation that is not resolvable or
        not supported (:data:`SUPPORTED`), ``min``/``max`` on a field that holds no number or
        not finite numbers or ``min > max``, or a default its own type or bounds refuse.
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"params {cls!r} is not a dataclass (declare @dataclass(frozen=True) with param() fields)")
    name = cls.__name__
    if not cls.__dataclass_params__.frozen:  # type: ignore[attr-defined]
        raise TypeError(f"params {name} is not frozen (declare @dataclass(frozen=True))")
    try:
        hints = typing.get_type_hints(cls)
    except Exception as e:  # noqa: BLE001 - a NameError of a forward reference, a typo...
        raise TypeError(f"params {name}: its annotations cannot be resolved ({type(e).__name__}: {e})") from None
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        where = f"parameter {f.name!r}"
        why = _unsupported(tp)
        if why is not None:
            raise TypeError(f"{where}: type {_type_repr(tp)} is not supported ({why}); supported: {SUPPORTED}")
        lo, hi = f.metadata.get("min"), f.metadata.get("max")
        for label, bound in (("min", lo), ("max", hi)):
            if bound is not None and not (_is_number(bound) and math.isfinite(bound)):
                raise TypeError(f"{where}: {label}={bound!r} is not a finite number")
        if (lo is not None or hi is not None) and not _holds_number(tp):
            raise TypeError(f"{where}: min/max given, but type {_type_repr(tp)} holds no number")
        if lo is not None and hi is not None and lo > hi:
            raise TypeError(f"{where}: min={lo} is above max={hi}")
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            continue  # a recipe must set it (build_params says so)
        try:
            _check_numbers(_coerce(default, tp, f"{where} default"), f"{where} default", lo, hi)
        except RecipeError as e:
            raise TypeError(str(e)) from None


def _type_repr(tp: Any) -> str:
    """An annotation as written (``list[set]``, ``Foo``)."""
    if isinstance(tp, type) and not get_args(tp):
        return tp.__name__
    return str(tp).replace("typing.", "")


def build_params(cls: type, table: Mapping[str, Any] | None, where: str, base: Path | None = None) -> Any:
    """Validate ``table`` against the parameter dataclass ``cls``.

    Parameters
    ----------
    cls : type
        A frozen dataclass declared with :func:`param` fields.
    table : mapping or None
        Values from the recipe (or the command line).
    where : str
        Location prefix for messages, e.g. ``"recipe.toml: stages.carve.params"``.
    base : Path, optional
        The folder relative ``Path`` parameters are relative to (the recipe's).

    Raises
    ------
    RecipeError
        Unknown key, missing key (a field without default), wrong type, out of range, or not
        one of the choices.
    """
    table = dict(table or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        known = ", ".join(sorted(fields)) or "none"
        raise RecipeError(f"{where}: unknown parameter {unknown[0]!r} (known: {known})")
    required = [n for n, f in fields.items() if f.init and n not in table
                and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if required:
        raise RecipeError(f"{where}: missing parameter {required[0]!r} (it has no default)")
    values: dict[str, Any] = {}
    for name, value in table.items():
        f = fields[name]
        key = f"{where}.{name}"
        v = _coerce(value, hints[name], key, base)
        _check_numbers(v, key, f.metadata.get("min"), f.metadata.get("max"))
        values[name] = v
    try:
        return cls(**values)
    except (ValueError, TypeError) as e:  # the dataclass's own checks (__post_init__), e.g. a bump's keys
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
        default = f.default
        if default is dataclasses.MISSING:
            default = f.default_factory() if f.default_factory is not dataclasses.MISSING else None
        out.append(
            {
                "name": f.name,
                "type": _type_name(hints[f.name]),
                "default": default.value if isinstance(default, enum.Enum) else default,
                "doc": f.metadata.get("doc", ""),
                "min": f.metadata.get("min"),
                "max": f.metadata.get("max"),
            }
        )
    return out
