"""``inspector calibrate``: commission the cell's cameras (built-in plugin ``calibrate``, a tool).

Four modes, one command::

    inspector calibrate TARGET.toml --captures DIR --out RIG.json [--force] [--report DIR]
    inspector calibrate --verify REFERENCE --captures DIR --rig RIG.json [--correct OUT.json] [--force]
    inspector calibrate --refine RIG.json --captures DIR --reference MESH --out RIG2.json [--intrinsics] [--force]
    inspector calibrate --background --captures DIR --out FOLDER [--force]

* calibrate (:mod:`.solve`): every camera's intrinsics and extrinsics from captures of a
  ChArUco target (:mod:`.target`), one bundle adjustment (:mod:`inspector.kernels.calibration`);
* ``--verify`` (:mod:`.gauge`): inspect captures of a gauge of known size with a rig and
  report its scale error (ppm) and BCPS residual; ``--correct`` writes the rig rescaled;
* ``--refine`` (:mod:`.refine`): every camera's extrinsics adjusted jointly with each
  capture's part pose so that the contour rays graze the aligned reference;
* ``--background`` (:mod:`.background`): each camera's empty field, several frames averaged,
  stored as ``FOLDER/background/<camera>.png`` where the segmentation finds it.

Every bad input is one line and exit 2, with nothing written; a rig file is written whole
(temporary file, then rename) and never over an existing file without ``--force``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import hookimpl
from inspector.errors import RecipeError
from inspector.registry import CommandSpec

if TYPE_CHECKING:
    from inspector.model import Rig
    from inspector.registry import CommandRegistry

__all__ = ["add_parser", "run", "write_rig", "check_new_file"]


def add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    p = sub.add_parser(
        "calibrate", help="commission the cameras: calibrate from a target, verify with a gauge, refine from parts, "
                          "store the empty field",
        description="Calibrate every camera from captures of a ChArUco target (TARGET.toml), verify a rig's scale "
                    "with a gauge (--verify), refine a rig from the silhouettes of good parts (--refine), or store "
                    "each camera's empty field for flat-fielding (--background).")
    p.add_argument("target", nargs="?", help="the target's TOML description (calibrate mode)")
    p.add_argument("--captures", required=True,
                   help="folder of capture folders (one per target pose, gauge, part or empty-field frame)")
    p.add_argument("--out", help="the rig file to write (calibrate, --refine); with --background the folder that "
                                 "receives background/<camera>.png (the cell's folder beside its rig.json)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--report", help="folder for the report's pictures and report.json (default: beside --out)")
    p.add_argument("--json", action="store_true", help="print the report as JSON instead of text")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--verify", metavar="REFERENCE", help="inspect captures of this gauge (mesh, mm) with --rig")
    mode.add_argument("--refine", metavar="RIG", help="refine this rig from captures of good parts (--reference)")
    mode.add_argument("--background", action="store_true",
                      help="average each camera's empty-field frames (--captures: one capture folder per frame, "
                           "nothing in the rig) into --out FOLDER/background/<camera>.png")
    p.add_argument("--rig", help="the rig to verify (--verify)")
    p.add_argument("--correct", metavar="OUT", help="with --verify: write the rig with its scale corrected")
    p.add_argument("--reference", help="with --refine: the parts' reference mesh (mm)")
    p.add_argument("--recipe", help="recipe that inspects the gauge or parts (default: the shipped default.toml)")
    p.add_argument("--intrinsics", action="store_true", help="with --refine: also refine focal length and principal point")


def check_new_file(path: str | os.PathLike[str], force: bool, what: str = "output") -> Path:
    """``path`` as a Path, refused (one line) when it exists and ``force`` is not set, or when
    its folder does not exist."""
    p = Path(path)
    if p.exists() and not force:
        raise RecipeError(f"{p}: the {what} file exists (use --force to overwrite it)")
    if p.exists() and p.is_dir():
        raise RecipeError(f"{p}: is a folder, not a file")
    if not p.parent.is_dir():
        raise RecipeError(f"{p.parent}: no such folder for the {what} file")
    return p


def write_rig(rig: Rig, path: str | os.PathLike[str], extra: dict[str, Any] | None = None) -> Path:
    """Write ``rig`` to ``path`` whole: a temporary file beside it, then an atomic rename.
    ``extra`` keys (e.g. ``calibration``: how it was made) are kept beside ``cameras``."""
    p = Path(path)
    data = rig.to_json()
    if extra:
        data.update(extra)
    tmp = p.with_name(f".{p.name}.partial")
    tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, p)
    return p


def run(args: argparse.Namespace) -> int:
    """Dispatch to the mode's module; every mode validates its inputs before writing anything."""
    if args.verify:
        from inspector.calibration.gauge import run_verify

        return run_verify(args)
    if args.refine:
        from inspector.calibration.refine_command import run_refine

        return run_refine(args)
    if getattr(args, "background", False):
        from inspector.calibration.background import run_background

        return run_background(args)
    if not args.target:
        raise RecipeError("calibrate: give a TARGET.toml (or --verify REFERENCE / --refine RIG / --background)")
    from inspector.calibration.solve import run_calibrate

    return run_calibrate(args)


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector calibrate``: a built-in plugin (entry point ``calibrate``), like ``feasibility``."""
    registry.add(CommandSpec("calibrate", add_parser, run,
                             "commission the cameras: calibrate (ChArUco), verify with a gauge, refine from parts, "
                             "store the empty field"))
