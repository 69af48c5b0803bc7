"""The plugin manager: built by a factory, used only through typed methods.

:func:`create_plugin_manager` adds the hookspecs, loads every plugin of the ``inspector``
entry-point group (built-ins included: they are declared in this project's
``pyproject.toml`` like any third-party plugin), honours a block list, and checks that every
hook implementation matches a spec. The core never calls ``pm.hook`` directly: it calls
the methods of :class:`PluginManager`.

One broken plugin never stops the others. Each entry point is loaded and validated on its
own; a plugin that fails to import, implements a hook that does not exist (a misspelled
name: pluggy's ``check_pending``) or with arguments the hook does not have, raises in its
registry hook or registers an invalid stage or driver (:mod:`inspector.registry`) is
*disabled*: it is unregistered, and it costs one warning line naming the plugin, its
distribution and version, the reason, and how to block it. Two plugins that register the same
stage or driver name are named both, and neither's is used. A plugin that defines no hook
implementation (``@hookimpl`` forgotten) is reported. Every command goes on; only a recipe
that uses a stage or driver of a disabled plugin is refused, naming the plugin
(:meth:`PluginManager.missing`). Plugins registered from code (``plugins=``,
:meth:`PluginManager.register`: tests, an embedding application) are checked the same way,
but raise :class:`~inspector.errors.PluginError` instead: the mistake is the caller's.

Lifecycle hooks are timed per plugin: each call returns ``{"hook:PLUGIN:HOOK": seconds}``
(``HOOK`` without its ``inspector_`` prefix), which the runner adds to ``timings_s``.

A plugin may declare the plugin API it was written for, a module attribute
``INSPECTOR_API = ">=1.0,<2"`` (comparisons of ``MAJOR.MINOR``, comma-separated; ``~=1.0``
means ``>=1.0,<2``) checked against :data:`inspector.API_VERSION` when it loads: a plugin made
for another API is disabled with one line saying which API it needs and which this
installation provides.

What a manager holds can be narrowed for a plugin's own tests (``only=``: the built-ins plus
the named entry points, so a broken plugin elsewhere on the machine cannot fail them), and
widened for development (``files=``: a local ``.py`` module loaded as a plugin, what
``inspector --plugin FILE.py`` does; never from a recipe).
"""

from __future__ import annotations

import difflib
import functools
import importlib.util
import os
import re
import sys
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pluggy

from inspector import API_VERSION, hookspecs
from inspector.errors import PluginError
from inspector.registry import CommandRegistry, DriverRegistry, SettingsRegistry, StageRegistry

if TYPE_CHECKING:
    from inspector.model import InspectionResult
    from inspector.pipeline import InspectionContext
    from inspector.recipe import Recipe
    from inspector.registry import CommandSpec, DriverSpec, SettingsSpec, StageSpec, _Registry
    from inspector.session import RunSummary

__all__ = ["ENTRY_POINT_GROUP", "BLOCK_ENV", "API_ATTR", "BUILTIN_DIST", "PluginInfo", "PluginProblem", "PluginManager",
           "create_plugin_manager", "hook_key", "api_problem"]

ENTRY_POINT_GROUP = "inspector"
#: Comma-separated entry-point names not to load, e.g. ``INSPECTOR_BLOCK_PLUGINS=my_plc``.
BLOCK_ENV = "INSPECTOR_BLOCK_PLUGINS"

#: The module attribute in which a plugin declares the API versions it works with.
API_ATTR = "INSPECTOR_API"
#: The distribution whose entry points are the built-in plugins.
BUILTIN_DIST = "inspector-bcps"

#: (hook, kind, registry class), in the order the registries are filled.
_REGISTRY_HOOKS: tuple[tuple[str, str, type[_Registry]], ...] = (
    ("inspector_register_stages", "stage", StageRegistry),
    ("inspector_register_drivers", "driver", DriverRegistry),
    ("inspector_register_commands", "command", CommandRegistry),
    ("inspector_register_settings", "settings", SettingsRegistry),
)
_KINDS = tuple(k for _, k, _ in _REGISTRY_HOOKS)
_HOOKS = sorted(n for n in vars(hookspecs) if n.startswith("inspector_"))


