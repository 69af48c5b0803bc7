"""``inspector serve`` on a production station (issue 27): a PLC has no login, so the server
runs as the operator and refuses, in one line and before it listens, a recipe no engineer
approved, or one changed since its approval."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import pytest

from inspector import roles, roles_password
from inspector_frontends.cli import main

PASSWORD = "correct-horse-42"
DEFAULT = Path(__file__).resolve().parents[3] / "recipes" / "default.toml"


@pytest.fixture
def production(tmp_path, monkeypatch):
    """A private configuration folder, the engineer password set, the station in production."""
    monkeypatch.setenv("INSPECTOR_CONFIG_DIR", str(tmp_path / "config"))
    monkeypatch.setattr(roles_password, "PBKDF2_ITERATIONS", 200_000)  # hashing is the slow part
    roles.set_password(PASSWORD)
    monkeypatch.setattr(sys, "stdin", io.StringIO(f"{PASSWORD}\n"))
    assert main(["roles", "production", "on", "--who", "erin"]) == 0


def _recipe(folder: Path) -> Path:
    import trimesh

    folder.mkdir()
    trimesh.creation.box(extents=(30.0, 30.0, 30.0)).export(folder / "part.stl")
    path = folder / "cube.toml"
    path.write_text(DEFAULT.read_text().replace('name = "default"', 'name = "default"\nreference = "part.stl"', 1))
    return path


def test_serve_refuses_an_unapproved_recipe_on_a_production_station(production, tmp_path, capsys):
    recipe = _recipe(tmp_path / "recipes")
    out = tmp_path / "out"
    code = main(["serve", str(recipe), "--opcua", "opc.tcp://127.0.0.1:48999", "--security", "none", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "production mode" in err and "cube.toml" in err, err
    assert "Traceback" not in err


def test_serve_accepts_the_recipe_once_approved_and_refuses_it_when_changed(production, tmp_path, monkeypatch, capsys):
    from inspector.approval import approval_problem
    from inspector.manager import create_plugin_manager
    from inspector.recipe import load_recipe

    recipe = _recipe(tmp_path / "recipes")
    monkeypatch.setattr(sys, "stdin", io.StringIO(f"{PASSWORD}\n"))
    assert main(["recipe", "approve", str(recipe), "--who", "erin"]) == 0
    pm = create_plugin_manager()
    assert approval_problem(load_recipe(recipe, pm)) is None  # what the server asks before it serves
    recipe.write_text(recipe.read_text().replace("[[stages]]", "# changed\n[[stages]]", 1))
    capsys.readouterr()
    code = main(["serve", str(recipe), "--opcua", "opc.tcp://127.0.0.1:48999", "--security", "none", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "production mode" in err, err
