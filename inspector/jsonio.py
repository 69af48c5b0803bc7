"""The one ``default`` hook for the JSON the product writes (capture folders, tool records).

Light on purpose (the standard library only): command modules loaded at every start import it.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import date, time
from os import PathLike
from typing import Any

__all__ = ["json_default"]


def json_default(obj: Any) -> Any:
    """``json.dumps(..., default=json_default)``: numpy arrays and scalars (anything with
    ``tolist``), paths, sets and tuples, dates and times (TOML's too), and read-only mappings as
    JSON; TypeError for anything else."""
    if isinstance(obj, Mapping):
        return dict(obj)
    if hasattr(obj, "tolist"):  # numpy arrays and scalars, without importing numpy
        return obj.tolist()
    if isinstance(obj, PathLike):
        return str(obj)
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    if isinstance(obj, (date, time)):  # datetimes too
        return obj.isoformat()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")
