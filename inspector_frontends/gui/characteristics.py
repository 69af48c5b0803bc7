"""The operator screen's characteristics (issue 28): the current part's measured
characteristics as a table (value, nominal, limits, a deviation bar within the tolerance, U,
OK / NOK / not measurable) and the trend of the selected one over the recorded parts, in a
tab beside the defect table (:class:`ResultTabs`).

Both draw what they are given: a :class:`~inspector_frontends.gui.viewmodel.ResultView`'s
:attr:`characteristics` and the history rows the history strip already read (no file is read
here). The trend and the bars are painted with ``QPainter`` on the GUI thread: a few dozen
lines and points, cheaper than a matplotlib figure and crisp at any size.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from PySide6.QtCore import QModelIndex, QPersistentModelIndex, QPointF, QRect, QRectF, QSize, Qt, Signal
from PySide6.QtGui import QColor, QPainter, QPainterPath, QPen
from PySide6.QtWidgets import (
    QHeaderView,
    QLabel,
    QSizePolicy,
    QStyledItemDelegate,
    QStyleOptionViewItem,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from inspector.characteristics.charts import I_CHART_K
from inspector.characteristics.definitions import rows_of
from inspector_frontends.gui.i18n import number
from inspector_frontends.gui.viewmodel import CharacteristicRow, ResultView
from inspector_frontends.gui.widgets import QT_TRANSLATE_NOOP, DefectTable, RowTable

__all__ = ["ResultTabs", "CharacteristicsPanel", "CharacteristicsTable", "TrendChart", "TrendPoint", "trend_of", "VERDICTS"]

#: Verdict of a characteristic -> (word, glyph, colour); the word and glyph say it without colour.
VERDICTS: dict[str, tuple[str, str, str]] = {
    "ok": (QT_TRANSLATE_NOOP("CharacteristicsTable", "OK"), "\u2714", "#1b7f3b"),
    "nok": (QT_TRANSLATE_NOOP("CharacteristicsTable", "NOK"), "\u2716", "#b3141b"),
    "not_measurable": (QT_TRANSLATE_NOOP("CharacteristicsTable", "not measurable"), "\u2014", "#5f6368"),
}
_IN, _OUT, _BAND = QColor("#1b7f3b"), QColor("#b3141b"), QColor(27, 127, 59, 40)
#: Column of the deviation bar.
BAR_COLUMN = 4


def _digits(unit: str) -> int:
    return 4 if unit == "mm" else 3


def _value(v: float, unit: str, k: int) -> str:
    """A value in its unit, short: mm bare (the screen's unit), degrees with ``°``."""
    return f"{number(v, k)}\u00b0" if unit == "deg" else number(v, k) if unit == "mm" else f"{number(v, k)} {unit}"


def _nominal(c: CharacteristicRow, k: int) -> str:
    """The nominal with its limits, short (the table shares the screen's right column with
    the cameras): ``36.0000 ±0.0500``, ``36.0000 -0.0200/+0.0500``, a form ``≤ 0.0500``."""
    if c.nominal == 0 and c.lower == 0:
        return f"\u2264 {number(c.upper, k)}"
    if c.lower == -c.upper:
        return f"{number(c.nominal, k)} \u00b1{number(c.upper, k)}"
    return f"{number(c.nominal, k)} {number(c.lower, k, sign=True)}/{number(c.upper, k, sign=True)}"


@dataclass(frozen=True)
class TrendPoint:
    """One recorded part's value of a characteristic (``value`` None: not measurable)."""

    capture: str
    value: float | None
    verdict: str
    nominal: float
    lower: float
    upper: float


def trend_of(history_rows: Sequence[Mapping[str, Any]], cid: str) -> list[TrendPoint]:
    """Characteristic ``cid``'s values over ``history_rows`` (the history's rows, oldest first;
    their ``extras`` column as the history stores it), skipping the parts that did not
    measure it (an error, another recipe)."""
    out = []
    for row in history_rows:
        raw = row.get("extras")
        try:
            extras = json.loads(raw) if isinstance(raw, str) else (raw or {})
        except ValueError:
            continue
        for r in rows_of({"extras": extras}):
            if str(r.get("id")) == cid:
                v = r.get("measured")
                try:
                    out.append(TrendPoint(str(row.get("capture", "")), None if v is None else float(v),
                                          str(r.get("verdict", "")), float(r.get("nominal", 0.0)),
                                          float(r.get("lower", 0.0)), float(r.get("upper", 0.0))))
                except (TypeError, ValueError):
                    pass
                break
    return out


class _BarDelegate(QStyledItemDelegate):
    """The deviation bar: the tolerance from ``lower`` to ``upper`` as a green band in the
    middle of the cell, the deviation as a tick with its ±U whisker, red outside the band."""

    def paint(self, painter: QPainter, option: QStyleOptionViewItem, index: QModelIndex | QPersistentModelIndex) -> None:
        super().paint(painter, option, index)
        row = index.data(Qt.ItemDataRole.UserRole)
        if not isinstance(row, CharacteristicRow):
            return
        # The bar on the cell's left 60 % (the deviation's number is right-aligned beside
        # it): the tolerance in its middle 60 %, a fifth of the bar each side for values outside.
        cell = QRectF(option.rect)
        r = QRectF(cell.left() + 6, cell.top() + 8, 0.6 * cell.width() - 12, cell.height() - 16)
        lo, hi = row.lower, row.upper
        width = hi - lo
        if r.width() < 20 or width <= 0:
            return
        band = QRectF(r.left() + 0.2 * r.width(), r.top(), 0.6 * r.width(), r.height())

        def x(v: float) -> float:
            return band.left() + (v - lo) / width * band.width()

        painter.save()
        painter.setRenderHint(QPainter.RenderHint.Antialiasing)
        painter.fillRect(band, _BAND)
        painter.setPen(QPen(_IN, 1))
        painter.drawRect(band)
        if row.deviation is not None:
            colour = _OUT if row.verdict == "nok" else _IN
            d = min(max(row.deviation, lo - width / 3), hi + width / 3)  # far outside: at the cell's edge
            if row.U:
                painter.setPen(QPen(colour, 1.5))
                a, b = x(max(d - row.U, lo - width / 3)), x(min(d + row.U, hi + width / 3))
                painter.drawLine(QPointF(a, r.center().y()), QPointF(b, r.center().y()))
            painter.setPen(QPen(colour, 3))
            painter.drawLine(QPointF(x(d), r.top() - 3), QPointF(x(d), r.bottom() + 3))
        painter.restore()


class CharacteristicsTable(RowTable):
    """One row per characteristic in the recipe's order; selecting one emits
    ``selected(id)``."""

    selected = Signal(str)
    HEADERS = ("#", QT_TRANSLATE_NOOP("CharacteristicsTable", "characteristic"),
               QT_TRANSLATE_NOOP("CharacteristicsTable", "measured"), QT_TRANSLATE_NOOP("CharacteristicsTable", "nominal"),
               QT_TRANSLATE_NOOP("CharacteristicsTable", "deviation"),
               QT_TRANSLATE_NOOP("CharacteristicsTable", "U (k=2)"), QT_TRANSLATE_NOOP("CharacteristicsTable", "verdict"))

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        header = self.horizontalHeader()
        # The label takes what is left (elided, whole in its tooltip); the bar a fixed width.
        header.setSectionResizeMode(1, QHeaderView.ResizeMode.Stretch)
        header.setSectionResizeMode(BAR_COLUMN, QHeaderView.ResizeMode.Fixed)
        header.resizeSection(BAR_COLUMN, 160)
        self.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.setItemDelegateForColumn(BAR_COLUMN, _BarDelegate(self))
        self.setAccessibleName(self.tr("characteristics table"))
        self.rows: tuple[CharacteristicRow, ...] = ()
        self.itemSelectionChanged.connect(self._selected)

    def show_rows(self, rows: tuple[CharacteristicRow, ...]) -> None:
        self.blockSignals(True)
        self.clearSelection()
        self.rows = rows
        self.setRowCount(len(rows))
        for r, c in enumerate(rows):
            k = _digits(c.unit)
            word, glyph, colour = VERDICTS.get(c.verdict, VERDICTS["not_measurable"])
            measured = "-" if c.measured is None else _value(c.measured, c.unit, k)
            values = (c.id, c.label, measured, _nominal(c, k),
                      "" if c.deviation is None else number(c.deviation, k, sign=True),
                      "-" if c.U is None else number(c.U, k), f"{glyph} {self.tr(word)}")
            for col, v in enumerate(values):
                item = QTableWidgetItem(v)
                if col in (0, 2, 3, 5):
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                if col == BAR_COLUMN:
                    item.setData(Qt.ItemDataRole.UserRole, c)
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                if col == len(values) - 1:
                    item.setForeground(QColor(colour))
                    font = item.font()
                    font.setBold(c.verdict != "ok")
                    item.setFont(font)
                tip = c.reason if c.verdict == "not_measurable" and c.reason else v
                item.setToolTip(tip)
                self.setItem(r, col, item)
        self.blockSignals(False)

    def select_id(self, cid: str | None) -> None:
        """Select the row of characteristic ``cid`` (none: no selection), emitting ``selected``."""
        for r, c in enumerate(self.rows):
            if c.id == cid:
                self.selectRow(r)
                return
        self.clearSelection()

    def _selected(self) -> None:
        rows = self.selectionModel().selectedRows()
        if rows and rows[0].row() < len(self.rows):
            self.selected.emit(self.rows[rows[0].row()].id)


class TrendChart(QWidget):
    """The selected characteristic's values over the recorded parts: the tolerance band,
    the nominal, the individuals chart's control limits (mean ± 2.66 × the mean moving range,
    from three values), the values (NOK red and crossed, not measurable as grey ticks at the
    bottom) and the current part ringed."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.points: list[TrendPoint] = []
        self.title = ""
        self.unit = "mm"
        self.current = ""
        self.setMinimumHeight(60)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setAccessibleName(self.tr("characteristic trend"))

    def sizeHint(self) -> QSize:
        return QSize(400, 170)

    def set_trend(self, title: str, unit: str, points: list[TrendPoint], current: str) -> None:
        self.title, self.unit, self.points, self.current = title, unit, points, current
        self.update()

    def limits(self) -> tuple[float, float] | None:
        """The control limits (None with fewer than three measured values)."""
        values = [p.value for p in self.points if p.value is not None]
        if len(values) < 3:
            return None
        mean = sum(values) / len(values)
        mr = sum(abs(b - a) for a, b in zip(values, values[1:], strict=False)) / (len(values) - 1)
        return mean - I_CHART_K * mr, mean + I_CHART_K * mr

    def paintEvent(self, event: Any) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        p.fillRect(self.rect(), self.palette().base())
        fm = p.fontMetrics()
        p.setPen(self.palette().text().color())
        p.drawText(QRect(8, 2, self.width() - 16, fm.height() + 2), Qt.AlignmentFlag.AlignLeft, self.title)
        legend = self.tr("green: tolerance \u00b7 dashed: control limits \u00b7 ring: this part")
        if self.points and fm.horizontalAdvance(self.title + legend) + 40 < self.width():  # else left out
            p.setPen(QColor("#5f6368"))
            p.drawText(QRect(8, 2, self.width() - 16, fm.height() + 2), Qt.AlignmentFlag.AlignRight, legend)
        if not self.points:
            p.drawText(self.rect(), Qt.AlignmentFlag.AlignCenter,
                       self.tr("select a characteristic to see its trend") if not self.title else
                       self.tr("no recorded value yet"))
            p.end()
            return
        last = self.points[-1]
        lo, hi = last.nominal + last.lower, last.nominal + last.upper
        values = [q.value for q in self.points if q.value is not None]
        control = self.limits()
        span = [lo, hi, *values, *(control or ())]
        y0, y1 = min(span), max(span)
        pad = 0.08 * (y1 - y0 or 1e-3)
        y0, y1 = y0 - pad, y1 + pad
        k = _digits(self.unit)
        left = fm.horizontalAdvance(number(-abs(y1) - 1, k)) + 14
        plot = QRectF(left, fm.height() + 8, self.width() - left - 12, self.height() - fm.height() - 20)

        def y(v: float) -> float:
            return plot.bottom() - (v - y0) / (y1 - y0) * plot.height()

        def x(i: int) -> float:
            n = len(self.points)
            return plot.left() + (plot.width() * (i + 0.5) / n)

        p.fillRect(QRectF(plot.left(), y(hi), plot.width(), y(lo) - y(hi)), _BAND)
        for v, pen in ((lo, QPen(_IN, 1)), (hi, QPen(_IN, 1)), (last.nominal, QPen(QColor("#888888"), 1, Qt.PenStyle.DotLine))):
            p.setPen(pen)
            p.drawLine(QPointF(plot.left(), y(v)), QPointF(plot.right(), y(v)))
        if control is not None:
            p.setPen(QPen(QColor("#1557a0"), 1, Qt.PenStyle.DashLine))
            for v in control:
                p.drawLine(QPointF(plot.left(), y(v)), QPointF(plot.right(), y(v)))
        p.setPen(self.palette().text().color())
        for v in (lo, last.nominal, hi):
            p.drawText(QRectF(0, y(v) - fm.height() / 2, left - 6, fm.height()),
                       Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter, number(v, k))
        line = QPainterPath()
        started = False
        for i, q in enumerate(self.points):
            if q.value is None:
                started = False
                continue
            (line.lineTo if started else line.moveTo)(QPointF(x(i), y(q.value)))
            started = True
        p.setPen(QPen(QColor("#37474f"), 1.2))
        p.drawPath(line)
        for i, q in enumerate(self.points):
            cx = x(i)
            if q.value is None:  # not measurable: a grey tick on the axis
                p.setPen(QPen(QColor("#5f6368"), 2))
                p.drawLine(QPointF(cx, plot.bottom() - 8), QPointF(cx, plot.bottom()))
                continue
            cy = y(q.value)
            if q.verdict == "nok":
                p.setPen(QPen(_OUT, 2.5))
                p.drawLine(QPointF(cx - 5, cy - 5), QPointF(cx + 5, cy + 5))
                p.drawLine(QPointF(cx - 5, cy + 5), QPointF(cx + 5, cy - 5))
            else:
                p.setPen(Qt.PenStyle.NoPen)
                p.setBrush(_IN)
                p.drawEllipse(QPointF(cx, cy), 3.5, 3.5)
            if q.capture == self.current:
                p.setBrush(Qt.BrushStyle.NoBrush)
                p.setPen(QPen(self.palette().text().color(), 1.5))
                p.drawEllipse(QPointF(cx, cy), 8, 8)
                text = number(q.value, k)
                tx = cx - 12 - fm.horizontalAdvance(text) if cx > plot.center().x() else cx + 12
                ty = cy - 6 if cy - 6 - fm.ascent() > plot.top() else cy + 6 + fm.ascent()  # above, else below
                p.drawText(QPointF(tx, ty), text)
        p.end()


class CharacteristicsPanel(QWidget):
    """The table above the trend of the selected characteristic. The selection is kept by
    id from part to part (an operator watches one characteristic); without one, the worst of
    the part is selected (a NOK first, else the one using most of its tolerance)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.table = CharacteristicsTable()
        self.trend = TrendChart()
        self.note = QLabel()
        self.note.setWordWrap(True)
        # The table as high as its rows (it scrolls when the screen is short), the trend the rest.
        self.table.setMinimumHeight(self.table.horizontalHeader().sizeHint().height() + 2 * 34 + 4)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.setSpacing(4)
        lay.addWidget(self.table, 0)
        lay.addWidget(self.trend, 1)
        self.chosen: str | None = None  # chosen by the operator
        self.history: list[Mapping[str, Any]] = []
        self.view: ResultView | None = None
        self.table.selected.connect(self._choose)

    @property
    def rows(self) -> tuple[CharacteristicRow, ...]:
        return self.table.rows

    def counts(self) -> tuple[int, int]:
        """(characteristics, NOK ones) of the part shown."""
        return len(self.rows), sum(1 for c in self.rows if c.verdict == "nok")

    def show_result(self, view: ResultView) -> None:
        self.view = view
        self.table.show_rows(view.characteristics)
        self.table.setMaximumHeight(self.table.horizontalHeader().sizeHint().height()
                                    + 34 * max(len(view.characteristics), 2) + 4)
        ids = [c.id for c in view.characteristics]
        target = self.chosen if self.chosen in ids else _worst(view.characteristics)
        self.table.blockSignals(True)
        self.table.select_id(target)
        self.table.blockSignals(False)
        self._draw_trend(target)

    def show_history(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """The recorded parts (the history strip's rows, oldest first) the trend is drawn from."""
        self.history = list(rows)
        selected = self.table.selectionModel().selectedRows()
        self._draw_trend(self.rows[selected[0].row()].id if selected else None)

    def _choose(self, cid: str) -> None:
        self.chosen = cid
        self._draw_trend(cid)

    def _draw_trend(self, cid: str | None) -> None:
        row = next((c for c in self.rows if c.id == cid), None)
        if row is None:
            self.trend.set_trend("", "mm", [], "")
            return
        points = trend_of(self.history, row.id)
        title = self.tr("{id} {label}: last {n} parts").format(id=row.id, label=row.label, n=len(points))
        self.trend.set_trend(title, row.unit, points, self.view.capture if self.view else "")


def _worst(rows: tuple[CharacteristicRow, ...]) -> str | None:
    if not rows:
        return None
    nok = [c for c in rows if c.verdict == "nok"]
    pool = nok or [c for c in rows if c.use is not None] or list(rows)
    return max(pool, key=lambda c: -math.inf if c.use is None else c.use).id


class ResultTabs(QTabWidget):
    """The defects and the characteristics of the part, as two tabs whose titles count them
    (``Defects (2)``, ``Characteristics (4, 1 NOK)``); the characteristics' tab is hidden
    while the recipe measures none. A new part brings forward the tab that explains its
    verdict: the defects when it has some, else the characteristics when one is NOK."""

    def __init__(self, defects: DefectTable, characteristics: CharacteristicsPanel,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.defects, self.characteristics = defects, characteristics
        self.addTab(defects, "")
        self.addTab(characteristics, "")
        self.setTabVisible(1, False)
        self._titles(0, 0, 0)
        # As small as the defect table alone was (the tab bar and the trend's own minimum
        # would grow the window past a 1366 x 768 screen); the tables scroll instead.
        self.setMinimumHeight(110)

    def _titles(self, n_defects: int, n_chars: int, n_nok: int) -> None:
        self.setTabText(0, self.tr("Defects ({n})").format(n=n_defects))
        self.setTabText(1, self.tr("Characteristics ({n}, {nok} NOK)").format(n=n_chars, nok=n_nok)
                        if n_nok else self.tr("Characteristics ({n})").format(n=n_chars))
        self.tabBar().setTabTextColor(1, _OUT if n_nok else self.palette().windowText().color())

    def show_result(self, view: ResultView) -> None:
        self.defects.show_result(view)
        self.characteristics.show_result(view)
        n, nok = self.characteristics.counts()
        self._titles(len(view.defects), n, nok)
        self.setTabVisible(1, n > 0)
        if view.defects or not n:
            self.setCurrentIndex(0)
        elif nok:
            self.setCurrentIndex(1)
