"""The shift report on paper: ``inspector history OUTDIR --shift [N] --pdf FILE``.

One A4 page per shift (oldest first), drawn with matplotlib's PDF backend (real text, which
readers can search and copy): the shift and its hours, the parts inspected, passed, failed and
in error, the yield, a bar of the verdicts' shares, and the worst regions, the worst measured
characteristics and the errors' reasons, as :mod:`inspector.shift` counts them (the same
numbers ``inspector history --shift`` prints and the GUI's shift panel shows).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path

from inspector.locale import _, number
from inspector.shift import ShiftCounters

__all__ = ["render_shift_pdf"]

_W, _H = 8.27, 11.69  # A4 portrait, inches
_MARGIN = 0.6
_GREY = "#555555"
_COLOURS = {"pass": "#2e7d32", "fail": "#c62828", "error": "#f0a202"}
_ROWS = 10  # at most this many rows per table


def render_shift_pdf(counters: Sequence[ShiftCounters], out: Path, *, source: str = "") -> Path:
    """Write one page per shift of ``counters`` to the PDF ``out`` (written to a temporary
    name and renamed: a reader never sees half a file); ``source`` names where the rows come
    from (the history's folder). Returns ``out``."""
    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    out = Path(out)
    tmp = out.with_name(out.name + ".part")
    made = datetime.now().astimezone().isoformat(timespec="seconds")
    try:
        with matplotlib.rc_context({"pdf.fonttype": 42, "font.family": "DejaVu Sans"}), PdfPages(tmp) as pdf:
            for c in counters:
                fig = Figure(figsize=(_W, _H))
                _draw(fig, c, source, made)
                pdf.savefig(fig)
            info = pdf.infodict()
            info["Title"] = _("Shift report: {shifts}").format(shifts=", ".join(c.shift.label() for c in counters))
            info["Creator"] = "inspector history --shift --pdf"
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


class _Ink:
    """Text on a figure, placed in inches from the top-left corner."""

    def __init__(self, fig) -> None:
        self.fig, self.y = fig, _MARGIN

    def text(self, x: float, s: str, **kw) -> None:
        kw.setdefault("va", "top")
        self.fig.text(x, _H - self.y, s, transform=self.fig.dpi_scale_trans, **kw)

    def line(self, s: str, size: float = 9.5, dy: float = 1.45, x: float = _MARGIN, **kw) -> None:
        self.text(x, s, fontsize=size, **kw)
        self.y += size * dy / 72

    def heading(self, s: str) -> None:
        self.y += 0.12
        self.line(s, 11, fontweight="bold")
        self.fig.add_artist(_rule(self.fig, self.y))
        self.y += 0.06


def _rule(fig, y: float):
    from matplotlib.lines import Line2D

    return Line2D([_MARGIN, _W - _MARGIN], [_H - y, _H - y], transform=fig.dpi_scale_trans, color="#9e9e9e", lw=0.6)


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{number(100 * x, '.1f')} %"


def _draw(fig, c: ShiftCounters, source: str, made: str) -> None:
    ink = _Ink(fig)
    s = c.shift
    ink.line(_("Shift report"), 18, fontweight="bold")
    ink.line(_("{name} shift, {start} to {end} ({zone})").format(
        name=s.name, start=f"{s.start:%Y-%m-%d %H:%M}", end=f"{s.end:%Y-%m-%d %H:%M}", zone=f"{s.start:%Z}{s.start:%z}"), 11)
    if source:
        ink.line(_("history: {source}").format(source=source), 8.5, color=_GREY)
    ink.line(_("made {time}").format(time=made), 8.5, color=_GREY)
    ink.y += 0.15
    # The figures, large: what a shift leader reads first.
    cells = [(_("inspected"), str(c.inspected), "black"), (_("pass"), str(c.passed), _COLOURS["pass"]),
             (_("fail"), str(c.failed), _COLOURS["fail"]), (_("error"), str(c.errors), "#a86f00"),
             (_("yield"), _pct(c.yield_), "black")]
    width = (_W - 2 * _MARGIN) / len(cells)
    for i, (label, value, colour) in enumerate(cells):
        x = _MARGIN + i * width
        ink.text(x, label, fontsize=9, color=_GREY)
        fig.text(x, _H - ink.y - 0.2, value, transform=fig.dpi_scale_trans, fontsize=22, fontweight="bold",
                 color=colour, va="top")
    ink.y += 0.75
    _verdict_bar(fig, ink, c)
    ink.heading(_("Worst regions (parts with a defect there, defects, worst deviation)"))
    if not c.regions:
        ink.line(_("no defect in this shift"), color=_GREY)
    for g in c.regions[:_ROWS]:
        _row(ink, [g.region, f"{g.parts}", f"{g.defects}", f"{number(g.worst_mm, '+.3f')} mm"])
    ink.heading(_("Worst characteristics (parts, NOK, not measurable, most of the tolerance used)"))
    if not c.characteristics:
        ink.line(_("no characteristic measured in this shift"), color=_GREY)
    for ch in c.characteristics[:_ROWS]:
        _row(ink, [ch.id, f"{ch.parts}", f"{ch.nok}", f"{ch.not_measurable}", _pct(ch.worst_use)],
             colour=_COLOURS["fail"] if ch.nok else None)
    ink.heading(_("Errors by reason"))
    if not c.error_groups:
        ink.line(_("no error in this shift"), color=_GREY)
    for e in c.error_groups[:_ROWS]:
        reason = e.reason if len(e.reason) <= 95 else e.reason[:94] + "…"
        _row(ink, [f"{e.count}×", reason], widths=(0.6,))


def _row(ink: _Ink, cells: list[str], *, widths: tuple[float, ...] = (2.6, 0.9, 0.9, 0.9, 1.1),
         colour: str | None = None) -> None:
    x = _MARGIN
    for i, cell in enumerate(cells):
        ink.text(x, cell, fontsize=9.5, color=colour or "black")
        x += widths[i] if i < len(widths) else 1.0
    ink.y += 9.5 * 1.45 / 72


def _verdict_bar(fig, ink: _Ink, c: ShiftCounters) -> None:
    """The shares of pass, fail and error as one bar across the page (nothing when no part
    was inspected)."""
    if not c.inspected:
        ink.line(_("no inspection in this shift"), color=_GREY)
        return
    from matplotlib.patches import Rectangle

    x, full, h = _MARGIN, _W - 2 * _MARGIN, 0.28
    for key, n in (("pass", c.passed), ("fail", c.failed), ("error", c.errors)):
        if not n:
            continue
        w = full * n / c.inspected
        fig.add_artist(Rectangle((x, _H - ink.y - h), w, h, transform=fig.dpi_scale_trans, color=_COLOURS[key], lw=0))
        if w > 0.5:
            fig.text(x + w / 2, _H - ink.y - h / 2, f"{_(key)} {n}", transform=fig.dpi_scale_trans, fontsize=8.5,
                     color="white" if key != "error" else "black", ha="center", va="center")
        x += w
    ink.y += h + 0.1
