"""What a plugin registers: stage and driver specifications.

A stage is a named, typed transformation of an :class:`~inspector.pipeline.InspectionContext`;
a driver yields captures. Both declare their parameters as a frozen dataclass (see
:mod:`inspector.params`) so recipes are validated before anything runs.

What a plugin registers is checked as it registers (:meth:`StageRegistry.add`,
:meth:`DriverRegistry.add`): the name, the callable, the parameter class
(:func:`inspector.params.check_param_class`), the kinds a stage ``requires``, and for an
evaluate stage its declared ``summary`` (:class:`inspector.model.EvaluationSummary`). A
refusal is a :class:`~inspector.errors.PluginError` naming the stage or driver and the field;
the plugin manager turns it into one warning naming the plugin, and disables that plugin.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from inspector.errors import PluginError
from inspector.model import SUMMARY_FIELDS
from inspector.params import NoParams, check_param_class

if TYPE_CHECKING:
    import argparse

    from inspector.model import Capture
    from inspector.pipeline import InspectionContext

__all__ = [
    "KINDS",
    "OUTPUTS",
    "StageSpec",
    "StageRegistry",
    "Acquisition",
    "Driver",
    "DriverSpec",
    "DriverRegistry",
    "CommandSpec",
    "CommandRegistry",
    "SettingsSpec",
    "SettingsRegistry",
]

#: Stage kinds in pipeline order; a stage may only need kinds that come before it.
KINDS = ("segment", "carve", "classify", "align", "bcps", "evaluate")

#: The context attribute each kind of stage sets (the runner checks it is set, and its type).
OUTPUTS = {
    "segment": "silhouettes",
    "carve": "reconstruction",
    "classify": "extras",
    "align": "alignment",
    "bcps": "bcps",
    "evaluate": "evaluation",
}


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
    summary : type, optional
        Evaluate stages only, and required for them: the class of the
        ``Evaluation.summary`` the stage fills, :class:`inspector.model.EvaluationSummary`
        or a dataclass with at least its fields (:data:`inspector.model.SUMMARY_FIELDS`).
    """

    name: str
    run: Callable[[InspectionContext, Any], InspectionContext]
    params: type = NoParams
    requires: tuple[str, ...] = ()
    doc: str = ""
    summary: type | None = None

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
    #: Name -> the plugin that registered it (set by the plugin manager).
    owners: dict[str, str] = field(default_factory=dict)
    #: The plugin whose hook is filling this registry now (set by the plugin manager).
    plugin: str | None = None
    #: Every name a plugin tried to add, valid or not (the manager names them when the
    #: plugin is disabled, so a recipe that uses one is told why it is missing).
    attempted: list[str] = field(default_factory=list)

    def add(self, spec: Any) -> None:
        name = getattr(spec, "name", None)
        if isinstance(name, str):
            self.attempted.append(name)
        self.check(spec)
        if spec.name in self.items:
            first = self.owners.get(spec.name)
            by = f" (by plugin {first!r} and by plugin {self.plugin!r})" if first and self.plugin else ""
            raise PluginError(f"{self.what} {spec.name!r} is registered twice{by}")
        self.items[spec.name] = spec
        if self.plugin is not None:
            self.owners[spec.name] = self.plugin

    def check(self, spec: Any) -> None:
        """Refuse an invalid spec (PluginError naming it and the field)."""
        raise NotImplementedError

    def _check_params(self, spec: Any) -> None:
        try:
            check_param_class(spec.params)
        except TypeError as e:
            raise PluginError(f"{self.what} {spec.name!r}: {e}") from None

    def __getitem__(self, name: str) -> Any:
        return self.items[name]

    def __contains__(self, name: object) -> bool:
        return name in self.items

    def names(self) -> list[str]:
        return sorted(self.items)

    def owner(self, name: str) -> str | None:
        """The plugin that registered ``name`` (None: unknown)."""
        return self.owners.get(name)


class StageRegistry(_Registry):
    """Stages by name. Filled through ``inspector_register_stages``."""

    def __init__(self) -> None:
        super().__init__("stage")

    def add(self, spec: StageSpec) -> None:
        """Add one stage, checked (:meth:`check`); PluginError naming it if invalid."""
        super().add(spec)

    def check(self, spec: Any) -> None:
        if not isinstance(spec, StageSpec):
            raise PluginError(f"registry.add({spec!r}): expected a StageSpec")
        if not isinstance(spec.name, str) or spec.name.count(".") != 1 or not all(spec.name.split(".")):
            raise PluginError(f"stage {spec.name!r}: name must be 'kind.variant', e.g. 'classify.size'")
        if spec.kind not in KINDS:
            raise PluginError(f"stage {spec.name!r}: kind must be one of {', '.join(KINDS)}")
        if not callable(spec.run):
            raise PluginError(f"stage {spec.name!r}: run must be a function run(context, params) -> context")
        if isinstance(spec.requires, str) or not all(r in KINDS for r in spec.requires):
            raise PluginError(f"stage {spec.name!r}: requires must be a tuple of kinds among {', '.join(KINDS)}, "
                              f"got {spec.requires!r}")
        self._check_params(spec)
        if spec.kind == "evaluate":
            _check_summary(spec)
        elif spec.summary is not None:
            raise PluginError(f"stage {spec.name!r}: summary is for evaluate stages only")


