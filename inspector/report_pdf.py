"""The one-page A4 PDF inspection report: its layout and its blocks (part of :mod:`inspector.report`).

:func:`inspector.report.render_pdf` is the entry point; this module lays the page out
(:class:`_Page`, inches from the top edge) and draws its blocks top-down: the verdict banner,
the identity, the reason, the deviation picture, the statistics, the defects, the
characteristics, the recipe and the footer. Every text is marked ``_("...")``.
"""

from __future__ import annotations

import os
import tomllib
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from inspector import __version__
from inspector.locale import _, list_separator
from inspector.report import _band, _defect_head, _draw_views, _fmt, _kind, _num, _verdict
from inspector.report_read import _UNFINISHED, _dict, _read_picture, _read_result, _recipe_info, _result_points

_W, _H = 8.27, 11.69  # A4 portrait, inches
_MARGIN = 0.55
_GREY = "#555555"
_RULE = "#9e9e9e"
_MAX_DEFECT_ROWS, _MIN_DEFECT_ROWS = 15, 5
_PICTURE, _MIN_PICTURE = 2.0, 1.3  # height of the deviation views, inches: preferred, smallest
_DEFECT_ROW_H = 7.5 * 1.45 / 72  # inches
_MIN_RECIPE_TEXT = 0.9  # inches of recipe text the picture makes room for


class _Page:
    """An A4 figure drawn top-down in inches: ``y`` is the distance from the top edge."""

    def __init__(self, fig) -> None:
        self.fig = fig
        self.y = _MARGIN  # the next free line, inches from the top

    def text(self, x: float, y: float, s: str, **kw):
        kw.setdefault("va", "top")
        kw.setdefault("fontsize", 8)
        return self.fig.text(x, _H - y, s, transform=self.fig.dpi_scale_trans, **kw)

    def rule(self, y: float, x0: float = _MARGIN, x1: float = _W - _MARGIN, **kw) -> None:
        from matplotlib.lines import Line2D

        kw.setdefault("color", _RULE)
        kw.setdefault("lw", 0.6)
        self.fig.add_artist(Line2D([x0, x1], [_H - y, _H - y], transform=self.fig.dpi_scale_trans, **kw))

    def box(self, x: float, y: float, w: float, h: float, **kw) -> None:
        from matplotlib.patches import Rectangle

        self.fig.add_artist(Rectangle((x, _H - y - h), w, h, transform=self.fig.dpi_scale_trans, **kw))

    def axes(self, x: float, y: float, w: float, h: float):
        return self.fig.add_axes((x / _W, 1 - (y + h) / _H, w / _W, h / _H))

    def width(self, s: str, fontsize: float, **font) -> float:
        """Width of ``s`` on the page, inches."""
        from matplotlib.font_manager import FontProperties

        renderer = self.fig.canvas.get_renderer()
        w, _, _ = renderer.get_text_width_height_descent(s, FontProperties(size=fontsize, **font), ismath=False)
        return w / self.fig.dpi

    def wrap(self, s: str, width: float, fontsize: float, **font) -> list[str]:
        """``s`` cut into lines no wider than ``width`` inches, at spaces."""
        lines: list[str] = []
        for word in s.split():
            if lines and self.width(f"{lines[-1]} {word}", fontsize, **font) <= width:
                lines[-1] += f" {word}"
                continue
            while self.width(word, fontsize, **font) > width:  # a long path: cut where it must
                cut = max(1, len(self.fit(word, width, fontsize, **font)) - 1)
                lines.append(word[:cut])
                word = word[cut:]
            lines.append(word)
        return lines

    def fit(self, s: Any, width: float, fontsize: float, **font) -> str:
        """``s`` on one line, cut (with an ellipsis) to at most ``width`` inches."""
        s = " ".join(str(s).split())
        if self.width(s, fontsize, **font) <= width:
            return s
        lo, hi = 0, len(s)  # the longest prefix that fits, by bisection
        while lo < hi:
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if self.width(s[:mid] + "…", fontsize, **font) <= width else (lo, mid - 1)
        return s[:lo] + "…"

    def heading(self, title: str) -> None:
        """A section title over a thin rule; moves ``y`` below it."""
        self.y += 0.12
        self.text(_MARGIN, self.y, title, fontsize=10, fontweight="bold")
        self.rule(self.y + 0.19)
        self.y += 0.27


