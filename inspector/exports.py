"""CSV exports for metrology users, next to the PLY files of a result folder.

``inspector run --csv`` (or ``[outputs] csv = true`` in the recipe) writes, for every
capture with BCPS points:

``bcps_points.csv``
    One row per BCPS point (the vertices of ``bcps_points.ply``, in the same order):
    ``x_mm, y_mm, z_mm`` (world), ``deviation_mm`` (signed, negative: missing material),
    ``camera`` (the camera whose contour gave the point), ``u_px, v_px`` (that contour point),
    ``segment_mm``, ``confidence``, ``region`` (the tolerance region whose band applies:
    ``default`` or a region's name), ``lower_mm, upper_mm`` (that band), and
    ``out_of_tolerance`` (1 or 0). The last four are empty without an evaluate stage.

``regions.csv``
    One row per tolerance region (``default`` first: the points in no named region), then
    ``all``: ``region, lower_mm, upper_mm, n_points, out_of_tolerance_points,
    within_tolerance, mean_mm, std_mm, min_mm, max_mm, p01_mm, p99_mm, mean_abs_mm,
    defects, worst_defect_mm``. Read from the evaluate stage's typed summary
    (:class:`inspector.model.EvaluationSummary`) and the result's defects.

Comma-separated, a header row, ``.`` decimal point, UTF-8, ``\\n`` line ends; empty fields
for unknown values. Each file is written to a temporary name and renamed.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from inspector.kernels.bcps import confidence
from inspector.model import DeviationStats, InspectionResult

__all__ = ["POINTS_CSV", "REGIONS_CSV", "POINT_COLUMNS", "REGION_COLUMNS", "write_csv", "remove_csv"]

POINTS_CSV = "bcps_points.csv"
REGIONS_CSV = "regions.csv"
POINT_COLUMNS = ("x_mm", "y_mm", "z_mm", "deviation_mm", "camera", "u_px", "v_px", "segment_mm", "confidence",
                 "region", "lower_mm", "upper_mm", "out_of_tolerance")
REGION_COLUMNS = ("region", "lower_mm", "upper_mm", "n_points", "out_of_tolerance_points", "within_tolerance",
                  "mean_mm", "std_mm", "min_mm", "max_mm", "p01_mm", "p99_mm", "mean_abs_mm", "defects",
                  "worst_defect_mm")


def _write(path: Path, text: str) -> None:
    """``path`` written under a temporary name and renamed; nothing left behind on failure."""
    tmp = path.with_name(path.name + ".part")
    try:
        tmp.write_bytes(text.encode("utf-8"))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _num(x: float | None, spec: str = ".6f") -> str:
    return "" if x is None or not np.isfinite(x) else format(float(x), spec)


def write_csv(result: InspectionResult, folder: Path) -> list[Path]:
    """Write ``bcps_points.csv`` and ``regions.csv`` of ``result`` into ``folder``.

    Returns
    -------
    list of Path
        The files written (none when the result has no BCPS points, e.g. an error).
    """
    folder = Path(folder)
    remove_csv(folder)
    b = result.bcps
    if b is None:
        return []
    n = len(b.deviation)
    summary = result.summary
    regions = tuple(getattr(summary, "regions", ()) or ())  # optional fields of the contract
    idx = getattr(summary, "point_region", None)
    if idx is None or len(idx) != n or not regions:
        idx, regions = None, ()
    names = result.rig.names if result.rig is not None else ()
    if result.rig is not None and len(result.rig):
        conf = confidence(b.segment_mm, result.rig.footprint_mm())
    else:
        conf = np.full(n, np.nan)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(POINT_COLUMNS)
    for i in range(n):
        cam = int(b.camera[i])
        row = [_num(b.points[i, 0]), _num(b.points[i, 1]), _num(b.points[i, 2]), _num(b.deviation[i]),
               names[cam] if 0 <= cam < len(names) else str(cam), _num(b.pixel[i, 0], ".4f"), _num(b.pixel[i, 1], ".4f"),
               _num(b.segment_mm[i]), _num(conf[i], ".4f")]
        if idx is not None and 0 <= int(idx[i]) < len(regions):
            r = regions[int(idx[i])]
            dev = float(b.deviation[i])
            row += [r.name, _num(r.lower_mm), _num(r.upper_mm), "1" if dev < r.lower_mm or dev > r.upper_mm else "0"]
        else:
            row += ["", "", "", ""]
        w.writerow(row)
    written = [folder / POINTS_CSV]
    _write(written[0], buf.getvalue())

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(REGION_COLUMNS)
    for r in regions:
        w.writerow(_region_row(r.name, r.lower_mm, r.upper_mm, r.n_points, r.out_of_tolerance_points,
                               r.deviation_mm, [d for d in result.defects if d.region == r.name]))
    out_all = summary.out_of_tolerance_points if summary is not None else None
    w.writerow(_region_row("all", None, None, n, out_all, DeviationStats.of(b.deviation), list(result.defects)))
    written.append(folder / REGIONS_CSV)
    _write(written[1], buf.getvalue())
    return written


def _region_row(name: str, lower: float | None, upper: float | None, n: int,
                out: int | None, dev: DeviationStats | None, defects: list) -> list[str]:
    within = "" if out is None or not n else _num(1.0 - out / n)
    stats = [_num(getattr(dev, k)) if dev is not None else "" for k in ("mean", "std", "min", "max", "p01", "p99",
                                                                         "mean_abs")]
    worst = max((d.worst_mm for d in defects), key=abs, default=None)
    return [name, _num(lower), _num(upper), str(n), "" if out is None else str(out), within, *stats,
            str(len(defects)), _num(worst)]


def remove_csv(folder: Path) -> None:
    """Remove the CSV exports of an earlier run from ``folder`` (they would not match)."""
    for name in (POINTS_CSV, REGIONS_CSV):
        (Path(folder) / name).unlink(missing_ok=True)
