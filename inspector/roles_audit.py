"""The audit trail of the operator station (part of :mod:`inspector.roles`).

Every role switch (login, refused login, logout, idle fallback) and every recipe change is
a row of the ``audit`` table (:data:`AUDIT_SCHEMA`) in ``OUTDIR/history.sqlite``, the
database the ``history`` plugin writes its inspections to. What concerns the station rather
than a run (a password set, changed, refused or reset; a recipe approved; production mode
switched) is a row of the same table in the station's ``audit.sqlite`` beside ``roles.json``.
Audit rows are hash-chained (:mod:`inspector.ledger`).
"""

from __future__ import annotations

import hashlib
import os
import sqlite3
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from inspector import ledger
from inspector.errors import InputError
from inspector.roles_password import config_dir

__all__ = [
    "AUDIT_ACTIONS",
    "AUDIT_SCHEMA",
    "file_sha256",
    "record_audit",
    "record_station_audit",
    "audit_path",
    "read_audit",
    "verify_audit",
    "station_audit_file",
]

#: The ``action`` of an audit row: a run's (the first five, and ``unapproved-run``: a recipe run
#: in production mode without an approval, told to) or the station's (the others).
AUDIT_ACTIONS = ("login", "logout", "idle-logout", "login-refused", "recipe-change", "password-set",
                 "password-refused", "password-reset", "recipe-approve", "approve-refused", "production-on",
                 "production-off", "unapproved-run")

#: Version 1 of the audit table; it lives beside the ``inspections`` tables of the history
#: plugin in the same file (and in the station's ``audit.sqlite``). ``at`` is UTC ISO-8601;
#: ``hash_*`` are the SHA-256 (hex) of the recipe files' bytes, null when there is no file (for
#: ``recipe-approve``, ``hash_after`` is the approval's digest, :mod:`inspector.approval`);
#: ``chain`` the row's link of the hash chain (:mod:`inspector.ledger`). A table from before
#: (fewer actions in its CHECK, no ``chain``) is rebuilt with its rows and ids when next written.
AUDIT_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS audit (
    id INTEGER PRIMARY KEY,
    at TEXT NOT NULL,
    who TEXT,
    action TEXT NOT NULL CHECK (action IN ({', '.join(repr(a) for a in AUDIT_ACTIONS)})),
    role_before TEXT,
    role_after TEXT,
    recipe_before TEXT,
    recipe_after TEXT,
    hash_before TEXT,
    hash_after TEXT,
    chain TEXT
);
CREATE INDEX IF NOT EXISTS audit_at ON audit (at);
"""

_AUDIT_COLUMNS = ("id", "at", "who", "action", "role_before", "role_after",
                  "recipe_before", "recipe_after", "hash_before", "hash_after")
_STATION_AUDIT = "audit.sqlite"


def _history_path(outdir: str | os.PathLike[str]) -> Path:
    # lazy: history_store loads numpy (inspector.model), which `import inspector.roles`
    # must not (tests/core/test_recipe_form.py::test_module_is_qt_free_and_light)
    from inspector.history_store import HISTORY_FILE

    return Path(outdir) / HISTORY_FILE


def file_sha256(path: str | os.PathLike[str] | None) -> str | None:
    """SHA-256 (hex) of a file's bytes; None when ``path`` is None or not a readable file."""
    if path is None:
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _path_text(path: str | os.PathLike[str] | None) -> str | None:
    if path is None:
        return None
    p = Path(path)
    try:
        return str(p.resolve())
    except OSError:
        return str(p)


def station_audit_file(config_dir_: str | os.PathLike[str] | None = None) -> Path:
    """The station's audit trail: ``audit.sqlite`` beside ``roles.json`` (:func:`config_dir`)."""
    return config_dir(config_dir_) / _STATION_AUDIT


def _audit_is_current(con: sqlite3.Connection) -> bool | None:
    """Whether the ``audit`` table has every action and the ``chain`` column (None: no table)."""
    found = con.execute("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'audit'").fetchone()
    if found is None:
        return None
    columns = {r[1] for r in con.execute("PRAGMA table_info(audit)")}
    return ledger.CHAIN_COLUMN in columns and all(f"'{a}'" in found[0] for a in AUDIT_ACTIONS)


def _ensure_audit(con: sqlite3.Connection) -> None:
    """Create the ``audit`` table, or rebuild one from before (its CHECK lacks actions added
    since, or it has no ``chain``) with its rows and ids: SQLite cannot change a CHECK in place.
    Its older rows have no hash; the chain starts at the next row."""
    state = _audit_is_current(con)
    if state:
        return
    if state is None:
        con.executescript(AUDIT_SCHEMA)
        if _audit_is_current(con):
            return
    con.execute("BEGIN IMMEDIATE")  # two writers: the second finds the table rebuilt
    try:
        if not _audit_is_current(con):
            have = [r[1] for r in con.execute("PRAGMA table_info(audit)")]
            keep = [c for c in (*_AUDIT_COLUMNS, ledger.CHAIN_COLUMN) if c in have]
            create = AUDIT_SCHEMA.split(";")[0].replace("CREATE TABLE IF NOT EXISTS audit", "CREATE TABLE audit_new")
            con.execute(create)
            con.execute(f"INSERT INTO audit_new ({', '.join(keep)}) SELECT {', '.join(keep)} FROM audit ORDER BY id")
            con.execute("DROP TABLE audit")
            con.execute("ALTER TABLE audit_new RENAME TO audit")
            con.execute("CREATE INDEX IF NOT EXISTS audit_at ON audit (at)")
        con.commit()
    except BaseException:
        con.rollback()
        raise


