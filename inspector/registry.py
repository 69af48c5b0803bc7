"""What a plugin registers: stage and driver specifications.

A stage is a named, typed transformation of an :class:`~inspector.pipeline.InspectionContext`;
a driver yields captures. Both declare their parameters as a frozen dataclass (see
:mod:`inspector.params`) so recipes are validated before anything runs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from inspector.params import NoParams

if TYPE_CHECKING:
    from inspector.model import Capture
    from inspector.pipeline import InspectionContext

__all__ = [
    "KINDS",
    "StageSpec",
    "StageRegistry",
    "Acquisition",
    "Driver",
    "DriverSpec",
    "DriverRegistry",
]

#: Stage kinds in pipeline order; a stage may only need kinds that come before it.
KINDS = ("segment", "carve", "classify", "align", "bcps", "evaluate")


@dataclass(frozen=True)
class StageSpec:
    """One stage a recipe can ``use``.

    Attributes
    ----------
    name : str
        ``"<kind>.<variant>"``, e.g. ``"carve.hull"``.
    run : callable
        ``run(context, params) -> context``: returns a new context with its output set.
    params : type
        Frozen dataclass of parameters (:func:`inspector.params.param` fields).
    requires : tuple of str
        Kinds whose output this stage reads; the recipe must run them earlier.
    doc : str
        One line shown by ``inspector plugins``.
    """

    name: str
    run: Callable[[InspectionContext, Any], InspectionContext]
    params: type = NoParams
    requires: tuple[str, ...] = ()
    doc: str = ""

    @property
    def kind(self) -> str:
        return self.name.split(".", 1)[0]


@dataclass(frozen=True)
class Acquisition:
    """One capture a driver offers: its name, and how to get it (may raise InputError)."""

    name: str
    load: Callable[[], Capture]


class Driver(Protocol):
    """An open acquisition source."""

    def acquire(self) -> Iterator[Acquisition]:
        """Yield one :class:`Acquisition` per trigger / capture."""
        ...

    def close(self) -> None:
        ...


@dataclass(frozen=True)
class DriverSpec:
    """One acquisition driver a recipe can ``use``.

    Attributes
    ----------
    name : str
    open : callable
        ``open(params) -> Driver``.
    params : type
        Frozen dataclass of parameters.
    doc : str
    """

    name: str
    open: Callable[[Any], Driver]
    params: type = NoParams
    doc: str = ""


@dataclass
class _Registry:
    what: str
    items: dict[str, Any] = field(default_factory=dict)

    def add(self, spec: Any) -> None:
        if spec.name in self.items:
            raise ValueError(f"{self.what} {spec.name!r} is registered twice")
        self.items[spec.name] = spec

    def __getitem__(self, name: str) -> Any:
        return self.items[name]

    def __contains__(self, name: object) -> bool:
        return name in self.items

    def names(self) -> list[str]:
        return sorted(self.items)


class StageRegistry(_Registry):
    """Stages by name. Filled through ``inspector_register_stages``."""

    def __init__(self) -> None:
        super().__init__("stage")

    def add(self, spec: StageSpec) -> None:
        if spec.kind not in KINDS:
            raise ValueError(f"stage {spec.name!r}: kind must be one of {', '.join(KINDS)}")
        super().add(spec)


class DriverRegistry(_Registry):
    """Drivers by name. Filled through ``inspector_register_drivers``."""

    def __init__(self) -> None:
        super().__init__("driver")
