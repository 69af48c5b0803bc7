"""The operator window on its screen (:class:`ScreenWindow`, the base of
:class:`~inspector_frontends.gui.window.MainWindow`).

The window fits the screen it opens on (:meth:`ScreenWindow.fit_screen`: the available
geometry in logical pixels, never larger; a portrait screen gets the portrait layout). In
kiosk mode it is full screen without decorations and comes back to the front after a dialog
(:class:`KioskGuard`: without a window manager nothing else would bring it back).
"""

from __future__ import annotations

from typing import Any

from PySide6.QtCore import QEvent, QObject, QRect, QSize, QTimer
from PySide6.QtGui import QGuiApplication, QScreen
from PySide6.QtWidgets import QApplication, QDialog, QMainWindow

__all__ = ["ScreenWindow", "KioskGuard"]


class ScreenWindow(QMainWindow):
    """A main window fitted to its screen: its available geometry (the whole screen and full
    screen in kiosk mode), the portrait layout on a screen higher than wide
    (:meth:`set_portrait`, which a subclass extends to arrange its panels)."""

    #: The cell's kiosk: full screen without decorations (set by the subclass).
    kiosk = False
    #: Whether the portrait layout is on.
    portrait = False
    #: Set once the window is closing: nothing is brought to the front any more.
    _closing = False
    #: The screen area (x, y, width, height) the window was last fitted to (None: not yet).
    _fitted_for: tuple[int, int, int, int] | None = None

    def set_portrait(self, portrait: bool) -> None:
        """The portrait layout (a screen higher than wide) or the landscape one."""
        self.portrait = portrait

    def fit_screen(self, screen: QScreen | None = None) -> QRect:
        """Size and place the window for ``screen`` (default: the one it is on, else the
        primary): its available geometry (the desktop's panels left out; logical pixels, so
        HiDPI scaling is honoured), never larger; the whole screen in kiosk mode. A portrait
        screen gets the portrait layout (:meth:`set_portrait`). Returns the geometry set."""
        screen = screen or self.screen() or QGuiApplication.primaryScreen()
        area = screen.geometry() if self.kiosk else screen.availableGeometry()
        self.set_portrait(area.height() > area.width())
        if self.kiosk:
            self.setGeometry(area)
            return area
        # A window manager adds its frame around the client area: known once shown (0 before,
        # and without a window manager); showEvent fits again with it.
        frame = self.frameGeometry().size() - self.geometry().size() if self.isVisible() else QSize(0, 0)
        size = area.size() - frame
        self.resize(size)
        self.move(area.topLeft())
        self._fitted_for = (area.x(), area.y(), area.width(), area.height())
        return QRect(area.topLeft(), size)

    def show_on_screen(self, screen: QScreen | None = None) -> None:
        """Show the window fitted to ``screen`` (full screen in kiosk mode)."""
        if screen is not None and self.windowHandle() is None:
            self.create()
        if screen is not None and self.windowHandle() is not None:
            self.windowHandle().setScreen(screen)
        self.fit_screen(screen)
        if self.kiosk:
            self.showFullScreen()
        else:
            self.show()

    def showEvent(self, event: Any) -> None:
        super().showEvent(event)
        if not self.kiosk and self._fitted_for is not None:
            QTimer.singleShot(0, self._refit_frame)

    def _refit_frame(self) -> None:
        """Once shown, a window manager's frame is known: the frame, not only the client
        area, must fit the available area."""
        screen = self.screen()
        if screen is None or self.isFullScreen() or self.isMaximized():
            return
        area = screen.availableGeometry()
        if not area.contains(self.frameGeometry()):
            self.fit_screen(screen)

    def to_front(self) -> None:
        """The window back in front and active (kiosk: after a dialog closed)."""
        if not self.isVisible() or self._closing:
            return
        if self.kiosk and not self.isFullScreen():
            self.showFullScreen()
        self.raise_()
        self.activateWindow()


class KioskGuard(QObject):
    """Kiosk: a dialog of the window that closes brings the window back to the front (without
    a window manager nothing else would), and so does the window losing the focus to nothing."""

    def __init__(self, window: ScreenWindow) -> None:
        super().__init__(window)
        self.window = window

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:
        kind = event.type()
        if kind == QEvent.Type.Hide and isinstance(obj, QDialog):
            QTimer.singleShot(0, self.window.to_front)
        elif kind == QEvent.Type.WindowDeactivate and obj is self.window:
            QTimer.singleShot(50, self._refocus)
        return False

    def _refocus(self) -> None:
        if QApplication.activeWindow() is None and QApplication.activeModalWidget() is None:
            self.window.to_front()
