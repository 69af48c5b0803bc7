"""What drawing a result takes, made ahead off the GUI thread: :func:`prepare_view` runs in the
session's worker thread (:class:`~inspector_frontends.gui.worker.SessionWorker`) and fills
:attr:`ResultView.prepared <inspector_frontends.gui.viewmodel.ResultView.prepared>`; the widgets
then only swap pictures (``QImage``, ``QPainter`` on an image and matplotlib's Agg canvas may be
used in any thread; no widget is read).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from inspector_frontends.gui.cameras import tile_image
from inspector_frontends.gui.history_strip import history_chart, read_rows, read_shift
from inspector_frontends.gui.viewmodel import ResultView
from inspector_frontends.gui.widgets import HISTORY, PICTURES, SHIFT

__all__ = ["prepare_view"]


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
