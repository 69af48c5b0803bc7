"""Inspector: 3D geometric quality inspection from the silhouettes of a multi-camera rig.

``import inspector`` is light: it loads neither Qt, VTK, Harvesters nor Aravis, nor the
numerical libraries; subpackages are imported where they are used.
"""

from __future__ import annotations

import pluggy

__version__ = "0.1.0"

#: Decorator for plugin hook implementations (see :mod:`inspector.hookspecs`).
hookimpl = pluggy.HookimplMarker("inspector")

__all__ = ["__version__", "hookimpl"]