def hook_key(plugin: str, hook: str) -> str:
    """The ``timings_s`` key of ``plugin``'s implementation of ``hook``:
    ``"hook:PLUGIN:HOOK"``, e.g. ``"hook:history:on_result"``."""
    return f"hook:{plugin}:{hook.removeprefix('inspector_')}"


@dataclass(frozen=True)
class PluginInfo:
    """Where a plugin comes from.

    Attributes
    ----------
    name : str
        Its name in the plugin manager: the entry-point name (what ``INSPECTOR_BLOCK_PLUGINS``
        takes), or the name it was registered with from code.
    dist, version : str or None
        Its distribution and version (None: registered from code).
    value : str or None
        The entry point's ``module:attr``, or the file of a ``--plugin FILE.py``.
    file : bool
        Loaded from a file for development (``inspector --plugin FILE.py``).
    """

    name: str
    dist: str | None = None
    version: str | None = None
    value: str | None = None
    file: bool = False

    @property
    def from_code(self) -> bool:
        """Registered from code or from a ``--plugin`` file: its problems raise PluginError."""
        return self.dist is None

    @property
    def builtin(self) -> bool:
        return self.dist == BUILTIN_DIST

    def label(self) -> str:
        """``plugin 'acme' (acme-inspect 1.2)``."""
        if self.file:
            return f"plugin {self.name!r} (file {self.value})"
        where = f" ({self.dist} {self.version})" if self.dist else ""
        return f"plugin {self.name!r}{where}"


@dataclass(frozen=True)
class PluginProblem:
    """One problem of a plugin, reported once as a warning line.

    Attributes
    ----------
    plugin : PluginInfo
    reason : str
        One line.
    disabled : bool
        The plugin was unregistered (False: reported, still registered).
    provides : tuple of str
        ``"stage NAME"`` / ``"driver NAME"`` it registers or tried to (empty: unknown, e.g.
        it could not be imported).
    fix : str
        What to do, when not "fix it or block it".
    """

    plugin: PluginInfo
    reason: str
    disabled: bool = True
    provides: tuple[str, ...] = ()
    fix: str = ""

    def message(self) -> str:
        """The warning, one line: the plugin, distribution and version, the reason, the fix."""
        block = f"block it with {BLOCK_ENV}={self.plugin.name}"
        state = " disabled" if self.disabled else ""
        fix = f"{self.fix}, or {block}" if self.fix else block
        if self.plugin.file:
            fix = self.fix or "fix the file"
        return f"{self.plugin.label()}{state}: {self.reason}; {fix}"


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _exc(e: BaseException) -> str:
    return f"{type(e).__name__}: {_one_line(e)}"


def _where(e: BaseException) -> str:
    """`` (at FILE:LINE)`` of the innermost frame outside importlib, for an import error."""
    frames = [f for f in traceback.extract_tb(e.__traceback__)
              if not f.filename.startswith("<frozen") and f"{os.sep}importlib{os.sep}" not in f.filename
              and Path(f.filename).name != "metadata.py" and f.filename != __file__]
    return f" (at {frames[-1].filename}:{frames[-1].lineno})" if frames else ""


