"""The operator screen's history strip: the last parts as verdict chips, the yield, the
trend chart of ``inspector history --plot`` and the current shift's panel
(:mod:`inspector.shift`).

The chart is a picture (:func:`history_chart`: matplotlib's Agg canvas drawn into a
``QImage``, safe in any thread), made with the history rows and the shift's counters off the
GUI thread after an inspection (:func:`~inspector_frontends.gui.prepare.prepare_view`); the
strip then only swaps it, in place.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QCoreApplication, QDate, QEvent, QLocale, QRect, QRectF, QSize, Qt, QTime, QTimer, Signal
from PySide6.QtGui import QColor, QFont, QHelpEvent, QImage, QPainter
from PySide6.QtWidgets import QFrame, QHBoxLayout, QLabel, QSizePolicy, QToolTip, QVBoxLayout, QWidget

from inspector.errors import InputError
from inspector.history_store import read_history
from inspector.shift import shift_counters
from inspector_frontends.gui.i18n import number, percent
from inspector_frontends.gui.widgets import QT_TRANSLATE_NOOP, VERDICT_STYLE, verdict_word
from inspector_plugins.history import draw_history, tally

__all__ = ["HistoryStrip", "ShiftPanel", "history_chart", "read_rows", "read_shift", "HISTORY_ROWS"]

#: History rows the strip reads (chips show the last ``HistoryStrip.CHIPS`` of them).
HISTORY_ROWS = 50
#: matplotlib's figures are not meant to be drawn by two threads at once.
_MPL_LOCK = threading.Lock()
#: The figure :func:`history_chart` draws on (under the lock), and its size.
_CHART: dict[str, Any] = {}


def history_chart(rows: list[dict[str, Any]], size: tuple[int, int], ratio: float = 1.0) -> QImage:
    """The trend chart of ``rows`` (``inspector history --plot``'s drawing, same data and
    limits) as an image of ``size`` (logical pixels) at device-pixel ``ratio``; safe in any
    thread (drawn on one module-level figure, under a lock)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dpi = 90.0 * ratio
    w, h = max(1, round(size[0] * ratio)), max(1, round(size[1] * ratio))
    with _MPL_LOCK:
        # One figure, drawn anew each time.
        if _CHART.get("key") != (w, h, dpi):
            figure = Figure(figsize=(w / dpi, h / dpi), dpi=dpi)
            _CHART.update(key=(w, h, dpi), figure=figure, canvas=FigureCanvasAgg(figure))
        figure, canvas = _CHART["figure"], _CHART["canvas"]
        figure.clear()
        ax = figure.add_subplot(111)
        if rows:
            draw_history(ax, rows, labels=False)
            _translate_chart(ax, rows)
        ax.tick_params(labelsize=7)
        figure.subplots_adjust(left=0.08, right=0.99, top=0.85, bottom=0.12)
        canvas.draw()
        buf = np.asarray(canvas.buffer_rgba())
        img = QImage(buf.data, buf.shape[1], buf.shape[0], buf.strides[0], QImage.Format.Format_RGBA8888).copy()
    img.setDevicePixelRatio(ratio)
    return img


def _translate_chart(ax: Any, rows: list[dict[str, Any]]) -> None:
    """The words of :func:`~inspector_plugins.history.draw_history`'s chart (its title and
    legend, English) in the GUI's language, its numbers in the locale's format."""
    n, share = tally(rows)
    yld = QCoreApplication.translate("Widgets", "yield {share}").format(share=percent(share)) if share is not None \
        else QCoreApplication.translate("Widgets", "no part judged")
    ax.set_title(QCoreApplication.translate("Widgets", "{n} inspections \u00b7 pass {p} \u00b7 fail {f} \u00b7 error {e} \u00b7 {yld}").format(
        n=len(rows), p=n["pass"], f=n["fail"], e=n["error"], yld=yld), fontsize=9)
    legend = ax.get_legend()
    if legend is not None:
        for t in legend.get_texts():
            if t.get_text() == "tolerance":
                t.set_text(QCoreApplication.translate("Widgets", "tolerance"))
    sep = QLocale().decimalPoint()
    if sep != ".":
        from matplotlib.ticker import FuncFormatter

        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}".replace(".", sep)))


