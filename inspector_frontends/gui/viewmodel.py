"""What the operator screen shows, as plain arrays: no Qt, no VTK.

A :class:`ResultView` is built from a fresh inspection (:func:`from_outcome`, which also has
the images and silhouettes) or from a result folder written earlier (:func:`from_folder`,
CONTRACT files only). Widgets only draw it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from inspector.capture_folder import read_rig
from inspector.characteristics.definitions import rows_of
from inspector.errors import InputError
from inspector.outputs import read_ply, result_to_json

__all__ = ["CameraThumb", "DefectRow", "CharacteristicRow", "ResultView", "characteristic_rows", "from_outcome", "from_folder", "reason_text", "camera_thumbs",
           "calibration_flags", "normalised", "point_arrays", "SPAN", "SCALED", "set_text", "translate", "number"]

# -- words and numbers --------------------------------------------------------------------------
# The texts of a view are marked with translate("ViewModel", ...), which Qt's lupdate collects
# into the GUI's translation files; this module stays Qt-free: the GUI points the hooks at Qt's
# translator and locale (inspector_frontends.gui.i18n.install). Headless: English, Python's number format.
_translate: Callable[[str, str], str] = lambda context, text: text  # noqa: E731
_number: Callable[..., str] = lambda value, decimals, *, sign=False: f"{value:{'+' if sign else ''}.{decimals}f}"  # noqa: E731


def set_text(translate_: Callable[[str, str], str] | None, number_: Callable[..., str] | None) -> None:
    """Translate this module's texts with ``translate_(context, text)`` and write numbers with
    ``number_(value, decimals, sign=False)`` (None: English, Python's format)."""
    global _translate, _number
    _translate = translate_ if translate_ is not None else (lambda context, text: text)
    _number = number_ if number_ is not None else (lambda value, decimals, *, sign=False:
                                                   f"{value:{'+' if sign else ''}.{decimals}f}")


def translate(context: str, text: str) -> str:
    """``text`` in the GUI's language (see :func:`set_text`)."""
    return _translate(context, text)


def number(value: float, decimals: int, *, sign: bool = False) -> str:
    """``value`` with ``decimals`` decimals in the GUI's locale (``sign``: ``+`` before a positive one)."""
    return _number(float(value), decimals, sign=sign)


#: The colour scale spans this many tolerance widths on each side.
SPAN = 3.0
#: Key of :attr:`ResultView.prepared` holding the deviations in units of their limit.
SCALED = "deviation / limit"
#: Thumbnails are at most this many pixels on their longer side.
THUMB_PX = 192
#: A camera is flagged when the share of its contour rays without a consistent BCPS point
#: exceeds the cameras' median share by this much (its silhouette disagrees with the others).
DISAGREE_MARGIN = 0.25


@dataclass(frozen=True, eq=False)
class CameraThumb:
    """One camera as the strip shows it.

    Attributes
    ----------
    name : str
    image : (h, w) uint8
        The camera image around the silhouette, downsampled by ``scale``.
    scale : float
        Thumbnail pixels per image pixel.
    origin : (2,) float
        Full-image pixel ``(u, v)`` of the thumbnail's top-left corner (it is cropped to
        the silhouette with a margin, so the part fills it).
    full : (H, W) uint8 or None
        The full image, for the large view (None when not kept).
    contour : (M, 2) float
        Sub-pixel contour points ``(u, v)`` in full-image pixels.
    touches_border : bool
    unmatched : float
        Share of this camera's contour rays with no BCPS point consistent with the other
        cameras' silhouettes (0: all consistent).
    flags : tuple of str
        Why the camera is flagged, in words (empty: not flagged).
    """

    name: str
    image: np.ndarray
    scale: float
    origin: np.ndarray
    full: np.ndarray | None
    contour: np.ndarray
    touches_border: bool
    unmatched: float
    flags: tuple[str, ...] = ()


@dataclass(frozen=True)
class DefectRow:
    """One defect cluster, numbered from 1 (worst first, as ``result.json`` lists them)."""

    number: int
    kind: str
    region: str
    n_points: int
    worst_mm: float
    position: tuple[float, float, float]
    extent: tuple[float, float, float]
    cameras: tuple[str, ...]


@dataclass(frozen=True)
class CharacteristicRow:
    """One measured characteristic of the part (``result.json`` ``extras.characteristics``).

    ``nominal`` and ``measured`` in ``unit`` (mm or deg); ``lower``/``upper`` are deviations
    from ``nominal`` (form: limits of the value, nominal 0); ``measured``, ``deviation`` and
    ``U`` (expanded uncertainty, k = 2) are None when ``verdict`` is ``not_measurable``, and
    ``reason`` says why.
    """

    id: str
    kind: str
    label: str
    unit: str
    nominal: float
    measured: float | None
    deviation: float | None
    lower: float
    upper: float
    U: float | None
    verdict: str
    reason: str = ""
    criticality: str = ""
    points: int = 0

    @property
    def use(self) -> float | None:
        """The share of the tolerance the deviation uses (1: on a limit, above: outside)."""
        if self.deviation is None:
            return None
        limit = self.upper if self.deviation >= 0 else self.lower
        return abs(self.deviation) / abs(limit) if limit else (0.0 if self.deviation == 0 else float("inf"))


def _float(v: Any) -> float | None:
    try:
        return None if v is None else float(v)
    except (TypeError, ValueError):
        return None


def characteristic_rows(doc: Any) -> tuple[CharacteristicRow, ...]:
    """The characteristics of a result (an :class:`~inspector.model.InspectionResult` or a
    ``result.json`` document), in the recipe's order; () when the recipe measures none."""
    out = []
    for r in rows_of(doc):
        try:
            out.append(CharacteristicRow(
                id=str(r["id"]), kind=str(r.get("kind", "")), label=str(r.get("description") or r.get("kind", "")),
                unit=str(r.get("unit", "mm")), nominal=float(r.get("nominal", 0.0)), measured=_float(r.get("measured")),
                deviation=_float(r.get("deviation")), lower=float(r.get("lower", 0.0)), upper=float(r.get("upper", 0.0)),
                U=_float(r.get("U")), verdict=str(r.get("verdict", "not_measurable")), reason=str(r.get("reason", "")),
                criticality=str(r.get("criticality", "")), points=int(r.get("points", 0) or 0)))
        except (KeyError, TypeError, ValueError):  # a damaged row: the others are still shown
            continue
    return tuple(out)


@dataclass(frozen=True, eq=False)
class ResultView:
    """One inspection, ready to draw.

    Attributes
    ----------
    points : (N, 3) float32, mm, world frame
    deviation : (N,) float32, mm (negative: missing material)
    camera : (N,) int
        Index of the camera whose contour produced each point.
    tolerance : (lower, upper) mm
    reference : ((V, 3) float, (F, 3) int) or None
        The reference mesh placed on the part (world frame).
    camera_centres : (C, 3) float
        Optical centres of the rig's cameras (world mm), in ``camera_names`` order.
    characteristics : tuple of CharacteristicRow
        The part's measured characteristics (:func:`characteristic_rows`), () when the
        recipe measures none.
    calibration_flagged : dict
        The cameras the evaluate stage's calibration health flagged, each with why in words
        (:func:`calibration_flags`; the camera strip marks their tiles).
    prepared : dict
        What was computed for drawing off the GUI thread (arrays, images), so the GUI thread
        only hands it to the widgets: :data:`SCALED` (``(N,) float32``, deviation in units
        of its limit, see :func:`normalised`) from :func:`from_outcome`; the GUI's worker adds
        its own entries. A widget computes what is missing itself.
    """

    capture: str
    verdict: str
    recipe: str = ""
    part_id: str | None = None
    cycle_s: float | None = None
    reason: str = ""
    error: str | None = None
    folder: Path | None = None
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    deviation: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    camera: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int16))
    tolerance: tuple[float, float] = (-0.1, 0.1)
    reference: tuple[np.ndarray, np.ndarray] | None = None
    defects: tuple[DefectRow, ...] = ()
    cameras: tuple[CameraThumb, ...] = ()
    camera_names: tuple[str, ...] = ()
    camera_centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    stats: dict[str, Any] = field(default_factory=dict)
    prepared: dict[str, Any] = field(default_factory=dict)
    calibration_flagged: dict[str, str] = field(default_factory=dict)
    characteristics: tuple[CharacteristicRow, ...] = ()


