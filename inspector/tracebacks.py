"""Traceback files of internal errors: the user sees one line naming the file, we get the file.

The file lives in the shared temporary folder, where any local user can create names in
advance: a fixed or guessable name (time and process id) can be a planted symlink that makes
us overwrite another file, or a file someone else can read. :func:`save_traceback` creates
a new file under an unpredictable name, exclusively (``O_CREAT | O_EXCL``, never through an
existing name or link), readable by its owner only.
"""

from __future__ import annotations

import os
import tempfile
import time

__all__ = ["save_traceback", "NOT_WRITTEN"]

#: What :func:`save_traceback` returns when no file could be written.
NOT_WRITTEN = "(could not be written)"


def save_traceback(text: str | None = None, *, directory: str | os.PathLike[str] | None = None) -> str:
    """Write ``text`` to a new private file and return its path.

    Parameters
    ----------
    text : str, optional
        The traceback; by default the exception being handled (``traceback.format_exc()``).
    directory : path-like, optional
        Where to create the file; by default :func:`tempfile.gettempdir`.

    Returns
    -------
    str
        The file's path (``inspector-traceback-YYYYmmdd-HHMMSS-XXXXXXXX.txt``, mode 0600),
        or :data:`NOT_WRITTEN` when it could not be written (nothing is left behind then).
        Never raises: it runs while another error is being reported.
    """
    if text is None:
        import traceback

        text = traceback.format_exc()
    prefix = f"inspector-traceback-{time.strftime('%Y%m%d-%H%M%S')}-"
    try:
        # mkstemp: O_CREAT | O_EXCL (and O_NOFOLLOW where there is one), mode 0600, a
        # random suffix retried on collision: a planted file or link is never opened.
        fd, path = tempfile.mkstemp(prefix=prefix, suffix=".txt", dir=directory)
    except OSError:
        return NOT_WRITTEN
    try:
        with os.fdopen(fd, "w", encoding="utf-8", errors="backslashreplace") as f:
            f.write(text)
    except OSError:  # a full disk: no half file left in the temporary folder
        try:
            os.unlink(path)
        except OSError:
            pass
        return NOT_WRITTEN
    return path