def read_rows(outdir: Path | None) -> list[dict[str, Any]]:
    """The last :data:`HISTORY_ROWS` rows of ``outdir/history.sqlite`` ([] when there is none)."""
    if outdir is None:
        return []
    try:
        return read_history(outdir, last=HISTORY_ROWS)
    except InputError:
        return []


def read_shift(outdir: Path | None, settings: Any) -> Any:
    """The counters of the current shift in ``outdir``'s history (:mod:`inspector.shift`;
    None: no history yet, or it cannot be read); safe in any thread."""
    if outdir is None:
        return None
    try:
        return shift_counters(outdir, settings)[-1]
    except InputError:
        return None


class _Chips(QWidget):
    """The last parts as chips: the verdict's glyph on its colour (word in the tooltip),
    oldest first; painted in one widget, updated in place."""

    SIZE = QSize(26, 34)
    GAP = 3

    def __init__(self, count: int, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.count = count
        self.rows: list[dict[str, Any]] = []
        self.setMinimumHeight(self.SIZE.height())
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)
        self.setAccessibleName(self.tr("history: last parts"))

    def sizeHint(self) -> QSize:
        return QSize(self.count * (self.SIZE.width() + self.GAP), self.SIZE.height())

    def set_rows(self, rows: list[dict[str, Any]]) -> None:
        self.rows = list(rows[-self.count:])
        self.setAccessibleDescription(", ".join(verdict_word(r["verdict"]) for r in self.rows))
        self.update()

    def _rect(self, k: int) -> QRect:
        return QRect(k * (self.SIZE.width() + self.GAP), 0, self.SIZE.width(), self.SIZE.height())

    def paintEvent(self, event: Any) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        f = QFont(self.font())
        f.setPointSize(13)
        p.setFont(f)
        for k, r in enumerate(self.rows):
            word, glyph, bg = VERDICT_STYLE.get(r["verdict"], VERDICT_STYLE["error"])
            rect = self._rect(k)
            p.setPen(Qt.PenStyle.NoPen)
            p.setBrush(QColor(bg))
            p.drawRoundedRect(QRectF(rect), 3, 3)
            p.setPen(QColor("white"))
            p.drawText(rect, Qt.AlignmentFlag.AlignCenter, glyph)
        p.end()

    def event(self, event: QEvent) -> bool:
        # A tool-tip event arrives as the QHelpEvent it is (PySide6 hands events over as their subclass).
        if event.type() == QEvent.Type.ToolTip and isinstance(event, QHelpEvent):
            for k, r in enumerate(self.rows):
                if self._rect(k).contains(event.pos()):
                    word = verdict_word(r["verdict"])
                    text = (self.tr("{capture}: {word}, worst {worst} mm").format(
                        capture=r["capture"], word=word, worst=number(r["worst_mm"], 3, sign=True))
                        if r.get("worst_mm") is not None else f"{r['capture']}: {word}")
                    QToolTip.showText(event.globalPos(), text, self)
                    return True
            QToolTip.hideText()
            event.ignore()
            return True
        return super().event(event)


class _Chart(QWidget):
    """A picture made elsewhere (the history chart), drawn at the widget's size; asks for a
    new one (``resized``) when its size changed and stays so for a moment."""

    resized = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.image: QImage | None = None
        self._px: tuple[tuple[int, int], float] = ((self.width(), self.height()), 1.0)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self._settle = QTimer(self)
        self._settle.setSingleShot(True)
        self._settle.setInterval(150)
        self._settle.timeout.connect(self._check)

    def sizeHint(self) -> QSize:
        return QSize(720, 171)  # the figure of `inspector history --plot`'s strip: 8 x 1.9 in at 90 dpi

    def size_px(self) -> tuple[tuple[int, int], float]:
        """(logical size, device-pixel ratio) a picture for this widget should have: a value
        kept on each resize, so another thread may ask."""
        return self._px

    def fits(self, image: QImage | None) -> bool:
        return image is not None and image.deviceIndependentSize().toSize() == self.size()

    def set_image(self, image: QImage) -> None:
        self.image = image
        self.update()

    def resizeEvent(self, event: Any) -> None:
        super().resizeEvent(event)
        self._px = ((self.width(), self.height()), float(self.devicePixelRatioF()))
        self._settle.start()

    def settle(self) -> None:
        """Ask for a new picture (``resized``) once the size stays put for a moment, unless the
        picture fits by then."""
        self._settle.start()

    def _check(self) -> None:
        if not self.fits(self.image):
            self.resized.emit()

    def paintEvent(self, event: Any) -> None:
        if self.image is None:
            return
        p = QPainter(self)
        if not self.fits(self.image):
            p.setRenderHint(QPainter.RenderHint.SmoothPixmapTransform)
        p.drawImage(self.rect(), self.image)
        p.end()


