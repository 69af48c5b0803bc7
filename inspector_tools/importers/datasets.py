"""Importers: third-party calibrated multi-view data -> capture folders (CONTRACT).

``inspector import FORMAT SRC --out DIR`` writes one capture folder (``rig.json``,
``images/<name>.png``, ``capture.json``) per calibration found in ``SRC``. When ``SRC``
holds exactly one calibration (the usual case) the capture is ``DIR`` itself; when it holds
several (a NeRF folder with ``transforms_train.json`` and ``transforms_test.json``, a
folder with several ``*_par.txt``) each becomes ``DIR/<name>/`` (``DIR`` is then a batch
folder: ``inspector run --capture DIR`` inspects them all).

Formats
-------
``middlebury``
    ``*_par.txt`` (Middlebury multi-view stereo: a count line, then one line per image
    ``"imgname k11..k33 r11..r33 t1 t2 t3"``, ``P = K [R t]``); the images are next to it.
    Units: **metres**, converted to mm (x1000). Bright object on a black background:
    polarity ``"bright-object"``; the photographs are copied unchanged (RGB). A
    ``*_good_silhouette_images.txt`` next to it is kept as
    ``capture.json["import"]["good_silhouettes"]``.
``nerf``
    ``transforms*.json`` (Blender / NeRF synthetic, also instant-ngp's keys): intrinsics
    from ``camera_angle_x`` (and ``camera_angle_y``) or ``fl_x``/``fl_y``/``cx``/``cy``/
    ``w``/``h`` (+ ``k1 k2 p1 p2 [k3]``), one frame per image with ``file_path`` and a
    4x4 ``transform_matrix``: camera -> world in the OpenGL convention (x right, y up,
    looking down -z), converted to OpenCV's (x right, y down, z forward) by
    ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``; ``R = c2w_cv[:3, :3].T``,
    ``t = -R @ c2w_cv[:3, 3]`` (the 3x3 block is re-orthonormalised: Blender writes float32).
    Principal point: NeRF's pixel coordinates put the *corner* of the top-left pixel at
    (0, 0) (Blender renders pixel ``i`` at ``i + 0.5``; instant-ngp and COLMAP use the same
    convention), so ``cx_opencv = cx - 0.5`` with ``cx = w / 2`` by default.
    Units: unknown ("scene units"): kept (scale 1) unless ``scale`` is given.
    Images: the alpha channel is the silhouette. Each image is written as the 8-bit grey
    ``255 * (1 - alpha)`` (16-bit for 16-bit PNGs) with polarity ``"dark-object"``:
    the object is dark on a white background, its anti-aliased edge is the alpha itself,
    so the segment stage's coverage is the alpha and its 0.5 level the alpha's 0.5 level.
``idr``
    ``cameras*.npz`` (IDR / NeuS / VolSDF: DTU, BlendedMVS): ``world_mat_i`` is the 3x4 (or
    4x4) projection ``P = K [R | t]``, optionally ``scale_mat_i``; images in ``image/``,
    masks in ``mask/`` (sorted file names, the i-th file is camera i). ``P`` is decomposed
    with ``cv2.decomposeProjectionMatrix`` and normalised so ``K[2, 2] = 1``,
    ``fx, fy > 0`` and ``det R = +1``. Frame: by default the dataset's own world
    (``world_mat``; DTU's is in mm); with ``frame="normalised"`` the IDR training frame
    ``P @ scale_mat`` (the object inside the unit sphere). ``scale_mat_0`` is kept in
    ``capture.json["import"]["scale_mat"]`` either way (``X_normalised = inv(S) @ X_world``).
    Units: unknown, kept. Images: the masks are the silhouettes, written as
    ``255 - mask`` with polarity ``"dark-object"`` (like nerf); the photographs are not
    copied (a capture has one image per camera).
``opencv``
    One ``cv2.FileStorage`` file per camera (``.yml``/``.yaml``/``.xml``/``.json``) with
    the intrinsics (``camera_matrix``, ``K``, ``cameraMatrix``, ``intrinsic``...), the
    distortion (``distortion_coefficients``, ``dist``, ``D``, ``dist_coeffs``...), the
    world -> camera pose (``R``/``rotation``/``rotation_matrix`` or ``rvec``;
    ``t``/``T``/``tvec``/``translation``) and optionally the size
    (``image_width``/``image_height``, ``width``/``height``, ``image_size``), plus an image
    with the same stem (same folder or ``images/``). Units: the file's ``units`` key
    (``"mm"`` or ``"m"``) when present, else unknown and kept. Images copied unchanged;
    polarity ``"dark-object"`` (the CONTRACT default) unless ``polarity`` is given.

Every capture gets ``capture.json`` with ``polarity``, ``part_id`` (the dataset's name)
and ``"import"``: ``format``, ``source``, ``units``, ``scale_to_mm`` (factor applied to
lengths), ``pixel_convention``, ``images`` (what the images are) and ``segment`` (the
segment-stage parameters that reproduce the dataset's silhouettes, used by
:func:`leave_one_out_iou`). Missing or corrupt inputs raise
:class:`~inspector.errors.InputError` with a one-line message naming the file.

:func:`leave_one_out_iou` validates an imported capture: the hull carved from all views
but one, projected into the one left out, compared with its silhouette.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from inspector.errors import InputError

# The formats, one module each (their shared helpers in importers.common), and the validation.
from inspector_tools.importers.common import _load_json_file, _read_text, fill_holes  # noqa: F401 - the tests import them from here
from inspector_tools.importers.idr import decompose_projection, import_idr
from inspector_tools.importers.middlebury import MIDDLEBURY_CLOSE_PX, MIDDLEBURY_LEVEL, import_middlebury
from inspector_tools.importers.nerf import import_nerf
from inspector_tools.importers.opencv import import_opencv
from inspector_tools.importers.validate import close_mask, leave_one_out_iou, project_mesh_mask

__all__ = [
    "IMPORTERS",
    "import_middlebury",
    "import_nerf",
    "import_idr",
    "import_opencv",
    "decompose_projection",
    "leave_one_out_iou",
    "fill_holes",
    "close_mask",
    "project_mesh_mask",
    "MIDDLEBURY_LEVEL",
    "MIDDLEBURY_CLOSE_PX",
    "add_parser",
    "run",
]

IMPORTERS: dict[str, Callable[[Path, Path], list[Path]]] = {
    "middlebury": import_middlebury,
    "nerf": import_nerf,
    "idr": import_idr,
    "opencv": import_opencv,
}


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``import`` sub-command to ``subparsers`` (argparse) and return its parser."""
    ip = subparsers.add_parser(
        "import",
        help="convert third-party calibrated multi-view data into capture folders",
        description=(
            "Convert calibrated multi-view data into capture folders (rig.json in mm). "
            "middlebury: *_par.txt (metres, x1000); nerf: transforms*.json (alpha = silhouette); "
            "idr: cameras*.npz + image/ + mask/; opencv: one FileStorage file per camera + same-stem images."
        ),
    )
    ip.add_argument("format", choices=sorted(IMPORTERS), help="input format")
    ip.add_argument("src", help="the calibration file, or the folder holding it")
    ip.add_argument("--out", required=True, metavar="DIR", help="capture folder to write (DIR/<name>/ when SRC holds several)")
    ip.add_argument("--scale", type=float, default=None, help="factor applied to lengths (default: 1000 for metres, 1 for unknown units)")
    ip.add_argument("--polarity", choices=("dark-object", "bright-object"), default=None, help="opencv only: polarity of the images (default dark-object)")
    ip.add_argument("--frame", choices=("world", "normalised"), default="world", help="idr only: dataset world (world_mat) or IDR's normalised frame (world_mat @ scale_mat)")
    ip.add_argument("--force", action="store_true", help="overwrite the capture entries of an existing capture folder")
    ip.add_argument("--validate", action="store_true", help="then print the leave-one-out IoU of each view (slow: one carving per view)")
    ip.add_argument("--voxel-mm", type=float, default=None, help="carving voxel for --validate (default 2 pixel footprints at the rig centre)")
    return ip


