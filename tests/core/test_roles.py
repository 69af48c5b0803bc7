"""Roles: the engineer password (hash only, 0600), the role session with its idle fallback,
and the audit rows in OUTDIR/history.sqlite beside the inspections."""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sqlite3
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from inspector import roles, roles_password

PASSWORD = "correct-horse-42"


@pytest.fixture
def config(tmp_path, monkeypatch):
    """A private configuration folder (INSPECTOR_CONFIG_DIR), never the user's."""
    d = tmp_path / "config"
    monkeypatch.setenv("INSPECTOR_CONFIG_DIR", str(d))
    return d


@pytest.fixture
def fast_hash(monkeypatch):
    """The smallest iteration count allowed, so a test can log in many times."""
    monkeypatch.setattr(roles_password, "PBKDF2_ITERATIONS", 200_000)


class FakeClock:
    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def roles_cli(*argv: str) -> int:
    ap = argparse.ArgumentParser(prog="inspector")
    sub = ap.add_subparsers(dest="command", required=True)
    roles.add_parser(sub)
    return roles.run(ap.parse_args(list(argv)))


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- password


def test_only_a_salted_hash_is_stored_mode_0600(config):
    path = roles.set_password(PASSWORD)
    assert path == config / "roles.json"
    raw = path.read_bytes()
    assert PASSWORD.encode() not in raw
    assert PASSWORD.encode().hex().encode() not in raw
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    rec = json.loads(raw)["engineer"]
    assert rec["algorithm"] == "pbkdf2_sha256"
    assert rec["iterations"] >= 200_000
    salt = bytes.fromhex(rec["salt"])
    assert len(salt) == 16
    assert bytes.fromhex(rec["hash"]) == hashlib.pbkdf2_hmac("sha256", PASSWORD.encode(), salt, rec["iterations"])
    assert [p.name for p in config.iterdir()] == ["roles.json"]  # no temporary file left behind

    assert roles.check_password(PASSWORD)
    assert not roles.check_password(PASSWORD + "x")
    assert not roles.check_password("")


def test_salt_is_random_and_a_new_password_replaces_the_old(config, fast_hash):
    roles.set_password(PASSWORD)
    first = json.loads((config / "roles.json").read_text())["engineer"]
    roles.set_password("another-password")
    second = json.loads((config / "roles.json").read_text())["engineer"]
    assert first["salt"] != second["salt"]
    assert roles.check_password("another-password")
    assert not roles.check_password(PASSWORD)


def test_no_password_set_locks_engineer_mode_with_a_message(config, tmp_path):
    assert not roles.password_is_set()
    assert not roles.check_password("anything-at-all")
    msg = roles.password_problem()
    assert "no engineer password is set" in msg and "inspector roles set-password" in msg
    session = roles.RoleSession(tmp_path / "out", clock=FakeClock())
    assert session.login_engineer("anything-at-all", "ann") is False
    assert session.role == roles.OPERATOR
    assert [r["action"] for r in roles.read_audit(tmp_path / "out")] == ["login-refused"]


def test_unreadable_roles_file_is_reported_not_a_crash(config):
    config.mkdir()
    (config / "roles.json").write_text("{not json")
    assert not roles.password_is_set()
    assert not roles.check_password(PASSWORD)
    assert "cannot be read" in roles.password_problem()