#: The default shift names (:class:`inspector.shift.ShiftSettings`), marked for translation: a
#: cell's own names are shown as they are.
_SHIFT_NAMES = (QT_TRANSLATE_NOOP("Shift", "early"), QT_TRANSLATE_NOOP("Shift", "late"),
                QT_TRANSLATE_NOOP("Shift", "night"))


def _shift_name(name: str) -> str:
    """A shift's name in the GUI's language when it is one of the default names."""
    context = "Shift"  # not a literal: lupdate collects the names from _SHIFT_NAMES, not from here
    return QCoreApplication.translate(context, name)


def _elided(label: QLabel) -> None:
    """A label that may be narrower than its text (its minimum width would otherwise be the
    whole text's, and the window could not fit a small screen); the full text in its tooltip."""
    label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
    label.setMinimumWidth(1)


class ShiftPanel(QFrame):
    """The current shift at a glance (:mod:`inspector.shift`): its name and hours, the parts
    inspected, passed, failed and in error, the yield, the worst regions and the errors'
    reasons grouped."""

    TOP = 3

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("shiftPanel")
        self.setFrameShape(QFrame.Shape.StyledPanel)
        self.title = QLabel()
        self.title.setObjectName("shiftTitle")
        self.counts = QLabel()
        self.counts.setObjectName("shiftCounts")
        self.regions = QLabel()
        self.chars = QLabel()
        self.errors = QLabel()
        for label in (self.title, self.counts, self.regions, self.chars, self.errors):
            _elided(label)
        for label in (self.counts, self.regions, self.chars, self.errors):
            label.setWordWrap(True)
        self.setStyleSheet("#shiftTitle { font-weight: bold; } #shiftCounts { font-weight: bold; }")
        lay = QVBoxLayout(self)
        lay.setContentsMargins(8, 2, 8, 2)
        lay.setSpacing(0)
        for label in (self.title, self.counts, self.regions, self.chars, self.errors):
            lay.addWidget(label)
        lay.addStretch(1)
        self.counters: Any = None
        self.show_counters(None)

    def show_counters(self, counters: Any) -> None:
        """Show a :class:`~inspector.shift.ShiftCounters` (None: no history yet)."""
        self.counters = counters
        if counters is None:
            self.title.setText(self.tr("Shift"))
            self.counts.setText(self.tr("no inspection in this shift yet"))
            self.regions.setText("")
            self.chars.setText("")
            self.chars.hide()
            self.errors.setText("")
            return
        s = counters.shift
        fmt = QLocale.FormatType.ShortFormat
        start = QLocale().toString(QTime(s.start.hour, s.start.minute), fmt)
        end = QLocale().toString(QTime(s.end.hour, s.end.minute), fmt)
        self.title.setText(self.tr("{name} shift, {date} {start} to {end}").format(
            name=_shift_name(s.name), date=QLocale().toString(
                QDate(s.start.year, s.start.month, s.start.day), fmt), start=start, end=end))
        yld = percent(counters.yield_) if counters.yield_ is not None else "-"
        self.counts.setText(self.tr("yield {share}: {n} inspected \u00b7 pass {p} \u00b7 fail {f} \u00b7 error {e}").format(
            share=yld, n=counters.inspected, p=counters.passed, f=counters.failed, e=counters.errors))
        if counters.regions:
            parts = [self.tr("{region} {parts}\u00d7 ({worst} mm)").format(
                region=g.region, parts=g.parts, worst=number(g.worst_mm, 3, sign=True)) for g in counters.regions[:self.TOP]]
            self.regions.setText(self.tr("worst regions: {list}").format(list=", ".join(parts)))
        else:
            self.regions.setText(self.tr("no defect in this shift"))
        self._show_characteristics(counters.characteristics)
        if counters.error_groups:
            groups = [f"{e.count}\u00d7 {e.reason}" for e in counters.error_groups[:self.TOP]]
            self.errors.setText(self.tr("errors: {list}").format(list="; ".join(groups)))
            self.errors.setToolTip("\n".join(f"{e.count}\u00d7 {e.example}" for e in counters.error_groups))
        else:
            self.errors.setText(self.tr("no error in this shift"))
            self.errors.setToolTip("")
        self.regions.setToolTip(self.regions.text())

    def _show_characteristics(self, chars: Any) -> None:
        """The worst measured characteristics of the shift (hidden when the recipe measures
        none): NOK and not measurable counts, else the most of the tolerance used."""
        if not chars:
            self.chars.setText("")
            self.chars.hide()
            return
        items = []
        for c in chars[:self.TOP]:
            if c.nok:
                items.append(self.tr("{id} {n}\u00d7 NOK").format(id=c.id, n=c.nok))
            elif c.not_measurable:
                items.append(self.tr("{id} {n}\u00d7 not measurable").format(id=c.id, n=c.not_measurable))
            elif c.worst_use is not None:
                items.append(self.tr("{id} at most {share} of the tolerance").format(id=c.id, share=percent(c.worst_use, 0)))
            else:
                items.append(c.id)
        self.chars.setText(self.tr("worst characteristics: {list}").format(list=", ".join(items)))
        self.chars.setToolTip(self.chars.text())
        self.chars.show()


