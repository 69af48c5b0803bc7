"""Capture names: each capture's result folder is ``OUTDIR/<name>/``, so a name is a path.

A capture's name comes from outside (a folder name given on the command line or dropped in
a hot folder), and it becomes a folder of ``--out``. One rule, :func:`name_problem`, decides
which names can: the drivers that name captures after folders check it before a capture is
read (a refused one becomes verdict ``error`` with one line, the others go on), and
:func:`inspector.outputs.write_result` checks it again, with the resolved path, before it
writes anything, so no driver (a third party's included) can write outside ``--out``.

Refused: the empty name, ``.`` and ``..``, a path separator (``/``, and ``\\`` which is one
on Windows shares), control characters (a newline would split the one-line reports), names
longer than 255 bytes, the names of what ``OUTDIR`` itself holds (:data:`RESERVED`), and
``.NAME.partial`` / ``.NAME.old``, the result writer's own temporary folders.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from inspector.errors import CaptureError

__all__ = ["RESERVED", "name_problem", "check_name", "printable", "folder_name", "text_problem"]

#: Entries of OUTDIR that are not result folders: the history database and its SQLite
#: journal files (a folder of that name disables the history), and the recipes the
#: operator's editor saves.
RESERVED = frozenset({"history.sqlite", "history.sqlite-wal", "history.sqlite-shm", "history.sqlite-journal", "recipes"})

# Characters that break a line (str.splitlines splits on some of these) or a terminal, and
# lone surrogates (undecodable bytes of a file name: printing one raises UnicodeEncodeError).
_UNPRINTABLE = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]")
# Bidirectional controls and invisible format characters: "part\u202egnp.exe" displays as
# another name than it is (in a file manager, the GUI, a report).
_DECEPTIVE = re.compile(r"[\u061c\u200b-\u200f\u202a-\u202e\u2060-\u2069\ufeff]")
_MAX_BYTES = 255  # NAME_MAX of every file system the product runs on


def name_problem(name: object) -> str | None:
    """Why ``name`` cannot name a result folder, or None when it can."""
    if not isinstance(name, str) or not name:
        return "is empty"
    if name in (".", ".."):
        return "is not a folder name"
    if "/" in name or "\\" in name or (os.sep in name) or (os.altsep and os.altsep in name):
        return "contains a path separator"
    if _UNPRINTABLE.search(name):
        return "contains a control character or bytes that are not UTF-8"
    if _DECEPTIVE.search(name):
        return "contains a bidirectional or invisible formatting character (it would display as another name)"
    if len(name.encode("utf-8")) > _MAX_BYTES:
        return f"is longer than {_MAX_BYTES} bytes"
    if name in RESERVED:
        return f"is reserved in the result folder (OUTDIR/{name} is not a result)"
    if name.startswith(".") and name.endswith((".partial", ".old")):
        # OUTDIR/.<name>.partial and .old are where write_result builds and swaps a result.
        return "is reserved for the result writer's temporary folders (.NAME.partial, .NAME.old)"
    return None


def text_problem(value: object) -> str | None:
    """Why a text read from a capture (``capture.json``'s ``part_id``, any string in it)
    cannot be stored, or None: a lone surrogate (JSON's ``"\\ud800"``) is not Unicode text,
    and SQLite, PostgreSQL and every UTF-8 file refuse it."""
    if isinstance(value, str):
        m = re.search(r"[\ud800-\udfff]", value)
        return None if m is None else f"is not valid Unicode text (a lone surrogate at character {m.start()})"
    if isinstance(value, dict):
        for k, v in value.items():
            why = text_problem(k) or text_problem(v)
            if why is not None:
                return why
    if isinstance(value, list):
        for v in value:
            why = text_problem(v)
            if why is not None:
                return why
    return None


def printable(name: object) -> str:
    """``name`` safe for a one-line message: with a control character or an undecodable
    byte, written as Python escapes it (``a\\nb``); else unchanged."""
    text = str(name)
    return ascii(text)[1:-1] if _UNPRINTABLE.search(text) or _DECEPTIVE.search(text) else text


def check_name(name: object, what: str = "capture") -> str:
    """``name`` when it can name a result folder.

    Raises
    ------
    CaptureError
        One line naming the capture (escaped) and the reason.
    """
    problem = name_problem(name)
    if problem is not None:
        raise CaptureError(f"{what} name '{printable(name)}' {problem}; rename it")
    return str(name)


def folder_name(folder: str | os.PathLike[str]) -> str:
    """The name a capture folder gives its capture: the last part of its absolute path,
    without resolving links (``caps/a/..`` is ``caps``; ``.`` is the current folder's name).

    The same rule as :func:`inspector.capture_folder.read_capture`'s ``Capture.name``.
    """
    return Path(os.path.abspath(folder)).name