def _line_h(fontsize: float, spacing: float = 1.3) -> float:
    """Height of one text line, inches."""
    return fontsize * spacing / 72



def _render_pdf(folder: Path, out: Path | None, picture: Path | None, recipe: Path | None) -> Path:
    """Write the page of :func:`inspector.report.render_pdf` (in the language set by it)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    folder = Path(folder)
    path = folder / "result.json"
    res = _read_result(path)
    points = _result_points(folder, res)
    image = _read_picture(Path(picture)) if picture is not None else None
    rec = _recipe_info(res, Path(recipe) if recipe is not None else None)
    out = Path(out) if out is not None else folder / "report.pdf"
    when = _inspection_time(res, path)

    # A Figure of its own, not pyplot's: the GUI's figures and backend are left alone.
    # Type 42 fonts: real TrueType text, which readers can search and copy.
    with matplotlib.rc_context({"pdf.fonttype": 42, "font.family": "DejaVu Sans"}):
        fig = Figure(figsize=(_W, _H))
        FigureCanvasAgg(fig)  # measures text while the page is laid out

        def compose(size: float, rows: int) -> float:
            """Draw the page with a picture ``size`` inches high and at most ``rows`` defect
            rows; returns the height left for the recipe text."""
            fig.clear()
            page = _Page(fig)
            _draw_banner(page, res)
            _draw_identity(page, res, folder, when, rec)
            _draw_reason(page, res, rec)
            _draw_picture(page, res, points, image, size, rows)
            _draw_stats(page, res)
            _draw_defects(page, res, rows)
            _draw_characteristics(page, res)
            left = _draw_recipe(page, rec)
            _draw_footer(page, folder)
            return left

        # Everything on one page: when the rest needs the room, a smaller picture first,
        # then fewer defect rows.
        short = (_MIN_RECIPE_TEXT if rec["text"] is not None else 0.0) - compose(_PICTURE, _MAX_DEFECT_ROWS)
        if short > 0:
            size = max(_PICTURE - short, _MIN_PICTURE)
            short -= _PICTURE - size
            cut = int(np.ceil(short / _DEFECT_ROW_H)) + 1 if short > 0 else 0  # +1: the "and N more" line
            compose(size, max(_MAX_DEFECT_ROWS - cut, _MIN_DEFECT_ROWS))
        tmp = out.with_name(out.name + ".part")
        try:
            fig.savefig(tmp, format="pdf", dpi=200, metadata={
                "Title": _("Inspection report: {capture} {verdict}").format(
                    capture=res["capture"], verdict=_verdict(str(res["verdict"]))[0]),
                "Subject": f"verdict {res['verdict']}", "Creator": "inspector report"})
            os.replace(tmp, out)
        finally:
            tmp.unlink(missing_ok=True)
    return out


def _inspection_time(res: dict, path: Path) -> tuple[str, str]:
    """When the part was inspected, and a note on the source: the capture's time
    (metadata ``timestamp`` or ``triggered_at``) if known, else result.json's mtime."""
    meta = _dict(res.get("metadata"))
    for key in ("timestamp", "triggered_at"):
        if meta.get(key):
            return " ".join(str(meta[key]).split()), ""
    t = datetime.fromtimestamp(path.stat().st_mtime, tz=UTC).astimezone()
    return t.isoformat(timespec="seconds"), _("(result file time)")