class PluginManager:
    """Typed façade over :class:`pluggy.PluginManager`.

    Attributes
    ----------
    pm : pluggy.PluginManager
        The underlying manager (for registering extra plugins in tests or apps).
    """

    def __init__(self, pm: pluggy.PluginManager, *, warn: Callable[[str], None] | None = None) -> None:
        self.pm = pm
        #: kind -> merged registry (None: not built yet).
        self._regs: dict[str, _Registry] | None = None
        #: plugin -> kind -> names it registered (valid ones).
        self._provided: dict[str, dict[str, list[str]]] = {}
        self._info: dict[str, PluginInfo] = {}
        self._problems: list[PluginProblem] = []
        self._reported: set[str] = set()
        #: (kind, name) -> why it is not in the registry (a disabled plugin, a duplicate).
        self._missing: dict[tuple[str, str], str] = {}
        self._blocked: set[str] = set()
        self._warn = warn if warn is not None else _stderr

    # -- loading -------------------------------------------------------------------
    def load_entrypoints(self, group: str = ENTRY_POINT_GROUP, *, only: Iterable[str] | None = None) -> None:
        """Load every entry point of ``group``, each on its own (see the module's doc).

        ``only``: load just these entry-point names besides the built-ins (those of
        :data:`BUILTIN_DIST`); None loads every one.
        """
        import importlib.metadata

        wanted = None if only is None else set(only)
        for dist in list(importlib.metadata.distributions()):
            for ep in dist.entry_points:
                if ep.group != group:
                    continue
                if wanted is not None and ep.name not in wanted and dist.metadata["Name"] != BUILTIN_DIST:
                    continue
                first = self._info.get(ep.name)
                if first is not None and first.dist is not None and first.dist != dist.metadata["Name"]:
                    other = PluginInfo(ep.name, dist.metadata["Name"] or "?", dist.version or "?", ep.value)
                    self._problem(PluginProblem(other, f"its entry-point name is also {first.label()}'s, which is "
                                                       "the one loaded", disabled=True,
                                                fix="rename one of the entry points"))
                if first is not None or self.pm.has_plugin(ep.name):
                    continue
                info = PluginInfo(ep.name, dist.metadata["Name"] or "?", dist.version or "?", ep.value)
                if self.pm.is_blocked(ep.name):
                    self._blocked.add(ep.name)
                    self._info.setdefault(ep.name, info)
                    continue
                self._info[ep.name] = info
                try:
                    plugin = ep.load()
                except (Exception, SystemExit) as e:  # noqa: BLE001 - a vendor SDK missing on the cell PC
                    self._problem(PluginProblem(info, f"cannot be imported: {_exc(e)}{_where(e)}"))
                    continue
                self._add(plugin, info)

    def load_file(self, path: str | os.PathLike[str]) -> str:
        """Load a local module as a plugin, for development (``inspector --plugin FILE.py``);
        its name is the file's stem. Never called for a recipe: recipes stay data.

        Raises
        ------
        PluginError
            The file is missing, does not import, or its hooks or what it registers are
            invalid (one line naming the file).
        """
        file = Path(path)
        name = file.stem
        info = PluginInfo(name, value=str(path), file=True)
        if not file.is_file() or file.suffix != ".py":
            raise PluginError(f"--plugin {path}: not a Python file")
        if name in self._info or self.pm.has_plugin(name):
            raise PluginError(f"--plugin {path}: a plugin named {name!r} is already loaded; rename the file")
        spec = importlib.util.spec_from_file_location(f"inspector_dev_plugin_{name}", file)
        if spec is None or spec.loader is None:
            raise PluginError(f"--plugin {path}: cannot be loaded as a module")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        try:
            spec.loader.exec_module(module)
        except (Exception, SystemExit) as e:  # noqa: BLE001 - one line, not a traceback
            sys.modules.pop(spec.name, None)
            raise PluginError(f"{info.label()}: cannot be imported: {_exc(e)}{_where(e)}") from None
        self._info[name] = info
        try:
            self._add(module, info)
        except pluggy.PluginValidationError as e:
            raise PluginError(_one_line(e)) from None
        self._regs = None
        return name

    def register(self, plugin: object, name: str | None = None) -> None:
        """Register one more plugin from code (resets the cached registries).

        Raises
        ------
        PluginError
            Its hooks do not match the hookspecs (it is not registered), or, when the
            registries are next built, what it registers is invalid.
        """
        self._add(plugin, None, name=name)
        self._regs = None

    def _add(self, plugin: object, info: PluginInfo | None, *, name: str | None = None) -> None:
        """Register ``plugin`` and check its hooks; an entry point's problem disables it."""
        if info is None and name is None:  # its class's or module's name, not pluggy's id()
            named = getattr(plugin, "__name__", None) or type(plugin).__name__
            name = named if self.pm.get_plugin(named) is None and not self.pm.is_blocked(named) else None
        try:
            pname = self.pm.register(plugin, name=info.name if info is not None else name)
        except pluggy.PluginValidationError as e:  # a hook with arguments its spec lacks
            if self.pm.is_registered(plugin):  # pluggy leaves it half-registered
                self.pm.unregister(plugin)
            if info is None:
                raise
            if info.file:
                raise PluginError(f"{info.label()}: a hook does not match its hookspec: {_one_line(e)}") from None
            self._problem(PluginProblem(info, f"a hook does not match its hookspec: {_one_line(e)}",
                                        provides=_probe(plugin)))
            return
        if pname is None:  # blocked
            return
        if info is None:
            info = PluginInfo(pname)
            self._info[pname] = info
        wrong_api = api_problem(plugin)
        if wrong_api is not None:
            self.pm.unregister(plugin)
            if info.from_code:
                raise PluginError(f"{info.label()}: {wrong_api}")
            self._problem(PluginProblem(info, wrong_api, provides=_probe(plugin),
                                        fix=f"install a version of {info.dist} made for API {_api()}"))
            return
        try:
            self.pm.check_pending()
        except pluggy.PluginValidationError:
            unknown = [hc.name for hc in (self.pm.get_hookcallers(plugin) or []) if not hc.has_spec()]
            self.pm.unregister(plugin)
            reason = "; ".join(_unknown_hook(n) for n in unknown) or "a hook without hookspec"
            if info.from_code:
                if info.file:
                    raise PluginError(f"{info.label()}: {reason}") from None
                raise pluggy.PluginValidationError(plugin, f"{info.label()}: {reason}") from None
            self._problem(PluginProblem(info, reason, provides=_probe(plugin)))
            return
        forgotten = _unmarked(plugin)
        if not self.pm.get_hookcallers(plugin):
            hint = f" ({', '.join(forgotten)} lacks @hookimpl)" if forgotten else ""
            self._problem(PluginProblem(info, f"defines no hook implementation{hint}, so it does nothing",
                                        disabled=False, fix="mark each hook function with @inspector.hookimpl"))
        elif forgotten:
            self._problem(PluginProblem(info, f"{', '.join(forgotten)} lacks @hookimpl and never runs",
                                        disabled=False, fix="mark it with @inspector.hookimpl"))

    def _problem(self, problem: PluginProblem) -> None:
        self._problems.append(problem)
        msg = problem.message()
        if msg not in self._reported:
            self._reported.add(msg)
            self._warn(f"inspector: warning: {msg}")
        for what in problem.provides:
            kind, _, name = what.partition(" ")
            self._missing.setdefault((kind, name), f"{what} is not available: {problem.plugin.label()} is disabled "
                                                   f"({problem.reason})")

    @property
    def problems(self) -> tuple[PluginProblem, ...]:
        """Every plugin problem found so far (each also reported once as a warning)."""
        self.build()
        return tuple(self._problems)

    def info(self, name: str) -> PluginInfo:
        """Where plugin ``name`` comes from."""
        return self._info.get(name) or PluginInfo(name)

    # -- registries ----------------------------------------------------------------
    @property
    def stages(self) -> StageRegistry:
        reg = self._registry("stage")
        assert isinstance(reg, StageRegistry)
        return reg

    @property
    def drivers(self) -> DriverRegistry:
        reg = self._registry("driver")
        assert isinstance(reg, DriverRegistry)
        return reg

    @property
    def commands(self) -> CommandRegistry:
        """The sub-commands plugins add (``inspector_register_commands``)."""
        reg = self._registry("command")
        assert isinstance(reg, CommandRegistry)
        return reg

    @property
    def settings(self) -> SettingsRegistry:
        """Plugins' recipe settings by plugin name (``inspector_register_settings``)."""
        reg = self._registry("settings")
        assert isinstance(reg, SettingsRegistry)
        return reg

    def _registry(self, kind: str) -> _Registry:
        self.build()
        assert self._regs is not None
        return self._regs[kind]

    def build(self) -> None:
        """Fill the registries, each plugin's registry hooks called on their own (nothing to do
        while they are filled; every query of the registries calls it first)."""
        if self._regs is not None:
            return
        # Phase 1: each plugin into registries of its own; a plugin that raises or registers
        # something invalid is disabled whole (its other hooks would see a half-registered plugin).
        own: list[tuple[str, dict[str, _Registry]]] = []
        callers = {hook: {id(i.plugin): i for i in getattr(self.pm.hook, hook).get_hookimpls()
                          if not (i.hookwrapper or i.wrapper)} for hook, _, _ in _REGISTRY_HOOKS}
        for name, plugin in list(self.pm.list_name_plugin()):
            if plugin is None:  # blocked
                continue
            regs: dict[str, _Registry] = {kind: cls() for _, kind, cls in _REGISTRY_HOOKS}  # type: ignore[call-arg]
            tried: list[str] = []
            hook = ""
            try:
                for hook, kind, _ in _REGISTRY_HOOKS:
                    reg = regs[kind]
                    reg.plugin = name
                    impl = callers[hook].get(id(plugin))
                    if impl is not None:
                        try:
                            impl.function(**{a: reg for a in impl.argnames if a == "registry"})
                        finally:
                            tried += [f"{kind} {n}" for n in reg.attempted]
            except Exception as e:
                info = self.info(name)
                reason = _one_line(e) if isinstance(e, PluginError) else f"{hook} raised {_exc(e)}"
                if info.from_code:
                    raise PluginError(f"{info.label()}: {reason}") from e
                self.pm.unregister(plugin)
                self._problem(PluginProblem(info, reason, provides=tuple(dict.fromkeys(tried))))
                continue
            own.append((name, regs))
            self._provided[name] = {kind: sorted(reg.items) for kind, reg in regs.items()}
        # Phase 2: merge; a name two plugins register is ambiguous: neither is used.
        merged_all: dict[str, _Registry] = {}
        for _, kind, cls in _REGISTRY_HOOKS:
            merged = cls()  # type: ignore[call-arg]
            merged_all[kind] = merged
            claims: dict[str, list[tuple[str, Any]]] = {}
            for owner, regs in own:
                for n, spec in regs[kind].items.items():
                    claims.setdefault(n, []).append((owner, spec))
            for n, owners in claims.items():
                if len(owners) == 1:
                    merged.items[n] = owners[0][1]
                    merged.owners[n] = owners[0][0]
                    continue
                infos = sorted((self.info(o) for o, _ in owners), key=lambda i: i.name)  # stable wording
                both = " and by ".join(i.label() for i in infos)
                text = f"{merged.what} {n!r} is registered twice, by {both}"
                if any(i.from_code for i in infos):
                    raise PluginError(text)
                last = infos[-1]
                block = " or ".join(f"{BLOCK_ENV}={i.name}" for i in infos)
                self._missing[(merged.what, n)] = f"{text}; block one with {block}"
                msg = f"{text}: neither is used; block one with {block}"
                if msg not in self._reported:
                    self._reported.add(msg)
                    self._problems.append(PluginProblem(last, f"{merged.what} {n!r} is also registered by "
                                                              f"{infos[0].label()}", disabled=False))
                    self._warn(f"inspector: warning: {msg}")
        self._regs = merged_all

    def plugin_names(self) -> list[str]:
        """The registered plugins (not the blocked or disabled ones)."""
        return sorted(n for n, p in self.pm.list_name_plugin() if p is not None)

    @property
    def blocked(self) -> tuple[str, ...]:
        """Entry points not loaded because they are blocked."""
        return tuple(sorted(self._blocked))

    def provides(self, name: str) -> dict[str, list[str]]:
        """What plugin ``name`` provides: ``{"stage": [...], "driver": [...], "command": [...],
        "settings": [...], "hook": [...]}`` (hooks without their ``inspector_`` prefix, registry
        hooks left out); empty lists for a blocked or disabled plugin."""
        self.build()
        out = {kind: list(names) for kind, names in self._provided.get(name, {}).items()}
        for kind in _KINDS:
            out.setdefault(kind, [])
        plugin = self.pm.get_plugin(name)
        hooks = [] if plugin is None else sorted(
            hc.name.removeprefix("inspector_") for hc in (self.pm.get_hookcallers(plugin) or [])
            if hc.name not in {h for h, _, _ in _REGISTRY_HOOKS})
        out["hook"] = hooks
        return out

    def plugins(self) -> list[dict[str, Any]]:
        """Every plugin known to this manager, loaded or not, by name: ``name``, ``dist``,
        ``version``, ``builtin``, ``status`` (``"loaded"``, ``"blocked"``, ``"disabled"``),
        ``problems`` (its warning lines) and what it ``provides`` (:meth:`provides`)."""
        self.build()
        loaded = set(self.plugin_names())
        rows = []
        for name in sorted(set(self._info) | loaded | self._blocked):
            info = self.info(name)
            status = "loaded" if name in loaded else "blocked" if name in self._blocked else "disabled"
            rows.append({
                "name": name, "dist": info.dist, "version": info.version, "builtin": info.builtin,
                "file": info.value if info.file else None, "status": status,
                "problems": [p.message() for p in self._problems if p.plugin.name == name],
                "provides": self.provides(name),
            })
        return rows

    def stage_plugin(self, name: str) -> str:
        """``plugin 'NAME'``: who registered stage ``name`` (for messages)."""
        owner = self.stages.owner(name)
        return f"plugin {owner!r}" if owner else "an unknown plugin"

    def missing(self, kind: str, name: str) -> str:
        """Why ``kind`` (``"stage"``, ``"driver"``, ``"command"`` or ``"settings"``) ``name``
        is not registered, in one line that names the plugin when one is to blame (disabled,
        a duplicate name), or lists the known names and the plugins that failed to load
        (which may provide it)."""
        self.build()
        if (kind, name) in self._missing:
            return self._missing[(kind, name)]
        reg = self._registry(kind)
        if kind == "settings":
            text = (f"no plugin {name!r} with settings (plugins with settings: {', '.join(reg.names()) or 'none'})")
            if name in self._blocked:
                return f"{text}; {name!r} is blocked ({BLOCK_ENV} or --block)"
            why = [p for p in self._problems if p.plugin.name == name and p.disabled]
            if why:
                return f"{text}; {why[0].plugin.label()} is disabled ({why[0].reason})"
        else:
            text = f"unknown {kind} {name!r} (known: {', '.join(reg.names()) or 'none'})"
        unknown = [p for p in self._problems if p.disabled and not p.provides]
        if unknown:
            text += "; " + "; ".join(f"{p.plugin.label()} may provide it but is disabled ({p.reason})" for p in unknown)
        blocked = sorted(self._blocked)
        if blocked:
            text += f"; blocked by {BLOCK_ENV}: {', '.join(blocked)}"
        return text

    # -- lifecycle -----------------------------------------------------------------
    # Lifecycle hooks observe; one that raises (a PLC off the network, a full disk) must not
    # stop the inspection, the batch, or the other plugins: each implementation is called on
    # its own and a failure is one warning line naming the plugin. Each returns the time of
    # each implementation, by hook_key().
    def on_run_start(self, recipe: Recipe, outdir: Path, source: str) -> dict[str, float]:
        return self._observe("inspector_on_run_start", f"run of {recipe.name}", recipe=recipe, outdir=outdir, source=source)

    def on_run_end(self, recipe: Recipe, outdir: Path, summary: RunSummary) -> dict[str, float]:
        return self._observe("inspector_on_run_end", f"run of {recipe.name}", recipe=recipe, outdir=outdir, summary=summary)

    def before_stage(self, context: InspectionContext, stage: StageSpec, step: str) -> dict[str, float]:
        return self._observe("inspector_before_stage", f"{context.capture.name}/{step}", context=context, stage=stage,
                             step=step)

    def after_stage(self, context: InspectionContext, stage: StageSpec, step: str, seconds: float) -> dict[str, float]:
        return self._observe("inspector_after_stage", f"{context.capture.name}/{step}", context=context, stage=stage,
                             step=step, seconds=seconds)

    def on_stage_error(self, context: InspectionContext, stage: StageSpec, step: str,
                       error: BaseException) -> dict[str, float]:
        return self._observe("inspector_on_stage_error", f"{context.capture.name}/{step}", context=context, stage=stage,
                             step=step, error=error)

    def on_result(self, result: InspectionResult, outdir: Path | None) -> dict[str, float]:
        return self._observe("inspector_on_result", result.capture, result=result, outdir=outdir)

    def _observe(self, hook: str, what: str, **kwargs: object) -> dict[str, float]:
        caller = getattr(self.pm.hook, hook)
        impls = caller.get_hookimpls()
        calls: list[tuple[str | None, Callable[[], object]]]
        if any(i.wrapper or i.hookwrapper for i in impls):  # wrappers need pluggy's own call
            calls = [(None, lambda: caller(**kwargs))]
        else:  # pluggy's order: last registered first
            calls = [(str(i.plugin_name), functools.partial(_call_impl, i, kwargs)) for i in reversed(impls)]
        times: dict[str, float] = {}
        for name, call in calls:
            t0 = time.perf_counter()
            try:
                call()
            except Exception as e:  # noqa: BLE001 - reported, never raised
                who = "a plugin" if name is None else f"plugin {name!r}"
                print(f"inspector: warning: {who} failed on {what} ({hook}): {_exc(e)}", file=sys.stderr, flush=True)
            finally:
                key = hook_key(name or "*", hook)
                times[key] = times.get(key, 0.0) + time.perf_counter() - t0
        return times

    def gui_panels(self, window: object) -> list[tuple[str, object]]:
        """``(plugin name, what inspector_gui_panel returned or the exception it raised)``
        for each implementation, each called on its own (the GUI checks and reports)."""
        out: list[tuple[str, object]] = []
        for impl in reversed(self.pm.hook.inspector_gui_panel.get_hookimpls()):
            try:
                value: object = impl.function(window=window)
            except Exception as e:  # noqa: BLE001 - reported by the GUI, never raised
                value = e
            out.append((str(impl.plugin_name), value))
        return out

    # -- lookups used by recipes -----------------------------------------------------
    def stage(self, name: str) -> StageSpec:
        spec: StageSpec = self.stages[name]
        return spec

    def driver(self, name: str) -> DriverSpec:
        spec: DriverSpec = self.drivers[name]
        return spec

    def command(self, name: str) -> CommandSpec:
        spec: CommandSpec = self.commands[name]
        return spec

    def settings_spec(self, plugin: str) -> SettingsSpec:
        spec: SettingsSpec = self.settings[plugin]
        return spec


