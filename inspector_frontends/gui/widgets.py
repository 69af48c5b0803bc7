"""The operator screen's 2D widgets: verdict banner, defect table, camera strip (and the
large camera view), history strip. They draw a :class:`~inspector_frontends.gui.viewmodel.ResultView`
or history rows; none of them runs anything.

What takes time to draw is made off the GUI thread by :func:`prepare_view` (camera
thumbnails with their contours as ``QImage``, the history rows and the trend chart as an
image: ``QImage``, ``QPainter`` on an image and matplotlib's Agg canvas may be used in any
thread); the widgets then only swap pictures, in place.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import dataclasses
import threading

import numpy as np
from PySide6.QtCore import (
    QCoreApplication,
    QDate,
    QEvent,
    QLocale,
    QPointF,
    QRect,
    QRectF,
    QSize,
    Qt,
    QTime,
    QTimer,
    Signal,
)
from PySide6.QtGui import QColor, QFont, QHelpEvent, QImage, QKeySequence, QPainter, QPainterPath, QPen, QPixmap, QShortcut
from PySide6.QtWidgets import (
    QAbstractItemView,
    QDialog,
    QFrame,
    QGraphicsPathItem,
    QGraphicsPixmapItem,
    QGraphicsScene,
    QGraphicsView,
    QGridLayout,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QSizePolicy,
    QTableWidget,
    QTableWidgetItem,
    QToolTip,
    QVBoxLayout,
    QWidget,
)

from inspector_frontends.gui.i18n import number, percent
from inspector_frontends.gui.viewmodel import CameraThumb, ResultView

__all__ = ["VERDICT_STYLE", "VerdictBanner", "DefectTable", "CameraStrip", "CameraDialog", "HistoryStrip", "ShiftPanel",
           "tile_image", "history_chart", "prepare_view", "verdict_word", "PICTURES", "HISTORY", "SHIFT"]



def QT_TRANSLATE_NOOP(context: str, text: str) -> str:
    """Mark ``text`` for translation in ``context`` (translated where it is shown); typed,
    unlike PySide6's own (which returns ``object``)."""
    return text


#: Keys of :attr:`ResultView.prepared` filled by :func:`prepare_view`.
PICTURES = "camera pictures"
HISTORY = "history"
SHIFT = "shift"
#: History rows the strip reads (chips show the last ``HistoryStrip.CHIPS`` of them).
HISTORY_ROWS = 50
#: matplotlib's figures are not meant to be drawn by two threads at once.
_MPL_LOCK = threading.Lock()
#: The figure :func:`history_chart` draws on (under the lock), and its size.
_CHART: dict[str, Any] = {}

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


def _qimage(gray: np.ndarray) -> QImage:
    """A QImage sharing nothing with ``gray`` ((h, w) uint8): Qt keeps its own copy."""
    a = np.ascontiguousarray(gray, np.uint8)
    h, w = a.shape
    return QImage(a.data, w, h, w, QImage.Format.Format_Grayscale8).copy()


def _points_path(uv: np.ndarray, scale: float, gap_px: float = 2.5) -> QPainterPath:
    """Contour points as a path: consecutive points closer than ``gap_px`` are joined."""
    path = QPainterPath()
    if not len(uv):
        return path
    # Pixel (0, 0) is the centre of the top-left pixel (CONTRACT); in a QImage it spans [0, 1].
    p = (np.asarray(uv, float) + 0.5) * scale
    jump = np.r_[True, np.hypot(*(np.diff(np.asarray(uv, float), axis=0).T)) > gap_px]
    # Python floats: PySide6 mis-counts references of numpy scalars passed to Qt (measured:
    # a 'deallocating None' abort when the interpreter exits).
    for (x, y), new in zip(p.tolist(), jump.tolist(), strict=True):
        if new:
            path.moveTo(x, y)
        else:
            path.lineTo(x, y)
    return path


