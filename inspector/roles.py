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
Whoever can write that file can set a new password: the protection is the operating
system's account separation, as for any local secret.

Every role switch (login, refused login, logout, idle fallback) and every recipe change is
a row of the ``audit`` table (:data:`AUDIT_SCHEMA`) in ``OUTDIR/history.sqlite``, the
database the ``history`` plugin writes its inspections to; ``inspector roles audit OUTDIR``
lists it. An audit row that cannot be written costs one warning line on stderr, never the
station.

This module is plain Python (no Qt): a GUI drives a :class:`RoleSession`.
"""

from __future__ import annotations

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
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

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
    "read_audit",
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

#: The ``action`` of an audit row.
AUDIT_ACTIONS = ("login", "logout", "idle-logout", "login-refused", "recipe-change")

MIN_PASSWORD_LENGTH = 8
#: PBKDF2-HMAC-SHA256 iterations of a new hash (a stored hash keeps its own count).
PBKDF2_ITERATIONS = 600_000
_ALGORITHM = "pbkdf2_sha256"
_ROLES_FILE = "roles.json"

#: Version 1 of the audit table; it lives beside the ``inspections`` tables of the history
#: plugin in the same file. ``at`` is UTC ISO-8601; ``hash_*`` are the SHA-256 (hex) of the
#: recipe files' bytes, null when there is no file.
AUDIT_SCHEMA = """
CREATE TABLE IF NOT EXISTS audit (
    id INTEGER PRIMARY KEY,
    at TEXT NOT NULL,
    who TEXT,
    action TEXT NOT NULL CHECK (action IN ('login', 'logout', 'idle-logout', 'login-refused', 'recipe-change')),
    role_before TEXT,
    role_after TEXT,
    recipe_before TEXT,
    recipe_after TEXT,
    hash_before TEXT,
    hash_after TEXT
);
CREATE INDEX IF NOT EXISTS audit_at ON audit (at);
"""

_AUDIT_COLUMNS = ("id", "at", "who", "action", "role_before", "role_after",
                  "recipe_before", "recipe_after", "hash_before", "hash_after")


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
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def _history_path(outdir: str | os.PathLike[str]) -> Path:
    from inspector_plugins.history import HISTORY_FILE

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
    needed.

    Raises
    ------
    ValueError
        ``action`` is not one of :data:`AUDIT_ACTIONS`.
    sqlite3.Error, OSError
        The database cannot be written (:class:`RoleSession` turns these into a warning).
    """
    if action not in AUDIT_ACTIONS:
        raise ValueError(f"unknown audit action {action!r} (expected one of {', '.join(AUDIT_ACTIONS)})")
    path = _history_path(outdir)
    path.parent.mkdir(parents=True, exist_ok=True)
    row = (
        (at or datetime.now(timezone.utc)).astimezone(timezone.utc).isoformat(timespec="milliseconds"),
        who,
        action,
        role_before,
        role_after,
        _path_text(recipe_before),
        _path_text(recipe_after),
        file_sha256(recipe_before),
        file_sha256(recipe_after),
    )
    con = sqlite3.connect(str(path), timeout=10.0)
    try:
        con.execute("PRAGMA journal_mode=WAL")
        con.executescript(AUDIT_SCHEMA)
        cur = con.execute(
            "INSERT INTO audit (at, who, action, role_before, role_after, recipe_before, recipe_after,"
            " hash_before, hash_after) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            row,
        )
        con.commit()
        return int(cur.lastrowid or 0)
    finally:
        con.close()


def read_audit(outdir: str | os.PathLike[str], *, last: int | None = None) -> list[dict[str, Any]]:
    """The audit rows of ``outdir``, oldest first (the ``last`` ones only); [] when the
    history holds none.

    Raises
    ------
    inspector.errors.InputError
        No ``history.sqlite`` in ``outdir``, or it cannot be read (the message names it).
    """
    from inspector.errors import InputError

    path = _history_path(outdir)
    if not path.is_file():
        raise InputError(f"{path}: no history (the station and inspector run write it in OUTDIR)")
    from inspector_plugins.history import read_table

    return read_table(path, "audit", _AUDIT_COLUMNS, last=last) or []


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
    """``inspector roles set-password`` and ``inspector roles audit OUTDIR``."""
    p = subparsers.add_parser("roles", help="engineer password and the audit trail of role and recipe changes")
    rsub = p.add_subparsers(dest="roles_command", required=True)
    rsub.add_parser(
        "set-password",
        help="set the engineer password (asked twice on a terminal; else one line read from stdin)",
    )
    a = rsub.add_parser("audit", help="list the logins, logouts and recipe changes recorded in OUTDIR/history.sqlite")
    a.add_argument("outdir", metavar="OUTDIR", help="the station's or inspector run's --out folder")
    a.add_argument("--last", type=int, metavar="N", help="only the last N rows")
    a.add_argument("--json", action="store_true", help="the rows as JSON")


def _err(msg: str) -> None:
    print(f"inspector: error: {msg}", file=sys.stderr)


def _read_new_password() -> str | None:
    """Twice with getpass on a terminal (None when they differ), else one line of stdin."""
    if sys.stdin is not None and sys.stdin.isatty():
        import getpass

        first = getpass.getpass("new engineer password: ")
        if getpass.getpass("again: ") != first:
            return None
        return first
    line = sys.stdin.readline() if sys.stdin is not None else ""
    return line.rstrip("\r\n")


def _set_password_cmd() -> int:
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
    print(f"engineer password set ({path})")
    return 0


def _audit_cmd(args) -> int:
    from inspector.errors import InputError

    if args.last is not None and args.last < 1:
        _err(f"--last: expected a number >= 1, got {args.last}")
        return 2
    try:
        rows = read_audit(Path(args.outdir), last=args.last)
    except InputError as e:
        _err(str(e))
        return 3
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'at (UTC)':24s} {'who':16s} {'action':14s} {'role':20s} recipe")
    for r in rows:
        role = f"{r['role_before'] or '-'} -> {r['role_after'] or '-'}"
        recipe = ""
        if r["action"] == "recipe-change":
            before = f"{r['recipe_before']} ({(r['hash_before'] or 'none')[:12]})" if r["recipe_before"] else "none"
            after = f"{r['recipe_after']} ({(r['hash_after'] or 'none')[:12]})" if r["recipe_after"] else "none"
            recipe = f"{before} -> {after}"
        print(f"{r['at'][:23]:24s} {(r['who'] or '-')[:16]:16s} {r['action']:14s} {role:20s} {recipe}".rstrip())
    print(f"{len(rows)} audit rows")
    return 0


def run(args) -> int:
    """Run ``inspector roles ...`` (exit 0; 2 invalid input; 3 a file cannot be read or written)."""
    if args.roles_command == "set-password":
        return _set_password_cmd()
    return _audit_cmd(args)
