"""Pictures and reports of one result, read from its result folder (CONTRACT outputs only).

``inspector report RESULT_DIR [...]`` writes ``deviation.png`` (BCPS deviations in three
views, defects circled) next to ``result.json``; with ``--pdf`` it also writes
``report.pdf``, a one-page A4 inspection report (:func:`render_pdf`, also used by the GUI).
Both read only the CONTRACT outputs, so they work on any result folder, later, elsewhere.

Their texts are in the language of :mod:`inspector.locale` (``--lang``, else
``$INSPECTOR_LANG``, else English; the GUI's language in the GUI): every text is marked
``_("...")`` and every number goes through :func:`_fmt` (a decimal comma in German and
Spanish). ``python -m inspector.locale.build`` collects the marked texts for translation.

The one-page PDF is laid out in :mod:`inspector.report_pdf`; the result folder is read by
:mod:`inspector.report_read`.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import InputError
from inspector.locale import _, choose, list_separator, number, using
from inspector.report_read import _read_result, _result_points

__all__ = ["render_report", "render_pdf", "add_parser", "run"]


def _views() -> tuple[tuple[int, int, str], ...]:
    """The three orthographic views: (horizontal axis, vertical axis, title), reference frame."""
    return (0, 1, _("top (X-Y)")), (0, 2, _("front (X-Z)")), (1, 2, _("side (Y-Z)"))


def _fmt(x: Any, spec: str) -> str:
    """The number ``x`` written with the format spec ``spec`` in the report's language."""
    return number(x, spec)


def _band(lo: Any, hi: Any, spec: str = "+.3f") -> str:
    """A tolerance band ``[lower, upper]`` (``[-0,100; +0,100]`` where the comma is the decimal sign)."""
    return f"[{_num(lo, spec)}{list_separator()}{_num(hi, spec)}]"


def _kind(kind: Any) -> str:
    """A defect's kind in words (``missing``, ``excess``; another as it is written)."""
    return {"missing": _("missing"), "excess": _("excess")}.get(str(kind), str(kind))


def _defect_head(d: dict) -> str:
    """What a defect is and where: "missing material in region 'default': worst -0.215 mm"."""
    values = {"region": d["region"], "worst": _fmt(d["worst_mm"], "+.3f"), "kind": d["kind"]}
    if d["kind"] == "missing":
        return _("missing material in region '{region}': worst {worst} mm").format(**values)
    if d["kind"] == "excess":
        return _("excess material in region '{region}': worst {worst} mm").format(**values)
    return _("{kind} material in region '{region}': worst {worst} mm").format(**values)


def _tolerance(res: dict) -> dict:
    """The default tolerance band of a result, mm (``{"lower", "upper"}``)."""
    return res["stats"].get("tolerance_mm", {"lower": -0.1, "upper": 0.1})