def run(args: argparse.Namespace) -> int:
    """Run ``inspector import``; 0 on success, 2 (one line on stderr) when an input is invalid, like every command."""
    try:
        fn = IMPORTERS[args.format]
        kw: dict[str, Any] = {"scale": args.scale, "overwrite": bool(args.force)}
        if args.format == "opencv":
            kw["polarity"] = args.polarity
        if args.format == "idr":
            kw["frame"] = args.frame
        folders = fn(Path(args.src), Path(args.out), **kw)
        for f in folders:
            print(f"wrote {f}", flush=True)
        if getattr(args, "validate", False):
            from inspector.capture_folder import read_rig

            for f in folders:
                voxel = args.voxel_mm or 2.0 * read_rig(Path(f) / "rig.json").footprint_mm()
                det: dict[str, Any] = {}
                res = leave_one_out_iou(f, voxel_mm=voxel, details=det)
                views = ", ".join(f"{k} {v:.3f}" for k, v in res.items() if k not in ("median", "mean", "min"))
                print(f"{f}: leave-one-out IoU (voxel {voxel:.3g} mm): {views}", flush=True)
                print(f"{f}: median {res['median']:.4f}, mean {res['mean']:.4f}, min {res['min']:.4f} ({len(det['clipped'])} clipped views left out)")
    except InputError as exc:
        print(f"inspector: error: {exc}", file=sys.stderr)
        return 2
    return 0
