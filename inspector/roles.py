"""Roles of the operator station, the engineer's password, and the audit trail.

Two roles:

``operator``
    inspects, views results and exports them (:data:`PERMISSIONS`).
``engineer``
    everything an operator does, plus choosing and editing recipes. Reaching it takes the
    engineer password; after :attr:`RoleSession.idle_s` seconds without user activity the
    station falls back to ``operator`` by itself.

The password is never stored: ``roles.json`` in the configuration folder
(``$INSPECTOR_CONFIG_DIR``, else ``~/.config/inspector``; mode 0600, written atomically)
holds a salted PBKDF2-HMAC-SHA256 hash (:func:`set_password`, :func:`check_password`).
``inspector roles set-password`` asks for the current password before it sets a new one. The
recovery of a forgotten password is ``inspector roles set-password --reset``: allowed only to
the owner of ``roles.json`` (the station's operating-system account) or root, who could edit
the file anyway (the protection is the operating system's account separation, as for any
local secret), and recorded as ``password-reset`` in the station's audit trail, so a reset is
never silent.

Every role switch (login, refused login, logout, idle fallback) and every recipe change is
a row of the ``audit`` table (:data:`AUDIT_SCHEMA`) in ``OUTDIR/history.sqlite``, the
database the ``history`` plugin writes its inspections to; ``inspector roles audit OUTDIR``
lists it. What concerns the station rather than a run (a password set, changed, refused or
reset; a recipe approved; production mode switched) is a row of the same table in the
station's ``audit.sqlite`` beside ``roles.json`` (``inspector roles audit`` without OUTDIR).
Audit rows are hash-chained (:mod:`inspector.ledger`); ``inspector roles audit [OUTDIR]
--verify`` names the first row changed or removed. An audit row that cannot be written costs
one warning line on stderr, never the station.

Production mode (``inspector roles production on``, a key of ``roles.json``): the station runs
only recipes an engineer approved (:mod:`inspector.approval`) in the operator role.

This module is plain Python (no Qt): a GUI drives a :class:`RoleSession`.
"""

from __future__ import annotations

import getpass
import hashlib
import hmac
import json
import os
import secrets
import sqlite3
import sys
import tempfile
import time
from collections.abc import Callable
from datetime import datetime, UTC
from pathlib import Path
from typing import Any

from inspector import ledger

__all__ = [
    "OPERATOR",
    "ENGINEER",
    "ROLES",
    "PERMISSIONS",
    "AUDIT_ACTIONS",
    "AUDIT_SCHEMA",
    "MIN_PASSWORD_LENGTH",
    "PBKDF2_ITERATIONS",
    "config_dir",
    "roles_file",
    "set_password",
    "check_password",
    "password_is_set",
    "password_problem",
    "file_sha256",
    "record_audit",
    "record_station_audit",
    "read_audit",
    "verify_audit",
    "station_audit_file",
    "production_mode",
    "set_production_mode",
    "RoleSession",
    "add_parser",
    "run",
]

OPERATOR = "operator"
ENGINEER = "engineer"
ROLES = (OPERATOR, ENGINEER)

#: What each role may do (a GUI greys out the rest).
PERMISSIONS: dict[str, frozenset[str]] = {
    OPERATOR: frozenset({"inspect", "view", "export"}),
    ENGINEER: frozenset({"inspect", "view", "export", "choose-recipe", "edit-recipe"}),
}

#: The ``action`` of an audit row: a run's (the first five, and ``unapproved-run``: a recipe run
#: in production mode without an approval, told to) or the station's (the others).
AUDIT_ACTIONS = ("login", "logout", "idle-logout", "login-refused", "recipe-change", "password-set",
                 "password-refused", "password-reset", "recipe-approve", "approve-refused", "production-on",
                 "production-off", "unapproved-run")

MIN_PASSWORD_LENGTH = 8
#: PBKDF2-HMAC-SHA256 iterations of a new hash (a stored hash keeps its own count).
PBKDF2_ITERATIONS = 600_000
_ALGORITHM = "pbkdf2_sha256"
_ROLES_FILE = "roles.json"

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