def _check_summary(spec: StageSpec) -> None:
    """An evaluate stage declares the summary it fills: EvaluationSummary or a dataclass
    with at least its fields."""
    cls = spec.summary
    if cls is None:
        raise PluginError(f"stage {spec.name!r}: missing field 'summary': an evaluate stage declares "
                          "StageSpec(summary=EvaluationSummary) and fills Evaluation(summary=...) "
                          "(inspector.model), which result.json, the history and the CSV export read")
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise PluginError(f"stage {spec.name!r}: summary {cls!r} is not a dataclass (use inspector.model.EvaluationSummary)")
    have = {f.name for f in dataclasses.fields(cls)}
    missing = [f for f in SUMMARY_FIELDS if f not in have]
    if missing:
        raise PluginError(f"stage {spec.name!r}: summary {cls.__name__} is missing field {missing[0]!r} "
                          f"(an evaluate summary has {', '.join(SUMMARY_FIELDS)}: subclass inspector.model.EvaluationSummary)")


class DriverRegistry(_Registry):
    """Drivers by name. Filled through ``inspector_register_drivers``."""

    def __init__(self) -> None:
        super().__init__("driver")

    def add(self, spec: DriverSpec) -> None:
        """Add one driver, checked (:meth:`check`); PluginError naming it if invalid."""
        super().add(spec)

    def check(self, spec: Any) -> None:
        if not isinstance(spec, DriverSpec):
            raise PluginError(f"registry.add({spec!r}): expected a DriverSpec")
        if not isinstance(spec.name, str) or not spec.name or any(c.isspace() for c in spec.name):
            raise PluginError(f"driver {spec.name!r}: name must be a non-empty word, e.g. 'usb3'")
        if not callable(spec.open):
            raise PluginError(f"driver {spec.name!r}: open must be a function open(params) -> Driver")
        self._check_params(spec)


#: A command name: a lower-case word (``history``, ``my-plc``).
_COMMAND = re.compile(r"^[a-z][a-z0-9_-]*$")


@dataclass(frozen=True)
class CommandSpec:
    """One ``inspector`` sub-command a plugin adds (``inspector NAME ...``).

    Attributes
    ----------
    name : str
        The sub-command, a lower-case word, e.g. ``"history"``.
    add_parser : callable
        ``add_parser(subparsers)``: adds the sub-parser ``name`` to ``subparsers`` (what
        :meth:`argparse.ArgumentParser.add_subparsers` returns) with its arguments, e.g.
        ``subparsers.add_parser("plc", help="...")``. Import heavy libraries in ``run``,
        not here: every command line builds every parser.
    run : callable
        ``run(args) -> int``: the command, given the parsed :class:`argparse.Namespace`
        (``args.plugin_manager`` is the command line's plugin manager); returns the exit
        status. Raise :class:`~inspector.errors.RecipeError` for an invalid command (exit 2,
        one line) and :class:`~inspector.errors.InspectorError` for a failure (exit 3).
    doc : str
        One line shown by ``inspector plugins``.
    """

    name: str
    add_parser: Callable[[argparse._SubParsersAction[Any]], object]
    run: Callable[[argparse.Namespace], int]
    doc: str = ""


class CommandRegistry(_Registry):
    """Sub-commands by name. Filled through ``inspector_register_commands``."""

    def __init__(self) -> None:
        super().__init__("command")

    def add(self, spec: CommandSpec) -> None:
        """Add one command, checked (:meth:`check`); PluginError naming it if invalid."""
        super().add(spec)

    def check(self, spec: Any) -> None:
        if not isinstance(spec, CommandSpec):
            raise PluginError(f"registry.add({spec!r}): expected a CommandSpec")
        if not isinstance(spec.name, str) or not _COMMAND.match(spec.name):
            raise PluginError(f"command {spec.name!r}: name must be a lower-case word, e.g. 'plc'")
        if not callable(spec.add_parser):
            raise PluginError(f"command {spec.name!r}: add_parser must be a function add_parser(subparsers)")
        if not callable(spec.run):
            raise PluginError(f"command {spec.name!r}: run must be a function run(args) -> int")


@dataclass(frozen=True)
class SettingsSpec:
    """A plugin's own recipe table, ``[plugins.NAME]`` (NAME: the plugin's name).

    Attributes
    ----------
    name : str
        The plugin's name (its entry-point name), set by the registry.
    params : type
        Frozen dataclass of :func:`inspector.params.param` fields, validated like a stage's
        parameters when a recipe is loaded; a recipe without the table gets the defaults.
    doc : str
        One line shown by ``inspector plugins``.
    """

    name: str
    params: type
    doc: str = ""


class SettingsRegistry(_Registry):
    """Plugins' recipe settings by plugin name. Filled through ``inspector_register_settings``."""

    def __init__(self) -> None:
        super().__init__("settings")

    def add(self, params: Any, doc: str = "") -> None:
        """Declare this plugin's settings: ``registry.add(MySettings, "one line")``.

        ``params`` is a frozen dataclass of :func:`inspector.params.param` fields, checked
        now (PluginError naming the field when a type or default is not supported).
        """
        spec: SettingsSpec
        if isinstance(params, SettingsSpec):
            spec = params
        else:
            spec = SettingsSpec(self.plugin or "<plugin>", params, doc)
        super().add(spec)

    def check(self, spec: Any) -> None:
        if not (isinstance(spec.params, type) and dataclasses.is_dataclass(spec.params)):
            raise PluginError(f"settings of plugin {spec.name!r}: {spec.params!r} is not a dataclass of param() fields")
        self._check_params(spec)