def _draw_banner(page: _Page, res: dict) -> None:
    """The verdict in words on its colour, and the capture's name."""
    word, colour, ink, meaning = _verdict(str(res["verdict"]))
    h = 0.85
    page.box(_MARGIN, page.y, _W - 2 * _MARGIN, h, facecolor=colour, edgecolor="none")
    size = 32.0  # a long word (ABGEBROCHEN, INTERRUMPIDA) smaller, down to 22 points, then cut
    while size > 22 and page.width(word, size, weight="bold") > 2.9:
        size -= 1
    word = page.fit(word, 2.9, size, weight="bold")
    page.text(_MARGIN + 0.22, page.y + h / 2, word, fontsize=size, fontweight="bold", color=ink, va="center")
    x = max(2.45, 0.22 + page.width(word, size, weight="bold") + 0.3)  # the meaning, after the word
    for msize in (11.0, 10.0, 9.0):  # on at most two lines
        lines = page.wrap(meaning, 4.75 - x, msize)
        if len(lines) <= 2:
            break
    lines = lines[:1] + [page.fit(" ".join(lines[1:]), 4.75 - x, msize)] if len(lines) > 1 else lines
    page.text(_MARGIN + x, page.y + h / 2, "\n".join(lines), fontsize=msize, color=ink, va="center", linespacing=1.15)
    page.text(_W - _MARGIN - 0.22, page.y + 0.2, page.fit(_("Inspection report"), 2.1, 9), fontsize=9, color=ink,
              ha="right")
    page.text(_W - _MARGIN - 0.22, page.y + 0.43, page.fit(res["capture"], 2.1, 12, weight="bold"), fontsize=12,
              fontweight="bold", color=ink, ha="right")
    page.y += h + 0.18


def _draw_identity(page: _Page, res: dict, folder: Path, when: tuple[str, str], rec: dict) -> None:
    """Capture, part id, time, cycle time, recipe and folder, in two columns."""
    meta = _dict(res.get("metadata"))
    total = _dict(res.get("timings_s")).get("total")
    part = meta.get("part_id")
    rows = [
        (_("Capture"), res["capture"], _("Part id"), "—" if part is None else part),
        (_("Inspected"), when[0], _("Cycle time"), _num(total, ".2f", " s")),
        (_("Recipe"), rec["name"], _("Result folder"), folder.resolve().name),
    ]
    lh = _line_h(9, 1.45)
    # Each column's keys as wide as its widest (a translated one may be longer), 1.05 to 1.6 inches.
    kw = [min(max(1.05, max(page.width(row[c], 9) for row in rows) + 0.12), 1.6) for c in (0, 2)]
    for k, (k1, v1, k2, v2) in enumerate(rows):
        y = page.y + k * lh
        for c, (x, width, key, value) in enumerate(((_MARGIN, 3.1, k1, v1), (_MARGIN + 4.3, _W - 2 * _MARGIN - 5.35, k2, v2))):
            weight = "bold" if (k, c) == (0, 0) else "normal"  # the capture
            page.text(x, y, page.fit(key, kw[c] - 0.05, 9), fontsize=9, color=_GREY)
            page.text(x + kw[c], y, page.fit(value, width + 1.05 - kw[c], 9, weight=weight), fontsize=9, fontweight=weight)
        if k == 1 and when[1]:  # where the time comes from, when it is not the capture's
            x = kw[0] + page.width(when[0], 9) + 0.08
            page.text(_MARGIN + x, y + 0.02, page.fit(when[1], 4.15 - x, 7), fontsize=7, color=_GREY)
    page.y += len(rows) * lh + 0.05


