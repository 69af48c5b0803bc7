"""A picture of one result: BCPS deviations in three views, defects circled.

``inspector report RESULT_DIR [...]`` writes ``deviation.png`` next to ``result.json``;
it reads only the CONTRACT outputs, so it works on any result folder, later, elsewhere.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

__all__ = ["render_report", "add_parser", "run"]


def render_report(folder: Path, out: Path | None = None) -> Path:
    """Render ``deviation.png`` for the result folder ``folder``; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    folder = Path(folder)
    res = _read_result(folder / "result.json")
    named = (res.get("points") or {}).get("bcps")
    points = None
    if res["verdict"] != "error" and named:
        points = _read_points(folder / str(named))
    out = out or folder / "deviation.png"
    fig = plt.figure(figsize=(13, 4.8), dpi=110)
    title = f"{res['capture']}  —  {res['verdict'].upper()}"
    if points is None:
        fig.text(0.5, 0.5, f"{title}\n{res.get('error') or 'no BCPS points'}", ha="center", va="center", fontsize=13)
        fig.savefig(out)
        plt.close(fig)
        return out
    X, dev = points
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
    for k, w in enumerate(res["stats"].get("warnings", [])):  # e.g. a tolerance the rig cannot resolve
        fig.text(0.5, 0.02 + 0.035 * k, f"warning: {w}", ha="center", va="bottom", fontsize=9, color="#b00000")
    fig.savefig(out)
    plt.close(fig)
    return out


def _read_result(path: Path) -> dict:
    """result.json (CONTRACT) with what the picture needs checked; InputError otherwise."""
    from inspector.errors import InputError

    try:
        res = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read ({type(e).__name__})") from None
    if not isinstance(res, dict):
        raise InputError(f"{path}: not a result (a JSON object is expected)")
    need = ("capture", "verdict") if res.get("verdict") == "error" else ("capture", "verdict", "pose", "stats")
    missing = [k for k in need if k not in res]
    if missing:
        raise InputError(f"{path}: missing key {missing[0]!r}")
    if res["verdict"] != "error":
        pose = np.asarray(res["pose"], dtype=object)
        if pose.shape != (4, 4):
            raise InputError(f"{path}: pose must be a 4x4 matrix")
    return res


def _read_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """BCPS points (N, 3) world mm and their deviations (N,) mm from a bcps_points.ply."""
    from inspector.errors import InputError
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
            print(f"inspector: error: {e}", file=sys.stderr, flush=True)
            status = 3
    return status
