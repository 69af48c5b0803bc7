"""Errors a user may see. Each carries a one-line message that names the file, camera or key.

The CLI prints ``str(error)`` and never a traceback for these; anything else is a bug,
which the CLI reports as one "internal error" line, its traceback saved to a file.
"""

from __future__ import annotations

__all__ = ["InspectorError", "RecipeError", "InputError", "CaptureError", "ReferenceMeshError", "StageError"]


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
