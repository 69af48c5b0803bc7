"""``inspector features REFERENCE [--json] [--picture PNG]``: the geometric features of a reference.

Built-in plugin ``features`` (a tool, like ``feasibility``): it lists the planes, cylinders,
cones, spheres and tori :func:`inspector.kernels.features.find_features` finds on the CAD mesh --
their ids, the ids a recipe's ``[[characteristics]]`` name -- with their nominal parameters,
area and triangle count; ``--json`` prints ``[{id, kind, nominal, area_mm2, triangles}]``;
``--picture`` draws the mesh with each feature coloured and labelled (matplotlib, off-screen).

Bad input (a missing or unreadable mesh, an unknown built-in, a picture in a missing folder):
one line, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector import hookimpl
from inspector.errors import RecipeError, ReferenceMeshError
from inspector.reference import Reference
from inspector.registry import CommandSpec

if TYPE_CHECKING:
    from inspector.kernels.features import Feature
    from inspector.registry import CommandRegistry

__all__ = ["add_parser", "describe", "draw_features", "run"]


def add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    p = sub.add_parser(
        "features", help="the reference's geometric features (planes, cylinders, cones, spheres, tori) and their ids",
        description="Find the geometric features of a reference mesh: planes, cylinders (bosses and bores), cones, "
                    "spheres and tori (fillets round circular edges, grooves), each with a stable id (F01 ...), its "
                    "nominal parameters, area and triangle count. "
                    "A recipe's [[characteristics]] name these ids.")
    p.add_argument("reference", help="the reference: a mesh file (STL, PLY, OBJ; mm) or builtin:NAME")
    p.add_argument("--json", action="store_true", help="print a JSON list of {id, kind, nominal, area_mm2, triangles}")
    p.add_argument("--picture", metavar="PNG", help="draw the features coloured and labelled into this PNG file")
    p.add_argument("--angle-tol", type=float, default=1.0, metavar="DEG",
                   help="largest angle between the triangles of one plane, degrees (default 1)")
    p.add_argument("--dist-tol", type=float, default=0.02, metavar="MM",
                   help="largest distance of a vertex from its feature's surface, mm (default 0.02)")


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (tuple, list)):
        return "(" + ", ".join(f"{x:.4g}" if abs(x) > 1e-6 else "0" for x in v) + ")"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def describe(f: Feature) -> str:
    """One line: ``F01 cylinder  r 4 ... area 150.8 mm2, 128 triangles``."""
    nm = ", ".join(f"{k} {_fmt(v)}" for k, v in f.nominal.items())
    return f"{f.id}  {f.kind:<8}  {nm}  |  area {f.area_mm2:.4g} mm2, {f.triangles} triangles"


def run(args: argparse.Namespace) -> int:
    from inspector.kernels.features import find_features

    picture = None
    if args.picture:
        picture = Path(args.picture)
        if picture.suffix.lower() != ".png":
            raise RecipeError(f"--picture {picture}: expected a .png file")
        if not picture.parent.is_dir():
            raise RecipeError(f"--picture {picture}: no such folder {picture.parent}")
        if picture.is_dir():
            raise RecipeError(f"--picture {picture}: is a folder, not a file")
    if not (0 < args.angle_tol < 20):
        raise RecipeError(f"--angle-tol: expected degrees in (0, 20), got {args.angle_tol}")
    if not (0 < args.dist_tol <= 10):
        raise RecipeError(f"--dist-tol: expected mm in (0, 10], got {args.dist_tol}")
    try:
        ref = Reference.load(args.reference)
    except ReferenceMeshError as e:
        raise RecipeError(str(e)) from None
    feats = find_features(ref.vertices, ref.faces, angle_tol_deg=args.angle_tol, dist_tol_mm=args.dist_tol)
    if args.json:
        json.dump([f.to_json() for f in feats], sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        assigned = sum(f.triangles for f in feats)
        print(f"{args.reference}: {len(feats)} features, {assigned} of {len(ref.faces)} triangles")
        for f in feats:
            print("  " + describe(f))
    if picture is not None:
        draw_features(ref.vertices, ref.faces, feats, picture, title=str(args.reference))
        if not args.json:
            print(f"picture: {picture}")
    return 0


#: Feature colours (tab20 without its greys), cycled.
_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf",
            "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5", "#c49c94", "#f7b6d2", "#dbdb8d", "#9edae5"]


def draw_features(vertices: np.ndarray, faces: np.ndarray, features: list[Feature], path: str | Path, *,
                  title: str = "", views: tuple[tuple[float, float], ...] = ((30.0, 60.0), (-30.0, -120.0))) -> Path:
    """Draw the mesh from two sides, each feature in a colour with its id at its centroid
    (unassigned triangles grey), and a legend; PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    colour = np.tile(np.array([0.78, 0.78, 0.78, 1.0]), (len(F), 1))
    rgba = matplotlib.colors.to_rgba_array(_COLOURS)
    for k, f in enumerate(features):
        colour[f.faces] = rgba[k % len(rgba)]
    tri = V[F]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    light = np.array([0.3, -0.4, 0.87])
    light /= np.linalg.norm(light)
    shade = 0.55 + 0.45 * np.abs(nrm @ light)
    fc = colour.copy()
    fc[:, :3] *= shade[:, None]
    lo, hi = V.min(0), V.max(0)
    mid, half = 0.5 * (lo + hi), 0.5 * float((hi - lo).max())
    fig = plt.figure(figsize=(13, 6.8), dpi=110)
    cent = [(tri[f.faces].mean(axis=1) * _areas(tri[f.faces])[:, None]).sum(0) / max(_areas(tri[f.faces]).sum(), 1e-300)
            for f in features]
    for i, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        e, a = np.radians(elev), np.radians(azim)
        eye = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        front = nrm @ eye > 0  # back faces culled: matplotlib sorts polygons, it has no depth buffer
        ax.add_collection3d(Poly3DCollection(tri[front], facecolors=fc[front], edgecolors="none", linewidths=0))
        ax.set_xlim(mid[0] - half, mid[0] + half)
        ax.set_ylim(mid[1] - half, mid[1] + half)
        ax.set_zlim(mid[2] - half, mid[2] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=elev, azim=azim)
        ax.set_xlabel("x mm")
        ax.set_ylabel("y mm")
        ax.set_zlabel("z mm")
        # Label the features facing the viewer (their mean normal towards the camera).
        for k, f in enumerate(features):
            n_mean = (nrm[f.faces] * _areas(tri[f.faces])[:, None]).sum(0)
            facing = np.linalg.norm(n_mean) < 1e-6 * max(f.area_mm2, 1e-300) or n_mean @ eye > 0
            if not facing:
                continue
            ax.text(*cent[k], f.id, fontsize=8, weight="bold", color="black", ha="center", va="center", zorder=10,
                    bbox={"boxstyle": "round,pad=0.15", "fc": _COLOURS[k % len(_COLOURS)], "ec": "black", "lw": 0.4,
                          "alpha": 0.9})
    handles = [plt.Rectangle((0, 0), 1, 1, fc=_COLOURS[k % len(_COLOURS)]) for k in range(len(features))]
    labels = [f"{f.id} {f.kind}" + (f" r{f.nominal['radius']:.4g}" if "radius" in f.nominal else "")
              + (f" R{f.nominal['major_radius']:.4g} r{f.nominal['minor_radius']:.4g}" if f.kind == "torus" else "")
              + (f" {f.nominal['half_angle_deg']:.3g} deg" if "half_angle_deg" in f.nominal else "") for f in features]
    if features:
        fig.legend(handles, labels, loc="center right", fontsize=7, ncol=1 if len(features) <= 30 else 2, frameon=False)
    fig.suptitle(f"{title}: {len(features)} features" if title else f"{len(features)} features")
    fig.subplots_adjust(left=0.0, right=0.84 if len(features) <= 30 else 0.74, top=0.93, bottom=0.02, wspace=0.0)
    out = Path(path)
    fig.savefig(out)
    plt.close(fig)
    return out


def _areas(tri: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector features``: a built-in plugin (entry point ``features``), like ``feasibility``."""
    registry.add(CommandSpec("features", add_parser, run,
                             "the reference's geometric features (planes, cylinders, cones, spheres, tori) and their ids"))
