"""The operator screen's cameras: the camera strip (a thumbnail per camera with its sub-pixel
contour, flagged cameras framed) and the large view of one camera (:class:`CameraDialog`).

A tile's picture is made off the GUI thread (:func:`tile_image`: ``QImage`` and ``QPainter``
on an image may be used in any thread, see :func:`~inspector_frontends.gui.prepare.prepare_view`);
the strip then only swaps pictures, in place.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from PySide6.QtCore import QPointF, QRectF, QSize, Qt, Signal
from PySide6.QtGui import QColor, QImage, QKeySequence, QPainter, QPainterPath, QPen, QPixmap, QShortcut
from PySide6.QtWidgets import (
    QDialog,
    QGraphicsPathItem,
    QGraphicsPixmapItem,
    QGraphicsScene,
    QGraphicsView,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSizePolicy,
    QVBoxLayout,
    QWidget,
)

from inspector_frontends.gui.viewmodel import CameraThumb, ResultView
from inspector_frontends.gui.widgets import PICTURES

__all__ = ["CameraTile", "CameraStrip", "CameraDialog", "tile_image"]


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