def _draw_views(axes, res: dict, X: np.ndarray, dev: np.ndarray, *, labels: list[str] | None = None,
                label_size: float = 8, title_size: float = 10, rasterized: bool = False):
    """Draw the BCPS deviations in the three views of ``_VIEWS``, defects circled.

    Parameters
    ----------
    axes : sequence of 3 matplotlib Axes
        Where to draw the top, front and side views.
    res : dict
        The result (``pose``, ``stats``, ``defects`` are used).
    X : (N, 3) array
        BCPS points, world mm.
    dev : (N,) array
        Their signed deviations, mm.
    labels : list of str, optional
        One label per defect ("" for none); default: its kind and worst deviation.
    label_size, title_size : float
        Font sizes (points) of the defect labels and the view titles.
    rasterized : bool
        Draw the points as a bitmap (small, fast vector files such as PDF).

    Returns
    -------
    matplotlib.collections.PathCollection
        The last view's scatter, for a colour bar (all views share one colour scale).
    """
    from matplotlib.colors import TwoSlopeNorm
    from matplotlib.patches import Circle

    pose = np.array(res["pose"], float)
    L = (X - pose[:3, 3]) @ pose[:3, :3]  # reference frame: what the drawing shows
    tol = _tolerance(res)
    lim = max(abs(tol["lower"]), abs(tol["upper"]), float(np.percentile(np.abs(dev), 99.5)))
    norm = TwoSlopeNorm(vmin=-lim, vcenter=0.0, vmax=lim)
    order = np.argsort(np.abs(dev))  # out-of-tolerance points drawn last, on top
    defects = res.get("defects", [])
    if labels is None:
        labels = [f"{_kind(d['kind'])} {_fmt(d['worst_mm'], '+.2f')}" for d in defects]
    sc = None
    for ax, (a, b, name) in zip(axes, _views()):
        sc = ax.scatter(L[order, a], L[order, b], c=dev[order], s=1.5, cmap="coolwarm", norm=norm, linewidths=0,
                        rasterized=rasterized)
        for d, label in zip(defects, labels):
            c = (np.asarray(d["position"]) - pose[:3, 3]) @ pose[:3, :3]
            r = max(1.5, 0.6 * max(d["extent"]))
            ax.add_patch(Circle((c[a], c[b]), r, fill=False, color="k", lw=1.2))
            if label:
                ax.annotate(label, (c[a] + r, c[b] + r), fontsize=label_size)
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=title_size)
        ax.set_xlabel("mm")
    return sc


def _pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def render_report(folder: Path, out: Path | None = None, *, lang: str | None = None) -> Path:
    """Render ``deviation.png`` for the result folder ``folder``; returns its path.

    ``lang``: the language of its texts (``en``, ``de``, ``es``; None: :mod:`inspector.locale`'s now)."""
    with using(lang):
        return _render_report(folder, out)


def _render_report(folder: Path, out: Path | None) -> Path:
    plt = _pyplot()
    folder = Path(folder)
    res = _read_result(folder / "result.json")
    points = _result_points(folder, res)
    out = out or folder / "deviation.png"
    fig = plt.figure(figsize=(13, 4.8), dpi=110)
    title = f"{res['capture']}  —  {_verdict(str(res['verdict']))[0]}"
    if points is None:
        why = res.get("error") or _("no BCPS points")
        fig.text(0.5, 0.5, f"{title}\n{why}", ha="center", va="center", fontsize=13)
        fig.savefig(out)
        plt.close(fig)
        return out
    axes = [fig.add_subplot(1, 3, k + 1) for k in range(3)]
    sc = _draw_views(axes, res, *points)
    cb = fig.colorbar(sc, ax=fig.axes, shrink=0.85, pad=0.02)
    cb.set_label(_("signed deviation, mm (negative: missing material)"))
    tol = _tolerance(res)
    defects = res.get("defects", [])
    d = res["stats"].get("deviation_mm", {})
    summary = _("mean {mean} mm, min {min}, max {max}; tolerance {band} mm; {n} defect(s)").format(
        mean=_fmt(d.get("mean", 0), "+.4f"), min=_fmt(d.get("min", 0), "+.3f"), max=_fmt(d.get("max", 0), "+.3f"),
        band=_band(tol["lower"], tol["upper"], "+.2f"), n=len(defects))
    fig.suptitle(f"{title}   {summary}", fontsize=11)
    for k, w in enumerate(res["stats"].get("warnings", [])):  # e.g. a tolerance the rig cannot resolve
        fig.text(0.5, 0.02 + 0.035 * k, _("warning: {text}").format(text=w), ha="center", va="bottom", fontsize=9,
                 color="#b00000")
    fig.savefig(out)
    plt.close(fig)
    return out


# -- the words and numbers of both -------------------------------------------------------------
def _verdict(verdict: str) -> tuple[str, str, str, str]:
    """(word, banner colour, text colour, what it means) of a verdict. The word is always
    printed: the colour only repeats it."""
    known = {
        "pass": (_("PASS"), "#2e7d32", "white", _("part within tolerance")),
        "fail": (_("FAIL"), "#c62828", "white", _("part out of tolerance")),
        "error": (_("ERROR"), "#f0a202", "black", _("inspection not completed")),
        "aborted": (_("ABORTED"), "#757575", "white", _("inspection cancelled")),
    }
    return known.get(verdict, (verdict.upper(), "#757575", "white", _("unknown verdict")))


