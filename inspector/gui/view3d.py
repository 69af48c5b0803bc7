"""The 3D view: BCPS points coloured by signed deviation on a scale fixed to the tolerance
limits, the aligned reference translucent, defects marked and numbered, and the cameras
that produced a selected defect.

Every actor has a name and is replaced, never added again (pyvista keeps unnamed actors
and their textures alive: a leak per inspection), and the plotter is closed explicitly.
Called on the GUI thread only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyvista as pv
from pyvistaqt import QtInteractor
from PySide6.QtWidgets import QWidget

from inspector.gui.viewmodel import DefectRow, ResultView

__all__ = ["DeviationView", "deviation_colormap", "normalised"]

#: The colour scale spans this many tolerance widths on each side.
SPAN = 3.0
BAR = "deviation"


def normalised(deviation: np.ndarray, tolerance: tuple[float, float]) -> np.ndarray:
    """Deviation in units of its own tolerance limit: -1 and +1 are the limits (which may
    be asymmetric), so the colour scale is fixed to them whatever the numbers.

    Parameters
    ----------
    deviation : (N,) float, mm
    tolerance : (lower, upper), mm, lower < 0 < upper
    """
    lo, hi = tolerance
    d = np.asarray(deviation, float)
    return np.where(d >= 0, d / max(hi, 1e-9), d / max(-lo, 1e-9)).clip(-SPAN, SPAN)


def deviation_colormap(n: int = 240):
    """Diverging, neutral grey inside the tolerance band: blues for missing material, from
    light at the limit to dark at SPAN limits, reds for excess."""
    from matplotlib.colors import LinearSegmentedColormap, ListedColormap

    k = n // 6  # entries per tolerance width: [-3,-1] 2k, [-1,1] 2k, [1,3] 2k
    blues = LinearSegmentedColormap.from_list("m", ["#08306b", "#2171b5", "#6baed6"])(np.linspace(0, 1, 2 * k))
    reds = LinearSegmentedColormap.from_list("e", ["#fd8d3c", "#e31a1c", "#67000d"])(np.linspace(0, 1, 2 * k))
    grey = np.tile(np.array([0.835, 0.847, 0.863, 1.0]), (2 * k, 1))
    return ListedColormap(np.vstack([blues, grey, reds]), name="inspector-deviation")


class DeviationView(QWidget):
    """A pyvistaqt ``QtInteractor`` that shows one :class:`ResultView` at a time."""

    ACTORS = ("bcps", "reference", "defects", "defect-labels", "selected", "camera-rays", "camera-labels")

    def __init__(self, parent: QWidget | None = None) -> None:
        from PySide6.QtWidgets import QVBoxLayout

        super().__init__(parent)
        # No periodic re-render (pyvistaqt renders 5 times a second by default: 80 % of a core
        # with software OpenGL on an idle screen, measured); the view renders after each change
        # and on interaction.
        self.plotter = QtInteractor(self, auto_update=False)
        self.plotter.set_background("#1f2428", top="#3b4450")
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.plotter.interactor)
        self.view: ResultView | None = None
        self._cmap = deviation_colormap()
        self.plotter.add_text("", name="caption", font_size=10, position="upper_left")
        self.plotter.add_axes()

    # -- showing ------------------------------------------------------------------------------
    def show_result(self, view: ResultView) -> None:
        p = self.plotter
        self.view = view
        # Every change below would render on its own (pyvista's scalar bar does, whatever
        # render=False says): rendering is held until the one render at the end.
        p.suppress_rendering = True
        try:
            self._replace_actors(view)
        finally:
            p.suppress_rendering = False
        p.render()  # once: each render costs 0.15-0.6 s with software OpenGL (measured)

    def _replace_actors(self, view: ResultView) -> None:
        p = self.plotter
        for name in self.ACTORS:
            p.remove_actor(name, render=False)
        if view.reference is not None:
            v, f = view.reference
            faces = np.hstack([np.full((len(f), 1), 3), f]).astype(np.int64).ravel()
            p.add_mesh(pv.PolyData(np.asarray(v, float), faces), name="reference", color="#7fa7c9", opacity=0.12,
                       show_edges=False, pickable=False, reset_camera=False, render=False)
        if len(view.points):
            cloud = pv.PolyData(np.asarray(view.points, np.float32))
            cloud["deviation / limit"] = normalised(view.deviation, view.tolerance).astype(np.float32)
            lo, hi = view.tolerance
            if BAR in p.scalar_bars:  # one bar, relabelled for this result's limits
                p.remove_scalar_bar(BAR, render=False)
            p.add_mesh(cloud, name="bcps", scalars="deviation / limit", cmap=self._cmap, clim=(-SPAN, SPAN),
                       render_points_as_spheres=True, point_size=5, reset_camera=False, show_scalar_bar=True,
                       annotations={-SPAN: f"{SPAN * lo:+.2f} mm", -1.0: f"{lo:+.2f} mm", 0.0: "0 mm",
                                    1.0: f"{hi:+.2f} mm", SPAN: f"{SPAN * hi:+.2f} mm"},
                       scalar_bar_args=dict(title=BAR, n_labels=0, vertical=True, position_x=0.86, position_y=0.12,
                                            height=0.76, width=0.07, title_font_size=16, label_font_size=14,
                                            color="white"), render=False)
        if view.defects:
            marks = pv.merge([pv.Sphere(radius=self._radius(d), center=d.position, theta_resolution=16, phi_resolution=12)
                              for d in view.defects])
            p.add_mesh(marks, name="defects", style="wireframe", color="#ffeb3b", line_width=1, opacity=0.45,
                       reset_camera=False, render=False)
            p.add_point_labels(np.array([d.position for d in view.defects]), [str(d.number) for d in view.defects],
                               name="defect-labels", font_size=22, text_color="black", point_color="#ffeb3b",
                               point_size=12, shape_color="#ffeb3b", shape_opacity=0.9, always_visible=True,
                               reset_camera=False, render=False)
        word = view.verdict.upper()
        p.add_text(f"{word}  {view.capture}  ({len(view.points)} points)", name="caption", font_size=10,
                   position="upper_left", color="white", render=False)
        if len(view.points):
            self.reset_camera(render=False)

    def reset_camera(self, render: bool = True) -> None:
        """Fit the part (not the whole rig) in the view."""
        v = self.view
        if v is None or not len(v.points):
            return
        lo, hi = v.points.min(axis=0), v.points.max(axis=0)
        self.plotter.renderer.reset_camera(render=False, bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        if render:
            self.plotter.render()

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
            p.remove_actor("camera-rays", render=False)
            p.remove_actor("camera-labels", render=False)
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
