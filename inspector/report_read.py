"""Reading a result folder for the pictures and the PDF report (CONTRACT outputs only).

``result.json`` with what the pictures need checked, its BCPS points, a picture given for the
PDF and the recipe it names: every file that is missing or unreadable is an
:class:`~inspector.errors.InputError` naming it. Part of :mod:`inspector.report`.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import InputError
from inspector.limits import json_depth, limit
from inspector.locale import _

#: Verdicts that come without pose, statistics or points.
_UNFINISHED = ("error", "aborted")


def _dict(x: Any) -> dict:
    """``x`` when it is a dict, else an empty one (a damaged optional entry shows as "—")."""
    return x if isinstance(x, dict) else {}


def _recipe_info(res: dict, recipe: Path | None) -> dict:
    """What the page says about the recipe: name, file, SHA-256, text and a note.

    ``recipe`` (given) is read and hashed; else the file ``result.json`` names
    (``recipe_path``) is shown only when its bytes still have the recorded ``recipe_sha256``.
    """
    recorded = res.get("recipe_sha256") if isinstance(res.get("recipe_sha256"), str) else None
    info: dict[str, Any] = {"name": str(res.get("recipe") or "—"), "path": None, "sha256": recorded,
                            "text": None, "note": None}
    if recipe is not None:
        try:
            data = recipe.read_bytes()
        except OSError as e:
            raise InputError(f"{recipe}: cannot read ({e.strerror or type(e).__name__})") from None
        info.update(path=str(recipe.resolve()), sha256=hashlib.sha256(data).hexdigest(),
                    text=data.decode("utf-8", "replace"))
        if recorded and recorded != info["sha256"]:
            info["note"] = _("not the recipe this inspection recorded (SHA-256 {sha})").format(sha=recorded)
        return info
    named = res.get("recipe_path")
    if not isinstance(named, str) or not named:
        info["note"] = _("(recipe file not found)") if recorded else _("recipe file not recorded in result.json")
        return info
    info["path"] = named
    try:
        data = Path(named).read_bytes()
    except OSError:
        info["note"] = _("(recipe file not found)")
        return info
    now = hashlib.sha256(data).hexdigest()
    if recorded and now != recorded:
        info["note"] = _("the file has changed since the inspection (now SHA-256 {sha}); its text is not shown").format(sha=now)
        return info
    info.update(sha256=now, text=data.decode("utf-8", "replace"))
    return info


def _read_result(path: Path) -> dict:
    """result.json (CONTRACT) with what the pictures need checked; InputError otherwise."""
    try:
        # Bounded like every JSON input, before it is read and parsed (a result.json nests
        # capture.json's metadata two levels down, hence + 2).
        size, most = path.stat().st_size, limit("MAX_JSON_BYTES")
        if size > most:
            raise InputError(f"{path}: cannot read ({size} bytes, more than the {most} a JSON input may have: INSPECTOR_MAX_JSON_BYTES)")
        text = path.read_text()
        depth, deepest = json_depth(text.encode("utf-8", "surrogatepass")), limit("MAX_JSON_DEPTH") + 2
        if depth > deepest:
            raise InputError(f"{path}: cannot read (nested {depth} levels deep, more than {deepest}: INSPECTOR_MAX_JSON_DEPTH)")
        res = json.loads(text)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read ({type(e).__name__})") from None
    if not isinstance(res, dict):
        raise InputError(f"{path}: not a result (a JSON object is expected)")
    need = ("capture", "verdict") if res.get("verdict") in _UNFINISHED else ("capture", "verdict", "pose", "stats")
    missing = [k for k in need if k not in res]
    if missing:
        raise InputError(f"{path}: missing key {missing[0]!r}")
    if not isinstance(res["verdict"], str):
        raise InputError(f"{path}: verdict must be a string")
    if res["verdict"] not in _UNFINISHED:
        try:
            pose = np.asarray(res["pose"], dtype=float)
        except (TypeError, ValueError):  # not numbers, or rows of different lengths
            pose = None
        if pose is None or pose.shape != (4, 4):
            raise InputError(f"{path}: pose must be a 4x4 matrix")
        if not isinstance(res["stats"], dict):
            raise InputError(f"{path}: stats must be an object")
        tol = res["stats"].get("tolerance_mm", {"lower": 0.0, "upper": 0.0})
        if not (isinstance(tol, dict) and all(isinstance(tol.get(k), (int, float)) for k in ("lower", "upper"))):
            raise InputError(f"{path}: stats.tolerance_mm must have numbers lower and upper")
    _check_defects(path, res.get("defects", []))
    return res


def _check_defects(path: Path, defects: Any) -> None:
    """Every defect has the keys and types the pictures use; InputError naming the first bad one."""
    if not isinstance(defects, list):
        raise InputError(f"{path}: defects must be a list")
    for i, d in enumerate(defects):
        where = f"{path}: defects[{i}]"
        if not isinstance(d, dict):
            raise InputError(f"{where}: not an object")
        for key in ("kind", "region", "n_points", "worst_mm", "position", "extent"):
            if key not in d:
                raise InputError(f"{where}: missing key {key!r}")
        if not isinstance(d["worst_mm"], (int, float)) or not isinstance(d["n_points"], int):
            raise InputError(f"{where}: worst_mm and n_points must be numbers")
        for key in ("position", "extent"):
            v = d[key]
            if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)):
                raise InputError(f"{where}: {key} must be 3 numbers")


def _result_points(folder: Path, res: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The BCPS points of a finished result, or None when it has none."""
    named = (_dict(res.get("points"))).get("bcps")
    if res["verdict"] in _UNFINISHED or not named:
        return None
    return _read_points(folder / str(named))


def _read_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """BCPS points (N, 3) world mm and their deviations (N,) mm from a bcps_points.ply."""
    from inspector.outputs import read_ply

    if not path.is_file():
        raise InputError(f"{path}: missing (result.json names it)")
    try:
        p = read_ply(path)
    except Exception as e:  # noqa: BLE001 - plyfile raises several types for a bad file
        raise InputError(f"{path}: not a readable PLY ({' '.join(str(e).split())})") from None
    absent = [k for k in ("x", "y", "z", "deviation") if k not in p]
    if absent:
        raise InputError(f"{path}: no vertex property {absent[0]!r}")
    return np.stack([p["x"], p["y"], p["z"]], axis=1).astype(float), p["deviation"].astype(float)


def _read_picture(path: Path) -> np.ndarray:
    """A PNG as an image array; InputError naming the file otherwise."""
    from matplotlib.image import imread

    if not path.is_file():
        raise InputError(f"{path}: picture not found")
    try:
        return imread(path, format="png")
    except Exception as e:  # noqa: BLE001 - Pillow raises several types for a bad image
        raise InputError(f"{path}: not a readable PNG ({type(e).__name__})") from None