def _reason(res: dict, rec: dict) -> tuple[str, str]:
    """(label, sentence) saying why the verdict is what it is."""
    verdict = res["verdict"]
    stats = _dict(res.get("stats"))
    if verdict in _UNFINISHED:
        return (_("Error") if verdict == "error" else _("Aborted"), str(res.get("error") or _("no reason recorded")))
    tol = _dict(stats.get("tolerance_mm"))
    lo, hi = tol.get("lower"), tol.get("upper")
    defects = res.get("defects") or []
    if verdict == "fail" and defects:
        d = defects[0]  # the evaluate stage lists them worst first
        default = d["region"] == "default"
        band = (lo, hi) if default else _region_band(rec.get("text"), d["region"])
        missing = d["kind"] == "missing" or d["worst_mm"] < 0
        values = {"limit": _num(band[0] if missing else band[1], "+.3f"), "band": _band(*band), "region": d["region"]}
        if band[0] is None:
            broken = (_("outside the tolerance (its band is not in this result)") if default else
                      _("outside the tolerance of region '{region}' (its band is not in the recipe shown)"))
        elif missing:
            broken = (_("below the lower limit {limit} mm of the tolerance {band} mm") if default else
                      _("below the lower limit {limit} mm of the region '{region}' tolerance {band} mm"))
        else:
            broken = (_("above the upper limit {limit} mm of the tolerance {band} mm") if default else
                      _("above the upper limit {limit} mm of the region '{region}' tolerance {band} mm"))
        where = _("{n} points, defect #1").format(n=_fmt(d["n_points"], "d"))
        others = _("; {n} more defect(s) below").format(n=len(defects) - 1) if len(defects) > 1 else ""
        return (_("Reason"), f"{_defect_head(d)}, {broken.format(**values)} ({where}){others}.")
    within = stats.get("within_tolerance")
    share = _num(100 * within, ".2f", " %") if isinstance(within, (int, float)) else "—"
    band_text = f"{_band(lo, hi)} mm"
    if verdict == "fail":
        outside = stats.get("out_of_tolerance_points", "—")
        return (_("Reason"), _("out of tolerance ({n} points outside {band}); no defect cluster recorded.").format(
            n=_num(outside, "d") if isinstance(outside, int) and not isinstance(outside, bool) else outside,
            band=band_text))
    found = _("{n} defect(s)").format(n=len(defects)) if defects else _("no defect(s)")
    return (_("Result"), _("{share} of {n} BCPS points within the tolerance {band}; {defects}.").format(
        share=share, n=_num(stats.get("n_points"), ",d"), band=band_text, defects=found))


def _region_band(text: str | None, region: str) -> tuple[Any, Any]:
    """(lower, upper) of a tolerance region in the recipe text; (None, None) when unknown."""
    try:
        regions = tomllib.loads(text or "").get("tolerance", {}).get("regions", [])
        band = next(r for r in regions if r.get("name") == region)
        return band["lower"], band["upper"]
    except (tomllib.TOMLDecodeError, AttributeError, KeyError, StopIteration):
        return None, None


def _draw_reason(page: _Page, res: dict, rec: dict) -> None:
    """The reason (or error) line, at most 4 lines, and at most two warnings of the result."""
    reason = _reason(res, rec)
    colour = {"fail": "#b71c1c", "error": "#8a5a00"}.get(res["verdict"], "black")
    width = _W - 2 * _MARGIN - 1.05
    lines = page.wrap(reason[1], width, 9)
    if len(lines) > 4:
        lines = lines[:3] + [page.fit(" ".join(lines[3:]), width, 9)]
    page.text(_MARGIN, page.y, page.fit(reason[0], 1.0, 9), fontsize=9, color=_GREY)
    for k, line in enumerate(lines):
        page.text(_MARGIN + 1.05, page.y + k * _line_h(9), line, fontsize=9, color=colour)
    page.y += len(lines) * _line_h(9)
    warnings = _dict(res.get("stats")).get("warnings") or []  # e.g. a tolerance the rig cannot resolve
    if not isinstance(warnings, list):
        warnings = [warnings]
    shown = [_("warning: {text}").format(text=w) for w in warnings[:2]] + (
        [_("and {n} more warning(s) in result.json").format(n=len(warnings) - 2)] if len(warnings) > 2 else [])
    for w in shown:
        lines = page.wrap(w, width, 8)
        for line in lines[:1] + ([page.fit(" ".join(lines[1:]), width, 8)] if len(lines) > 1 else []):
            page.text(_MARGIN + 1.05, page.y, line, fontsize=8, color="#b00000")
            page.y += _line_h(8)