def test_explicit_config_dir_and_default_location(tmp_path, monkeypatch, fast_hash):
    monkeypatch.delenv("INSPECTOR_CONFIG_DIR", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert roles.roles_file() == tmp_path / "home" / ".config" / "inspector" / "roles.json"
    roles.set_password(PASSWORD, config_dir=tmp_path / "elsewhere")
    assert roles.check_password(PASSWORD, config_dir=tmp_path / "elsewhere")
    assert not roles.password_is_set()  # the default location has none


def test_short_password_refused_by_the_function(config):
    with pytest.raises(ValueError, match="shorter than 8"):
        roles.set_password("short")
    with pytest.raises(ValueError, match="empty"):
        roles.set_password("")
    assert not (config / "roles.json").exists()


# --------------------------------------------------------------------------- inspector roles set-password


def test_set_password_from_piped_stdin(config, monkeypatch, capsys):
    monkeypatch.setattr(sys, "stdin", io.StringIO(PASSWORD + "\n"))
    assert roles_cli("roles", "set-password") == 0
    assert "engineer password set" in capsys.readouterr().out
    assert roles.check_password(PASSWORD)
    assert PASSWORD not in (config / "roles.json").read_text()


@pytest.mark.parametrize("line", ["\n", "", "short\n"])
def test_set_password_refuses_empty_or_short_exit_2(config, monkeypatch, capsys, line):
    monkeypatch.setattr(sys, "stdin", io.StringIO(line))
    assert roles_cli("roles", "set-password") == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("inspector: error: set-password:")
    assert not (config / "roles.json").exists()


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_set_password_on_a_terminal_asks_twice(config, monkeypatch, capsys):
    import getpass

    answers = iter([PASSWORD, PASSWORD + "-typo"])
    prompts = []
    monkeypatch.setattr(sys, "stdin", _Tty(""))
    monkeypatch.setattr(getpass, "getpass", lambda prompt="": prompts.append(prompt) or next(answers))
    assert roles_cli("roles", "set-password") == 2
    assert "differ" in capsys.readouterr().err
    assert len(prompts) == 2 and not (config / "roles.json").exists()
    answers = iter([PASSWORD, PASSWORD])
    assert roles_cli("roles", "set-password") == 0
    assert roles.check_password(PASSWORD)


def test_set_password_through_a_real_pipe(config, tmp_path):
    """A script pipes the password into the command (stdin is not a terminal)."""
    script = (
        "import argparse, sys\n"
        "from inspector import roles\n"
        "ap = argparse.ArgumentParser(prog='inspector'); sub = ap.add_subparsers(dest='command')\n"
        "roles.add_parser(sub)\n"
        "sys.exit(roles.run(ap.parse_args(['roles', 'set-password'])))\n"
    )
    env = {**os.environ, "INSPECTOR_CONFIG_DIR": str(config)}
    p = subprocess.run([sys.executable, "-c", script], input=PASSWORD + "\n", text=True, capture_output=True,
                       env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    assert roles.check_password(PASSWORD)
    p = subprocess.run([sys.executable, "-c", script], input=PASSWORD + "\n1234567\n", text=True, capture_output=True,
                       env=env, timeout=120)  # the current password, then a new one too short
    assert p.returncode == 2
    assert "shorter than 8" in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert roles.check_password(PASSWORD)  # unchanged


# --------------------------------------------------------------------------- the session and the audit


def test_login_refused_then_login_logout_audited(config, fast_hash, tmp_path):
    roles.set_password(PASSWORD)
    out = tmp_path / "out"
    s = roles.RoleSession(out, clock=FakeClock())
    assert s.role == roles.OPERATOR and not s.allowed("edit-recipe") and s.allowed("inspect")
    assert s.login_engineer("wrong-password", "ann") is False
    assert s.role == roles.OPERATOR
    assert s.login_engineer(PASSWORD, "ann") is True
    assert s.role == roles.ENGINEER and s.user == "ann"
    assert s.allowed("edit-recipe") and s.allowed("choose-recipe") and s.allowed("export")
    assert s.logout() is True
    assert s.logout() is False  # already operator: nothing recorded
    assert s.role == roles.OPERATOR and s.user is None

    rows = roles.read_audit(out)
    assert [(r["action"], r["who"], r["role_before"], r["role_after"]) for r in rows] == [
        ("login-refused", "ann", "operator", "operator"),
        ("login", "ann", "operator", "engineer"),
        ("logout", "ann", "engineer", "operator"),
    ]
    for r in rows:
        assert r["at"].endswith("+00:00")  # UTC ISO-8601
        assert r["recipe_before"] is None and r["hash_after"] is None
    with pytest.raises(ValueError):
        s.login_engineer(PASSWORD, "  ")


def test_idle_fallback_with_a_fake_clock(config, fast_hash, tmp_path):
    roles.set_password(PASSWORD)
    clock = FakeClock()
    out = tmp_path / "out"
    s = roles.RoleSession(out, idle_s=300, clock=clock)
    assert s.login_engineer(PASSWORD, "bob")
    clock.t += 299.0
    assert not s.check_idle() and s.role == roles.ENGINEER
    s.touch()  # activity restarts the countdown
    clock.t += 299.0
    assert s.role == roles.ENGINEER
    assert s.idle_remaining() == pytest.approx(1.0)
    clock.t += 1.0
    assert s.check_idle() is True
    assert s.role == roles.OPERATOR and s.user is None
    assert s.check_idle() is False  # once
    rows = roles.read_audit(out)
    assert [(r["action"], r["who"]) for r in rows] == [("login", "bob"), ("idle-logout", "bob")]

    # Reading the role applies the fallback even without a timer, and activity after the
    # deadline does not revive the session.
    assert s.login_engineer(PASSWORD, "bob")
    clock.t += 1000.0
    s.touch()
    assert s.role == roles.OPERATOR
    assert [r["action"] for r in roles.read_audit(out)][-1] == "idle-logout"

    short = roles.RoleSession(None, idle_s=5, clock=clock)  # no outdir: nothing recorded
    assert short.login_engineer(PASSWORD, "cy")
    clock.t += 5
    assert short.role == roles.OPERATOR


def test_recipe_change_rows_carry_paths_and_hashes(config, fast_hash, tmp_path, recipes_dir):
    roles.set_password(PASSWORD)
    out = tmp_path / "out"
    before = tmp_path / "before.toml"
    before.write_bytes((recipes_dir / "demo.toml").read_bytes())
    after = tmp_path / "after.toml"
    after.write_text(before.read_text().replace("voxel_mm = 0.5", "voxel_mm = 0.4"))
    s = roles.RoleSession(out, clock=FakeClock())
    assert s.login_engineer(PASSWORD, "dee")
    s.record_recipe_change("dee", before, after)
    s.record_recipe_change("dee", None, after)  # a first recipe: nothing before
    rows = roles.read_audit(out, last=2)
    first, second = rows
    assert first["action"] == "recipe-change" and first["who"] == "dee"
    assert first["role_before"] == first["role_after"] == "engineer"
    assert first["recipe_before"] == str(before.resolve()) and first["recipe_after"] == str(after.resolve())
    assert first["hash_before"] == sha(before) and first["hash_after"] == sha(after)
    assert first["hash_before"] != first["hash_after"]
    assert second["recipe_before"] is None and second["hash_before"] is None
    assert second["hash_after"] == sha(after)
    assert len(roles.read_audit(out)) == 3  # the login too


def test_audit_shares_history_sqlite_with_the_inspections(config, fast_hash, tmp_path):
    from inspector.history_store import HISTORY_FILE, SCHEMA, read_history

    out = tmp_path / "out"
    out.mkdir()
    con = sqlite3.connect(out / HISTORY_FILE)
    con.executescript(SCHEMA)  # what inspector run creates
    con.execute("INSERT INTO inspections (inspected_at, capture, recipe, verdict, n_defects) "
                "VALUES ('2026-12-01T00:00:00+00:00', 'cap', 'demo', 'pass', 0)")
    con.commit()
    con.close()
    roles.set_password(PASSWORD)
    s = roles.RoleSession(out, clock=FakeClock())
    assert s.login_engineer(PASSWORD, "eve")
    assert [r["capture"] for r in read_history(out)] == ["cap"]
    assert [r["action"] for r in roles.read_audit(out)] == ["login"]
    con = sqlite3.connect(out / HISTORY_FILE)
    try:
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert con.execute("PRAGMA user_version").fetchone()[0] == 1  # the history's, untouched
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        assert {"inspections", "defects", "audit"} <= tables
    finally:
        con.close()
    # An inspections-only history has no audit rows yet: an empty list, not an error.
    other = tmp_path / "other"
    other.mkdir()
    con = sqlite3.connect(other / HISTORY_FILE)
    con.executescript(SCHEMA)
    con.close()
    assert roles.read_audit(other) == []


def test_unwritable_history_is_a_warning_not_a_crash(config, fast_hash, tmp_path, capsys):
    roles.set_password(PASSWORD)
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    s = roles.RoleSession(blocked, clock=FakeClock())
    assert s.login_engineer(PASSWORD, "fay") is True
    assert s.role == roles.ENGINEER
    s.record_recipe_change("fay", None, None)
    assert s.logout()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3
    assert all(line.startswith("inspector: warning:") and "not recorded" in line for line in err)


def test_record_audit_refuses_unknown_actions(tmp_path):
    with pytest.raises(ValueError, match="unknown audit action"):
        roles.record_audit(tmp_path, "reboot", who="x", role_before=None, role_after=None)


# --------------------------------------------------------------------------- inspector roles audit


def test_audit_command_table_json_last_and_errors(config, fast_hash, tmp_path, capsys):
    roles.set_password(PASSWORD)
    out = tmp_path / "out"
    s = roles.RoleSession(out, clock=FakeClock())
    s.login_engineer("nope-nope", "gil")
    s.login_engineer(PASSWORD, "gil")
    recipe = tmp_path / "r.toml"
    recipe.write_text("[recipe]\nname = 'r'\n")
    s.record_recipe_change("gil", None, recipe)
    s.logout()
    capsys.readouterr()

    assert roles_cli("roles", "audit", str(out)) == 0
    text = capsys.readouterr().out
    for word in ("login-refused", "login", "recipe-change", "logout", "gil", "engineer -> operator",
                 sha(recipe)[:12], "4 audit rows"):
        assert word in text

    assert roles_cli("roles", "audit", str(out), "--last", "2", "--json") == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["action"] for r in rows] == ["recipe-change", "logout"]
    assert rows[0]["hash_after"] == sha(recipe)

    assert roles_cli("roles", "audit", str(out), "--last", "0") == 2
    assert "--last" in capsys.readouterr().err
    assert roles_cli("roles", "audit", str(tmp_path / "nothing-here")) == 3
    err = capsys.readouterr().err
    assert "no history" in err and len(err.strip().splitlines()) == 1


def test_module_is_qt_free():
    src = Path(roles.__file__).read_text()
    for name in ("PySide6", "PyQt", "pyvista"):
        assert name not in src


# --------------------------------------------------------------------------- a record you can trust (issue 27)


def _sql(path: Path, *statements: str) -> None:
    con = sqlite3.connect(path)
    try:
        for s in statements:
            con.execute(s)
        con.commit()
    finally:
        con.close()


def test_set_password_needs_the_current_one_and_is_audited(config, fast_hash, monkeypatch, capsys):
    monkeypatch.setattr(sys, "stdin", io.StringIO(PASSWORD + "\n"))
    assert roles_cli("roles", "set-password", "--who", "erin") == 0  # the first one: nothing to ask
    monkeypatch.setattr(sys, "stdin", io.StringIO("not-the-password\nnew-password-1\n"))
    assert roles_cli("roles", "set-password", "--who", "mallory") == 2
    err = capsys.readouterr().err
    assert "wrong engineer password; nothing changed" in err and len(err.strip().splitlines()) == 1
    assert roles.check_password(PASSWORD) and not roles.check_password("new-password-1")
    monkeypatch.setattr(sys, "stdin", io.StringIO(PASSWORD + "\nnew-password-1\n"))
    assert roles_cli("roles", "set-password", "--who", "erin") == 0
    assert roles.check_password("new-password-1")
    rows = roles.read_audit(None)
    assert [(r["action"], r["who"]) for r in rows] == [("password-set", "erin"), ("password-refused", "mallory"),
                                                        ("password-set", "erin")]
    assert roles.station_audit_file() == config / "audit.sqlite"
    assert roles_cli("roles", "audit", "--verify") == 0
    assert "chain intact: 3 rows from id 1" in capsys.readouterr().out


def test_a_forgotten_password_is_reset_by_the_files_owner_and_the_reset_is_recorded(config, fast_hash, monkeypatch,
                                                                                       capsys):
    roles.set_password(PASSWORD)
    monkeypatch.setattr(sys, "stdin", io.StringIO("recovered-password\n"))
    assert roles_cli("roles", "set-password", "--reset", "--who", "admin") == 0
    out = capsys.readouterr()
    assert "reset without the current one; recorded in" in out.err and roles.check_password("recovered-password")
    assert [r["action"] for r in roles.read_audit(None)] == ["password-reset"]
    # someone who does not own roles.json (and is not root) may not
    monkeypatch.setattr(os, "geteuid", lambda: 4242)
    monkeypatch.setattr(sys, "stdin", io.StringIO("another-password\n"))
    assert roles_cli("roles", "set-password", "--reset") == 2
    assert "only the owner of" in capsys.readouterr().err and roles.check_password("recovered-password")


def test_audit_verify_names_an_edited_or_removed_row(config, fast_hash, tmp_path, capsys):
    roles.set_password(PASSWORD)
    out = tmp_path / "out"
    s = roles.RoleSession(out, clock=FakeClock())
    for _ in range(3):
        assert s.login_engineer(PASSWORD, "alice")
        assert s.logout()
    db = out / "history.sqlite"
    assert roles_cli("roles", "audit", str(out), "--verify") == 0
    assert "chain intact: 6 rows from id 1" in capsys.readouterr().out
    _sql(db, "UPDATE audit SET who = 'bob' WHERE id = 3")  # alice -> bob
    assert roles_cli("roles", "audit", str(out), "--verify") == 1
    err = capsys.readouterr().err
    assert "row id 3 (login by bob) was changed after it was written" in err and len(err.strip().splitlines()) == 1
    _sql(db, "UPDATE audit SET who = 'alice' WHERE id = 3")
    assert roles_cli("roles", "audit", str(out), "--verify") == 0
    capsys.readouterr()
    _sql(db, "DELETE FROM audit WHERE id IN (4, 5)")
    assert roles_cli("roles", "audit", str(out), "--verify") == 1
    assert "2 rows removed before row id 6 (logout by alice): ids 4 to 5 missing" in capsys.readouterr().err
    assert roles_cli("roles", "audit", str(tmp_path / "nothing"), "--verify") == 3


def test_an_older_audit_table_is_rebuilt_with_its_rows_and_the_chain_starts_after(config, fast_hash, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    old = roles.AUDIT_SCHEMA.replace(",\n    chain TEXT", "")
    old = old[:old.index("CHECK (")] + "CHECK (action IN ('login', 'logout', 'idle-logout', 'login-refused', " \
        "'recipe-change')),\n" + old[old.index("    role_before"):]
    _sql(out / "history.sqlite", *[s for s in old.split(";") if s.strip()],
         "INSERT INTO audit (at, who, action) VALUES ('2026-01-01T00:00:00+00:00', 'carl', 'login')",
         "INSERT INTO audit (at, who, action) VALUES ('2026-01-01T00:01:00+00:00', 'carl', 'logout')")
    roles.record_audit(out, "unapproved-run", who="dora", role_before="operator", role_after="operator")
    rows = roles.read_audit(out)
    assert [(r["id"], r["who"], r["action"]) for r in rows] == [(1, "carl", "login"), (2, "carl", "logout"),
                                                                (3, "dora", "unapproved-run")]
    report = roles.verify_audit(out)
    assert report.ok and report.unchained == 2 and report.first_id == 3
    assert roles_cli("roles", "audit", str(out), "--verify") == 0
    assert "the 2 rows before id 3 were written before the chain" in capsys.readouterr().out


def test_production_mode_needs_the_engineer_password(config, fast_hash, monkeypatch, capsys):
    assert roles_cli("roles", "production") == 0 and "production mode is off" in capsys.readouterr().out
    monkeypatch.setattr(sys, "stdin", io.StringIO("whatever-it-is\n"))
    assert roles_cli("roles", "production", "on") == 2  # no password set: locked
    assert "no engineer password is set" in capsys.readouterr().err and not roles.production_mode()
    roles.set_password(PASSWORD)
    monkeypatch.setattr(sys, "stdin", io.StringIO("wrong-password\n"))
    assert roles_cli("roles", "production", "on") == 2 and not roles.production_mode()
    monkeypatch.setattr(sys, "stdin", io.StringIO(PASSWORD + "\n"))
    assert roles_cli("roles", "production", "on", "--who", "erin") == 0 and roles.production_mode()
    assert [r["action"] for r in roles.read_audit(None)] == ["password-refused", "production-on"]
