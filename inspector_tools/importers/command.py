"""``inspector import``: public datasets and calibrated image sets -> capture folders.

A built-in plugin (entry point ``import``): the command is registered through
``inspector_register_commands`` like any plugin's; the importers themselves are
:mod:`inspector_tools.importers.datasets` (one module per format beside it).
"""

from __future__ import annotations

import argparse
from typing import Any

from inspector import hookimpl
from inspector.registry import CommandRegistry, CommandSpec
from inspector_tools.importers import datasets as importers

__all__ = ["inspector_register_commands"]


def _add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    importers.add_parser(sub)


def _run(args: argparse.Namespace) -> int:
    return importers.run(args)


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    registry.add(CommandSpec("import", _add_parser, _run,
                             "import Middlebury, NeRF, IDR or OpenCV-calibrated image sets as capture folders"))