def tile_image(thumb: CameraThumb) -> QImage:
    """The thumbnail of ``thumb`` with its sub-pixel contour drawn over it (RGB32); safe in
    any thread."""
    img = _qimage(thumb.image).convertToFormat(QImage.Format.Format_RGB32)
    painter = QPainter(img)
    painter.setRenderHint(QPainter.RenderHint.Antialiasing)
    painter.setPen(QPen(QColor("#00e676"), 1.2))
    painter.drawPath(_points_path(thumb.contour - thumb.origin, thumb.scale))
    painter.end()
    return img


def history_chart(rows: list[dict[str, Any]], size: tuple[int, int], ratio: float = 1.0) -> QImage:
    """The trend chart of ``rows`` (``inspector history --plot``'s drawing, same data and
    limits) as an image of ``size`` (logical pixels) at device-pixel ``ratio``; safe in any
    thread (drawn on one module-level figure, under a lock)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from inspector_plugins.history import draw_history

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
    from inspector_plugins.history import tally

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
    from inspector.errors import InputError
    from inspector.history_store import read_history

    if outdir is None:
        return []
    try:
        return read_history(outdir, last=HISTORY_ROWS)
    except InputError:
        return []


def prepare_view(view: ResultView, outdir: Path | None, chart: tuple[tuple[int, int], float] | None,
                 shifts: Any = None) -> ResultView:
    """``view`` with what its drawing needs made ahead, in the calling (worker) thread: the
    camera pictures (:data:`PICTURES`) and, with ``chart`` (size and device-pixel ratio of
    the history chart), the history rows of ``outdir`` and their chart (:data:`HISTORY`)
    and, with ``shifts`` (:class:`~inspector.shift.ShiftSettings`), the current shift's
    counters (:data:`SHIFT`)."""
    prepared = dict(view.prepared)
    prepared[PICTURES] = {t.name: tile_image(t) for t in view.cameras}
    if chart is not None:
        rows = read_rows(outdir)
        prepared[HISTORY] = (rows, history_chart(rows, *chart))
        if shifts is not None:
            prepared[SHIFT] = read_shift(outdir, shifts)
    return dataclasses.replace(view, prepared=prepared)


def read_shift(outdir: Path | None, settings: Any) -> Any:
    """The counters of the current shift in ``outdir``'s history (:mod:`inspector.shift`;
    None: no history yet, or it cannot be read); safe in any thread."""
    from inspector.errors import InputError
    from inspector.shift import shift_counters

    if outdir is None:
        return None
    try:
        return shift_counters(outdir, settings)[-1]
    except InputError:
        return None


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


class DefectTable(QTableWidget):
    """One row per defect cluster; selecting a row emits ``defect_selected(row index)``."""

    defect_selected = Signal(int)
    HEADERS = ("#", QT_TRANSLATE_NOOP("DefectTable", "kind"), QT_TRANSLATE_NOOP("DefectTable", "region"),
               QT_TRANSLATE_NOOP("DefectTable", "points"), QT_TRANSLATE_NOOP("DefectTable", "worst mm"),
               QT_TRANSLATE_NOOP("DefectTable", "extent mm"), QT_TRANSLATE_NOOP("DefectTable", "cameras"))

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(0, len(self.HEADERS), parent)
        self.setHorizontalHeaderLabels([self.tr(h) for h in self.HEADERS])
        self.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.verticalHeader().setVisible(False)
        self.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.horizontalHeader().setStretchLastSection(True)
        self.verticalHeader().setDefaultSectionSize(34)  # touch-size rows
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


class CameraTile(QLabel):
    """A camera thumbnail with its sub-pixel contour; a thick amber frame and a warning sign
    when flagged, a blue frame when it produced the selected defect."""

    opened = Signal(str)

    def __init__(self, thumb: CameraThumb, parent: QWidget | None = None, picture: QImage | None = None) -> None:
        super().__init__(parent)
        self.highlighted = False
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.setMinimumSize(56, 56)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.set_thumb(thumb, picture)

    def set_thumb(self, thumb: CameraThumb, picture: QImage | None = None) -> None:
        """Show ``thumb`` (``picture``: its :func:`tile_image`, made ahead; else made here)."""
        self.thumb = thumb
        self.highlighted = False
        tip = thumb.name + ("\n" + "\n".join(thumb.flags) if thumb.flags else "")
        self.setToolTip(tip + "\n" + self.tr("(double-click or Enter: open large)"))
        self.setAccessibleName((self.tr("camera {name} flagged") if thumb.flags else self.tr("camera {name}")).format(
            name=thumb.name))
        self._pixmap = QPixmap.fromImage(picture if picture is not None else tile_image(thumb))
        self._scaled: QPixmap | None = None  # the pixmap at the tile's size, made on the first paint
        self.update()

    def set_highlighted(self, on: bool) -> None:
        if on != self.highlighted:
            self.highlighted = on
            self.update()

    def resizeEvent(self, event: Any) -> None:
        self._scaled = None
        super().resizeEvent(event)

    def paintEvent(self, event: Any) -> None:
        p = QPainter(self)
        r = self.rect()
        if self._scaled is None:
            self._scaled = self._pixmap.scaled(r.size() - QSize(6, 6), Qt.AspectRatioMode.KeepAspectRatio,
                                               Qt.TransformationMode.SmoothTransformation)
        scaled = self._scaled
        x = (r.width() - scaled.width()) // 2
        y = (r.height() - scaled.height()) // 2
        p.drawPixmap(x, y, scaled)
        frame = "#1e88e5" if self.highlighted else ("#ffab00" if self.thumb.flags else ("#ffffff" if self.hasFocus() else "#455a64"))
        width = 5 if (self.highlighted or self.thumb.flags) else 2
        p.setPen(QPen(QColor(frame), width))
        p.drawRect(r.adjusted(width // 2, width // 2, -(width + 1) // 2, -(width + 1) // 2))
        p.setPen(QColor("white"))
        f = p.font()
        f.setPointSize(10)
        f.setBold(True)
        p.setFont(f)
        label = self.thumb.name + ("  \u26a0" if self.thumb.flags else "")
        p.fillRect(QRectF(6, 6, p.fontMetrics().horizontalAdvance(label) + 8, p.fontMetrics().height() + 2), QColor(0, 0, 0, 150))
        p.drawText(QPointF(10, 6 + p.fontMetrics().ascent()), label)
        p.end()

    def mouseDoubleClickEvent(self, event: Any) -> None:
        self.opened.emit(self.thumb.name)

    def keyPressEvent(self, event: Any) -> None:
        if event.key() in (Qt.Key.Key_Return, Qt.Key.Key_Enter):
            self.opened.emit(self.thumb.name)
        else:
            super().keyPressEvent(event)


class CameraStrip(QWidget):
    """The rig's cameras in a grid; ``opened(name)`` on a double-click or Enter. The same
    cameras as the last result: the tiles are kept and their pictures swapped."""

    opened = Signal(str)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.grid = QGridLayout(self)
        self.grid.setSpacing(4)
        self.grid.setContentsMargins(0, 0, 0, 0)
        self.tiles: dict[str, CameraTile] = {}
        self.placeholder = QLabel(self.tr("Camera images appear here after an inspection."))
        self.placeholder.setWordWrap(True)
        self.placeholder.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.grid.addWidget(self.placeholder, 0, 0)

    def show_result(self, view: ResultView) -> None:
        pictures = view.prepared.get(PICTURES) or {}
        names = [t.name for t in view.cameras]
        if names != list(self.tiles):
            for tile in self.tiles.values():
                self.grid.removeWidget(tile)
                tile.deleteLater()
            self.tiles = {}
            cols = max(1, int(np.ceil(np.sqrt(len(view.cameras)))))
            for k, thumb in enumerate(view.cameras):
                tile = CameraTile(thumb, self, pictures.get(thumb.name))
                tile.opened.connect(self.opened)
                self.grid.addWidget(tile, 1 + k // cols, k % cols)
                self.tiles[thumb.name] = tile
        else:
            for thumb in view.cameras:
                self.tiles[thumb.name].set_thumb(thumb, pictures.get(thumb.name))
        self.placeholder.setVisible(not view.cameras)
        if not view.cameras:
            self.placeholder.setText(self.tr("No camera images: this result was opened from its folder.")
                                     if view.folder is not None and view.verdict != "aborted" else
                                     self.tr("Camera images appear here after an inspection."))

    def highlight(self, names: tuple[str, ...] | list[str]) -> None:
        for n, tile in self.tiles.items():
            tile.set_highlighted(n in names)


class _ZoomView(QGraphicsView):
    def wheelEvent(self, event: Any) -> None:
        f = 1.25 if event.angleDelta().y() > 0 else 0.8
        self.scale(f, f)


class CameraDialog(QDialog):
    """One camera large: the full image, its sub-pixel contour, zoom with the wheel or + / -
    and 0 to fit; its flags in words."""

    def __init__(self, thumb: CameraThumb, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle(self.tr("Camera {name}").format(name=thumb.name))
        self.resize(900, 860)
        image = thumb.full if thumb.full is not None else thumb.image
        scale = 1.0 if thumb.full is not None else thumb.scale
        origin = 0.0 if thumb.full is not None else thumb.origin
        scene = QGraphicsScene(self)
        scene.addItem(QGraphicsPixmapItem(QPixmap.fromImage(_qimage(image))))
        path = _points_path(thumb.contour - origin, scale)
        item = QGraphicsPathItem(path)
        pen = QPen(QColor("#00e676"), 0)  # cosmetic: one screen pixel at any zoom
        item.setPen(pen)
        scene.addItem(item)
        self.view = _ZoomView(scene)
        self.view.setRenderHint(QPainter.RenderHint.Antialiasing)
        self.view.setDragMode(QGraphicsView.DragMode.ScrollHandDrag)
        info = QLabel("\n".join(thumb.flags) if thumb.flags else self.tr("silhouette consistent with the other cameras"))
        info.setWordWrap(True)
        info.setStyleSheet("font-size: 14pt;" + (" color: #b86e00; font-weight: bold;" if thumb.flags else ""))
        fit = QPushButton(self.tr("Fit (0)"))
        fit.setMinimumHeight(44)
        fit.clicked.connect(self.fit)
        close = QPushButton(self.tr("Close (Esc)"))
        close.setMinimumHeight(44)
        close.clicked.connect(self.accept)
        row = QHBoxLayout()
        row.addWidget(info, 1)
        row.addWidget(fit)
        row.addWidget(close)
        lay = QVBoxLayout(self)
        lay.addWidget(self.view, 1)
        lay.addLayout(row)
        for key, f in (("+", 1.25), ("=", 1.25), ("-", 0.8)):
            QShortcut(QKeySequence(key), self).activated.connect(lambda f=f: self.view.scale(f, f))
        QShortcut(QKeySequence("0"), self).activated.connect(self.fit)

    def fit(self) -> None:
        self.view.fitInView(self.view.scene().itemsBoundingRect(), Qt.AspectRatioMode.KeepAspectRatio)

    def showEvent(self, event: Any) -> None:
        super().showEvent(event)
        self.fit()


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

    The chart is a picture made by :func:`history_chart`: by :func:`prepare_view` in the
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
        """Size and device-pixel ratio of the chart (for :func:`prepare_view`)."""
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
        from inspector_plugins.history import tally

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
            self.canvas._settle.start()  # the strip was resized meanwhile: drawn again at its size

    def _redraw(self) -> None:
        self.canvas.set_image(history_chart(self.rows, *self.chart_size()))