def _num(x: Any, fmt: str, unit: str = "") -> str:
    """``x`` formatted with ``fmt`` in the report's language, or an em dash when it is not a number."""
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
        return "—"
    try:
        return f"{_fmt(x, fmt)}{unit}"
    except ValueError:  # e.g. a float where a count was expected
        return f"{x}{unit}"


def render_pdf(folder: Path, out: Path | None = None, *, picture: Path | None = None,
               recipe: Path | None = None, lang: str | None = None) -> Path:
    """Write the one-page A4 inspection report of a result folder as a PDF.

    The page holds the verdict (word and colour), the capture, part id, inspection time and
    cycle time, the reason of a FAIL (worst defect and the tolerance limit it breaks) or the
    error line, a picture of the deviations, the statistics with the time of each stage,
    the defects (worst first, at most 15 rows) and the recipe (name, SHA-256 and text).

    Parameters
    ----------
    folder : Path
        A result folder (``result.json``, and ``bcps_points.ply`` when it names one).
    out : Path, optional
        The PDF to write; default ``folder / "report.pdf"``. Written to a temporary name and
        renamed, so a reader never sees half a file.
    picture : Path, optional
        A PNG shown as the deviation picture (e.g. a 3D view saved by the GUI); default:
        the three views of :func:`render_report`, drawn from the BCPS points.
    recipe : Path, optional
        The recipe file to show; default: the file ``result.json`` names
        (``recipe_path``, checked against ``recipe_sha256``).
    lang : str, optional
        The page's language: ``en``, ``de`` or ``es``; default: :mod:`inspector.locale`'s
        current one (English, or what ``inspector report --lang`` or the GUI set).

    Returns
    -------
    Path
        The PDF written.

    Raises
    ------
    InputError
        ``result.json``, the points, ``picture`` or ``recipe`` is missing or unreadable;
        the message names the file.
    """
    from inspector.report_pdf import _render_pdf

    with using(lang):
        return _render_pdf(Path(folder), out, picture, recipe)


# -- command line -----------------------------------------------------------------------------
def add_parser(subparsers) -> None:
    p = subparsers.add_parser("report", help="draw deviation.png (and report.pdf) for result folders")
    p.add_argument("results", nargs="+", metavar="RESULT_DIR", help="result folders (one per capture) or their parent")
    p.add_argument("--pdf", action="store_true", help="also write report.pdf, a one-page A4 inspection report")
    p.add_argument("--recipe", metavar="RECIPE", type=Path,
                   help="recipe file shown in report.pdf (default: the one result.json names)")
    p.add_argument("--lang", metavar="LANG",
                   help="language of report.pdf and deviation.png: en, de or es (default: $INSPECTOR_LANG, else en; "
                        "never the system locale: the command's own lines stay English, plant scripts parse them)")


def run(args) -> int:
    try:
        lang = choose(getattr(args, "lang", None))
    except ValueError as e:
        print(f"inspector: error: {e}", file=sys.stderr, flush=True)
        return 2
    with using(lang):
        return _run(args)


def _run(args) -> int:
    folders: list[Path] = []
    for raw in args.results:
        f = Path(raw)
        folders.extend(sorted(q for q in f.iterdir() if (q / "result.json").is_file()) if not (f / "result.json").is_file() and f.is_dir() else [f])
    status = 0
    for f in folders:
        try:
            print(f"wrote {render_report(f)}", flush=True)
            if getattr(args, "pdf", False):
                print(f"wrote {render_pdf(f, recipe=getattr(args, 'recipe', None))}", flush=True)
        except InputError as e:
            print(f"inspector: error: {e}", file=sys.stderr, flush=True)
            status = 3
    return status