def _draw_picture(page: _Page, res: dict, points, image, side: float, rows: int) -> None:
    """The given picture, else the three views (``side`` inches square) and their colour bar."""
    page.heading(_("Deviation map"))
    w = _W - 2 * _MARGIN
    if image is not None:
        h = side + 0.85  # the room the three views and their colour bar would take
        ax = page.axes(_MARGIN, page.y, w, h)
        ax.imshow(image, interpolation="none")  # embedded as it is, not resampled
        ax.set_axis_off()
        page.y += h + 0.05
        return
    if points is None:
        h = 0.5
        page.box(_MARGIN, page.y, w, h, facecolor="#f2f2f2", edgecolor=_RULE, lw=0.6)
        page.text(_W / 2, page.y + h / 2, page.fit(_("no deviation map: this inspection produced no BCPS points"), w - 0.2, 9),
                  ha="center", va="center", fontsize=9, color=_GREY)
        page.y += h + 0.05
        return
    gap = min((w - 0.3 - 3 * side) / 2, 0.55)
    x0 = _MARGIN + 0.15 + (w - 0.3 - 3 * side - 2 * gap) / 2  # the group centred, room for tick labels
    axes = [page.axes(x0 + k * (side + gap), page.y + 0.2, side, side) for k in range(3)]
    # Defects numbered as in the table; those past its last row circled only.
    labels = [str(i + 1) if i < rows else "" for i in range(len(res.get("defects", [])))]
    sc = _draw_views(axes, res, *points, labels=labels, label_size=7, title_size=8, rasterized=True)
    for ax in axes:
        ax.set_aspect("equal", adjustable="datalim")  # three boxes of one size, one scale per view
        ax.tick_params(labelsize=6, length=2)
        ax.xaxis.label.set_size(6.5)
        for label in ax.texts:
            label.set_clip_on(True)
            label.set_fontweight("bold")
            label.set_bbox({"facecolor": "white", "alpha": 0.75, "edgecolor": "none", "pad": 0.6})
    cax = page.axes(_MARGIN + 1.5 * w / 6, page.y + side + 0.62, w / 2, 0.09)
    cb = page.fig.colorbar(sc, cax=cax, orientation="horizontal")
    cb.ax.tick_params(labelsize=6, length=2)
    cb.set_label(page.fit(_("signed deviation, mm (negative: missing material); circles: defects, numbered as below"),
                          w - 0.2, 7), fontsize=7)
    page.y += side + 1.05


