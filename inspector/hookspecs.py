"""Every hook Inspector calls, in one module (the plugin API).

A plugin is a module or object with functions named like these hooks, decorated with
:data:`inspector.hookimpl`, and advertised in the ``inspector`` entry-point group of its
distribution::

    [project.entry-points.inspector]
    my_stage = "my_package.my_module"

Built-in stages and drivers are registered exactly this way (see ``pyproject.toml``).

Three kinds of hooks:

* **registry hooks** are called once when the plugin manager is built; a plugin adds
  its stages, drivers, sub-commands and recipe settings to the registry it is given (each
  checked as it is added: a plugin that registers something invalid is disabled with one
  warning naming it);
* **lifecycle hooks** are called by the session at a run's start and end, and by the
  runner around every stage and for every result, so an integrator can publish results
  (PLC, MES, database) or show progress without touching the core.
  They must not change what they receive. Each implementation is called on its own: one
  that raises is a one-line warning naming its plugin, and the inspection, the batch and
  the other plugins go on (the built-in ``history`` plugin is such an observer). Each is
  timed: ``result.json`` ``timings_s["hook:PLUGIN:HOOK"]``, and a call over the recipe's
  hook budget (``[budget] hook_s``, ``INSPECTOR_HOOK_BUDGET_S``; 1 s) is a warning naming it;
* **GUI hooks** are called only by the operator GUI (``inspector gui``), never by the
  headless core, so a plugin that implements one imports Qt inside it, and the core never
  needs Qt.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from inspector.model import InspectionResult
    from inspector.pipeline import InspectionContext
    from inspector.recipe import Recipe
    from inspector.registry import CommandRegistry, DriverRegistry, SettingsRegistry, StageRegistry, StageSpec
    from inspector.session import RunSummary
    from inspector_frontends.gui.window import MainWindow

PROJECT = "inspector"
hookspec = pluggy.HookspecMarker(PROJECT)


@hookspec
def inspector_register_stages(registry: StageRegistry) -> None:
    """Add stages with ``registry.add(StageSpec(...))``.

    Parameters
    ----------
    registry : StageRegistry
        Collects every stage; names must be unique (``"kind.variant"``).
    """


@hookspec
def inspector_register_drivers(registry: DriverRegistry) -> None:
    """Add acquisition drivers with ``registry.add(DriverSpec(...))``.

    Parameters
    ----------
    registry : DriverRegistry
        Collects every driver; names must be unique words (``"usb3"``). A driver is
        ``DriverSpec(name, open, params, doc)``: ``open(params)`` returns an object with
        ``acquire()`` (yields :class:`~inspector.registry.Acquisition`) and ``close()``.
    """


@hookspec
def inspector_register_commands(registry: CommandRegistry) -> None:
    """Add ``inspector`` sub-commands with ``registry.add(CommandSpec(...))`` (as datasette's
    ``register_commands``).

    Parameters
    ----------
    registry : CommandRegistry
        Collects every sub-command; names must be unique lower-case words, and cannot be
        one of the core's (``run``, ``plugins``, ``plugin``, ``recipe``, ``report``,
        ``roles``). ``CommandSpec(name, add_parser, run, doc)``: ``add_parser(subparsers)``
        adds the argparse sub-parser, ``run(args) -> int`` runs it. ``bench``,
        ``experiment``, ``feasibility``, ``capture``, ``history``, ``import``, ``simulate``,
        ``demo``, ``serve`` and ``gui`` are registered this way by the built-in plugins.
    """


@hookspec
def inspector_register_settings(registry: SettingsRegistry) -> None:
    """Declare the plugin's recipe table ``[plugins.NAME]`` with ``registry.add(Settings,
    "one line")``.

    Parameters
    ----------
    registry : SettingsRegistry
        ``Settings`` is a frozen dataclass of :func:`inspector.params.param` fields (like a
        stage's parameters), checked when the plugin registers. A recipe's
        ``[plugins.NAME]`` table is validated against it when the recipe is loaded (unknown
        key, type, range: one line naming the file and key); the validated settings (the
        defaults when the recipe has no table) are ``recipe.plugins[NAME]`` in
        ``inspector_on_run_start`` and ``context.settings[NAME]`` in a stage. Recipes stay
        data: settings never name code to load.
    """


# -- lifecycle: a run -------------------------------------------------------------------
@hookspec
def inspector_on_run_start(recipe: Recipe, outdir: Path, source: str) -> None:
    """Called when a session starts a run, before the first capture is acquired.

    Parameters
    ----------
    recipe : Recipe
        The validated recipe the run inspects with.
    outdir : Path
        The run's result folder (one sub-folder per capture, ``history.sqlite``).
    source : str
        Where captures come from, in words: ``"captures"``, ``"watch INBOX"`` or
        ``"driver NAME"``.
    """


@hookspec
def inspector_on_run_end(recipe: Recipe, outdir: Path, summary: RunSummary) -> None:
    """Called once when a run ends, however it ends (done, stopped, cancelled, or an
    error of the driver); ``summary`` holds the verdict counts and how it ended."""


# -- lifecycle: a capture ---------------------------------------------------------------
@hookspec
def inspector_before_stage(context: InspectionContext, stage: StageSpec, step: str) -> None:
    """Called before stage ``step`` (the recipe's name for it) runs on ``context``."""


@hookspec
def inspector_after_stage(context: InspectionContext, stage: StageSpec, step: str, seconds: float) -> None:
    """Called after stage ``step`` succeeded; ``context`` holds its output."""


@hookspec
def inspector_on_stage_error(context: InspectionContext, stage: StageSpec, step: str, error: BaseException) -> None:
    """Called when stage ``step`` raised; the capture's verdict becomes ``"error"``."""


@hookspec
def inspector_on_result(result: InspectionResult, outdir: Path | None) -> None:
    """Called once per capture with its final result (after the outputs were written,
    ``outdir`` being that capture's result folder, or None when nothing was written);
    ``result.extras`` holds what the stages put in ``context.extras`` (JSON-safe), and
    ``result.summary`` the evaluate stage's :class:`~inspector.model.EvaluationSummary`."""


# -- GUI (called only by ``inspector gui``) -------------------------------------------------
@hookspec
def inspector_gui_panel(window: MainWindow) -> tuple[str, object] | None:
    """Return ``(title, widget)``: a panel (a ``QWidget``) the GUI adds as a dock widget.

    Called once when the operator window is built, on the GUI thread. ``window`` is the
    main window: its ``result_shown`` signal carries each result shown (a
    :class:`inspector_frontends.gui.viewmodel.ResultView`), its ``run_finished`` signal each run's
    summary, and ``current_result`` is the result on screen. A plugin that raises, or returns something
    else than a title and a widget, is disabled with a warning naming it; the GUI goes on.
    """
