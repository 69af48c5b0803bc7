"""Process start-up: what a new ``inspector`` process does before its first import of Open3D.

``import open3d`` also imports its Plotly viewer (``open3d.visualization.draw_plotly``),
which imports Dash, Plotly, Werkzeug, urllib3 and pydantic: measured with ``python -X
importtime`` on an ``inspector run``, about 40 % of the process's import time (issue 15: a
new process must reach its first verdict within 3 s). Inspector never draws with it. The
CLI therefore registers a stand-in for that one module before Open3D is first imported:
its three functions load the real module on their first call, so a user's script that
does call ``open3d.visualization.draw_plotly`` still gets it.

Nothing here is imported by ``import inspector``; :func:`defer_open3d_plotly` is called by
:func:`inspector_frontends.cli.main` (every front end: CLI, GUI, bench, Dask workers started by it).
"""

from __future__ import annotations

import importlib.util
import sys
import types
from typing import Any

__all__ = ["defer_open3d_plotly"]

_NAME = "open3d.visualization.draw_plotly"
_EXPORTS = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def _real() -> types.ModuleType:
    """The real ``draw_plotly`` module, loaded from Open3D's own file under a private name."""
    mod = sys.modules.get("_inspector_real_draw_plotly")
    if mod is not None:
        return mod
    import open3d.visualization as vis

    path = vis.__path__[0] + "/draw_plotly.py"
    spec = importlib.util.spec_from_file_location("_inspector_real_draw_plotly", path)
    if spec is None or spec.loader is None:  # pragma: no cover - Open3D without the file
        raise ImportError(f"open3d's {_NAME} not found at {path}")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _deferred(name: str) -> Any:
    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(_real(), name)(*args, **kwargs)

    call.__name__ = name
    call.__doc__ = f"open3d.visualization.{name}, loaded on its first call (see inspector.startup)."
    return call


def defer_open3d_plotly() -> bool:
    """Register the stand-in for ``open3d.visualization.draw_plotly`` unless Open3D (or
    that module) is already imported or Open3D is not installed. Returns whether it did."""
    if "open3d" in sys.modules or _NAME in sys.modules or importlib.util.find_spec("open3d") is None:
        return False
    stub = types.ModuleType(_NAME, "Stand-in registered by inspector.startup: the real module loads on first call.")
    for name in _EXPORTS:
        setattr(stub, name, _deferred(name))
    sys.modules[_NAME] = stub
    return True