def _draw_stats(page: _Page, res: dict) -> None:
    """Deviation, alignment and size, and the time of each stage, in three columns."""
    page.heading(_("Statistics"))
    stats = _dict(res.get("stats"))
    dev = _dict(stats.get("deviation_mm"))
    tol = _dict(stats.get("tolerance_mm"))
    al = _dict(stats.get("alignment"))
    size = _dict(stats.get("size_fit"))
    within = stats.get("within_tolerance")
    shift = size.get("shift_mm")
    stages = [(str(k), _num(v, ".3f", " s")) for k, v in _dict(res.get("timings_s")).items()
              if k != "total" and not str(k).startswith("hook:")][:8]  # plugins' hook times are not stages
    columns = [
        (_("Deviation"), [
            (_("BCPS points"), _num(stats.get("n_points"), ",d")),
            (_("mean"), _num(dev.get("mean"), "+.4f", " mm")),
            (_("min / max"), f"{_num(dev.get('min'), '+.3f')} / {_num(dev.get('max'), '+.3f')} mm"),
            (_("p01 / p99"), f"{_num(dev.get('p01'), '+.3f')} / {_num(dev.get('p99'), '+.3f')} mm"),
            (_("within tolerance"), _num(100 * within, ".2f", " %") if isinstance(within, (int, float)) else "—"),
            (_("tolerance"), f"{_band(tol.get('lower'), tol.get('upper'))} mm"),
        ]),
        (_("Alignment and size"), [
            (_("method"), str(al.get("method", "—"))),
            (_("fitness"), _num(al.get("fitness"), ".4f")),
            (_("RMSE"), _num(al.get("rmse_mm"), ".4f", " mm")),
            (_("size scale"), _num(size.get("scale"), ".5f") if size else _("— (not fitted)")),
            (_("size inliers"), _num(100 * size["inliers"], ".1f", " %")
             if isinstance(size.get("inliers"), (int, float)) else "—"),
            (_("size shift"), list_separator().join(_num(v, "+.2f") for v in shift) + " mm"
             if isinstance(shift, list) and len(shift) == 3 else "—"),
        ]),
        (_("Cycle time per stage"), stages + [(_("total"), _num(_dict(res.get("timings_s")).get("total"), ".3f", " s"))]),
    ]
    lh, colw = _line_h(8, 1.4), (_W - 2 * _MARGIN) / 3
    for c, (title, rows) in enumerate(columns):
        x = _MARGIN + c * colw
        page.text(x, page.y, page.fit(title, colw - 0.2, 8, weight="bold"), fontsize=8, fontweight="bold")
        for k, (key, value) in enumerate(rows):
            y = page.y + (k + 1) * lh
            bold = "bold" if c == 2 and k == len(rows) - 1 else "normal"  # the total
            # The value first, leaving the key up to 0.9 inch; the key gets the rest.
            value = page.fit(value, colw - 0.3 - min(page.width(key, 8, weight=bold), 0.9), 8, weight=bold)
            key = page.fit(key, colw - 0.3 - page.width(value, 8, weight=bold), 8, weight=bold)
            page.text(x, y, key, color=_GREY, fontweight=bold)
            page.text(x + colw - 0.2, y, value, ha="right", fontweight=bold)
    page.y += (1 + max(len(rows) for __, rows in columns)) * lh


def _draw_defects(page: _Page, res: dict, rows: int) -> None:
    """The defect table, worst first: at most ``rows`` rows, then a count of the others."""
    defects = res.get("defects") or []
    page.heading(_("Defects ({n})").format(n=len(defects)))
    if not defects:
        page.text(_MARGIN, page.y, _("no defect"), fontsize=8, color=_GREY)
        page.y += _line_h(8)
        return
    # (title, x of its anchor, alignment, the most it may take, inches)
    cols = (("#", 0.22, "right", 0.2), (_("kind"), 0.35, "left", 0.65), (_("region"), 1.05, "left", 0.85),
            (_("points"), 2.4, "right", 0.5), (_("worst, mm"), 3.2, "right", 0.7),
            (_("position x, y, z, mm"), 5.25, "right", 1.9), (_("extent, mm"), 7.17, "right", 1.8))
    lh = _DEFECT_ROW_H
    for title, x, ha, most in cols:
        page.text(_MARGIN + x, page.y, page.fit(title, most, 7.5, weight="bold"), fontsize=7.5, fontweight="bold", ha=ha)
    page.rule(page.y + lh - 0.02, lw=0.4)
    sep = list_separator()
    for i, d in enumerate(defects[:rows]):
        y = page.y + (i + 1) * lh + 0.02
        if i % 2:
            page.box(_MARGIN, y - 0.025, _W - 2 * _MARGIN, lh, facecolor="#f3f3f3", edgecolor="none")
        cells = (str(i + 1), page.fit(_kind(d["kind"]), 0.65, 7.5), page.fit(d["region"], 0.85, 7.5),
                 _fmt(d["n_points"], ",d"), _fmt(d["worst_mm"], "+.3f"), sep.join(_fmt(v, ".1f") for v in d["position"]),
                 " × ".join(_fmt(v, ".1f") for v in d["extent"]))
        for (__, x, ha, _most), cell in zip(cols, cells):
            page.text(_MARGIN + x, y, cell, fontsize=7.5, ha=ha)
    n = min(len(defects), rows)
    page.y += (n + 1) * lh + 0.06
    if len(defects) > n:
        page.text(_MARGIN + 0.35, page.y, _("and {n} more (result.json lists them all)").format(n=len(defects) - n),
                  fontsize=7.5, color=_GREY)
        page.y += lh


