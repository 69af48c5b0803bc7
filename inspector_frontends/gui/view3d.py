"""The 3D view: BCPS points coloured by signed deviation on a scale fixed to the tolerance
limits, the aligned reference translucent, defects marked and numbered, and the cameras
that produced a selected defect.

The actors are made once and updated in place (their data objects' arrays replaced): pyvista
keeps unnamed actors and their textures alive (a leak per inspection), and re-adding costs
time on the GUI thread. The plotter is closed explicitly. Called on the GUI thread only.

Software OpenGL (Mesa llvmpipe) draws every frame on the CPU: no multisampling (4x MSAA
costs more than the points themselves there), flat square points (sphere impostors cost
two to three times as much), translucency without order-independent transparency, one render
per change, the widget's paint after a render only shows that frame instead of rendering it
again (:class:`_Interactor`), and the OpenGL widget in a native window of its own, so that
the rest of the window repaints without OpenGL.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import numpy as np
import pyvista as pv
from PySide6.QtCore import Qt, QTimer
from PySide6.QtWidgets import QWidget
from pyvistaqt import QtInteractor

from inspector_frontends.gui.i18n import number
from inspector_frontends.gui.viewmodel import SCALED, SPAN, DefectRow, ResultView, normalised
from inspector_frontends.gui.widgets import verdict_word

__all__ = ["DeviationView", "deviation_colormap", "normalised", "SPAN"]

BAR = "deviation"  # the colour bar's title in English (DeviationView._bar: in the GUI's language)
#: Points are drawn as flat squares of this many pixels.
POINT_PX = 4
#: Names of the actors a defect selection adds (removed when a new result is shown).
_SELECTION = ("selected", "camera-rays", "camera-labels-points", "camera-labels-labels")


def deviation_colormap(n: int = 240):
    """Diverging, neutral grey inside the tolerance band: blues for missing material, from
    light at the limit to dark at SPAN limits, reds for excess."""
    from matplotlib.colors import LinearSegmentedColormap, ListedColormap

    k = n // 6  # entries per tolerance width: [-3,-1] 2k, [-1,1] 2k, [1,3] 2k
    blues = LinearSegmentedColormap.from_list("m", ["#08306b", "#2171b5", "#6baed6"])(np.linspace(0, 1, 2 * k))
    reds = LinearSegmentedColormap.from_list("e", ["#fd8d3c", "#e31a1c", "#67000d"])(np.linspace(0, 1, 2 * k))
    grey = np.tile(np.array([0.835, 0.847, 0.863, 1.0]), (2 * k, 1))
    return ListedColormap(np.vstack([blues, grey, reds]), name="inspector-deviation")


class _Interactor(QtInteractor):
    """pyvistaqt's ``QtInteractor`` that draws each frame once, in two event-loop turns.

    Every ``render()`` ends with VTK's frame event, on which pyvistaqt schedules a paint of
    the widget; that paint renders the whole scene again before showing it (pyvistaqt does
    so in case the scene changed without a render). Here the paint that follows a render
    only shows the frame just rendered: the scene is not rendered twice (with software
    OpenGL a render of 20k points costs 15-20 ms, of 100k 30-45 ms, on a quiet machine;
    several times that on a loaded one). A paint for any
    other reason (expose, resize) still renders. And the paint is asked for one event-loop
    turn after the render, not at once: the render and the showing of its frame (a copy and
    a buffer swap, 6-25 ms) then block the GUI thread one after the other, not together.
    """

    _fresh = False  # a frame was rendered since the last paint: show it as it is
    _paint_asked = False

    def _cb_frame(self, obj, evt) -> None:
        rw = self._RenderWindow
        if rw is None or self._in_paint:
            return
        if rw.GetDoubleBuffer() and not rw.GetSwapBuffers():  # a back-buffer render, not to be shown
            return
        self._fresh = True
        if not self._paint_asked:
            self._paint_asked = True
            QTimer.singleShot(0, self, self._show_frame)

    @property
    def frame_pending(self) -> bool:
        """Whether a frame was rendered that no paint has shown yet."""
        return self._fresh

    def _show_frame(self) -> None:
        self._paint_asked = False
        if self._fresh:  # not shown meanwhile by a paint for another reason
            self.update()

    def resizeGL(self, w: int, h: int) -> None:
        self._fresh = False
        super().resizeGL(w, h)

    def paintGL(self) -> None:
        if not self._fresh or self._in_paint:
            super().paintGL()
            return
        self._fresh = False
        self._in_paint = True  # pyvistaqt's paintGL then skips its render and only blits
        try:
            super().paintGL()
        finally:
            self._in_paint = False


class DeviationView(QWidget):
    """A pyvistaqt ``QtInteractor`` that shows one :class:`ResultView` at a time."""

    def __init__(self, parent: QWidget | None = None) -> None:
        from PySide6.QtWidgets import QVBoxLayout

        super().__init__(parent)
        self._bar = self.tr("deviation")  # the colour bar's title, also pyvista's key of the bar
        # No periodic re-render (pyvistaqt renders 5 times a second by default: 80 % of a core
        # with software OpenGL on an idle screen, measured); the view renders after each change
        # and on interaction. No multisampling (see the module's doc).
        self.plotter = _Interactor(self, auto_update=False, multi_samples=0)
        # This class calls the renderers' and the renderer's own set_background, add_axes and
        # remove_actor, not the plotter's forwarders to them: those are made with
        # functools.wraps, which mypy types as unbound functions (``self`` missing). The same
        # calls: the plotter has one renderer.
        self.plotter.renderers.set_background("#1f2428", top="#3b4450")
        # Translucency by plain blending: VTK's order-independent transparency costs extra
        # full-window passes (7-25 ms a render with software OpenGL, measured), and the
        # translucent parts (a convex reference, wireframe markers) look the same without.
        self.plotter.renderer.SetUseOIT(False)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.plotter.interactor)
        # The OpenGL widget in a native window of its own (not its ancestors): a window that
        # holds an OpenGL widget otherwise composes every repaint of any of its widgets (a
        # label's new text) with OpenGL, which with software OpenGL costs 25-60 ms a time for
        # the whole window (measured: 0.3 ms like this). On a native parent instead of the
        # widget itself, the view stays black ("QOpenGLWidget: No fbo").
        self.plotter.setAttribute(Qt.WidgetAttribute.WA_DontCreateNativeAncestors)
        self.plotter.setAttribute(Qt.WidgetAttribute.WA_NativeWindow)
        self.view: ResultView | None = None
        self._cmap = deviation_colormap()
        self._caption = self.plotter.add_text("", name="caption", font_size=10, position="upper_left", color="white")
        self.plotter.renderer.add_axes()
        # Made on first use, then updated in place.
        self._cloud: pv.PolyData | None = None
        self._cloud_actor: pv.Actor | None = None
        self._bar_tolerance: tuple[float, float] | None = None
        self._ref: pv.PolyData | None = None
        self._ref_actor: pv.Actor | None = None
        self._ref_faces: np.ndarray | None = None
        self._marks: pv.PolyData | None = None
        self._marks_actor: pv.Actor | None = None
        self._labels: pv.PolyData | None = None

    # -- showing ------------------------------------------------------------------------------
    def show_result(self, view: ResultView, *, render: bool = True) -> None:
        """Show ``view``: the scene updated, then one render (``render=False``: the caller
        renders later, see :meth:`render`)."""
        self.update_scene(view)
        if render:
            self.render()

    def update_scene(self, view: ResultView) -> None:
        """Put ``view`` in the scene without rendering it."""
        p = self.plotter
        self.view = view
        # Every change below could render on its own (pyvista's scalar bar does, whatever
        # render=False says): rendering is held until render().
        p.suppress_rendering = True
        try:
            for name in _SELECTION:
                p.renderer.remove_actor(name, reset_camera=False, render=False)
            self._set_reference(view.reference)
            self._set_cloud(view)
            self._set_defects(view.defects)
            self._caption.set_text("upper_left", self.tr("{verdict}  {capture}  ({n} points)").format(
                verdict=verdict_word(view.verdict), capture=view.capture, n=len(view.points)))
            if len(view.points):
                self.reset_camera(render=False)
        finally:
            p.suppress_rendering = False

    # Replaces QWidget.render(target, ...) (drawing the widget into a paint device), which this
    # view never uses: its callers (the window's drawing steps, the bench) mean the 3D scene.
    def render(self) -> None:  # type: ignore[override]
        """One render of the scene (the widget's paint then shows it without rendering again)."""
        self.plotter.render()

    @property
    def frame_pending(self) -> bool:
        """Whether a frame was rendered that the widget has not shown yet (its paint comes
        in a later event-loop turn)."""
        return bool(self.plotter.frame_pending) and self.plotter.isVisible()

    def _set_reference(self, reference: tuple[np.ndarray, np.ndarray] | None) -> None:
        if reference is None:
            if self._ref_actor is not None:
                self._ref_actor.SetVisibility(False)
            return
        v, f = reference
        v = np.asarray(v, float)
        if self._ref is not None and self._ref_faces is not None and (
                f is self._ref_faces or (f.shape == self._ref_faces.shape and np.array_equal(f, self._ref_faces))):
            self._ref.points = v  # the same mesh placed anew: only its vertices move
        else:
            faces = np.hstack([np.full((len(f), 1), 3), f]).astype(np.int64).ravel()
            mesh = pv.PolyData(v, faces)
            if self._ref is None:
                self._ref = mesh
                self._ref_actor = self.plotter.add_mesh(mesh, name="reference", color="#7fa7c9", opacity=0.12,
                                                        show_edges=False, pickable=False, reset_camera=False,
                                                        render=False)
            else:
                self._ref.copy_from(mesh, deep=False)
        self._ref_faces = f
        assert self._ref_actor is not None  # made with self._ref
        self._ref_actor.SetVisibility(True)

    def _set_cloud(self, view: ResultView) -> None:
        p = self.plotter
        if not len(view.points):
            if self._cloud_actor is not None:
                self._cloud_actor.SetVisibility(False)
                if self._bar in p.scalar_bars:
                    p.scalar_bars[self._bar].SetVisibility(False)
            return
        scaled = view.prepared.get(SCALED)
        if scaled is None or len(scaled) != len(view.points):
            scaled = normalised(view.deviation, view.tolerance)
        cloud = pv.PolyData(np.asarray(view.points, np.float32))
        # cast: pyvista types set_array's data as float64 (ArrayLike[float]) but takes any numeric
        # dtype (its own __setitem__ passes ArrayLike[Any]); float32 here, half the memory.
        cloud.point_data.set_array(cast(Any, np.asarray(scaled, np.float32)), SCALED, deep_copy=False)
        lo, hi = view.tolerance
        notes = {-SPAN: f"{number(SPAN * lo, 2, sign=True)} mm", -1.0: f"{number(lo, 2, sign=True)} mm", 0.0: "0 mm",
                 1.0: f"{number(hi, 2, sign=True)} mm", SPAN: f"{number(SPAN * hi, 2, sign=True)} mm"}
        if self._cloud is None:
            self._cloud = cloud
            self._cloud_actor = p.add_mesh(
                cloud, name="bcps", scalars=SCALED, cmap=self._cmap, clim=(-SPAN, SPAN), point_size=POINT_PX,
                render_points_as_spheres=False, reset_camera=False, show_scalar_bar=True, annotations=notes,
                scalar_bar_args=dict(title=self._bar, n_labels=0, vertical=True, position_x=0.86, position_y=0.12,
                                     height=0.76, width=0.07, title_font_size=16, label_font_size=14, color="white"),
                render=False)
        else:
            assert self._cloud_actor is not None  # made with self._cloud
            self._cloud.copy_from(cloud, deep=False)  # the actor's own data object, new arrays
            if self._bar_tolerance != view.tolerance:  # the bar relabelled for this result's limits
                self._cloud_actor.mapper.lookup_table.annotations = notes
            self._cloud_actor.SetVisibility(True)
        self._bar_tolerance = view.tolerance
        if self._bar in p.scalar_bars:
            p.scalar_bars[self._bar].SetVisibility(True)

    def _set_defects(self, defects: tuple[DefectRow, ...]) -> None:
        p = self.plotter
        label_actors = [p.renderer.actors.get(n) for n in ("defect-labels-points", "defect-labels-labels")]
        if not defects:
            for a in [self._marks_actor, *label_actors]:
                if a is not None:
                    a.SetVisibility(False)
            return
        marks = pv.merge([pv.Sphere(radius=self._radius(d), center=d.position, theta_resolution=16, phi_resolution=12)
                          for d in defects], merge_points=False)
        if not isinstance(marks, pv.PolyData):
            marks = marks.extract_surface()
        if self._marks is None:
            self._marks = marks
            self._marks_actor = p.add_mesh(marks, name="defects", style="wireframe", color="#ffeb3b", line_width=1,
                                           opacity=0.45, reset_camera=False, render=False)
        else:
            self._marks.copy_from(marks, deep=False)
        assert self._marks_actor is not None  # made with self._marks
        self._marks_actor.SetVisibility(True)
        from vtkmodules.vtkCommonCore import vtkStringArray

        labels = pv.PolyData(np.array([d.position for d in defects], float))
        text = vtkStringArray()
        text.SetName("labels")
        for d in defects:
            text.InsertNextValue(str(d.number))
        labels.GetPointData().AddArray(text)
        if self._labels is None:
            self._labels = labels
            p.add_point_labels(labels, "labels", name="defect-labels", font_size=22, text_color="black",
                               point_color="#ffeb3b", point_size=12, shape_color="#ffeb3b", shape_opacity=0.9,
                               always_visible=True, reset_camera=False, render=False)
        else:
            self._labels.copy_from(labels, deep=True)
            for a in label_actors:
                if a is not None:
                    a.SetVisibility(True)

    def reset_camera(self, render: bool = True) -> None:
        """Fit the part (not the whole rig) in the view."""
        v = self.view
        if v is None or not len(v.points):
            return
        lo, hi = v.points.min(axis=0), v.points.max(axis=0)
        self.plotter.renderer.reset_camera(render=False, bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        if render:
            self.render()

    @staticmethod
    def _radius(d: DefectRow) -> float:
        return max(1.5, 0.6 * max(d.extent) + 0.5)

    def fly_to(self, index: int) -> None:
        """Centre the view on defect ``index`` (0-based), looking at it from the cameras that
        saw it, and draw rays towards those cameras."""
        v = self.view
        if v is None or not 0 <= index < len(v.defects):
            return
        d = v.defects[index]
        p = self.plotter
        pos = np.asarray(d.position, float)
        idx = [v.camera_names.index(c) for c in d.cameras if c in v.camera_names]
        direction = None
        if idx and len(v.camera_centres):
            rays = v.camera_centres[idx] - pos
            rays /= np.linalg.norm(rays, axis=1, keepdims=True)
            length = 25.0
            ends = pos + rays * length
            lines = pv.merge([pv.Line(pos, e) for e in ends])
            p.add_mesh(lines, name="camera-rays", color="#00e5ff", line_width=2, reset_camera=False, render=False)
            p.add_point_labels(ends, [v.camera_names[i] for i in idx], name="camera-labels", font_size=14,
                               text_color="white", shape_color="#006064", shape_opacity=0.85, point_size=1,
                               always_visible=True, reset_camera=False, render=False)
            direction = rays.mean(axis=0)
            if np.linalg.norm(direction) < 1e-6:
                direction = rays[0]
        else:
            for name in _SELECTION[1:]:
                p.renderer.remove_actor(name, render=False)
        if direction is None:
            cam = np.asarray(p.camera.position) - np.asarray(p.camera.focal_point)
            direction = cam
        direction = direction / np.linalg.norm(direction)
        # A ring about the defect facing the view, not a sphere over it: its points stay visible.
        r = self._radius(d) * 1.6
        p.add_mesh(pv.Disc(center=pos, inner=r, outer=r * 1.12, normal=direction, r_res=1, c_res=72), name="selected",
                   color="#00e5ff", reset_camera=False, lighting=False, render=False)
        distance = max(40.0, 8.0 * self._radius(d))
        p.camera.focal_point = tuple(pos)
        p.camera.position = tuple(pos + direction * distance)
        p.reset_camera_clipping_range()
        p.render()

    def screenshot(self, path: Path) -> Path:
        """The view as a PNG (for the report)."""
        self.plotter.render()
        self.plotter.screenshot(str(path))
        return Path(path)

    def close_plotter(self) -> None:
        """Release VTK's window and actors (before the widget goes)."""
        self.plotter.close()