def calibration_flags(stats: Any) -> dict[str, str]:
    """The cameras a result's ``stats.calibration`` flags, each with why in words: how far
    it is off the others and what to do."""
    cal = stats.get("calibration") if isinstance(stats, dict) else None
    if not isinstance(cal, dict):
        return {}
    cams = cal.get("cameras")
    if not isinstance(cams, dict):
        cams = {}
    out = {}
    for name in cal.get("flagged") or ():
        off = (cams.get(name) or {}).get("off_px")
        limit = cal.get("threshold_px")
        limit_text = number(limit, 2) if isinstance(limit, (int, float)) else "?"
        if isinstance(off, (int, float)):
            text = translate("ViewModel", "calibration: disagrees with the other cameras by {off} px (threshold {limit} px): "
                                          "check its mounting or recalibrate").format(off=number(off, 2), limit=limit_text)
        else:
            text = translate("ViewModel", "calibration: disagrees with the other cameras (threshold {limit} px): "
                                          "check its mounting or recalibrate").format(limit=limit_text)
        out[str(name)] = text
    return out


def normalised(deviation: np.ndarray, tolerance: tuple[float, float]) -> np.ndarray:
    """Deviation in units of its own tolerance limit, as float32: -1 and +1 are the limits
    (which may be asymmetric), so the colour scale is fixed to them whatever the numbers;
    clipped to +-:data:`SPAN`.

    Parameters
    ----------
    deviation : (N,) float, mm
    tolerance : (lower, upper), mm, lower < 0 < upper
    """
    lo, hi = tolerance
    d = np.asarray(deviation, np.float32)
    return np.where(d >= 0, d / np.float32(max(hi, 1e-9)), d / np.float32(max(-lo, 1e-9))).clip(-SPAN, SPAN) \
        .astype(np.float32, copy=False)