def _call_impl(impl: pluggy.HookImpl, kwargs: dict[str, object]) -> object:
    return impl.function(**{a: kwargs[a] for a in impl.argnames})


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _unknown_hook(name: str) -> str:
    close = difflib.get_close_matches(name, _HOOKS, n=1)
    hint = f" (did you mean {close[0]}?)" if close else f" (hooks: {', '.join(_HOOKS)})"
    return f"implements {name}, which is no hook{hint}"


def _unmarked(plugin: object) -> list[str]:
    """Functions of ``plugin`` named like a hook but without ``@hookimpl``."""
    out = []
    for attr in dir(plugin):
        if not attr.startswith("inspector_"):
            continue
        try:
            value = getattr(plugin, attr)
        except Exception:  # noqa: BLE001 - a property that raises is no hook
            continue
        if callable(value) and not hasattr(value, f"{hookspecs.PROJECT}_impl") \
                and not hasattr(value, f"{hookspecs.PROJECT}_spec"):
            out.append(attr)
    return out


def _probe(plugin: object) -> tuple[str, ...]:
    """``"stage NAME"`` / ``"driver NAME"`` that a plugin disabled at load would have
    registered (its marked registry hooks, called on throwaway registries), best effort."""
    import inspect

    out: list[str] = []
    for hook, kind, cls in _REGISTRY_HOOKS:
        reg = cls()  # type: ignore[call-arg]
        fn = getattr(plugin, hook, None)
        if not callable(fn) or not hasattr(fn, f"{hookspecs.PROJECT}_impl"):
            continue
        try:
            fn(**({"registry": reg} if "registry" in inspect.signature(fn).parameters else {}))
        except Exception:  # noqa: BLE001 - best effort: what it added before raising still counts
            pass
        out += [f"{kind} {n}" for n in reg.attempted]
    return tuple(dict.fromkeys(out))


