"""A result as the PLC reads it: :func:`record` is what ``LastResult`` holds (JSON-safe, small,
no server path) and what the server publishes variable by variable; :func:`log_line` its line
in the server's log.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from inspector.characteristics.definitions import rows_of
from inspector.outputs import one_line

__all__ = ["record", "log_line", "MAX_DEFECTS_LISTED"]

#: Defects listed in a record (the count is whole).
MAX_DEFECTS_LISTED = 10


def _finite(x: Any) -> float | None:
    try:
        f = float(x)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def record(result: Any, folder: Path | None) -> dict[str, Any]:
    """A result as ``LastResult`` tells it (JSON-safe, small)."""
    meta = dict(result.metadata or {})
    worst = None
    summary = result.summary
    dev = summary.deviation_mm if summary is not None else None
    if dev is not None:
        lo, hi = _finite(dev.min), _finite(dev.max)
        if lo is not None and hi is not None:
            worst = hi if abs(hi) >= abs(lo) else lo
    defects = [{"kind": d.kind, "region": d.region, "n_points": int(d.n_points), "worst_mm": _finite(d.worst_mm),
                "position": [_finite(x) for x in d.position]} for d in result.defects[:MAX_DEFECTS_LISTED]]
    part = meta.get("part_id")
    return {"part_id": "" if part is None else str(part), "capture": result.capture, "verdict": result.verdict,
            "error": result.error, "recipe": result.recipe, "inspection_s": _finite(result.timings_s.get("total")),
            "worst_deviation_mm": worst, "defect_count": len(result.defects), "defects": defects,
            "result_dir": folder.name if folder is not None else None,  # relative to --out: no server path
            "triggered_at": None if meta.get("timestamp") is None else str(meta["timestamp"]),
            "calibration": _calibration(result.stats), "characteristics": _characteristics(result)}


def _characteristics(result: Any) -> list[dict[str, Any]]:
    """The result's characteristics as the PLC reads them (issue 28): a few numbers each."""
    keys = ("id", "kind", "measured", "deviation", "lower", "upper", "U", "verdict")
    return [{k: (_finite(r.get(k)) if k in ("measured", "deviation", "lower", "upper", "U") else r.get(k))
             for k in keys} for r in rows_of(result)]


def _calibration(stats: Any) -> dict[str, Any] | None:
    """The result's calibration health as ``LastResult`` tells it: the flagged cameras and how
    far each camera is off (px); None when the part did not check it."""
    cal = stats.get("calibration") if isinstance(stats, dict) else None
    if not isinstance(cal, dict) or not isinstance(cal.get("cameras"), dict):
        return None
    return {"flagged": [str(n) for n in cal.get("flagged") or ()],
            "off_px": {str(n): _finite((c or {}).get("off_px")) for n, c in cal["cameras"].items()}}


def log_line(result: Any) -> str:
    """The result's line in the server's log (``inspector run``'s progress line)."""
    return one_line(result)