#: Characteristic rows on the page; the others are counted (result.json lists them all).
_MAX_CHAR_ROWS = 12


def _draw_characteristics(page: _Page, res: dict) -> None:
    """The measured characteristics (issue 28), when the result has some: value, limits,
    deviation, expanded uncertainty U (k = 2) and verdict, in the recipe's order."""
    chars = (_dict(res.get("extras")).get("characteristics")) or []
    chars = [c for c in chars if isinstance(c, dict)]
    if not chars:
        return
    nok = sum(c.get("verdict") == "nok" for c in chars)
    page.heading(_("Characteristics ({n}, {nok} NOK)").format(n=len(chars), nok=nok))
    # (title, x of its anchor, alignment, the most it may take, inches)
    cols = ((_("id"), 0.22, "right", 0.3), (_("kind"), 0.35, "left", 1.3), (_("nominal"), 2.0, "right", 0.65),
            (_("measured"), 2.85, "right", 0.8), (_("deviation"), 3.7, "right", 0.8), (_("limits"), 4.75, "right", 0.95),
            (_("U (k=2)"), 5.5, "right", 0.7), (_("verdict"), 5.75, "left", 1.4))
    lh = _DEFECT_ROW_H
    for title, x, ha, most in cols:
        page.text(_MARGIN + x, page.y, page.fit(title, most, 7.5, weight="bold"), fontsize=7.5, fontweight="bold", ha=ha)
    page.rule(page.y + lh - 0.02, lw=0.4)
    shown = chars[:_MAX_CHAR_ROWS]
    for i, c in enumerate(shown):
        y = page.y + (i + 1) * lh + 0.02
        if i % 2:
            page.box(_MARGIN, y - 0.025, _W - 2 * _MARGIN, lh, facecolor="#f3f3f3", edgecolor="none")
        verdict = {"ok": _("OK"), "nok": _("NOK"), "not_measurable": _("NOT MEASURABLE")}.get(
            str(c.get("verdict", "")), str(c.get("verdict", "")).replace("_", " ").upper())
        why = f": {c['reason']}" if c.get("verdict") == "not_measurable" and c.get("reason") else ""
        cells = (page.fit(str(c.get("id", "")), 0.4, 7.5), page.fit(str(c.get("kind", "")), 1.3, 7.5),
                 _num(c.get("nominal"), ".4f"), _num(c.get("measured"), ".4f"), _num(c.get("deviation"), "+.4f"),
                 f"{_num(c.get('lower'), '+.3f')} / {_num(c.get('upper'), '+.3f')}", _num(c.get("U"), ".4f"),
                 page.fit(verdict + why, 1.2, 7.5))
        color = "#b00020" if c.get("verdict") == "nok" else "black"
        for (__, x, ha, _most), cell in zip(cols, cells):
            page.text(_MARGIN + x, y, cell, fontsize=7.5, ha=ha, color=color)
    page.y += (len(shown) + 1) * lh + 0.06
    if len(chars) > len(shown):
        page.text(_MARGIN + 0.35, page.y, _("and {n} more (result.json lists them all)").format(n=len(chars) - len(shown)),
                  fontsize=7.5, color=_GREY)
        page.y += lh


