"""Production recipes (issue 27): an engineer approves a recipe's content (file and reference
mesh); on a production station ``inspector run`` in the operator role refuses a recipe that is
not approved, or changed since, in one line, unless ``--unapproved`` (a warning and an audit row)."""

from __future__ import annotations

import io
import json
import sqlite3
import sys
from pathlib import Path

import pytest

from inspector import approval, roles, roles_password
from inspector.recipe import load_recipe
from inspector_frontends.cli import main

PASSWORD = "correct-horse-42"
DEFAULT = Path(__file__).resolve().parents[2] / "recipes" / "default.toml"


@pytest.fixture
def station(tmp_path, monkeypatch):
    """A private configuration folder with the engineer password set (cheap hash)."""
    d = tmp_path / "config"
    monkeypatch.setenv("INSPECTOR_CONFIG_DIR", str(d))
    monkeypatch.setattr(roles_password, "PBKDF2_ITERATIONS", 200_000)
    roles.set_password(PASSWORD)
    return d


@pytest.fixture
def recipe(tmp_path):
    """The default recipe with a reference mesh file of its own beside it (a 30 mm cube STL)."""
    import trimesh

    folder = tmp_path / "recipes"
    folder.mkdir()
    trimesh.creation.box(extents=(30.0, 30.0, 30.0)).export(folder / "part.stl")
    text = DEFAULT.read_text().replace('name = "default"', 'name = "default"\nreference = "part.stl"', 1)
    path = folder / "cube.toml"
    path.write_text(text)
    return path


def _stdin(monkeypatch, *lines: str) -> None:
    monkeypatch.setattr(sys, "stdin", io.StringIO("".join(f"{line}\n" for line in lines)))


def _production(monkeypatch, on: bool) -> None:
    _stdin(monkeypatch, PASSWORD)
    assert main(["roles", "production", "on" if on else "off", "--who", "erin"]) == 0


def test_approval_is_of_the_content_and_a_change_of_file_or_mesh_is_seen(station, recipe, pm, monkeypatch, capsys):
    loaded = load_recipe(recipe, pm)
    assert approval.approval_problem(loaded) is None  # not a production station: every valid recipe runs
    _production(monkeypatch, True)
    problem = approval.approval_problem(loaded)
    assert problem is not None and "not approved" in problem and str(recipe) in problem
    assert approval.approval_problem(loaded, role=roles.ENGINEER) is None  # an engineer may try a recipe

    _stdin(monkeypatch, "wrong-password")
    assert main(["recipe", "approve", str(recipe), "--who", "erin"]) == 2
    assert "wrong engineer password" in capsys.readouterr().err and not approval.approvals_file().exists()
    _stdin(monkeypatch, PASSWORD)
    assert main(["recipe", "approve", str(recipe), "--who", "erin"]) == 0
    assert "approved" in capsys.readouterr().out
    assert approval.approval_problem(load_recipe(recipe, pm)) is None
    stored = json.loads(approval.approvals_file().read_text())["approvals"]
    assert len(stored) == 1 and stored[0]["approved_by"] == "erin" and stored[0]["reference"].startswith("sha256:")

    # the recipe file changed: refused, naming what changed and who approved the old one
    recipe.write_text(recipe.read_text().replace("voxel_mm = 0.5", "voxel_mm = 0.6"))
    problem = approval.approval_problem(load_recipe(recipe, pm))
    assert problem is not None and "changed since it was approved (its file differs" in problem and "erin" in problem
    recipe.write_text(recipe.read_text().replace("voxel_mm = 0.6", "voxel_mm = 0.5"))  # back: approved again
    assert approval.approval_problem(load_recipe(recipe, pm)) is None
    # the reference mesh changed (same recipe file): refused
    import trimesh

    trimesh.creation.box(extents=(30.0, 30.0, 31.0)).export(recipe.parent / "part.stl")
    problem = approval.approval_problem(load_recipe(recipe, pm))
    assert problem is not None and "its reference mesh differs" in problem
    # the station's audit has every step, chained
    actions = [r["action"] for r in roles.read_audit(None)]
    assert actions == ["production-on", "approve-refused", "recipe-approve"]
    assert roles.verify_audit(None).ok


def test_run_in_production_mode_refuses_an_unapproved_recipe_in_one_line(station, recipe, small_capture, tmp_path,
                                                                         monkeypatch, capfd):
    _production(monkeypatch, True)
    out = tmp_path / "out"
    argv = ["run", str(recipe), "--capture", str(small_capture), "--out", str(out), "-q"]
    assert main(argv) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("inspector: error: ") and "not approved" in err[0] and "--unapproved" in err[0]
    assert not (out / "history.sqlite").exists()  # nothing inspected
    # told otherwise: it runs, with one warning line and an audit row in the run's history
    assert main([*argv, "--unapproved"]) in (0, 1)
    err = capfd.readouterr().err
    assert "run anyway (--unapproved), recorded in the audit" in err
    rows = roles.read_audit(out)
    assert [r["action"] for r in rows] == ["unapproved-run"] and rows[0]["recipe_after"] == str(recipe.resolve())
    # approved: it runs without a word about approval
    _stdin(monkeypatch, PASSWORD)
    assert main(["recipe", "approve", str(recipe)]) == 0
    capfd.readouterr()
    assert main(argv) in (0, 1)
    assert "approv" not in capfd.readouterr().err
    # --reference replaces the approved mesh: not what was approved
    assert main([*argv, "--reference", "builtin:cube30"]) == 2
    assert "changed since it was approved (its reference mesh differs" in capfd.readouterr().err
    # production mode off: any valid recipe runs
    _production(monkeypatch, False)
    recipe.write_text(recipe.read_text() + "\n# edited\n")
    assert main(argv) in (0, 1)


def test_a_broken_approvals_file_refuses_in_one_line(station, recipe, pm, monkeypatch):
    _production(monkeypatch, True)
    approval.approvals_file().write_text("{ not json")
    problem = approval.approval_problem(load_recipe(recipe, pm))
    assert problem is not None and "approvals.json: cannot be read" in problem and "\n" not in problem


def test_the_digest_covers_the_file_and_the_mesh(recipe, pm):
    a = approval.recipe_digest(load_recipe(recipe, pm))
    b = approval.recipe_digest(load_recipe(recipe, pm, reference="builtin:cube30"))
    assert a[1] == b[1] and a[0] != b[0] and b[2] == "builtin:cube30"
    assert approval.recipe_digest(load_recipe(recipe, pm)) == a  # stable: the same content, the same digest


def test_the_station_audit_is_not_the_run_history(station, tmp_path):
    assert roles.station_audit_file() == station / "audit.sqlite"
    roles.record_station_audit("password-set", who="erin")
    con = sqlite3.connect(station / "audit.sqlite")
    try:
        assert {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")} == {"audit"}
    finally:
        con.close()


def test_an_unreadable_roles_file_fails_closed(station, recipe, pm):
    (station / "roles.json").write_text("{ broken")
    problem = approval.approval_problem(load_recipe(recipe, pm))
    assert problem is not None and "roles.json: cannot be read" in problem and "production mode is unknown" in problem
    assert approval.approval_problem(load_recipe(recipe, pm), role=roles.ENGINEER) is None
