"""A picture of one result: BCPS deviations in three views, defects circled.

``inspector report RESULT_DIR [...]`` writes ``deviation.png`` next to ``result.json``;
it reads only the CONTRACT outputs, so it works on any result folder, later, elsewhere.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["render_report", "add_parser", "run"]


def render_report(folder: Path, out: Path | None = None) -> Path:
    """Render ``deviation.png`` for the result folder ``folder``; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    from inspector.errors import InputError
    from inspector.outputs import BCPS_PLY, read_ply

    folder = Path(folder)
    try:
        res = json.loads((folder / "result.json").read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"{folder / 'result.json'}: cannot read ({type(e).__name__})") from None
    out = out or folder / "deviation.png"
    fig = plt.figure(figsize=(13, 4.8), dpi=110)
    title = f"{res['capture']}  —  {res['verdict'].upper()}"
    if res["verdict"] == "error" or not (folder / BCPS_PLY).is_file():
        fig.text(0.5, 0.5, f"{title}\n{res.get('error') or 'no BCPS points'}", ha="center", va="center", fontsize=13)
        fig.savefig(out)
        plt.close(fig)
        return out
    p = read_ply(folder / BCPS_PLY)
    X = np.stack([p["x"], p["y"], p["z"]], axis=1).astype(float)
    dev = p["deviation"].astype(float)
    pose = np.array(res["pose"], float)
    L = (X - pose[:3, 3]) @ pose[:3, :3]  # reference frame: what the drawing shows
    tol = res["stats"].get("tolerance_mm", {"lower": -0.1, "upper": 0.1})
    lim = max(abs(tol["lower"]), abs(tol["upper"]), float(np.percentile(np.abs(dev), 99.5)))
    norm = TwoSlopeNorm(vmin=-lim, vcenter=0.0, vmax=lim)
    order = np.argsort(np.abs(dev))  # out-of-tolerance points drawn last, on top
    defects = res.get("defects", [])
    for k, (a, b, name) in enumerate(((0, 1, "top (X-Y)"), (0, 2, "front (X-Z)"), (1, 2, "side (Y-Z)"))):
        ax = fig.add_subplot(1, 3, k + 1)
        sc = ax.scatter(L[order, a], L[order, b], c=dev[order], s=1.5, cmap="coolwarm", norm=norm, linewidths=0)
        for d in defects:
            c = (np.asarray(d["position"]) - pose[:3, 3]) @ pose[:3, :3]
            r = max(1.5, 0.6 * max(d["extent"]))
            ax.add_patch(plt.Circle((c[a], c[b]), r, fill=False, color="k", lw=1.2))
            ax.annotate(f"{d['kind']} {d['worst_mm']:+.2f}", (c[a] + r, c[b] + r), fontsize=8)
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("mm")
    cb = fig.colorbar(sc, ax=fig.axes, shrink=0.85, pad=0.02)
    cb.set_label("signed deviation, mm (negative: missing material)")
    d = res["stats"].get("deviation_mm", {})
    fig.suptitle(
        f"{title}   mean {d.get('mean', 0):+.4f} mm, min {d.get('min', 0):+.3f}, max {d.get('max', 0):+.3f};"
        f" tolerance [{tol['lower']:+.2f}, {tol['upper']:+.2f}] mm; {len(defects)} defect(s)",
        fontsize=11,
    )
    fig.savefig(out)
    plt.close(fig)
    return out


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("report", help="draw deviation.png for result folders (from result.json and bcps_points.ply)")
    p.add_argument("results", nargs="+", metavar="RESULT_DIR", help="result folders (one per capture) or their parent")


def run(args) -> int:
    from inspector.errors import InputError

    folders: list[Path] = []
    for raw in args.results:
        f = Path(raw)
        folders.extend(sorted(q for q in f.iterdir() if (q / "result.json").is_file()) if not (f / "result.json").is_file() and f.is_dir() else [f])
    status = 0
    for f in folders:
        try:
            print(f"wrote {render_report(f)}", flush=True)
        except InputError as e:
            print(f"inspector: error: {e}", flush=True)
            status = 3
    return status
