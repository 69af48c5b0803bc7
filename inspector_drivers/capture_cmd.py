"""``inspector capture``: acquire triggers from any driver and write them as capture folders.

    inspector capture --driver aravis --out captures/ --param rig=rig/rig.json \\
        --param 'serials={cam00="SN0001", cam01="SN0002"}' --count 10
    inspector capture --recipe recipes/line3.toml --out captures/ --count 10

Every trigger becomes ``OUT/<capture name>/`` in the CONTRACT layout
(:func:`~inspector.capture_folder.write_capture`: ``rig.json`` with the rig's
calibration, ``images/``, ``capture.json`` with the driver's metadata, ``truth/`` for simulated
captures), so any live capture can be inspected again later with
``inspector run RECIPE --capture OUT``.

Parameters come from the recipe's ``[driver]`` table (``--recipe``), then from ``--param
KEY=VALUE`` (TOML values: ``count=3``, ``exposure_us=2500.0``, ``serials={cam00="1"}``; a
value that is not TOML is a string: ``rig=rig/rig.json``), then ``--count``. They are checked
like a recipe's before any device is opened.

Calibration captures (commissioning the cell, ``docs/commissioning.md``): one capture folder
per pose of the calibration target, so one trigger per pose, the target moved between them
(:data:`CALIBRATION_HELP`, shown by ``inspector capture --help``); then ``inspector calibrate
TARGET.toml --captures DIR --out rig.json``. The empty field for flat-fielding: a few triggers
with nothing in the rig, then ``inspector calibrate --background --captures DIR --out CELL``.

Exit status: 0 every trigger was written; 2 invalid command, recipe or parameter (nothing
acquired); 3 the driver could not be opened, or at least one trigger failed (the others are
written, each failure is one line naming the camera).

A built-in plugin (entry point ``capture``): the command is registered through
``inspector_register_commands`` like any plugin's.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import hookimpl
from inspector.errors import InspectorError, RecipeError
from inspector.manager import create_plugin_manager
from inspector.params import build_params
from inspector.registry import CommandSpec

if TYPE_CHECKING:
    from inspector.manager import PluginManager
    from inspector.registry import CommandRegistry

__all__ = ["add_parser", "run", "parse_param", "driver_table", "CALIBRATION_HELP"]

EXIT_OK, EXIT_INVALID, EXIT_ERROR, EXIT_INTERRUPTED = 0, 2, 3, 130
_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

#: ``inspector capture --help``'s epilog: how to take the captures ``inspector calibrate`` reads.
CALIBRATION_HELP = """\
calibration captures (commissioning the cell; see docs/commissioning.md):
  inspector calibrate reads one capture folder per pose of the calibration target (a ChArUco
  board or cube described by a TARGET.toml, e.g. examples/calibration/charuco_cube.toml), so
  take one trigger per pose and move the target between triggers:

    for i in $(seq 30); do
      read -p "pose $i: place the target in the rig, tilted a new way, then Enter "
      inspector capture --recipe cell.toml --out calib/ --count 1 -q
    done
    inspector calibrate TARGET.toml --captures calib/ --out cell/rig.json

  Each run adds one folder (named by driver, time and number). Take 20 to 30 poses: the target
  near the middle of the rig, turned so that every camera sees a board in several poses, near
  the edges of its image too, some of them steeply. The driver's rig parameter may name a
  nominal rig.json (camera names and image sizes): calibrate reads only the images. Simulated
  captures of the same kind: inspector simulate --target TARGET.toml --poses 30 --out calib/.

  The empty field, for flat-fielding: with nothing in the rig,
    inspector capture --recipe cell.toml --out empty/ --count 8
    inspector calibrate --background --captures empty/ --out cell/
  writes cell/background/<camera>.png; a driver whose rig parameter names cell/ attaches it to
  every capture.
