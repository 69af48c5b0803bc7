"""``inspector plugin``: the plugin author's tools, a built-in command plugin (entry point
``plugin``) registered like any third party's.

``inspector plugin new NAME`` writes a plugin package (:mod:`inspector_tools.scaffold`);
``inspector plugin reference [OUT.md]`` writes the plugin author's reference, what
``docs/plugins.md`` is (:mod:`inspector_tools.plugin_docs`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from inspector import hookimpl
from inspector.registry import CommandRegistry, CommandSpec
from inspector_tools.scaffold import add_arguments
from inspector_tools.scaffold import run as new

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    """``inspector plugin new ...`` and ``inspector plugin reference [OUT.md]``."""
    pg = sub.add_parser("plugin", help="plugin author's tools: `inspector plugin new NAME` writes a plugin package, "
                                       "`inspector plugin reference` the author's reference")
    psub = pg.add_subparsers(dest="plugin_command", required=True, parser_class=type(pg))
    add_arguments(psub.add_parser("new", help="write a complete plugin package (pyproject, stage, driver, hook, "
                                              "tests, README) that installs and passes its tests at once"))
    ref = psub.add_parser("reference", help="write the plugin author's reference (hooks, public API, registries) "
                                            "as Markdown, what docs/plugins.md is")
    ref.add_argument("out", nargs="?", default="-", metavar="OUT.md", help="where to write it (default: stdout)")


def run(args: argparse.Namespace) -> int:
    """Run ``inspector plugin new`` or ``inspector plugin reference``; the exit status."""
    if args.plugin_command == "new":
        return new(args)
    from inspector_tools.plugin_docs import reference_markdown

    text = reference_markdown()
    if args.out == "-":
        sys.stdout.write(text)
    else:
        Path(args.out).write_text(text, encoding="utf-8")
        print(f"wrote {args.out}")
    return 0


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector plugin``: a built-in plugin (entry point ``plugin``), like any command."""
    registry.add(CommandSpec("plugin", add_parser, run, "the plugin author's tools (new package, reference)"))