def point_arrays(points: Any, deviation: Any, camera: Any, tolerance: tuple[float, float]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """The per-point arrays of a view, copied (the inspection can be dropped), and what is
    drawn from them (``prepared``): all the work that grows with the number of points,
    done in the thread that builds the view."""
    pts = np.ascontiguousarray(points, np.float32).copy()
    dev = np.ascontiguousarray(deviation, np.float32).copy()
    cam = np.asarray(camera, np.int16).copy()
    return pts, dev, cam, {SCALED: normalised(dev, tolerance)}


def reason_text(verdict: str, defects: list[dict[str, Any]] | tuple[DefectRow, ...], tolerance: tuple[float, float],
                error: str | None, characteristics: tuple[CharacteristicRow, ...] = ()) -> str:
    """The verdict's reason in words: for a FAIL the worst defect against its limit (and how
    many characteristics are out of tolerance), or the worst NOK characteristic when no defect
    failed it; for an ERROR (or ABORTED) the one-line error."""
    if verdict in ("error", "aborted"):
        return error or ""
    nok = sorted((c for c in characteristics if c.verdict == "nok"), key=lambda c: -(c.use or 0.0))
    if verdict != "fail":
        return ""
    if not defects:
        return _nok_text(nok[0], len(nok) - 1) if nok else ""
    return _defect_text(defects, tolerance) + (
        translate("ViewModel", " (+{n} NOK characteristics)").format(n=len(nok)) if nok else "")


def _nok_text(c: CharacteristicRow, more: int) -> str:
    """``characteristic 2 (depth 30): 30.021 mm, limits -0.010 / +0.010``."""
    digits = 3 if c.unit == "mm" else 2
    text = translate("ViewModel", "characteristic {id} ({label}): {value} {unit}, deviation {dev}, limits {lower} / {upper}")
    text = text.format(id=c.id, label=c.label, value=number(c.measured or 0.0, digits), unit=c.unit,
                       dev=number(c.deviation or 0.0, digits, sign=True), lower=number(c.lower, digits, sign=True),
                       upper=number(c.upper, digits, sign=True))
    if more:
        text += translate("ViewModel", " (+{n} more NOK)").format(n=more)
    return text


def _defect_text(defects: list[dict[str, Any]] | tuple[DefectRow, ...], tolerance: tuple[float, float]) -> str:
    rows: list[dict[str, Any]] = [
        d if isinstance(d, dict) else {"kind": d.kind, "region": d.region, "worst_mm": d.worst_mm} for d in defects]
    worst = max(rows, key=lambda d: abs(d["worst_mm"]))
    limit = tolerance[0] if worst["kind"] == "missing" else tolerance[1]
    text = (translate("ViewModel", "missing material in region '{region}': {worst} mm, limit {limit} mm")
            if worst["kind"] == "missing" else
            translate("ViewModel", "excess material in region '{region}': {worst} mm, limit {limit} mm"))
    text = text.format(region=worst["region"], worst=number(worst["worst_mm"], 3, sign=True),
                       limit=number(limit, 3, sign=True))
    if len(rows) == 2:
        text += translate("ViewModel", " (+1 more defect)")
    elif len(rows) > 2:
        text += translate("ViewModel", " (+{n} more defects)").format(n=len(rows) - 1)
    return text


def _defect_cameras(d: dict[str, Any], points: np.ndarray, deviation: np.ndarray, camera: np.ndarray,
                    tolerance: tuple[float, float], names: tuple[str, ...]) -> tuple[str, ...]:
    """Cameras whose contour points make up the defect: out-of-tolerance points of its kind
    inside its bounding box (grown by a millimetre)."""
    if not len(points):
        return ()
    lo = np.asarray(d["position"]) - np.asarray(d["extent"]) / 2 - 1.0
    hi = np.asarray(d["position"]) + np.asarray(d["extent"]) / 2 + 1.0
    bad = deviation < tolerance[0] if d["kind"] == "missing" else deviation > tolerance[1]
    sel = bad & np.all((points >= lo) & (points <= hi), axis=1)
    idx = np.unique(camera[sel])
    return tuple(names[i] if 0 <= i < len(names) else f"#{i}" for i in idx)


def _xyz(v: Any) -> tuple[float, float, float]:
    """A 3-vector of a defect (``position``, ``extent``) as floats."""
    x, y, z = v
    return float(x), float(y), float(z)


def _defect_rows(defects: list[dict[str, Any]], points, deviation, camera, tolerance, names) -> tuple[DefectRow, ...]:
    return tuple(
        DefectRow(
            number=k + 1,
            kind=str(d["kind"]),
            region=str(d.get("region", "default")),
            n_points=int(d["n_points"]),
            worst_mm=float(d["worst_mm"]),
            position=_xyz(d["position"]),
            extent=_xyz(d["extent"]),
            cameras=_defect_cameras(d, points, deviation, camera, tolerance, names),
        )
        for k, d in enumerate(defects)
    )


def _thumb(image: np.ndarray, contour: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """(thumbnail, scale, origin, full 8-bit image) of a camera image of any supported type;
    the thumbnail is the square around the contour's bounding box, with a 25 % margin."""
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = img.mean(axis=2)
    if img.dtype != np.uint8:
        top = float(img.max()) if img.size else 1.0
        img = np.clip(img.astype(np.float32) * (255.0 / max(top, 1e-9)), 0, 255).astype(np.uint8)
    h, w = img.shape
    u0, v0, u1, v1 = 0, 0, w, h
    if len(contour):
        lo, hi = np.floor(contour.min(axis=0)), np.ceil(contour.max(axis=0))
        centre, half = (lo + hi) / 2, max(hi - lo) * 0.625 + 8
        u0, v0 = (int(max(0, centre[0] - half)), int(max(0, centre[1] - half)))
        u1, v1 = (int(min(w, centre[0] + half)), int(min(h, centre[1] + half)))
    crop = img[v0:v1, u0:u1]
    ch, cw = crop.shape
    scale = min(1.0, THUMB_PX / max(ch, cw))
    small = cv2.resize(crop, (max(1, round(cw * scale)), max(1, round(ch * scale))), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(small), scale, np.array([u0, v0], float), np.ascontiguousarray(img)


def camera_thumbs(ctx: Any, keep_full: bool = True) -> tuple[CameraThumb, ...]:
    """The cameras of an inspection's context (``outcome.context``) as the strip shows them:
    thumbnails around the silhouette, contours, flags; () without a context."""
    if ctx is None:
        return ()
    capture = ctx.capture
    names = capture.rig.names
    sils = {s.camera: s for s in (ctx.silhouettes or ())}
    per_cam = np.zeros(len(names))
    if ctx.bcps is not None and len(ctx.bcps.camera):
        per_cam = np.bincount(np.asarray(ctx.bcps.camera, int), minlength=len(names))[: len(names)].astype(float)
    unmatched = np.zeros(len(names))
    for i, n in enumerate(names):
        s = sils.get(n)
        if s is not None and len(s.contour) and ctx.bcps is not None:
            unmatched[i] = max(0.0, 1.0 - per_cam[i] / len(s.contour))
    median = float(np.median(unmatched)) if len(unmatched) else 0.0
    calibration = calibration_flags(ctx.evaluation.stats) if ctx.evaluation is not None else {}
    out = []
    for i, n in enumerate(names):
        if n not in capture.images:
            continue
        s = sils.get(n)
        contour = np.asarray(s.contour, float) if s is not None else np.zeros((0, 2))
        small, scale, origin, full = _thumb(capture.images[n], contour)
        flags = []
        if s is not None and s.touches_border:
            flags.append(translate("ViewModel", "silhouette touches the image border"))
        if ctx.bcps is not None and unmatched[i] > median + DISAGREE_MARGIN:
            flags.append(translate("ViewModel", "silhouette disagrees with the others: {share} % of its contour rays "
                                                "inconsistent (median {median} %)").format(
                share=number(100 * unmatched[i], 0), median=number(100 * median, 0)))
        if n in calibration:
            flags.append(calibration[n])
        out.append(CameraThumb(n, small, scale, origin, full if keep_full else None, contour,
                               bool(s.touches_border) if s is not None else False, float(unmatched[i]), tuple(flags)))
    return tuple(out)


def _centres(rig: Any) -> tuple[tuple[str, ...], np.ndarray]:
    if rig is None or not len(rig):
        return (), np.zeros((0, 3))
    return tuple(rig.names), np.array([np.asarray(c.centre, float) for c in rig.cameras])


def _placed(reference: Any, pose: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    if reference is None or pose is None:
        return None
    pose = np.asarray(pose, float)
    return np.asarray(reference.vertices, float) @ pose[:3, :3].T + pose[:3, 3], np.asarray(reference.faces, np.int64)


def from_outcome(outcome: Any, folder: Path | None, reference: Any = None, *, keep_full: bool = True,
                 cameras: bool = True) -> ResultView:
    """The view of a fresh inspection (an :class:`inspector.runner.Outcome`).

    ``reference`` is the session's :class:`~inspector.reference.Reference` (drawn on the
    part, translucent). Call it in the thread that ran the inspection: it copies what it
    needs, so the outcome can be dropped right after. ``cameras=False`` leaves the camera
    thumbnails out (the slowest part: the verdict can be shown before they are made with
    :func:`camera_thumbs`).
    """

    res = outcome.result
    doc = result_to_json(res, with_points=False)
    ctx = outcome.context
    names, centres = _centres(res.rig)
    tol = doc["stats"].get("tolerance_mm", {})
    if not tol and ctx is not None:
        tol = {"lower": ctx.tolerance.default.lower, "upper": ctx.tolerance.default.upper}
    tolerance = (float(tol.get("lower", -0.1)), float(tol.get("upper", 0.1)))
    points = np.zeros((0, 3), np.float32)
    deviation = np.zeros(0, np.float32)
    camera = np.zeros(0, np.int16)
    prepared: dict[str, Any] = {}
    if res.bcps is not None:
        points, deviation, camera, prepared = point_arrays(res.bcps.points, res.bcps.deviation, res.bcps.camera,
                                                           tolerance)
    thumbs = camera_thumbs(ctx, keep_full) if cameras else ()
    chars = characteristic_rows(doc)
    return ResultView(
        capture=res.capture,
        verdict=res.verdict,
        recipe=res.recipe,
        part_id=_part_id(doc["metadata"]),
        cycle_s=res.timings_s.get("total"),
        reason=reason_text(res.verdict, doc["defects"], tolerance, res.error, chars),
        error=res.error,
        folder=folder,
        points=points,
        deviation=deviation,
        camera=camera,
        tolerance=tolerance,
        reference=_placed(reference, res.pose),
        defects=_defect_rows(doc["defects"], points, deviation, camera, tolerance, names),
        cameras=thumbs,
        camera_names=names,
        camera_centres=centres,
        stats=doc["stats"],
        prepared=prepared,
        calibration_flagged=calibration_flags(doc["stats"]),
        characteristics=chars,
    )


def _part_id(metadata: dict[str, Any]) -> str | None:
    v = metadata.get("part_id")
    return None if v is None else str(v)


def from_folder(folder: Path, reference: Any = None) -> ResultView:
    """The view of a result folder written earlier (``result.json`` and its PLY files),
    without inspecting again. InputError naming the file when it cannot be read."""

    folder = Path(folder)
    path = folder / "result.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        verdict = str(doc["verdict"])
    except FileNotFoundError:
        raise InputError(f"{path}: no result.json (not a result folder)") from None
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: not a readable result ({type(e).__name__})") from None
    stats = doc.get("stats") or {}
    tol = stats.get("tolerance_mm") or {}
    tolerance = (float(tol.get("lower", -0.1)), float(tol.get("upper", 0.1)))
    points = np.zeros((0, 3), np.float32)
    deviation = np.zeros(0, np.float32)
    camera = np.zeros(0, np.int16)
    named = (doc.get("points") or {}).get("bcps")
    if named:
        try:
            cols = read_ply(folder / str(named))
            points = np.column_stack([cols["x"], cols["y"], cols["z"]]).astype(np.float32)
            deviation = np.asarray(cols["deviation"], np.float32)
            camera = np.asarray(cols.get("camera", np.zeros(len(points))), np.int16)
        except Exception as e:  # noqa: BLE001 - a damaged PLY: the verdict is still shown
            raise InputError(f"{folder / str(named)}: cannot be read ({type(e).__name__})") from None
    names: tuple[str, ...] = ()
    centres = np.zeros((0, 3))
    rig_file = folder / "rig.json"
    if rig_file.is_file():  # not a CONTRACT output; used when present
        try:
            names, centres = _centres(read_rig(rig_file))
        except Exception:  # noqa: BLE001 - the rig is optional here
            pass
    defects = list(doc.get("defects") or [])
    chars = characteristic_rows(doc)
    pose = doc.get("pose")
    ref = reference if reference is not None and doc.get("recipe") else None
    return ResultView(
        capture=str(doc.get("capture", folder.name)),
        verdict=verdict,
        recipe=str(doc.get("recipe", "")),
        part_id=_part_id(doc.get("metadata") or {}),
        cycle_s=(doc.get("timings_s") or {}).get("total"),
        reason=reason_text(verdict, defects, tolerance, doc.get("error"), chars),
        error=doc.get("error"),
        folder=folder,
        points=points,
        deviation=deviation,
        camera=camera,
        tolerance=tolerance,
        reference=_placed(ref, np.asarray(pose, float) if pose is not None else None),
        defects=_defect_rows(defects, points, deviation, camera, tolerance, names),
        camera_names=names,
        camera_centres=centres,
        stats=stats,
        prepared={SCALED: normalised(deviation, tolerance)},
        calibration_flagged=calibration_flags(stats),
        characteristics=chars,
    )

