"""``inspector history OUTDIR --characteristics [PNG]``: each characteristic's capability over
the recorded parts as a table, and its individuals control chart (issue 28).

The figures come from :mod:`.spc`; this module only reads the history's rows and draws. An
individuals (I) chart is used because a gauge measures every part once: its control limits
are the mean +- 2.66 x the mean moving range (Montgomery, *Statistical Quality Control*,
the I-MR chart), drawn with the tolerance band.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from inspector.characteristics import spc
from inspector.characteristics.definitions import rows_of

__all__ = ["parts_rows", "capability_text", "plot_charts", "I_CHART_K"]

#: d2 of a moving range of two (1.128): 3 / d2 = 2.66 times the mean moving range.
I_CHART_K = 3.0 / 1.128


def parts_rows(history_rows: Sequence[Mapping[str, Any]]) -> list[list[dict[str, Any]]]:
    """Each recorded inspection's characteristics rows (its ``extras`` column), in order;
    inspections without characteristics (an error, an older recipe) are left out."""
    out = []
    for row in history_rows:
        raw = row.get("extras")
        if not raw:
            continue
        extras = json.loads(raw) if isinstance(raw, str) else raw
        rows = rows_of({"extras": extras})
        if rows:
            out.append(rows)
    return out


def _num(v: Any, fmt: str) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


def capability_text(parts: Sequence[Sequence[Mapping[str, Any]]]) -> list[str]:
    """One line per characteristic: n, mean, s, Cp, Cpk, values out of tolerance and the
    type-1 figures Cg, Cgk against the nominal; a header line first."""
    lines = [f"{'id':>6s} {'kind':12s} {'nominal':>9s} {'limits':>17s} {'n':>4s} {'n.m.':>4s} {'mean':>10s} "
             f"{'s':>8s} {'Cp':>6s} {'Cpk':>6s} {'out':>4s} {'Cg':>6s} {'Cgk':>6s}"]
    for t in spc.table(parts):
        limits = f"{t['lower']:.4f}..{t['upper']:.4f}"
        lines.append(f"{t['id']:>6s} {str(t['kind'])[:12]:12s} {t['nominal']:9.4f} {limits:>17s} {t['n']:4d} "
                     f"{t['not_measurable']:4d} {_num(t['mean'], '10.4f')} {_num(t['s'], '8.5f')} {_num(t['cp'], '6.2f')} "
                     f"{_num(t['cpk'], '6.2f')} {t['out_of_tolerance']:4d} {_num(t['cg'], '6.2f')} {_num(t['cgk'], '6.2f')}")
    return lines


def plot_charts(parts: Sequence[Sequence[Mapping[str, Any]]], path: Path) -> Path:
    """An individuals chart per characteristic (one panel each, parts in recorded order):
    the values, their centre line and control limits, and the tolerance band. OSError when
    the picture cannot be written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = spc.table(parts)
    values = spc.series(parts)
    fig, axes = plt.subplots(max(len(table), 1), 1, figsize=(9, 2.4 * max(len(table), 1)), squeeze=False)
    for ax, t in zip(axes[:, 0], table):
        v = values[t["id"]]
        xs = [i + 1 for i, x in enumerate(v) if x is not None]
        ys = [x for x in v if x is not None]
        ax.axhspan(t["lower"], t["upper"], color="#dff0d8", label="tolerance")
        ax.plot(xs, ys, "o-", color="#1f4e79", ms=3, lw=1)
        if len(ys) >= 2:
            mr = sum(abs(b - a) for a, b in zip(ys, ys[1:])) / (len(ys) - 1)
            centre = sum(ys) / len(ys)
            ax.axhline(centre, color="0.3", lw=0.8)
            for lim in (centre - I_CHART_K * mr, centre + I_CHART_K * mr):
                ax.axhline(lim, color="#c0392b", lw=0.8, ls="--")
        out = [(x, y) for x, y in zip(xs, ys) if not t["lower"] <= y <= t["upper"]]
        if out:
            ax.plot(*zip(*out), "x", color="#c0392b", ms=7)
        cpk = "-" if t["cpk"] is None else f"{t['cpk']:.2f}"
        ax.set_title(f"{t['id']} {t['kind']}  nominal {t['nominal']:g} {t['unit']}  n {t['n']}  Cpk {cpk}", fontsize=9)
        ax.set_ylabel(t["unit"])
        ax.tick_params(labelsize=8)
    axes[-1, 0].set_xlabel("part (recorded order)")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
    return path
