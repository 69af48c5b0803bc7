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

This module is plain Python (no Qt): a GUI drives a :class:`RoleSession`. The password store is
:mod:`inspector.roles_password`, the audit trail :mod:`inspector.roles_audit`; their public
names are also importable from here (:data:`__all__`).
"""

from __future__ import annotations

import getpass
import json
import os
import sqlite3
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from inspector.errors import InputError
from inspector.roles_audit import (
    AUDIT_ACTIONS,
    AUDIT_SCHEMA,
    audit_path,
    file_sha256,
    read_audit,
    record_audit,
    record_station_audit,
    station_audit_file,
    verify_audit,
)
from inspector.roles_password import (
    MIN_PASSWORD_LENGTH,
    check_password,
    config_dir,
    password_error,
    password_is_set,
    password_problem,
    read_config,
    roles_file,
    set_password,
    write_config,
)

__all__ = [
    "OPERATOR",
    "ENGINEER",
    "ROLES",
    "PERMISSIONS",
    "AUDIT_ACTIONS",
    "AUDIT_SCHEMA",
    "MIN_PASSWORD_LENGTH",
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


# --------------------------------------------------------------------------- production mode


def production_mode(*, config_dir: str | os.PathLike[str] | None = None) -> bool:
    """Whether the station is in production mode (``roles.json`` ``"production": true``): in
    the operator role it runs only approved recipes (:mod:`inspector.approval`). False when
    the file is missing or unreadable: a station is switched on explicitly."""
    try:
        return read_config(roles_file(config_dir)).get("production") is True
    except (OSError, ValueError):
        return False


def set_production_mode(on: bool, who: str | None, *, config_dir: str | os.PathLike[str] | None = None) -> Path:
    """Switch production mode (``roles.json``, written atomically) and audit it
    (``production-on``/``production-off`` in the station's audit). The caller checks the
    engineer password first (:func:`check_password`)."""
    path = roles_file(config_dir)
    data = read_config(path)
    data["production"] = bool(on)
    write_config(path, data)
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
        # cycle: inspector.approval imports inspector.roles at its top
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
    problem = password_error(password)
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
        where = audit_path(outdir, None)
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
