"""``inspector gui``: the operator window's command, a built-in plugin (entry point ``gui``).

Registered through ``inspector_register_commands`` like any plugin's command, so the core
command line never imports the GUI package; :mod:`inspector_frontends.gui.app` (imported here:
it imports no Qt at its top) imports Qt only when the command runs.
"""

from __future__ import annotations

import argparse
from typing import Any

from inspector import hookimpl
from inspector.registry import CommandRegistry, CommandSpec
from inspector_frontends.gui import app

__all__ = ["inspector_register_commands"]


def _add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    app.add_parser(sub)


def _run(args: argparse.Namespace) -> int:
    return app.run(args)


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    registry.add(CommandSpec("gui", _add_parser, _run, "the operator window (PySide6 + PyVista)"))
