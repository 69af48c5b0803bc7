"""``inspector gui``: the operator window.

Without a display it says so in one line and exits 2; with no recipe it opens the cell demo
(a simulated rig, every second part notched) and inspects the first part at once.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from inspector.resources import recipe_path

__all__ = ["add_parser", "run", "DEMO_RECIPE"]

DEMO_RECIPE = recipe_path("cell-demo.toml")  # shipped as package data: works outside the source tree


def add_parser(sub: argparse._SubParsersAction) -> None:
    g = sub.add_parser("gui", help="the operator window (PySide6 + PyVista)")
    g.add_argument("recipe", nargs="?", help=f"recipe TOML file (default: the cell demo, {DEMO_RECIPE.name})")
    src = g.add_mutually_exclusive_group()
    src.add_argument("--capture", metavar="DIR", help="capture folder (or folder of captures) that INSPECT reads")
    src.add_argument("--watch", metavar="INBOX", help="hot folder that LIVE watches")
    g.add_argument("--out", metavar="OUTDIR", help="result folder (default out/gui)")
    g.add_argument("--reference", metavar="MESH", help="reference mesh; replaces the recipe's")
    g.add_argument("--idle-logout", type=float, default=300.0, metavar="S",
                   help="engineer mode falls back to operator after S seconds without input (default 300)")


def display_problem() -> str | None:
    """Why no window can open here, in one line (None: a display is there)."""
    platform = os.environ.get("QT_QPA_PLATFORM", "")
    if platform and platform not in ("xcb", "wayland"):
        return f"QT_QPA_PLATFORM={platform}: the 3D view needs a real display (xcb or wayland)"
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        return "no display (DISPLAY is not set): run it on the cell's screen, or under xvfb-run for a virtual one"
    return None


def run(args: argparse.Namespace) -> int:
    problem = display_problem()
    if problem:
        print(f"inspector: error: gui: {problem}", file=sys.stderr)
        return 2
    for flag, value in (("--capture", args.capture), ("--watch", args.watch)):
        if value is not None and not Path(value).is_dir():
            print(f"inspector: error: {flag} {value}: not a folder", file=sys.stderr)
            return 2
    try:
        from PySide6.QtWidgets import QApplication

        from inspector.gui.window import MainWindow, freeze_startup_objects
    except ImportError as e:
        print(f"inspector: error: gui: {e.name or e} is not installed (make setup installs the GUI packages)", file=sys.stderr)
        return 2
    app = QApplication.instance() or QApplication([sys.argv[0]])
    app.setApplicationName("Inspector")
    demo = args.recipe is None
    window = MainWindow(Path(args.recipe) if args.recipe else DEMO_RECIPE, Path(args.out or "out/gui"),
                        capture=args.capture, watch=args.watch, reference=args.reference,
                        idle_logout_s=args.idle_logout)
    window.resize(1600, 960)
    window.show()
    freeze_startup_objects(window)
    if demo:  # a newcomer sees a part inspected at once
        window.inspect()
    return 0 if app.exec() == 0 else 3
