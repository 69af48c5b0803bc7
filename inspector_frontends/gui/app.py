"""``inspector gui``: the operator window.

Without a display it says so in one line and exits 2; with no recipe it opens the cell demo
(a simulated rig, every second part notched) and inspects the first part at once.

The cell's settings file (``--config cell.toml``, else ``cell.toml`` in the configuration
folder, ``$INSPECTOR_CONFIG_DIR`` or ``~/.config/inspector``, when there is one) may hold::

    [gui]
    kiosk = true          # full screen, no decorations, only the engineer can close it
    lang = "de"           # en, de or es; empty: the system locale

    [shifts]              # the shift panel's times (inspector.shift)
    starts = ["06:00", "14:00", "22:00"]
    names = ["early", "late", "night"]

``--kiosk`` and ``--lang`` replace the file's values.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from inspector.cell import cell_file, load_cell
from inspector.errors import RecipeError
from inspector.params import build_params, param
from inspector.resources import recipe_path
from inspector.shift import ShiftSettings

if TYPE_CHECKING:
    from inspector_frontends.gui.window import MainWindow

__all__ = ["add_parser", "run", "DEMO_RECIPE", "GuiSettings", "load_gui_settings"]


@dataclass(frozen=True)
class GuiSettings:
    """``[gui]`` of the cell's settings file."""

    kiosk: bool = param(False, "full screen without decorations; only the engineer can close the window")
    lang: str = param("", "language of the operator window: en, de or es (empty: the system locale)")


def load_gui_settings(path: Path | None) -> tuple[GuiSettings, ShiftSettings]:
    """``([gui], [shifts])`` of the cell's settings file (defaults without one).

    Raises RecipeError in one line naming the file and the key."""
    tables = load_cell(path)
    name = path.name if path is not None else "cell"
    gui: GuiSettings = build_params(GuiSettings, tables.get("gui"), f"{name}: gui")
    shifts: ShiftSettings = build_params(ShiftSettings, tables.get("shifts"), f"{name}: shifts")
    return gui, shifts

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
    g.add_argument("--kiosk", action="store_true", default=None,
                   help="the cell's kiosk: full screen, no decorations, only the engineer can close it")
    g.add_argument("--lang", metavar="LANG", help="language: en, de or es (default: [gui] lang, else the system locale)")
    g.add_argument("--config", metavar="TOML", help="the cell's settings ([gui], [shifts]; default cell.toml in "
                                                    "$INSPECTOR_CONFIG_DIR or ~/.config/inspector when present)")


def _stop_on_sigterm(window: MainWindow) -> None:
    """SIGTERM (``systemctl stop``, a shutdown) closes the window as the engineer would: the
    inspection in progress is cancelled and the worker joined, then the program exits 0.
    Python runs a signal's handler only between its own bytecodes: a timer lets it run while
    Qt's event loop waits."""
    import signal

    from PySide6.QtCore import QTimer

    signal.signal(signal.SIGTERM, lambda *_: window.shutdown())
    tick = QTimer(window)
    tick.setInterval(500)
    tick.timeout.connect(lambda: None)
    tick.start()


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
    from inspector_frontends.gui.i18n import choose

    try:
        gui, shifts = load_gui_settings(cell_file(getattr(args, "config", None)))
        lang = choose(getattr(args, "lang", None) or gui.lang or None)
    except (RecipeError, ValueError) as e:
        print(f"inspector: error: {e}", file=sys.stderr)
        return 2
    kiosk = gui.kiosk if getattr(args, "kiosk", None) is None else bool(args.kiosk)
    try:
        from PySide6.QtWidgets import QApplication

        from inspector_frontends.gui.i18n import install
        from inspector_frontends.gui.window import MainWindow, freeze_startup_objects
    except ImportError as e:
        print(f"inspector: error: gui: {e.name or e} is not installed (make setup installs the GUI packages)", file=sys.stderr)
        return 2
    app = QApplication.instance() or QApplication([sys.argv[0]])
    app.setApplicationName("Inspector")
    try:
        install(lang)
    except FileNotFoundError as e:
        print(f"inspector: error: gui: {e}", file=sys.stderr)
        return 2
    demo = args.recipe is None
    from inspector_frontends.gui.collector import GuiThreadCollector

    collector = GuiThreadCollector(app)  # Qt objects in cycles are freed on this thread, never a worker's
    window = MainWindow(Path(args.recipe) if args.recipe else DEMO_RECIPE, Path(args.out or "out/gui"),
                        capture=args.capture, watch=args.watch, reference=args.reference,
                        idle_logout_s=args.idle_logout, kiosk=kiosk, shifts=shifts)
    window.show_on_screen()
    _stop_on_sigterm(window)
    freeze_startup_objects(window)
    if demo:  # a newcomer sees a part inspected at once
        window.inspect()
    try:
        return 0 if app.exec() == 0 else 3
    finally:
        collector.uninstall()
