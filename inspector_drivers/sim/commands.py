"""``inspector simulate``: the simulator's sub-command.

Registered by the ``sim`` plugin through ``inspector_register_commands`` (like any plugin's
command), so the core command line never imports the simulator.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from inspector.errors import RecipeError
from inspector.params import build_params, describe_params
from inspector.registry import CommandSpec
from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate

__all__ = ["COMMANDS", "add_simulate_parser", "simulate_command"]

EXIT_OK, EXIT_ERROR = 0, 3

#: ``simulate --target``: defaults, and the SimParams options that apply to a target (the
#: rig's geometry, noise, seed, sub-sampling, offset); any other one is refused.
DEFAULT_POSES, DEFAULT_BLUR_PX, DEFAULT_TARGET_SUPERSAMPLE, DEFAULT_TARGET_OFFSET_MM = 30, 0.7, 2, 8.0
_RIG_OPTIONS = ("cameras", "radius_mm", "mm_per_px", "width", "height", "dist")
_TARGET_OPTIONS = (*_RIG_OPTIONS, "noise_sigma", "seed", "supersample", "offset_mm")


def _parse_bump(text: str) -> dict[str, Any]:
    parts = [p.strip() for p in text.split(",")]
    try:
        if len(parts) not in (4, 5):
            raise ValueError
        x, y, z, r = (float(v) for v in parts[:4])
    except ValueError:
        raise RecipeError(f"--bump {text!r}: expected X,Y,Z,RADIUS[,add|remove]") from None
    kind = parts[4] if len(parts) == 5 else "remove"
    if kind not in ("add", "remove"):
        raise RecipeError(f"--bump {text!r}: kind must be add or remove")
    return {"at": [x, y, z], "radius_mm": r, "kind": kind}


def _add_param_options(parser: argparse.ArgumentParser, cls: type, skip: set[str]) -> None:
    """One ``--option`` per parameter of ``cls`` (types and docs from the dataclass)."""
    for d in describe_params(cls):
        if d["name"] in skip:
            continue
        flag = "--" + d["name"].replace("_", "-")
        if d["type"] == "bool":
            parser.add_argument(flag, action="store_true", default=None, help=d["doc"])
        elif d["type"].startswith("list of"):
            parser.add_argument(flag, type=float, nargs="+", default=None, help=d["doc"])
        else:
            conv: Any = {"int": int, "float": float}.get(d["type"], str)
            if d["type"] == "8 | 16":
                conv = int
            parser.add_argument(flag, type=conv, default=None, help=f"{d['doc']} (default {d['default']!r})")


def add_simulate_parser(sub: argparse._SubParsersAction[Any]) -> None:
    s = sub.add_parser("simulate", help="write simulated capture folders")
    s.add_argument("--out", required=True, help="folder that receives one capture folder per capture")
    s.add_argument("--bump", action="append", metavar="X,Y,Z,R[,KIND]",
                   help="a bump in the part's frame (kind add|remove, default remove); repeatable")
    t = s.add_argument_group("calibration target (instead of a part)")
    t.add_argument("--target", metavar="TARGET.toml",
                   help="render this calibration target (ChArUco board or cube) in random poses, one capture "
                        "folder pose_000, pose_001, ... per pose; with it apply --cameras, --radius-mm, "
                        "--mm-per-px, --width, --height, --dist, --noise-sigma, --seed, --supersample "
                        "(default 2 here) and --offset-mm (default 8 here)")
    t.add_argument("--poses", type=int, default=None, help=f"poses of the target (default {DEFAULT_POSES})")
    t.add_argument("--blur-px", type=float, default=None,
                   help=f"Gaussian blur of the target's images, px (default {DEFAULT_BLUR_PX})")
    t.add_argument("--rig", metavar="RIG.json",
                   help="render with the cameras of this rig.json instead of the simulated sphere rig")
    _add_param_options(s, SimParams, skip={"bumps"})


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def simulate_command(args: argparse.Namespace) -> int:
    from inspector.capture_folder import save_capture

    table = {d["name"]: getattr(args, d["name"]) for d in describe_params(SimParams)
             if getattr(args, d["name"], None) is not None}
    if getattr(args, "target", None) is not None:
        return _simulate_target(args, table)
    for name in ("poses", "blur_px", "rig"):
        if getattr(args, name, None) is not None:
            raise RecipeError(f"{_flag(name)}: only with --target")
    if args.bump:
        table["bumps"] = [_parse_bump(b) for b in args.bump]
    if "dist" in table:
        table["dist"] = list(table["dist"])
    p = build_params(SimParams, table, "simulate")
    out = Path(args.out)
    rig = sim_rig(p)
    for i in range(p.count):
        folder = save_capture(cap := simulate(p, i, rig), out / cap.name, overwrite=True)
        print(f"[{i + 1}/{p.count}] wrote {folder}", flush=True)
    return EXIT_OK


def _simulate_target(args: argparse.Namespace, table: dict[str, Any]) -> int:
    """``simulate --target``: one capture folder per pose of the calibration target."""
    from inspector.calibration.target import load_target
    from inspector.capture_folder import read_rig, save_capture
    from inspector_drivers.sim.target import simulate_target

    for name in table:
        if name not in _TARGET_OPTIONS:
            raise RecipeError(f"{_flag(name)}: not with --target (it simulates a part)")
    if args.bump:
        raise RecipeError("--bump: not with --target (it simulates a part)")
    if args.rig is not None:
        for name in _RIG_OPTIONS:
            if name in table:
                raise RecipeError(f"{_flag(name)}: not with --rig (the rig file gives the cameras)")
    poses = DEFAULT_POSES if args.poses is None else args.poses
    if not 1 <= poses <= 100000:
        raise RecipeError(f"--poses: expected a number of poses in 1..100000, got {poses}")
    blur = DEFAULT_BLUR_PX if args.blur_px is None else args.blur_px
    if not 0.0 <= blur <= 50.0:  # also refuses NaN
        raise RecipeError(f"--blur-px: expected a blur in 0..50 px, got {blur}")
    table = {"supersample": DEFAULT_TARGET_SUPERSAMPLE, "offset_mm": DEFAULT_TARGET_OFFSET_MM, **table}
    if "dist" in table:
        table["dist"] = list(table["dist"])
    p = build_params(SimParams, table, "simulate")
    target = load_target(args.target)  # RecipeError naming the file and the key
    rig = read_rig(args.rig) if args.rig is not None else sim_rig(p)
    out = Path(args.out)
    captures = simulate_target(target, rig, poses, seed=p.seed, blur_px=blur, noise_sigma=p.noise_sigma,
                               supersample=p.supersample, offset_mm=p.offset_mm)
    for i, cap in enumerate(captures):
        folder = save_capture(cap, out / cap.name, overwrite=True)
        print(f"[{i + 1}/{poses}] wrote {folder}", flush=True)
    return EXIT_OK


COMMANDS = (
    CommandSpec("simulate", add_simulate_parser, simulate_command, "write simulated capture folders"),
)
