"""Every hook Inspector calls, in one module (the plugin API).

A plugin is a module or object with functions named like these hooks, decorated with
:data:`inspector.hookimpl`, and advertised in the ``inspector`` entry-point group of its
distribution::

    [project.entry-points.inspector]
    my_stage = "my_package.my_module"

Built-in stages and drivers are registered exactly this way (see ``pyproject.toml``).

Two kinds of hooks:

* **registry hooks** are called once when the plugin manager is built; a plugin adds
  its stages and drivers to the registry it is given;
* **lifecycle hooks** are called by the runner around every stage and for every result,
  so an integrator can publish results (PLC, MES, database) without touching the core.
  They must not change what they receive. Each implementation is called on its own: one
  that raises is a one-line warning naming its plugin, and the inspection, the batch and
  the other plugins go on (the built-in ``history`` plugin is such an observer).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from inspector.model import InspectionResult
    from inspector.pipeline import InspectionContext
    from inspector.registry import DriverRegistry, StageRegistry, StageSpec

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
    """Add acquisition drivers with ``registry.add(DriverSpec(...))``."""


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
    ``outdir`` being that capture's result folder, or None when nothing was written)."""