def _api() -> str:
    return API_VERSION


def _version(text: str) -> tuple[int, ...]:
    parts = text.strip().split(".")
    if not all(p.isdigit() for p in parts):
        raise ValueError(text)
    return tuple(int(p) for p in parts)


_API_CLAUSE = re.compile(r"^\s*(>=|<=|==|!=|~=|>|<)?\s*([0-9][0-9.]*)\s*$")


def api_problem(plugin: object, api: str | None = None) -> str | None:
    """Why ``plugin``'s declared ``INSPECTOR_API`` range excludes ``api`` (default: this
    installation's :data:`inspector.API_VERSION`), in words; None when it has no such
    attribute or the range holds."""
    spec = getattr(plugin, API_ATTR, None)
    if spec is None:
        return None
    api = api or _api()
    if not isinstance(spec, str) or not spec.strip():
        return f"{API_ATTR} = {spec!r} is not a version range like '>=1.0,<2'"
    have = _version(api)
    for clause in spec.split(","):
        m = _API_CLAUSE.match(clause)
        if m is None:
            return f"{API_ATTR} = {spec!r} is not a version range like '>=1.0,<2'"
        op, want = m.group(1) or "==", _version(m.group(2))
        n = max(len(have), len(want))
        a, b = have + (0,) * (n - len(have)), want + (0,) * (n - len(want))
        ok = {">=": a >= b, "<=": a <= b, ">": a > b, "<": a < b, "==": a == b, "!=": a != b,
              "~=": a >= b and a[:max(1, len(want) - 1)] == b[:max(1, len(want) - 1)]}[op]
        if not ok:
            return f"needs inspector plugin API {spec.strip()}, this inspector provides API {api}"
    return None