# --------------------------------------------------------------------------- the password


def config_dir(config_dir: str | os.PathLike[str] | None = None) -> Path:
    """The configuration folder: ``config_dir`` if given, else ``$INSPECTOR_CONFIG_DIR``,
    else ``~/.config/inspector``."""
    if config_dir is not None:
        return Path(config_dir)
    env = os.environ.get("INSPECTOR_CONFIG_DIR")
    if env:
        return Path(env).expanduser()
    return Path.home() / ".config" / "inspector"


def roles_file(config_dir_: str | os.PathLike[str] | None = None) -> Path:
    """The ``roles.json`` of :func:`config_dir`."""
    return config_dir(config_dir_) / _ROLES_FILE


def _hash(password: str, salt: bytes, iterations: int) -> bytes:
    return hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)


def _read_config(path: Path) -> dict[str, Any]:
    """roles.json as a dict ({} when there is none); ValueError/OSError when unreadable."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    data = json.loads(text)
    if not isinstance(data, dict):
        raise ValueError("expected a JSON object")
    return data


def _write_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as JSON to ``path``: mode 0600, a temporary file renamed over it."""
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")  # mode 0600
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(data, f, indent=1, sort_keys=True)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o600)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:  # the rename itself survives a power cut
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


def _password_error(password: str) -> str | None:
    if not password:
        return "the password is empty"
    if len(password) < MIN_PASSWORD_LENGTH:
        return f"the password is shorter than {MIN_PASSWORD_LENGTH} characters"
    return None


def set_password(password: str, *, config_dir: str | os.PathLike[str] | None = None) -> Path:
    """Set the engineer password: store its salted PBKDF2-HMAC-SHA256 hash in ``roles.json``.

    Parameters
    ----------
    password : str
        At least :data:`MIN_PASSWORD_LENGTH` characters.
    config_dir : path, optional
        The configuration folder (default :func:`config_dir`).

    Returns
    -------
    Path
        The ``roles.json`` written (mode 0600; other keys it held are kept).

    Raises
    ------
    ValueError
        Empty or too short a password.
    OSError
        The file cannot be written.
    """
    problem = _password_error(password)
    if problem:
        raise ValueError(problem)
    path = roles_file(config_dir)
    try:
        data = _read_config(path)
    except (OSError, ValueError):
        data = {}  # an unreadable file is replaced: setting the password is how it is repaired
    salt = secrets.token_bytes(16)
    data["version"] = 1
    data["engineer"] = {
        "algorithm": _ALGORITHM,
        "iterations": PBKDF2_ITERATIONS,
        "salt": salt.hex(),
        "hash": _hash(password, salt, PBKDF2_ITERATIONS).hex(),
        "set_at": _now(),
    }
    _write_atomic(path, data)
    return path


def _engineer_record(config_dir_: str | os.PathLike[str] | None) -> dict[str, Any]:
    """The stored hash, checked; ValueError/OSError saying what is wrong."""
    path = roles_file(config_dir_)
    data = _read_config(path)
    rec = data.get("engineer")
    if rec is None:
        raise LookupError("no engineer password is set")
    if not isinstance(rec, dict) or rec.get("algorithm") != _ALGORITHM:
        raise ValueError(f"unknown password algorithm (expected {_ALGORITHM})")
    iterations = rec.get("iterations")
    if not isinstance(iterations, int) or isinstance(iterations, bool) or iterations < 1:
        raise ValueError("bad iteration count")
    salt, digest = bytes.fromhex(str(rec.get("salt", ""))), bytes.fromhex(str(rec.get("hash", "")))
    if not salt or len(digest) != 32:
        raise ValueError("bad salt or hash")
    return {"iterations": iterations, "salt": salt, "hash": digest}


def password_problem(*, config_dir: str | os.PathLike[str] | None = None) -> str | None:
    """Why engineer mode cannot be reached (one line, for the GUI), or None when a password
    is set."""
    path = roles_file(config_dir)
    try:
        _engineer_record(config_dir)
    except LookupError:
        return ("engineer mode is locked: no engineer password is set "
                f"(set one with `inspector roles set-password`; it is stored in {path})")
    except (OSError, ValueError) as e:
        return (f"engineer mode is locked: {path} cannot be read ({e}); "
                "set the password again with `inspector roles set-password`")
    return None


