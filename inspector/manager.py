"""The plugin manager: built by a factory, used only through typed methods.

:func:`create_plugin_manager` adds the hookspecs, loads every plugin of the ``inspector``
entry-point group (built-ins included: they are declared in this project's
``pyproject.toml`` like any third-party plugin), honours a block list, and checks that every
hook implementation matches a spec. The core never calls ``pm.hook`` directly: it calls
the methods of :class:`PluginManager`.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import pluggy

from inspector import hookspecs
from inspector.registry import DriverRegistry, StageRegistry

if TYPE_CHECKING:
    from inspector.model import InspectionResult
    from inspector.recipe import Recipe
    from inspector.session import RunSummary
    from inspector.pipeline import InspectionContext
    from inspector.registry import DriverSpec, StageSpec

__all__ = ["ENTRY_POINT_GROUP", "BLOCK_ENV", "PluginManager", "create_plugin_manager"]

ENTRY_POINT_GROUP = "inspector"
#: Comma-separated entry-point names not to load, e.g. ``INSPECTOR_BLOCK_PLUGINS=my_plc``.
BLOCK_ENV = "INSPECTOR_BLOCK_PLUGINS"


class PluginManager:
    """Typed façade over :class:`pluggy.PluginManager`.

    Attributes
    ----------
    pm : pluggy.PluginManager
        The underlying manager (for registering extra plugins in tests or apps).
    """

    def __init__(self, pm: pluggy.PluginManager) -> None:
        self.pm = pm
        self._stages: StageRegistry | None = None
        self._drivers: DriverRegistry | None = None

    # -- registries ----------------------------------------------------------------
    def register(self, plugin: object, name: str | None = None) -> None:
        """Register one more plugin (resets the cached registries)."""
        self.pm.register(plugin, name=name)
        self.pm.check_pending()
        self._stages = self._drivers = None

    @property
    def stages(self) -> StageRegistry:
        if self._stages is None:
            reg = StageRegistry()
            self.pm.hook.inspector_register_stages(registry=reg)
            self._stages = reg
        return self._stages

    @property
    def drivers(self) -> DriverRegistry:
        if self._drivers is None:
            reg = DriverRegistry()
            self.pm.hook.inspector_register_drivers(registry=reg)
            self._drivers = reg
        return self._drivers

    def plugin_names(self) -> list[str]:
        return sorted(n for n, _ in self.pm.list_name_plugin())

    # -- lifecycle -----------------------------------------------------------------
    # Lifecycle hooks observe; one that raises (a PLC off the network, a full disk) must not
    # stop the inspection, the batch, or the other plugins: each implementation is called on
    # its own and a failure is one warning line naming the plugin.
    def on_run_start(self, recipe: Recipe, outdir: Path, source: str) -> None:
        self._observe("inspector_on_run_start", f"run of {recipe.name}", recipe=recipe, outdir=outdir, source=source)

    def on_run_end(self, recipe: Recipe, outdir: Path, summary: RunSummary) -> None:
        self._observe("inspector_on_run_end", f"run of {recipe.name}", recipe=recipe, outdir=outdir, summary=summary)

    def before_stage(self, context: InspectionContext, stage: StageSpec, step: str) -> None:
        self._observe("inspector_before_stage", f"{context.capture.name}/{step}", context=context, stage=stage, step=step)

    def after_stage(self, context: InspectionContext, stage: StageSpec, step: str, seconds: float) -> None:
        self._observe("inspector_after_stage", f"{context.capture.name}/{step}", context=context, stage=stage, step=step,
                      seconds=seconds)

    def on_stage_error(self, context: InspectionContext, stage: StageSpec, step: str, error: BaseException) -> None:
        self._observe("inspector_on_stage_error", f"{context.capture.name}/{step}", context=context, stage=stage,
                      step=step, error=error)

    def on_result(self, result: InspectionResult, outdir: Path | None) -> None:
        self._observe("inspector_on_result", result.capture, result=result, outdir=outdir)

    def _observe(self, hook: str, what: str, **kwargs: object) -> None:
        caller = getattr(self.pm.hook, hook)
        impls = caller.get_hookimpls()
        if any(i.wrapper or i.hookwrapper for i in impls):  # wrappers need pluggy's own call
            calls = [(self._name(None), lambda: caller(**kwargs))]
        else:  # pluggy's order: last registered first
            calls = [(self._name(i), lambda i=i: i.function(**{a: kwargs[a] for a in i.argnames})) for i in reversed(impls)]
        for name, call in calls:
            try:
                call()
            except Exception as e:  # noqa: BLE001 - reported, never raised
                msg = " ".join(str(e).split())
                print(f"inspector: warning: {name} failed on {what} ({hook}): {type(e).__name__}: {msg}",
                      file=sys.stderr, flush=True)

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

    @staticmethod
    def _name(impl: object | None) -> str:
        return "a plugin" if impl is None else f"plugin {getattr(impl, 'plugin_name', '?')!r}"

    # -- lookups used by recipes -----------------------------------------------------
    def stage(self, name: str) -> StageSpec:
        return self.stages[name]

    def driver(self, name: str) -> DriverSpec:
        return self.drivers[name]


def create_plugin_manager(
    *,
    load_entrypoints: bool = True,
    block: Iterable[str] | None = None,
    plugins: Iterable[object] = (),
) -> PluginManager:
    """Build a fresh plugin manager.

    Parameters
    ----------
    load_entrypoints : bool
        Load the ``inspector`` entry-point group (built-ins and installed third-party plugins).
    block : iterable of str, optional
        Entry-point names not to load; defaults to ``$INSPECTOR_BLOCK_PLUGINS``.
    plugins : iterable of objects
        Extra plugins to register (tests, embedding applications).
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    blocked = set(block) if block is not None else {b.strip() for b in os.environ.get(BLOCK_ENV, "").split(",") if b.strip()}
    for name in blocked:
        pm.set_blocked(name)
    if load_entrypoints:
        pm.load_setuptools_entrypoints(ENTRY_POINT_GROUP)
    for plugin in plugins:
        pm.register(plugin)
    pm.check_pending()
    return PluginManager(pm)