"""


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``capture`` sub-command to ``subparsers`` (from ``add_subparsers()``)."""
    p = subparsers.add_parser(
        "capture",
        help="acquire captures from a driver and write them as capture folders (replayable)",
        description="Acquire triggers from a driver and write each as a capture folder (CONTRACT layout).",
        epilog=CALIBRATION_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--driver", metavar="NAME", help="driver (see `inspector plugins`); default: the recipe's driver")
    p.add_argument("--out", required=True, metavar="DIR", help="folder that receives one capture folder per trigger")
    p.add_argument("--recipe", metavar="R", help="recipe whose [driver] table gives the driver and its parameters")
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="driver parameter, VALUE in TOML syntax (count=3, serials={cam00=\"1\"}; not TOML: a string); repeatable, overrides the recipe",
    )
    p.add_argument("--count", type=int, metavar="N", help="triggers to acquire (default: the driver's count parameter)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    return p


def parse_param(text: str) -> tuple[str, Any]:
    """``"key=value"`` -> ``(key, value)``; the value is TOML if it parses, else the string."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not _KEY.match(key):
        raise RecipeError(f"--param {text!r}: expected KEY=VALUE")
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def driver_table(recipe: str | None) -> tuple[str | None, dict[str, Any]]:
    """The recipe's ``[driver]`` ``use`` and ``params`` (RecipeError naming the file)."""
    if not recipe:
        return None, {}
    from inspector.recipe import read_recipe_toml

    p = Path(recipe)
    data = read_recipe_toml(p)
    drv = data.get("driver", {})
    if not isinstance(drv, dict):
        raise RecipeError(f"{p.name}: driver: expected a table")
    use = drv.get("use")
    if use is not None and not isinstance(use, str):
        raise RecipeError(f"{p.name}: driver.use: expected a driver name")
    params = drv.get("params", {})
    if not isinstance(params, dict):
        raise RecipeError(f"{p.name}: driver.params: expected a table")
    return use, dict(params)


def _err(msg: str) -> None:
    print(f"inspector: error: {msg}", file=sys.stderr)


def _write(out: Path, cap: Any) -> Path:
    from inspector.capture_folder import save_capture

    return save_capture(cap, out / cap.name)


def run(args: argparse.Namespace, pm: PluginManager | None = None) -> int:
    """Run ``inspector capture``; returns the exit status (errors are one line on stderr).

    ``pm``: a plugin manager (default: the command line's, ``args.plugin_manager``, else
    :func:`inspector.manager.create_plugin_manager`).
    """
    import dataclasses

    quiet = bool(getattr(args, "quiet", False))
    driver = None
    written = failed = 0
    try:
        pm = pm or getattr(args, "plugin_manager", None)
        if pm is None:
            pm = create_plugin_manager()
        use, table = driver_table(getattr(args, "recipe", None))
        name = args.driver or use
        if not name:
            raise RecipeError("capture: give --driver NAME (or --recipe with a [driver] table)")
        if args.driver and use and args.driver != use:
            raise RecipeError(f"--driver {args.driver}: the recipe uses driver {use!r}")
        if name not in pm.drivers:
            raise RecipeError(f"--driver: unknown driver {name!r} (known: {', '.join(pm.drivers.names())})")
        spec = pm.drivers[name]
        for item in getattr(args, "param", None) or []:
            k, v = parse_param(item)
            table[k] = v
        fields = {f.name for f in dataclasses.fields(spec.params)}
        limit = args.count
        if limit is not None:
            if limit < 1:
                raise RecipeError(f"--count: expected at least 1, got {limit}")
            if "count" in fields:
                table["count"] = limit
        where = f"{Path(args.recipe).name}: driver.params" if getattr(args, "recipe", None) else "capture --param"
        params = build_params(spec.params, table, where)
        out = Path(args.out)
        total = limit if limit is not None else (getattr(params, "count", None) or None)

        driver = spec.open(params)
        for i, acq in enumerate(driver.acquire(), start=1):
            if limit is not None and i > limit:
                break
            of = f"/{total}" if total else ""
            t0 = time.perf_counter()
            try:
                cap = acq.load()
                folder = _write(out, cap)
            except (InspectorError, FileExistsError, ValueError) as exc:
                failed += 1  # one trigger lost; the next ones are independent
                msg = " ".join(str(exc).split())
                if quiet:
                    _err(f"{acq.name}: {msg}")
                else:
                    print(f"[{i}{of}] {acq.name}: error: {msg}", flush=True)
                continue
            written += 1
            if not quiet:
                print(f"[{i}{of}] wrote {folder} ({len(cap.images)} cameras, {time.perf_counter() - t0:.2f} s)", flush=True)
    except RecipeError as exc:
        _err(str(exc))
        return EXIT_INVALID
    except InspectorError as exc:
        _err(str(exc))
        return EXIT_ERROR
    except OSError as exc:
        _err(f"{exc.filename or ''}: {exc.strerror or exc}".strip(": "))
        return EXIT_ERROR
    except KeyboardInterrupt:
        _err(f"interrupted; {written} capture(s) written are kept")
        return EXIT_INTERRUPTED
    finally:
        if driver is not None:
            try:
                driver.close()
            except Exception:  # noqa: BLE001 - closing must not hide the outcome
                pass
    if not quiet:
        print(f"{written} capture(s) written to {Path(args.out).resolve()}" + (f", {failed} failed" if failed else ""))
    if written == 0 and failed == 0:
        _err("the driver gave no capture")
        return EXIT_ERROR
    return EXIT_ERROR if failed else EXIT_OK


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    registry.add(CommandSpec("capture", add_parser, run, "live triggers of any driver -> capture folders (replayable)"))
