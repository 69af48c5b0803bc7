"""Inspector: 3D geometric quality inspection from the silhouettes of a multi-camera rig.

``import inspector`` is light: it loads neither Qt, VTK, Harvesters nor Aravis, nor the
numerical libraries; subpackages are imported where they are used.
"""

from __future__ import annotations

import pluggy

#: The product's version: the one source (``pyproject.toml`` reads it from here).
__version__ = "0.2.0"

#: The plugin API's version, ``MAJOR.MINOR``: what :mod:`inspector.api` and
#: :mod:`inspector.hookspecs` offer. MINOR grows when something is added, MAJOR when something
#: a plugin may use changes or goes. A plugin declares the range it needs with a module
#: attribute ``INSPECTOR_API = ">=1.0,<2"``, checked when it loads.
API_VERSION = "1.0"

#: Decorator for plugin hook implementations (see :mod:`inspector.hookspecs`).
hookimpl = pluggy.HookimplMarker("inspector")

__all__ = ["API_VERSION", "__version__", "hookimpl"]
