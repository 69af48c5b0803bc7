"""``inspector experiment``: the report: aggregation of the rows, the plots (matplotlib,
imported when used) and ``summary.md``."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from inspector_tools.experiment_cases import METHODS, OBJECT_VARIANTS, PAPER_TABLE1, Case
from inspector_tools.experiment_execution import sort_key

__all__ = ["ratio_ranges", "write_plots", "write_summary"]

# --------------------------------------------------------------------------- aggregation


def _num(r: Mapping[str, Any], k: str) -> float | None:
    v = r.get(k)
    if v is None or v == "":
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _groups(rows: Iterable[Mapping[str, Any]]) -> dict[tuple[str, str], list[Mapping[str, Any]]]:
    g: dict[tuple[str, str], list[Mapping[str, Any]]] = defaultdict(list)
    for r in rows:
        g[(r["case"], r["part"])].append(r)
    return g


def _values_in_order(case: Case, rows: Sequence[Mapping[str, Any]]) -> list[Any]:
    vals = list(dict.fromkeys(r["value"] for r in rows))
    if case.numeric:
        return sorted(vals, key=float)
    order = list(OBJECT_VARIANTS)
    return sorted(vals, key=lambda v: order.index(v) if v in order else 99)


def _series(rows: Sequence[Mapping[str, Any]], values: Sequence[Any], method: str | None, key: str) -> dict[str, list[float]]:
    """Mean, min, max, std over orientations of column ``key`` at each value (NaN if none).

    ``method=None``: the reconstruction columns, one sample per (value, orientation).
    """
    import numpy as np

    out: dict[str, list[float]] = {"mean": [], "min": [], "max": [], "std": [], "n": []}
    for v in values:
        if method is None:
            seen: dict[Any, float] = {}
            for r in rows:
                x = _num(r, key)
                if r["value"] == v and x is not None:
                    seen.setdefault(r["orientation"], x)
            xs = list(seen.values())
        else:
            xs = [x for r in rows if r["value"] == v and r["method"] == method and r["status"] == "ok" and (x := _num(r, key)) is not None]
        a = np.asarray(xs, float)
        for s, f in (("mean", np.mean), ("min", np.min), ("max", np.max), ("std", np.std)):
            out[s].append(float(f(a)) if len(a) else float("nan"))
        out["n"].append(len(a))
    return out


def ratio_ranges(rows: Sequence[Mapping[str, Any]], method: str, stat: str) -> tuple[float, float] | None:
    """Min and max over a sweep's values of (reconstruction error / BCPS error).

    At each value, the errors are first averaged over the orientations whose BCPS run
    succeeded (the same runs for numerator and denominator).
    """
    import numpy as np

    per_value: dict[Any, list[tuple[float, float]]] = defaultdict(list)
    for r in rows:
        if r["method"] != method or r["status"] != "ok":
            continue
        a, b = _num(r, f"recon_{stat}_mm"), _num(r, f"bcps_{stat}_mm")
        if a is not None and b is not None and b > 0:
            per_value[r["value"]].append((a, b))
    ratios = [float(np.mean([a for a, _ in ab]) / np.mean([b for _, b in ab])) for ab in per_value.values() if ab]
    return (min(ratios), max(ratios)) if ratios else None


def _fmt_range(rng: tuple[float, float] | None) -> str:
    if rng is None:
        return "—"
    a, b = rng

    def f(x: float) -> str:
        return f"{x:.3g}" if x < 100 else f"{x:.0f}"

    return f"[{f(a)}]" if f(a) == f(b) else f"[{f(a)}–{f(b)}]"


# --------------------------------------------------------------------------- plots

_COLOURS = {
    ("recon", "mean"): "tab:orange", ("recon", "max"): "tab:red",
    ("ray", "mean"): "tab:blue", ("ray", "max"): "tab:green",
    ("surface", "mean"): "tab:purple", ("surface", "max"): "tab:olive",
}


def write_plots(rows: Sequence[Mapping[str, Any]], out: Path, cases: Iterable[Case], *, band: str = "minmax") -> list[Path]:
    """One PNG per (case, part): mean and max error of the reconstruction and of each BCPS
    method against the swept value; a grey band up to one pixel's footprint; a shaded band
    over the orientations (``minmax`` or ``std``). Log-y when the errors span > 30x.
    """
    import numpy as np
    from matplotlib.figure import Figure

    paths = []
    groups = _groups(rows)
    for case in cases:
        for part in case.parts:
            rs = groups.get((case.name, part))
            if not rs:
                continue
            values = _values_in_order(case, rs)
            methods = [m for m in METHODS if any(r["method"] == m for r in rs)]
            x = np.array([float(v) for v in values]) if case.numeric else np.arange(len(values), dtype=float)
            fig = Figure(figsize=(8.0, 5.6), dpi=110)
            ax = fig.add_subplot(1, 1, 1)
            curves = [("recon", None, "reconstruction")] + [(m, m, f"BCPS {m}" + (" (paper's)" if m == "surface" else "")) for m in methods]
            positives: list[float] = []
            n_or = len({r["orientation"] for r in rs})
            for who, method, label in curves:
                for stat in ("mean", "max"):
                    col = "recon" if method is None else "bcps"
                    s = _series(rs, values, method, f"{col}_{stat}_mm")
                    y = np.array(s["mean"])
                    if np.all(np.isnan(y)):
                        continue
                    lo, hi = (np.array(s["min"]), np.array(s["max"])) if band == "minmax" else (y - np.array(s["std"]), y + np.array(s["std"]))
                    colour = _colours(who, stat)
                    style = "--" if who == "surface" else "-"
                    if case.numeric:
                        ax.plot(x, y, style, marker="o", ms=3.5, color=colour, label=f"{label}, {stat} error")
                        ax.fill_between(x, lo, hi, color=colour, alpha=0.18, linewidth=0)
                    else:
                        off = {"recon": -0.2, "ray": 0.0, "surface": 0.2}[who] + (0.05 if stat == "max" else -0.05)
                        ax.errorbar(x + off, y, yerr=[np.maximum(y - lo, 0), np.maximum(hi - y, 0)], fmt="o" if stat == "mean" else "s",
                                    ms=4.5, color=colour, capsize=3, label=f"{label}, {stat} error")
                    positives += [v for v in np.concatenate([lo, y, hi]) if np.isfinite(v) and v > 0]
            fps = [f for r in rs if (f := _num(r, "footprint_mm"))]
            fp = float(np.median(fps)) if fps else None
            log = bool(positives) and max(positives) / max(min(positives), 1e-9) > 30
            if log:
                ax.set_yscale("log")
                bottom = min(min(positives) * 0.5, fp * 0.5 if fp else math.inf)
                ax.set_ylim(bottom=bottom)
            else:
                ax.set_ylim(bottom=0)
            if fp:
                ax.axhspan(ax.get_ylim()[0] if log else 0, fp, color="0.6", alpha=0.3, linewidth=0,
                           label=f"one pixel ({fp:.3g} mm)", zorder=0)
            if case.numeric:
                ref = 1.0 if case.variable == "scale" else 0.0
                ax.axvline(ref, color="0.4", lw=0.8, ls=":")
            else:
                ax.set_xticks(x)
                ax.set_xticklabels([str(v) for v in values])
            ax.set_xlabel(case.xlabel)
            ax.set_ylabel("distance to the true surface, mm" + (" (log)" if log else ""))
            bandtxt = "min–max" if band == "minmax" else "±1 std"
            ax.set_title(f"{case.title}\n{part}: {n_or} orientation(s) per value, {'shaded' if case.numeric else 'bars'} {bandtxt}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            handles, labels = ax.get_legend_handles_labels()
            fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=3, frameon=False)
            fig.tight_layout(rect=(0, 0.03 * (1 + (len(labels) + 2) // 3), 1, 1))
            path = out / f"{case.stem}_{part}.png"
            fig.savefig(path)
            paths.append(path)
    return paths


def _colours(who: str, stat: str) -> str:
    return _COLOURS[(who, stat)]


# --------------------------------------------------------------------------- summary


def write_summary(rows: Sequence[Mapping[str, Any]], out: Path, cases: Sequence[Case], config: Mapping[str, Any]) -> Path:
    """``summary.md``: Table-1-style improvement ratios beside the paper's, then the errors."""
    groups = _groups(rows)
    methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
    rig = config.get("rig", {})
    lines = [
        "# BCPS experiments",
        "",
        f"Preset `{config.get('preset')}`: {rig.get('cameras')} cameras, {rig.get('width')}x{rig.get('height')} px, "
        f"{rig.get('mm_per_px')} mm/px at the rig centre; methods: {', '.join(methods) or 'none'}; "
        f"{config.get('tasks', '?')} runs in {config.get('elapsed_s', float('nan')):.0f} s.",
        "Errors are distances of points to the true (simulated) surface. *Improvement* = reconstruction error / BCPS error "
        "(errors averaged over the orientations at each value), min–max over the sweep, as in the paper's Table 1. "
        "`ray` is this product's BCPS (exact rays, sub-pixel contours); `surface` is the paper's (reconstruction's surface points).",
        "",
        "## Improvement (Table 1 style)",
        "",
    ]
    head = ["sweep", "paper column (figure)", "runs ok"]
    for stat in ("mean", "max"):
        head += [f"{stat} error, {m}" for m in methods] + [f"{stat} error, paper"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for case in cases:
        for part in case.parts:
            rs = groups.get((case.name, part))
            if not rs:
                continue
            paper = PAPER_TABLE1.get((case.name, part))
            ok = sum(r["status"] == "ok" for r in rs)
            cells = [f"{case.number} {case.name}: {part}", f"{paper['label']} ({paper['figure']})" if paper else "— (not in Table 1)", f"{ok}/{len(rs)}"]
            for stat in ("mean", "max"):
                cells += [_fmt_range(ratio_ranges(rs, m, stat)) for m in methods]
                cells.append(_fmt_range(paper[stat]) if paper else "—")
            lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Paper columns Gauge, Blade and Cube-Sphere are measured on *real* objects in the paper (simulated here). "
        "Paper numbers: Pérez Soler et al. 2023, Table 1 (see docs/bcps-notes.md).",
        "",
        "## Errors, mm (mean over orientations; reconstruction / BCPS)",
        "",
    ]
    head = ["case", "part", "value", "n", "recon mean", "recon max"]
    for m in methods:
        head += [f"{m} mean", f"{m} max"]
    head += ["1 px, mm"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for case in cases:
        for part in case.parts:
            rs = groups.get((case.name, part))
            if not rs:
                continue
            values = _values_in_order(case, rs)
            rec = {s: _series(rs, values, None, f"recon_{s}_mm") for s in ("mean", "max")}
            per = {(m, s): _series(rs, values, m, f"bcps_{s}_mm") for m in methods for s in ("mean", "max")}
            fps = _series(rs, values, None, "footprint_mm")
            for i, v in enumerate(values):
                n = len({r["orientation"] for r in rs if r["value"] == v})
                cells = [str(case.number), part, f"{v:g}" if isinstance(v, float) else str(v), str(n),
                         _f(rec["mean"]["mean"][i]), _f(rec["max"]["mean"][i])]
                for m in methods:
                    cells += [_f(per[(m, "mean")]["mean"][i]), _f(per[(m, "max")]["mean"][i])]
                cells.append(_f(fps["mean"][i]))
                lines.append("| " + " | ".join(cells) + " |")
    bad = [r for r in rows if r["status"] != "ok"]
    lines += ["", "## Failed runs", ""]
    if not bad:
        lines.append("None.")
    else:
        lines.append(f"{len(bad)} of {len(rows)} rows (see the `error` column of the CSVs):")
        lines.append("")
        for r in sorted(bad, key=sort_key)[:30]:
            lines.append(f"- case {r['case']}, {r['part']}, {r['variable']}={r['value']}, orientation {r['orientation']}, "
                         f"{r['method']}: {r.get('error') or 'error'}")
        if len(bad) > 30:
            lines.append(f"- ... and {len(bad) - 30} more")
    lines += ["", "## Files", ""]
    for case in cases:
        pngs = [f"`{case.stem}_{p}.png`" for p in case.parts if (case.name, p) in groups]
        lines.append(f"- `{case.stem}.csv`" + (": plots " + ", ".join(pngs) if pngs else ""))
    lines.append("")
    path = out / "summary.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def _f(x: float) -> str:
    return "—" if x is None or not math.isfinite(x) else f"{x:.4f}"


