"""The history's charts: the trend of the inspections (``inspector history --plot``, the GUI's
history strip) and each camera's calibration health (``--cameras``), drawn with matplotlib
(imported when a chart is drawn), and the yield they show (:func:`tally`)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["VERDICT_COLOURS", "draw_cameras", "draw_history", "plot_cameras", "plot_history", "tally"]


def plot_history(rows: list[dict[str, Any]], out: Path) -> Path:
    """A trend picture of ``rows`` (:func:`read_history`), drawn by :func:`draw_history`,
    written to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 4.5), dpi=110)
    draw_history(ax, rows)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)
    return out


def plot_cameras(rows: list[dict[str, Any]], out: Path) -> Path:
    """The calibration health of ``rows`` (:func:`read_history`), drawn by
    :func:`draw_cameras`, written to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 4.5), dpi=110)
    draw_cameras(ax, rows)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)
    return out


def _calibration(row: Mapping[str, Any]) -> dict[str, Any] | None:
    """A row's ``calibration_json`` read (None: not checked, or not readable)."""
    raw = row.get("calibration_json")
    if not raw:
        return None
    try:
        doc = json.loads(raw) if isinstance(raw, str) else raw
    except ValueError:
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("off_px"), dict) else None


def draw_cameras(ax: Any, rows: list[dict[str, Any]]) -> str:
    """Draw each camera's calibration health over ``rows`` on the matplotlib axes ``ax``: per
    camera a line of how far it was off (px, ``stats.calibration`` ``off_px``) in each
    inspection, in order, a flagged inspection as a ring, and the threshold as a dashed
    line. Inspections without the figures (errors, older rows) are gaps. Returns the title."""
    docs = [_calibration(r) for r in rows]
    names = sorted({n for d in docs if d is not None for n in d["off_px"]})
    nan = float("nan")
    x = list(range(len(rows)))
    worst: dict[str, float] = {}
    cmap = _camera_colours(len(names))
    for k, name in enumerate(names):
        y = [nan if d is None or d["off_px"].get(name) is None else float(d["off_px"][name]) for d in docs]
        worst[name] = max((v for v in y if v == v), default=nan)
        ax.plot(x, y, "-", color=cmap[k], lw=1.2, marker=".", ms=4, label=name)
        flagged = [(i, v) for i, (d, v) in enumerate(zip(docs, y)) if d is not None and name in (d.get("flagged") or [])]
        if flagged:
            ax.plot([i for i, _ in flagged], [v for _, v in flagged], "o", mfc="none", mec="#c01010", ms=10, mew=2)
    limit = [nan if d is None or d.get("threshold_px") is None else float(d["threshold_px"]) for d in docs]
    if any(v == v for v in limit):
        ax.step(x, limit, where="mid", color="#c01010", ls="--", lw=1.2, label="threshold")
    from matplotlib.ticker import MaxNLocator

    ax.set_xlim(-0.5, max(len(rows), 1) - 0.5)
    ax.set_ylim(bottom=0.0)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    ax.set_xlabel("inspection (oldest first)")
    ax.set_ylabel("camera off by, px")
    if names:
        ax.legend(loc="upper left", fontsize=7, ncol=min(len(names) + 1, 9))
    flagged_rows = sum(1 for d in docs if d is not None and d.get("flagged"))
    checked = sum(1 for d in docs if d is not None)
    top = max(worst, key=lambda n: worst[n] if worst[n] == worst[n] else -1.0) if worst else None
    most = f"; most off: {top} {worst[top]:.2f} px" if top is not None and worst[top] == worst[top] else ""
    title = f"calibration health: {checked} of {len(rows)} inspections checked, {flagged_rows} with a camera flagged{most}"
    ax.set_title(title, fontsize=11)
    if len(rows) <= 30:
        ax.set_xticks(range(len(rows)), [r["capture"][:14] for r in rows], rotation=60, ha="right", fontsize=7)
    return title


def _camera_colours(n: int) -> list[Any]:
    """``n`` distinguishable line colours (matplotlib's tab20, then repeated)."""
    import matplotlib

    cmap = matplotlib.colormaps["tab20"]
    return [cmap(k % 20) for k in range(n)]


#: Verdict colours of the trend (the GUI's history strip uses the same).
VERDICT_COLOURS = {"pass": "#2e8b2e", "fail": "#c01010", "error": "#888888"}


def tally(rows: list[dict[str, Any]]) -> tuple[dict[str, int], float | None]:
    """Inspections per verdict (pass, fail, error) and the yield: the passed share of the
    parts judged (pass or fail); None when none was judged."""
    n = {v: sum(r["verdict"] == v for r in rows) for v in ("pass", "fail", "error")}
    judged = n["pass"] + n["fail"]
    return n, (n["pass"] / judged if judged else None)


def draw_history(ax: Any, rows: list[dict[str, Any]], *, labels: bool = True) -> str:
    """Draw the trend of ``rows`` on the matplotlib axes ``ax``: per inspection, in order, the
    range of its BCPS deviations (mm) as a bar, green for a pass and red for a fail, its
    worst defect as a dot, errors as grey marks on the zero line, and the tolerance band.
    Returns the title (counts and yield). ``inspector history --plot`` and the GUI's history
    strip both draw with this function, so they show the same data and limits."""
    colour = VERDICT_COLOURS
    for k, r in enumerate(rows):
        c = colour.get(r["verdict"], "#888888")
        if r["verdict"] == "error" or r["deviation_min_mm"] is None:
            ax.plot([k], [0.0], marker="x", color=c, ms=7, mew=2)
            continue
        ax.vlines(k, r["deviation_min_mm"], r["deviation_max_mm"], color=c, lw=3)
        if r["worst_mm"] is not None:
            ax.plot([k], [r["worst_mm"]], "o", color=c, ms=5)
    nan = float("nan")  # an error row has no tolerance: a gap in the band
    lo = [nan if r["tolerance_lower_mm"] is None else r["tolerance_lower_mm"] for r in rows]
    hi = [nan if r["tolerance_upper_mm"] is None else r["tolerance_upper_mm"] for r in rows]
    if any(v == v for v in lo + hi):
        x = list(range(len(rows)))
        ax.step(x, lo, where="mid", color="k", ls="--", lw=1, label="tolerance")
        ax.step(x, hi, where="mid", color="k", ls="--", lw=1)
        ax.legend(loc="upper right", fontsize=8)
    ax.axhline(0.0, color="#cccccc", lw=0.8, zorder=0)
    from matplotlib.ticker import MaxNLocator

    ax.set_xlim(-0.5, max(len(rows), 1) - 0.5)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))  # inspections are counted, not measured
    if labels:
        ax.set_xlabel("inspection (oldest first)")
        ax.set_ylabel("BCPS deviation, mm (negative: missing)")
    n, share = tally(rows)
    yld = f"yield {share:.1%}" if share is not None else "no part judged"
    title = f"{len(rows)} inspections: {n['pass']} pass, {n['fail']} fail, {n['error']} error; {yld}"
    ax.set_title(title, fontsize=11 if labels else 9)
    if labels and len(rows) <= 30:
        ax.set_xticks(range(len(rows)), [r["capture"][:14] for r in rows], rotation=60, ha="right", fontsize=7)
    return title