def _append_audit(path: Path, action: str, *, who: str | None, role_before: str | None, role_after: str | None,
                  recipe_before: str | None, recipe_after: str | None, hash_before: str | None,
                  hash_after: str | None, at: datetime | None) -> int:
    """One chained row appended to the ``audit`` table of the SQLite file ``path``."""
    if action not in AUDIT_ACTIONS:
        raise ValueError(f"unknown audit action {action!r} (expected one of {', '.join(AUDIT_ACTIONS)})")
    path.parent.mkdir(parents=True, exist_ok=True)
    row = (
        (at or datetime.now(UTC)).astimezone(UTC).isoformat(timespec="milliseconds"),
        who, action, role_before, role_after, recipe_before, recipe_after, hash_before, hash_after,
    )
    con = sqlite3.connect(str(path), timeout=10.0)
    try:
        con.execute("PRAGMA journal_mode=WAL")
        _ensure_audit(con)
        cur = con.execute(
            "INSERT INTO audit (at, who, action, role_before, role_after, recipe_before, recipe_after,"
            " hash_before, hash_after) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            row,
        )
        rid = int(cur.lastrowid or 0)
        ledger.seal(con, "audit", rid)  # in the insert's transaction: the previous row is fixed
        con.commit()
        return rid
    finally:
        con.close()


def record_audit(
    outdir: str | os.PathLike[str],
    action: str,
    *,
    who: str | None,
    role_before: str | None,
    role_after: str | None,
    recipe_before: str | os.PathLike[str] | None = None,
    recipe_after: str | os.PathLike[str] | None = None,
    at: datetime | None = None,
) -> int:
    """Append one row to the ``audit`` table of ``outdir/history.sqlite``; returns its id.

    The recipe files are hashed now (SHA-256 of their bytes). ``outdir`` is created if
    needed. The row is hash-chained to the one before (:mod:`inspector.ledger`).

    Raises
    ------
    ValueError
        ``action`` is not one of :data:`AUDIT_ACTIONS`.
    sqlite3.Error, OSError
        The database cannot be written (:class:`RoleSession` turns these into a warning).
    """
    if action not in AUDIT_ACTIONS:
        raise ValueError(f"unknown audit action {action!r} (expected one of {', '.join(AUDIT_ACTIONS)})")
    return _append_audit(_history_path(outdir), action, who=who, role_before=role_before, role_after=role_after,
                         recipe_before=_path_text(recipe_before), recipe_after=_path_text(recipe_after),
                         hash_before=file_sha256(recipe_before), hash_after=file_sha256(recipe_after), at=at)


def record_station_audit(action: str, *, who: str | None, role_before: str | None = None,
                         role_after: str | None = None, recipe: str | os.PathLike[str] | None = None,
                         digest: str | None = None, config_dir: str | os.PathLike[str] | None = None) -> int:
    """Append one row to the station's audit trail (:func:`station_audit_file`): a password
    set, refused or reset, a recipe approved (``recipe`` and its approval ``digest`` as
    ``recipe_after``/``hash_after``), production mode switched. Returns its id.

    Raises
    ------
    ValueError
        ``action`` is not one of :data:`AUDIT_ACTIONS`.
    sqlite3.Error, OSError
        The file cannot be written.
    """
    return _append_audit(station_audit_file(config_dir), action, who=who, role_before=role_before,
                         role_after=role_after, recipe_before=None, recipe_after=_path_text(recipe),
                         hash_before=None, hash_after=digest, at=None)


def audit_path(outdir: str | os.PathLike[str] | None, config_dir_: str | os.PathLike[str] | None) -> Path:
    """The SQLite file of an audit trail: ``outdir/history.sqlite``, or the station's
    (:func:`station_audit_file`) when ``outdir`` is None."""
    return station_audit_file(config_dir_) if outdir is None else _history_path(outdir)


def read_audit(outdir: str | os.PathLike[str] | None, *, last: int | None = None,
               config_dir: str | os.PathLike[str] | None = None) -> list[dict[str, Any]]:
    """The audit rows of ``outdir`` (None: the station's), oldest first (the ``last`` ones
    only); [] when the file holds none.

    Raises
    ------
    inspector.errors.InputError
        No ``history.sqlite`` in ``outdir`` (no station audit file), or it cannot be read (the
        message names it).
    """
    path = audit_path(outdir, config_dir)
    if not path.is_file():
        if outdir is None:
            raise InputError(f"{path}: no station audit yet (set-password, recipe approve and production write it)")
        raise InputError(f"{path}: no history (the station and inspector run write it in OUTDIR)")
    # lazy: history_store loads numpy (inspector.model), which `import inspector.roles`
    # must not (tests/core/test_recipe_form.py::test_module_is_qt_free_and_light)
    from inspector.history_store import read_table

    return read_table(path, "audit", _AUDIT_COLUMNS, last=last) or []


def verify_audit(outdir: str | os.PathLike[str] | None, *,
                 config_dir: str | os.PathLike[str] | None = None) -> ledger.ChainReport:
    """The hash chain of the audit rows of ``outdir`` (None: the station's) checked
    (:func:`inspector.ledger.verify`).

    Raises
    ------
    inspector.errors.InputError
        No such file, or it cannot be read.
    """
    path = audit_path(outdir, config_dir)
    if not path.is_file():
        raise InputError(f"{path}: no audit trail")
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        try:
            return ledger.verify(con, "audit", describe=lambda r: f"{r.get('action')} by {r.get('who') or '-'}")
        finally:
            con.close()
    except sqlite3.Error as e:
        raise InputError(f"{path}: cannot be read ({e})") from None