def _draw_recipe(page: _Page, rec: dict) -> float:
    """Recipe name, file, SHA-256 and its text in the space left above the footer.

    Returns the height (inches) that was left for the text.
    """
    page.heading(_("Recipe"))
    lh = _line_h(8, 1.4)
    rows = [(_("name"), rec["name"]), (_("file"), rec["path"] or "—"), (_("SHA-256"), rec["sha256"] or "—")]
    width = _W - 2 * _MARGIN - 1.05
    for k, (key, value) in enumerate(rows):
        page.text(_MARGIN, page.y + k * lh, page.fit(key, 1.0, 8), color=_GREY)
        if k == 2 and rec["sha256"]:
            mono = {"family": "DejaVu Sans Mono"}
            page.text(_MARGIN + 1.05, page.y + k * lh, page.fit(value, width, 7.5, **mono), fontsize=7.5, **mono)
        else:
            page.text(_MARGIN + 1.05, page.y + k * lh, page.fit(value, width, 8))
    page.y += len(rows) * lh
    if rec["note"]:
        for line in page.wrap(rec["note"], width, 8)[:2]:  # a long note (a hash in a translated sentence) on two lines
            page.text(_MARGIN + 1.05, page.y, page.fit(line, width, 8), color="#b00000")
            page.y += lh
    text = rec["text"]
    bottom = _H - _MARGIN - 0.3  # above the footer
    room = bottom - page.y
    if text is None or room < 0.3:
        return room
    # Monospace text in the columns (1 to 3) that show the most of it; what does not fit is cut.
    size = 6.0
    y0, lh, cw = page.y + 0.08, _line_h(size, 1.25), 0.6 * size / 72  # DejaVu Sans Mono advance: 0.6 em
    page.box(_MARGIN, y0 - 0.05, _W - 2 * _MARGIN, bottom - y0 + 0.05, facecolor="#f6f6f6", edgecolor=_RULE, lw=0.5)
    lines = text.expandtabs(4).splitlines()
    per_col = max(1, int((bottom - y0 - 0.05) / lh))

    def layout(ncols: int) -> tuple[int, int, int, list[str]]:
        """(lines shown, characters shown, columns, lines) when set in ``ncols`` columns."""
        width = int(((_W - 2 * _MARGIN) / ncols - 0.2) / cw)
        fit = per_col * ncols
        shown = lines if len(lines) <= fit else lines[: fit - 1] + [_("… {n} more line(s)").format(n=len(lines) - fit + 1)]
        cut = [ln if len(ln) <= width else ln[: width - 1] + "…" for ln in shown]
        kept = cut[: min(len(lines), fit if len(lines) <= fit else fit - 1)]
        return len(kept), sum(len(ln) for ln in kept), ncols, cut

    __, ___, ncols, cut = max(layout(n) for n in (1, 2, 3))  # every line first, then the most text
    colw = (_W - 2 * _MARGIN) / ncols
    for c in range(ncols):
        chunk = cut[c * per_col:(c + 1) * per_col]
        if chunk:
            page.text(_MARGIN + 0.1 + c * colw, y0, "\n".join(chunk), family="DejaVu Sans Mono", fontsize=size,
                      linespacing=1.25)
    page.y = bottom
    return room


def _draw_footer(page: _Page, folder: Path) -> None:
    """Who made the page, when, from which folder; the page number."""
    now = datetime.now(UTC).astimezone().isoformat(timespec="seconds")
    y = _H - _MARGIN - 0.12
    page.rule(y - 0.06)
    made = _("inspector {version} · report generated {time} · {folder}").format(version=__version__, time=now,
                                                                                 folder=folder.resolve())
    page.text(_MARGIN, y, page.fit(made, _W - 2 * _MARGIN - 0.8, 6.5), fontsize=6.5, color=_GREY)
    page.text(_W - _MARGIN, y, page.fit(_("page 1 of 1"), 0.75, 6.5), fontsize=6.5, color=_GREY, ha="right")