def create_plugin_manager(
    *,
    load_entrypoints: bool = True,
    block: Iterable[str] | None = None,
    plugins: Iterable[object] = (),
    warn: Callable[[str], None] | None = None,
    only: Iterable[str] | None = None,
    files: Iterable[str | os.PathLike[str]] = (),
) -> PluginManager:
    """Build a fresh plugin manager.

    Parameters
    ----------
    load_entrypoints : bool
        Load the ``inspector`` entry-point group (built-ins and installed third-party plugins),
        each entry point on its own: a broken one is disabled with one warning.
    block : iterable of str, optional
        Entry-point names not to load; defaults to ``$INSPECTOR_BLOCK_PLUGINS``.
    plugins : iterable of objects
        Extra plugins to register (tests, embedding applications); a broken one raises
        :class:`~inspector.errors.PluginError`.
    warn : callable, optional
        Receives each plugin warning line (default: printed on stderr), once.
    only : iterable of str, optional
        Load just these entry points besides the built-ins (a plugin's own tests: see
        :mod:`inspector_tools.testing`); None loads every installed plugin.
    files : iterable of paths
        Local ``.py`` modules to load as plugins (``inspector --plugin FILE.py``); a broken
        one raises :class:`~inspector.errors.PluginError` naming the file.

    The registries are built before it returns, so every plugin problem is reported here.
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    blocked = set(block) if block is not None else {b.strip() for b in os.environ.get(BLOCK_ENV, "").split(",") if b.strip()}
    for name in blocked:
        pm.set_blocked(name)
    manager = PluginManager(pm, warn=warn)
    if load_entrypoints:
        manager.load_entrypoints(ENTRY_POINT_GROUP, only=only)
    for file in files:
        manager.load_file(file)
    for plugin in plugins:
        manager.register(plugin)
    manager.build()
    return manager
