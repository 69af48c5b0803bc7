"""Errors a user may see. Each carries a one-line message that names the file, camera or key.

The CLI prints ``str(error)`` and never a traceback for these; anything else is a bug,
which the CLI reports as one "internal error" line, its traceback saved to a file.
"""

from __future__ import annotations

__all__ = ["InspectorError", "RecipeError", "InputError", "CaptureError", "ReferenceMeshError", "StageError", "PluginError"]


class InspectorError(Exception):
    """Base class: a problem the user can fix, with a one-line message."""

    def __init__(self, message: str) -> None:
        # Keep messages to one line whatever the cause says.
        super().__init__(" ".join(str(message).split()))


class RecipeError(InspectorError):
    """The recipe or the command line is invalid (exit status 2, nothing inspected)."""


class InputError(InspectorError):
    """An input file is missing, unreadable or inconsistent."""


class CaptureError(InputError):
    """A capture folder cannot be inspected (exit status 3 for that capture)."""


class ReferenceMeshError(InputError):
    """The reference mesh is missing, unreadable or not watertight."""


class StageError(InspectorError):
    """A stage could not produce its result from valid inputs (e.g. empty silhouette)."""


class PluginError(InspectorError, ValueError):
    """A plugin cannot be used: it does not import, its hooks do not match the hookspecs, or
    what it registers is invalid (a stage name, a parameter type, the evaluate contract).

    A plugin loaded from an entry point that raises this is disabled with one warning naming
    it (see :mod:`inspector.manager`); one registered from code (tests, an embedding
    application) raises it. A ``ValueError`` too, for callers that caught that before.
    """