class HistoryStrip(QWidget):
    """The last parts as verdict chips (word and colour), the yield, and the trend chart of
    ``inspector history --plot`` (same rows, same drawing function, same limits).

    The chart is a picture made by :func:`history_chart`: by :func:`~inspector_frontends.gui.prepare.prepare_view` in the
    worker thread after an inspection, here after :meth:`refresh` or a resize."""

    CHIPS = 24

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.canvas = _Chart()
        self.canvas.setMinimumHeight(100)
        self.canvas.setMaximumHeight(170)
        self.canvas.resized.connect(self._redraw)
        self.chips = _Chips(self.CHIPS)
        self.yield_label = QLabel(self.tr("no inspection yet"))
        self.yield_label.setStyleSheet("font-size: 14pt; font-weight: bold;")
        _elided(self.yield_label)
        self.yield_label.setWordWrap(True)
        self.chips.setMinimumWidth(self.chips.SIZE.width() * 6)
        self.shift = ShiftPanel()
        left = QVBoxLayout()
        left.addWidget(self.yield_label)
        left.addWidget(self.chips)
        left.addStretch(1)
        lay = QHBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addLayout(left, 2)
        lay.addWidget(self.shift, 2)
        lay.addWidget(self.canvas, 3)
        self.rows: list[dict[str, Any]] = []

    def chart_size(self) -> tuple[tuple[int, int], float]:
        """Size and device-pixel ratio of the chart (for :func:`~inspector_frontends.gui.prepare.prepare_view`)."""
        return self.canvas.size_px()

    def refresh(self, outdir: Path | None, shifts: Any = None) -> None:
        """Re-read ``outdir/history.sqlite`` (nothing when there is none yet); with ``shifts``
        (:class:`~inspector.shift.ShiftSettings`) the current shift's counters too."""
        self.show_rows(read_rows(outdir))
        if shifts is not None:
            self.shift.show_counters(read_shift(outdir, shifts))

    def show_rows(self, rows: list[dict[str, Any]], chart: QImage | None = None) -> None:
        """Show ``rows``; ``chart``: their :func:`history_chart`, made ahead (else drawn here,
        or later when it was made for another size)."""
        self.rows = rows
        self.chips.set_rows(rows)
        n, share = tally(rows)
        if share is not None:
            text = self.tr("last {n}: yield {share} \u00b7 pass {p} \u00b7 fail {f} \u00b7 error {e}").format(
                n=len(rows), share=percent(share), p=n["pass"], f=n["fail"], e=n["error"])
        else:
            text = self.tr("no part judged yet") if not rows else self.tr("error {e}").format(e=n["error"])
        if text != self.yield_label.text():
            self.yield_label.setText(text)
        if chart is None:
            chart = history_chart(rows, *self.chart_size())
        self.canvas.set_image(chart)
        if not self.canvas.fits(chart):
            self.canvas.settle()  # the strip was resized meanwhile: drawn again at its size

    def _redraw(self) -> None:
        self.canvas.set_image(history_chart(self.rows, *self.chart_size()))