def password_is_set(*, config_dir: str | os.PathLike[str] | None = None) -> bool:
    """Whether a usable engineer password is stored (else :func:`password_problem` says why)."""
    return password_problem(config_dir=config_dir) is None


def check_password(password: str, *, config_dir: str | os.PathLike[str] | None = None) -> bool:
    """Whether ``password`` is the engineer password; False when none is set (or the file
    cannot be read: :func:`password_problem`)."""
    try:
        rec = _engineer_record(config_dir)
    except (LookupError, OSError, ValueError):
        return False
    return hmac.compare_digest(_hash(password, rec["salt"], rec["iterations"]), rec["hash"])


# --------------------------------------------------------------------------- the audit trail


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _history_path(outdir: str | os.PathLike[str]) -> Path:
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


def _audit_path(outdir: str | os.PathLike[str] | None, config_dir_: str | os.PathLike[str] | None) -> Path:
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
    from inspector.errors import InputError

    path = _audit_path(outdir, config_dir)
    if not path.is_file():
        if outdir is None:
            raise InputError(f"{path}: no station audit yet (set-password, recipe approve and production write it)")
        raise InputError(f"{path}: no history (the station and inspector run write it in OUTDIR)")
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
    from inspector.errors import InputError

    path = _audit_path(outdir, config_dir)
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


# --------------------------------------------------------------------------- production mode


def production_mode(*, config_dir: str | os.PathLike[str] | None = None) -> bool:
    """Whether the station is in production mode (``roles.json`` ``"production": true``): in
    the operator role it runs only approved recipes (:mod:`inspector.approval`). False when
    the file is missing or unreadable: a station is switched on explicitly."""
    try:
        return _read_config(roles_file(config_dir)).get("production") is True
    except (OSError, ValueError):
        return False


def set_production_mode(on: bool, who: str | None, *, config_dir: str | os.PathLike[str] | None = None) -> Path:
    """Switch production mode (``roles.json``, written atomically) and audit it
    (``production-on``/``production-off`` in the station's audit). The caller checks the
    engineer password first (:func:`check_password`)."""
    path = roles_file(config_dir)
    data = _read_config(path)
    data["production"] = bool(on)
    _write_atomic(path, data)
    record_station_audit("production-on" if on else "production-off", who=who, config_dir=config_dir)
    return path


# --------------------------------------------------------------------------- the session


