"""The operator screen's verdict: the verdict banner and the defect table, and what every
widget of the screen shares (the verdicts' words, glyphs and colours; the keys of what
:func:`~inspector_frontends.gui.prepare.prepare_view` makes ahead). They draw a
:class:`~inspector_frontends.gui.viewmodel.ResultView`; none of them runs anything.

The other widgets: the camera strip and the large camera view
(:mod:`inspector_frontends.gui.cameras`), the history strip with the shift panel
(:mod:`inspector_frontends.gui.history_strip`). What takes time to draw is made off the GUI
thread by :func:`~inspector_frontends.gui.prepare.prepare_view`; the widgets then only swap
pictures, in place.
"""

from __future__ import annotations

from PySide6.QtCore import QCoreApplication, QLocale, Qt, Signal
from PySide6.QtWidgets import (
    QAbstractItemView,
    QFrame,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from inspector_frontends.gui.i18n import number
from inspector_frontends.gui.viewmodel import ResultView

__all__ = ["VERDICT_STYLE", "VerdictBanner", "RowTable", "DefectTable", "verdict_word", "QT_TRANSLATE_NOOP", "PICTURES", "HISTORY",
           "SHIFT"]


def QT_TRANSLATE_NOOP(context: str, text: str) -> str:
    """Mark ``text`` for translation in ``context`` (translated where it is shown); typed,
    unlike PySide6's own (which returns ``object``)."""
    return text


#: Keys of :attr:`ResultView.prepared` filled by :func:`~inspector_frontends.gui.prepare.prepare_view`.
PICTURES = "camera pictures"
HISTORY = "history"
SHIFT = "shift"

#: Verdict -> (word, icon glyph, background). The word and the glyph say it without colour.
#: The words are English sources: :func:`verdict_word` gives them in the GUI's language.
VERDICT_STYLE: dict[str, tuple[str, str, str]] = {
    "pass": (QT_TRANSLATE_NOOP("Verdict", "PASS"), "\u2714", "#1b7f3b"),
    "fail": (QT_TRANSLATE_NOOP("Verdict", "FAIL"), "\u2716", "#b3141b"),
    "error": (QT_TRANSLATE_NOOP("Verdict", "ERROR"), "\u26a0", "#b86e00"),
    "aborted": (QT_TRANSLATE_NOOP("Verdict", "ABORTED"), "\u25a0", "#5f6368"),
    "busy": (QT_TRANSLATE_NOOP("Verdict", "INSPECTING"), "\u25f7", "#1557a0"),
    "ready": (QT_TRANSLATE_NOOP("Verdict", "READY"), "\u25cb", "#37474f"),
    "invalid": (QT_TRANSLATE_NOOP("Verdict", "RECIPE INVALID"), "\u26a0", "#6d4c41"),
}


def verdict_word(state: str) -> str:
    """The word of a verdict (or state) in the GUI's language (``FAIL``, ``NIO``, ``RECHAZADA`` ...)."""
    return QCoreApplication.translate("Verdict", VERDICT_STYLE.get(state, VERDICT_STYLE["error"])[0])


class VerdictBanner(QFrame):
    """PASS / FAIL / ERROR / ABORTED in words and an icon, the part, the cycle time and,
    for a FAIL, the reason in words (worst region, deviation, limit)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("verdictBanner")
        self.icon = QLabel()
        self.word = QLabel()
        self.detail = QLabel()
        self.reason = QLabel()
        self.reason.setWordWrap(True)
        # Wrapped, not wider than the screen: a long part id or path must not widen the window.
        self.detail.setWordWrap(True)
        # Sizes in the style sheet: a window's style sheet would override set fonts.
        self.icon.setObjectName("verdictIcon")
        self.word.setObjectName("verdictWord")
        self.reason.setObjectName("verdictReason")
        top = QHBoxLayout()
        top.addWidget(self.icon)
        top.addWidget(self.word)
        top.addStretch(1)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(16, 8, 16, 8)
        lay.addLayout(top)
        lay.addWidget(self.detail)
        lay.addWidget(self.reason)
        self.state = ""
        self.compact = False
        self._lay = lay
        self.set_state("ready", self.tr("Press INSPECT (Space) to inspect the next part."))

    def set_compact(self, compact: bool) -> None:
        """Smaller type for small screens (1366x768): the banner must leave room for the part."""
        if compact != self.compact:
            self.compact = compact
            self._lay.setContentsMargins(12, 2 if compact else 8, 12, 2 if compact else 8)
            self._lay.setSpacing(0 if compact else 6)
            self._style()

    def set_state(self, state: str, detail: str = "", reason: str = "") -> None:
        _, glyph, bg = VERDICT_STYLE[state]
        word = verdict_word(state)
        self.state = state
        self.icon.setText(glyph)
        self.word.setText(word)
        self.detail.setText(detail)
        self.reason.setText(reason)
        self.reason.setVisible(bool(reason))
        self._bg = bg
        self._style()
        self.setAccessibleName(self.tr("verdict {word}").format(word=word))

    def _style(self) -> None:
        big, text, reason = (28, 13, 14) if self.compact else (40, 15, 17)
        self.setStyleSheet(f"#verdictBanner {{ background: {self._bg}; border-radius: 6px; }}"
                           f" QLabel {{ color: white; font-size: {text}pt; }}"
                           f" #verdictWord, #verdictIcon {{ font-size: {big}pt; font-weight: bold; }}"
                           f" #verdictReason {{ font-size: {reason}pt; font-weight: bold; }}")

    def show_result(self, view: ResultView) -> None:
        bits = [self.tr("part {id}").format(id=view.part_id) if view.part_id else None,
                self.tr("capture {name}").format(name=view.capture),
                self.tr("cycle {s} s").format(s=number(view.cycle_s, 2)) if view.cycle_s is not None else None]
        if view.verdict in ("pass", "fail") and view.stats.get("deviation_mm"):
            d = view.stats["deviation_mm"]
            bits.append(self.tr("deviation {lo} to {hi} mm (limits {lower} / {upper})").format(
                lo=number(d["min"], 3, sign=True), hi=number(d["max"], 3, sign=True),
                lower=number(view.tolerance[0], 2, sign=True), upper=number(view.tolerance[1], 2, sign=True)))
        self.set_state(view.verdict if view.verdict in VERDICT_STYLE else "error",
                       "   \u00b7   ".join(b for b in bits if b), view.reason)


class RowTable(QTableWidget):
    """An operator's read-only table: its class's ``HEADERS`` (translated in the class's
    context), whole rows selected one at a time, touch-size rows, columns sized to contents."""

    HEADERS: tuple[str, ...] = ()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(0, len(self.HEADERS), parent)
        self.setHorizontalHeaderLabels([QCoreApplication.translate(type(self).__name__, h) for h in self.HEADERS])
        self.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.verticalHeader().setVisible(False)
        self.verticalHeader().setDefaultSectionSize(34)  # touch-size rows
        self.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)


class DefectTable(RowTable):
    """One row per defect cluster; selecting a row emits ``defect_selected(row index)``."""

    defect_selected = Signal(int)
    HEADERS = ("#", QT_TRANSLATE_NOOP("DefectTable", "kind"), QT_TRANSLATE_NOOP("DefectTable", "region"),
               QT_TRANSLATE_NOOP("DefectTable", "points"), QT_TRANSLATE_NOOP("DefectTable", "worst mm"),
               QT_TRANSLATE_NOOP("DefectTable", "extent mm"), QT_TRANSLATE_NOOP("DefectTable", "cameras"))

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.horizontalHeader().setStretchLastSection(True)
        self.setAccessibleName(self.tr("defect table"))
        self.itemSelectionChanged.connect(self._selected)

    def show_result(self, view: ResultView) -> None:
        self.blockSignals(True)
        self.clearSelection()
        self.setRowCount(len(view.defects))
        for r, d in enumerate(view.defects):
            kind = self.tr("missing material") if d.kind == "missing" else self.tr("excess material")
            values = (str(d.number), kind, d.region, QLocale().toString(d.n_points), number(d.worst_mm, 3, sign=True),
                      " \u00d7 ".join(number(e, 1) for e in d.extent), ", ".join(d.cameras) or "-")
            for c, v in enumerate(values):
                item = QTableWidgetItem(v)
                if c in (0, 3, 4):
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                item.setToolTip(v)
                self.setItem(r, c, item)
        self.setCurrentCell(-1, -1)  # so Down (keyboard) selects the first, worst, defect
        self.blockSignals(False)

    def _selected(self) -> None:
        rows = self.selectionModel().selectedRows()
        if rows:
            self.defect_selected.emit(rows[0].row())