class RoleSession:
    """The role of an operator station, with the engineer's idle fallback and the audit.

    Parameters
    ----------
    outdir : path or None
        The run's result folder; audit rows go to its ``history.sqlite``. None: nothing is
        recorded.
    idle_s : float
        Seconds without :meth:`touch` after which an engineer falls back to operator.
    clock : callable
        Monotonic seconds (injectable for tests).
    config_dir : path, optional
        Where ``roles.json`` is (default :func:`config_dir`).

    Notes
    -----
    Reading :attr:`role` applies the idle fallback first, so a stale engineer session is
    never reported; a GUI still calls :meth:`check_idle` from a timer so the fallback shows
    (and is audited) without waiting for the next question.
    """

    def __init__(
        self,
        outdir: str | os.PathLike[str] | None,
        *,
        idle_s: float = 300.0,
        clock: Callable[[], float] = time.monotonic,
        config_dir: str | os.PathLike[str] | None = None,
    ) -> None:
        if not idle_s > 0:
            raise ValueError(f"idle_s: expected seconds > 0, got {idle_s!r}")
        self.outdir = None if outdir is None else Path(outdir)
        self.idle_s = float(idle_s)
        self.clock = clock
        self.config_dir = config_dir
        self._role = OPERATOR
        self._user: str | None = None
        self._last = clock()

    # -- state
    @property
    def role(self) -> str:
        """``"operator"`` or ``"engineer"`` (after applying the idle fallback)."""
        self.check_idle()
        return self._role

    @property
    def user(self) -> str | None:
        """Who logged in as engineer (None as operator)."""
        self.check_idle()
        return self._user

    def allowed(self, permission: str) -> bool:
        """Whether the current role may do ``permission`` (see :data:`PERMISSIONS`)."""
        return permission in PERMISSIONS[self.role]

    def idle_remaining(self, now: float | None = None) -> float:
        """Seconds before an engineer session falls back (``idle_s`` as operator)."""
        now = self.clock() if now is None else now
        return max(0.0, self.idle_s - (now - self._last))

    # -- transitions
    def login_engineer(self, password: str, who: str) -> bool:
        """Switch to engineer if ``password`` is right; every attempt is audited.

        Returns False (and records ``login-refused``) for a wrong password or when no password
        is set (:func:`password_problem` says why).
        """
        who = (who or "").strip()
        if not who:
            raise ValueError("who: a name is needed for the audit trail")
        self.check_idle()
        before = self._role
        if not check_password(password, config_dir=self.config_dir):
            self._audit("login-refused", who, before, before)
            return False
        self._role, self._user, self._last = ENGINEER, who, self.clock()
        self._audit("login", who, before, ENGINEER)
        return True

    def logout(self) -> bool:
        """Back to operator; False (nothing recorded) when already operator."""
        if self.check_idle() or self._role == OPERATOR:
            return False
        who = self._user
        self._role, self._user = OPERATOR, None
        self._audit("logout", who, ENGINEER, OPERATOR)
        return True

    def touch(self, now: float | None = None) -> None:
        """User activity: restarts the idle countdown (activity after it ran out does not
        revive the engineer session)."""
        now = self.clock() if now is None else now
        self.check_idle(now)
        self._last = now

    def check_idle(self, now: float | None = None) -> bool:
        """Fall back to operator if an engineer was idle ``idle_s`` seconds; True when this
        call did it (and recorded ``idle-logout``)."""
        if self._role != ENGINEER:
            return False
        now = self.clock() if now is None else now
        if now - self._last < self.idle_s:
            return False
        who = self._user
        self._role, self._user = OPERATOR, None
        self._audit("idle-logout", who, ENGINEER, OPERATOR)
        return True

    def run_problem(self, recipe: Any) -> str | None:
        """Why ``recipe`` (a loaded :class:`~inspector.recipe.Recipe`) may not run in the
        current role on this station, one line; None when it may
        (:func:`inspector.approval.approval_problem`: in production mode the operator role runs
        only approved recipes)."""
        from inspector.approval import approval_problem

        return approval_problem(recipe, role=self.role, config_dir=self.config_dir)

    def record_recipe_change(
        self,
        who: str,
        recipe_path_before: str | os.PathLike[str] | None,
        recipe_path_after: str | os.PathLike[str] | None,
    ) -> None:
        """Audit a recipe change (the recipe files are hashed now: call it once the new
        recipe is written and before the old one is changed, if ever)."""
        role = self.role
        self._audit("recipe-change", who, role, role, recipe_path_before, recipe_path_after)

    def _audit(self, action: str, who: str | None, before: str, after: str,
               recipe_before: str | os.PathLike[str] | None = None,
               recipe_after: str | os.PathLike[str] | None = None) -> None:
        if self.outdir is None:
            return
        try:
            record_audit(self.outdir, action, who=who, role_before=before, role_after=after,
                         recipe_before=recipe_before, recipe_after=recipe_after)
        except (sqlite3.Error, OSError) as e:
            print(f"inspector: warning: {self.outdir}: audit row {action!r} not recorded ({e})",
                  file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- inspector roles


def add_parser(subparsers) -> None:
    """``inspector roles set-password``, ``inspector roles audit [OUTDIR]`` and ``inspector roles
    production``."""
    p = subparsers.add_parser("roles", help="engineer password, production mode and the audit trail of role and "
                                            "recipe changes")
    rsub = p.add_subparsers(dest="roles_command", required=True)
    sp = rsub.add_parser(
        "set-password",
        help="set the engineer password: the current one first, then the new one (on a terminal asked, the new one "
             "twice; else lines read from stdin: the current, then the new)",
    )
    sp.add_argument("--reset", action="store_true",
                    help="recovery of a forgotten password: set it without the current one (only the owner of "
                         "roles.json or root; recorded as password-reset in the station's audit)")
    sp.add_argument("--who", metavar="NAME", help="who does it, for the audit (default: the login name)")
    a = rsub.add_parser("audit", help="list (or --verify) the audit trail: a run's (OUTDIR/history.sqlite: logins, "
                                      "logouts, recipe changes) or, without OUTDIR, the station's (passwords, approvals, "
                                      "production mode)")
    a.add_argument("outdir", metavar="OUTDIR", nargs="?",
                   help="the station's or inspector run's --out folder (none: the station's audit.sqlite)")
    a.add_argument("--last", type=int, metavar="N", help="only the last N rows")
    a.add_argument("--json", action="store_true", help="the rows as JSON")
    a.add_argument("--verify", action="store_true", help="check the rows' hash chain: name the first row changed or "
                                                         "removed (exit 1), else exit 0")
    pr = rsub.add_parser("production", help="production mode: the operator role runs only recipes an engineer approved "
                                            "(inspector recipe approve); on/off asks the engineer password")
    pr.add_argument("state", nargs="?", choices=("on", "off"), help="switch it (none: say whether it is on)")
    pr.add_argument("--who", metavar="NAME", help="who does it, for the audit (default: the login name)")


def _err(msg: str) -> None:
    print(f"inspector: error: {msg}", file=sys.stderr)


def login_name() -> str | None:
    """The operating system's name of who runs the command (for audit rows), None if unknown."""
    try:
        return getpass.getuser()
    except Exception:  # noqa: BLE001 - no name in the environment or the password database
        return None


def _read_line(prompt: str) -> str:
    """A secret: with getpass on a terminal, else one line of stdin (EOFError at its end)."""
    if sys.stdin is not None and sys.stdin.isatty():
        return getpass.getpass(prompt)
    line = sys.stdin.readline() if sys.stdin is not None else ""
    if not line:
        raise EOFError
    return line.rstrip("\r\n")


def _read_new_password() -> str | None:
    """Twice with getpass on a terminal (None when they differ), else one line of stdin."""
    if sys.stdin is not None and sys.stdin.isatty():
        first = getpass.getpass("new engineer password: ")
        if getpass.getpass("again: ") != first:
            return None
        return first
    line = sys.stdin.readline() if sys.stdin is not None else ""
    return line.rstrip("\r\n")


def ask_engineer(action: str, who: str | None, *, config_dir: str | os.PathLike[str] | None = None) -> bool:
    """Ask the engineer password (:func:`_read_line`) for ``action`` (one word, for the
    messages); False with one error line (and a refused row in the station's audit) when none
    is set or it is wrong."""
    problem = password_problem(config_dir=config_dir)
    if problem is not None:
        _err(f"{action}: {problem}")
        return False
    try:
        password = _read_line("engineer password: ")
    except (EOFError, KeyboardInterrupt):
        _err(f"{action}: no password read")
        return False
    if not check_password(password, config_dir=config_dir):
        try:
            record_station_audit("approve-refused" if action.startswith("approve") else "password-refused", who=who,
                                 role_before=OPERATOR, role_after=OPERATOR, config_dir=config_dir)
        except (sqlite3.Error, OSError) as e:
            print(f"inspector: warning: {station_audit_file(config_dir)}: audit row not recorded ({e})", file=sys.stderr)
        _err(f"{action}: wrong engineer password; nothing changed")
        return False
    return True


def _may_reset(path: Path) -> str | None:
    """Why this process may not reset the password in ``path`` (None: it may)."""
    if not hasattr(os, "geteuid") or os.geteuid() == 0:
        return None
    try:
        owner = path.stat().st_uid
    except FileNotFoundError:
        return None
    except OSError as e:
        return f"{path}: cannot be read ({e.strerror or e})"
    if owner != os.geteuid():
        return f"only the owner of {path} (uid {owner}) or root may reset the engineer password"
    return None


def _set_password_cmd(args) -> int:
    who = getattr(args, "who", None) or login_name()
    reset = bool(getattr(args, "reset", False))
    path = roles_file()
    if reset:
        problem = _may_reset(path)
        if problem:
            _err(f"set-password --reset: {problem}; nothing changed")
            return 2
    elif password_problem() is None and not ask_engineer("set-password", who):
        return 2  # a password is set: the current one first
    try:
        password = _read_new_password()
    except (EOFError, KeyboardInterrupt):
        _err("set-password: no password read")
        return 2
    if password is None:
        _err("set-password: the two passwords differ; nothing changed")
        return 2
    problem = _password_error(password)
    if problem:
        _err(f"set-password: {problem} (at least {MIN_PASSWORD_LENGTH}); nothing changed")
        return 2
    try:
        path = set_password(password)
    except OSError as e:
        _err(f"set-password: {roles_file()}: cannot write ({e.strerror or e})")
        return 3
    action = "password-reset" if reset else "password-set"
    try:
        record_station_audit(action, who=who, role_before=None, role_after=ENGINEER)
    except (sqlite3.Error, OSError) as e:
        print(f"inspector: warning: {station_audit_file()}: audit row {action!r} not recorded ({e})", file=sys.stderr)
    if reset:
        print(f"inspector: warning: the engineer password was reset without the current one; recorded in "
              f"{station_audit_file()}", file=sys.stderr)
    print(f"engineer password set ({path})")
    return 0


def _production_cmd(args) -> int:
    if args.state is None:
        print(f"production mode is {'on' if production_mode() else 'off'} ({roles_file()})")
        return 0
    who = args.who or login_name()
    if not ask_engineer(f"production {args.state}", who):
        return 2
    try:
        set_production_mode(args.state == "on", who)
    except (OSError, ValueError, sqlite3.Error) as e:
        _err(f"production: {roles_file()}: cannot write ({e})")
        return 3
    print(f"production mode is {args.state}: " + ("the operator role runs only approved recipes"
                                                   if args.state == "on" else "any valid recipe runs"))
    return 0


def _audit_cmd(args) -> int:
    from inspector.errors import InputError

    if args.last is not None and args.last < 1:
        _err(f"--last: expected a number >= 1, got {args.last}")
        return 2
    outdir = None if args.outdir is None else Path(args.outdir)
    if getattr(args, "verify", False):
        try:
            report = verify_audit(outdir)
        except InputError as e:
            _err(str(e))
            return 3
        where = _audit_path(outdir, None)
        if not report.ok:
            _err(f"{where}: {report.summary()}")
            return 1
        print(f"{where}: {report.summary()}")
        return 0
    try:
        rows = read_audit(outdir, last=args.last)
    except InputError as e:
        _err(str(e))
        return 3
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'at (UTC)':24s} {'who':16s} {'action':16s} {'role':20s} recipe")
    for r in rows:
        role = f"{r['role_before'] or '-'} -> {r['role_after'] or '-'}"
        recipe = ""
        if r["action"] == "recipe-change":
            before = f"{r['recipe_before']} ({(r['hash_before'] or 'none')[:12]})" if r["recipe_before"] else "none"
            after = f"{r['recipe_after']} ({(r['hash_after'] or 'none')[:12]})" if r["recipe_after"] else "none"
            recipe = f"{before} -> {after}"
        elif r["recipe_after"]:
            recipe = f"{r['recipe_after']} ({(r['hash_after'] or 'none')[:12]})"
        print(f"{r['at'][:23]:24s} {(r['who'] or '-')[:16]:16s} {r['action']:16s} {role:20s} {recipe}".rstrip())
    print(f"{len(rows)} audit rows")
    return 0


def run(args) -> int:
    """Run ``inspector roles ...`` (exit 0; 1 a broken hash chain (--verify); 2 invalid input or
    a wrong password; 3 a file cannot be read or written)."""
    if args.roles_command == "set-password":
        return _set_password_cmd(args)
    if args.roles_command == "production":
        return _production_cmd(args)
    return _audit_cmd(args)
