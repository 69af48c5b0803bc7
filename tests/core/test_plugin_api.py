"""The plugin API (issue 16, items 5 and 6): the generated reference and its meta-tests,
the API version a plugin declares, `inspector plugins` (distribution, version, what each
provides, blocked), `--block` and `--plugin`, per-plugin recipe settings, and sub-commands
registered through ``inspector_register_commands``."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pytest
from test_plugin_isolation import make_dist

from inspector import API_VERSION, hookimpl
from inspector.errors import PluginError, RecipeError
from inspector.manager import api_problem, create_plugin_manager
from inspector.params import param
from inspector.recipe import parse_recipe
from inspector.registry import CommandSpec
from inspector_frontends.cli import main
from inspector_tools.plugin_docs import fixture_names, hook_names, public_names, reference_markdown

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "docs" / "plugins.md"
PY = sys.executable


# --------------------------------------------------------------------------- reference
def test_the_reference_in_the_repository_is_the_generated_one():
    """docs/plugins.md is what `inspector plugin reference` writes now: regenerate it
    (`inspector plugin reference docs/plugins.md`) after changing a hook, an API name or
    a fixture."""
    assert REFERENCE.read_text(encoding="utf-8") == reference_markdown()


def test_every_hook_public_name_and_fixture_is_documented():
    text = REFERENCE.read_text(encoding="utf-8")
    for name in hook_names():
        assert f"### `{name}`" in text, f"hook {name} is not in docs/plugins.md"
    for name in public_names():
        assert re.search(rf"^### `{re.escape(name)}` \(", text, re.M), f"inspector.api.{name} is not in docs/plugins.md"
    assert set(fixture_names()) >= {"inspector_pm", "inspector_capture", "inspector_recipe", "inspector_run"}
    for name in fixture_names():
        assert f"### `{name}` (fixture)" in text
    assert "(no docstring)" not in text
    assert "## Writing a driver" in text and "read_capture(folder) -> Capture" in text


def test_every_hook_is_implemented_by_a_test():
    """As datasette's meta-test: each hook is implemented (``def inspector_...(``) in a test."""
    text = "".join(p.read_text() for p in (ROOT / "tests").rglob("test_*.py"))
    for name in hook_names():
        assert re.search(rf"def {name}\(", text), f"no test implements {name}"


def test_the_public_api_is_importable_and_versioned():
    import inspector.api as api

    assert api.API_VERSION == API_VERSION and re.fullmatch(r"\d+\.\d+", API_VERSION)
    for name in api.__all__:
        assert getattr(api, name) is not None
    from inspector.capture_folder import read_capture

    assert api.read_capture is read_capture


# --------------------------------------------------------------------------- API version
@pytest.mark.parametrize(("spec", "ok"), [
    (">=1.0,<2", True), ("~=1.0", True), ("1.0", True), (">=1.1", False), ("<1", False), ("!=1.0", False),
    (">=0.9, <1.5", True), ("~=0.9", False),
])
def test_api_ranges(spec, ok):
    assert (api_problem(SimpleNamespace(INSPECTOR_API=spec), "1.0") is None) == ok


def test_a_malformed_api_range_is_a_problem():
    assert "not a version range" in api_problem(SimpleNamespace(INSPECTOR_API="newest"), "1.0")
    assert api_problem(SimpleNamespace(), "1.0") is None


def test_a_plugin_for_another_api_is_disabled_with_one_line(tmp_path, monkeypatch):
    make_dist(tmp_path, "acme_future", "acme-future", "3.0", """
from inspector import hookimpl
from inspector.registry import StageSpec
INSPECTOR_API = ">=2.0,<3"

@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.future", run=lambda c, p: c))
""")
    monkeypatch.syspath_prepend(str(tmp_path))
    lines: list[str] = []
    pm = create_plugin_manager(warn=lines.append)
    assert lines == [f"inspector: warning: plugin 'acme_future' (acme-future 3.0) disabled: needs inspector plugin API "
                     f">=2.0,<3, this inspector provides API {API_VERSION}; install a version of acme-future made "
                     f"for API {API_VERSION}, or block it with INSPECTOR_BLOCK_PLUGINS=acme_future"]
    assert "classify.future" not in pm.stages and "segment.threshold" in pm.stages
    with pytest.raises(RecipeError, match="stage classify.future is not available: plugin 'acme_future'"):
        parse_recipe({"stages": [{"use": "classify.future"}]}, pm)


def test_a_plugin_for_another_api_registered_from_code_raises():
    with pytest.raises(PluginError, match="needs inspector plugin API >=9"):
        create_plugin_manager(load_entrypoints=False, plugins=[SimpleNamespace(INSPECTOR_API=">=9")])


# --------------------------------------------------------------------------- plugins, --block
def _cli_json(*argv: str, env: dict[str, str] | None = None) -> tuple[dict, str]:
    out = subprocess.run([PY, "-m", "inspector_frontends.cli", *argv, "plugins", "--json"], capture_output=True, text=True,
                         env=env)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout), out.stderr


def test_plugins_lists_distribution_version_what_each_provides_and_blocked(capsys):
    from inspector import __version__

    assert main(["--block", "sim,genicam", "plugins", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    info = {p["name"]: p for p in doc["plugin_info"]}
    assert info["bcps"] == {"name": "bcps", "dist": "inspector-bcps", "version": __version__, "builtin": True,
                            "file": None, "status": "loaded", "problems": [],
                            "provides": {"stage": ["bcps.ray", "bcps.surface"], "driver": [], "command": [],
                                         "settings": [], "hook": []}}
    assert info["history"]["provides"]["command"] == ["history"] and info["history"]["provides"]["hook"] == [
        "on_result", "on_run_end", "on_run_start"]
    assert info["sim"]["status"] == "blocked" and info["sim"]["provides"]["driver"] == []
    assert info["genicam"]["status"] == "blocked"
    assert doc["blocked"] == ["genicam", "sim"] and "sim" not in doc["drivers"]
    assert "simulate" not in doc["commands"] and doc["commands"]["bench"]["plugin"] == "bench"
    assert doc["commands"]["demo"]["plugin"] == "demo" and doc["commands"]["plugin"]["plugin"] == "plugin"
    assert doc["api_version"] == API_VERSION


def test_plugins_in_words_marks_the_blocked(capsys, monkeypatch):
    monkeypatch.setenv("INSPECTOR_BLOCK_PLUGINS", "aravis")
    assert main(["--block", "bench", "plugins"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^  aravis \(inspector-bcps [^)]*, built-in\)  \[BLOCKED\]", out, re.M)
    assert re.search(r"^  bench \(inspector-bcps [^)]*, built-in\)  \[BLOCKED\]", out, re.M)
    assert re.search(r"^  sim \(inspector-bcps [^)]*\): driver sim; command simulate$", out, re.M)
    import os

    assert os.environ["INSPECTOR_BLOCK_PLUGINS"] == "aravis"  # --block does not outlive the command


def test_a_blocked_plugins_command_is_gone(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--block", "history", "history", "out"])
    assert e.value.code == 2
    assert "invalid choice: 'history'" in capsys.readouterr().err


# --------------------------------------------------------------------------- --plugin FILE.py
DEV = '''
from dataclasses import dataclass
from inspector import hookimpl
from inspector.params import param
from inspector.registry import CommandSpec, StageSpec


@dataclass(frozen=True)
class Settings:
    threshold: float = param(1.0, "a threshold", min=0.0)


def _parser(sub):
    p = sub.add_parser("hello", help="says hello")
    p.add_argument("who")


def _run(args):
    print(f"hello {args.who}; stages: {len(args.plugin_manager.stages.names())}")
    return 0


@hookimpl
def inspector_register_commands(registry):
    registry.add(CommandSpec("hello", _parser, _run, "says hello"))


@hookimpl
def inspector_register_settings(registry):
    registry.add(Settings, "the dev plugin's threshold")


@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.dev", run=lambda c, p: c.evolve(extras={**c.extras, "dev": 1})))
'''


def test_plugin_file_loads_a_local_module_for_development(tmp_path, capsys):
    f = tmp_path / "devplug.py"
    f.write_text(DEV)
    assert main(["--plugin", str(f), "hello", "world"]) == 0
    assert capsys.readouterr().out.startswith("hello world; stages: ")
    assert main(["--plugin", str(f), "plugins", "--json"]) == 0
    info = {p["name"]: p for p in json.loads(capsys.readouterr().out)["plugin_info"]}
    assert info["devplug"]["file"] == str(f) and info["devplug"]["dist"] is None
    assert info["devplug"]["provides"]["command"] == ["hello"] and info["devplug"]["provides"]["settings"] == ["devplug"]
    with pytest.raises(SystemExit):  # not loaded without --plugin
        main(["hello", "world"])


def test_a_broken_plugin_file_is_one_line_and_exit_2(tmp_path, capsys):
    f = tmp_path / "bad.py"
    f.write_text("import not_installed_anywhere\n")
    assert main(["--plugin", str(f), "plugins"]) == 2
    err = capsys.readouterr().err
    assert err == (f"inspector: error: plugin 'bad' (file {f}): cannot be imported: ModuleNotFoundError: "
                   f"No module named 'not_installed_anywhere' (at {f}:1)\n")
    assert main(["--plugin", str(tmp_path / "missing.py"), "plugins"]) == 2
    assert "not a Python file" in capsys.readouterr().err


def test_a_recipe_cannot_load_code(tmp_path):
    f = tmp_path / "devplug.py"
    f.write_text(DEV)
    pm = create_plugin_manager()
    for key in ("plugin", "plugins_files", "import"):
        with pytest.raises(RecipeError):
            parse_recipe({key: str(f), "stages": [{"use": "segment.threshold"}]}, pm)
    with pytest.raises(RecipeError, match="no plugin 'devplug' with settings"):
        parse_recipe({"plugins": {"devplug": {"threshold": 2.0}}, "stages": [{"use": "segment.threshold"}]}, pm)


# --------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class LineSettings:
    line: str = param("line-1", "production line")
    speed: float = param(1.0, "belt speed, m/s", min=0.0, max=5.0)
    stations: tuple[int, ...] = param((1, 2), "stations")


class LinePlugin:
    @hookimpl
    def inspector_register_settings(self, registry):
        registry.add(LineSettings, "where the cell is")


def _recipe(plugins=None):
    doc = {"recipe": {"name": "t"}, "stages": [{"use": "segment.threshold"}]}
    if plugins is not None:
        doc["plugins"] = plugins
    return doc


def test_plugin_settings_are_validated_like_stage_parameters(tmp_path):
    pm = create_plugin_manager(plugins=[LinePlugin()])
    r = parse_recipe(_recipe({"LinePlugin": {"line": "L3", "stations": [4, 5]}}), pm, path=tmp_path / "r.toml")
    assert r.plugins["LinePlugin"] == LineSettings("L3", 1.0, (4, 5))
    assert parse_recipe(_recipe(), pm).plugins["LinePlugin"] == LineSettings()  # defaults
    for table, key in (({"speed": 9.0}, "speed"), ({"speed": float("nan")}, "speed"), ({"line": 3}, "line"),
                       ({"colour": "red"}, "colour"), ({"stations": ["a"]}, "stations")):
        with pytest.raises(RecipeError, match=rf"r\.toml: plugins\.LinePlugin.*{key}"):
            parse_recipe(_recipe({"LinePlugin": table}), pm, path=tmp_path / "r.toml")
    with pytest.raises(RecipeError, match=r"plugins\.nobody: no plugin 'nobody' with settings \(plugins with settings: "
                                          r"LinePlugin, history\)"):
        parse_recipe(_recipe({"nobody": {}}), pm, path=tmp_path / "r.toml")


def test_settings_of_a_blocked_plugin_name_it(tmp_path, monkeypatch):
    make_dist(tmp_path, "acme_line", "acme-line", "1.0", """
from dataclasses import dataclass
from inspector import hookimpl
from inspector.params import param

@dataclass(frozen=True)
class S:
    line: str = param("x", "line")

@hookimpl
def inspector_register_settings(registry):
    registry.add(S)
""")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "acme_line" in create_plugin_manager().settings
    pm = create_plugin_manager(block=["acme_line"])
    with pytest.raises(RecipeError, match="'acme_line' is blocked"):
        parse_recipe(_recipe({"acme_line": {"line": "y"}}), pm)


def test_a_settings_class_of_an_unsupported_type_is_refused_at_registration():
    @dataclass(frozen=True)
    class Bad:
        weights: set[int] = param(frozenset(), "no sets")

    class P:
        @hookimpl
        def inspector_register_settings(self, registry):
            registry.add(Bad)

    with pytest.raises(PluginError, match="settings 'P'.*weights"):
        create_plugin_manager(load_entrypoints=False, plugins=[P()])


# --------------------------------------------------------------------------- commands
def _command_plugin(name: str, add=None, run=None):
    class Cmd:
        @hookimpl
        def inspector_register_commands(self, registry):
            registry.add(CommandSpec(name, add or (lambda sub: sub.add_parser(name)), run or (lambda args: 0)))

    return Cmd()


def test_commands_come_from_the_hook_built_ins_included():
    pm = create_plugin_manager()
    assert {"bench", "experiment", "capture", "history", "import", "simulate", "demo", "gui"} <= set(pm.commands.names())
    assert pm.commands.owner("history") == "history" and pm.commands.owner("import") == "import"


def test_a_command_taking_a_core_name_is_left_out_with_a_warning(capsys):
    from inspector_frontends.cli import build_parser

    pm = create_plugin_manager(plugins=[_command_plugin("run", run=lambda a: 99)])
    parser = build_parser(pm)
    assert "command 'run' is a core command" in capsys.readouterr().err
    args = parser.parse_args(["run", "r.toml", "--out", "o"])
    assert args.command == "run" and args.recipe == "r.toml"


def test_a_command_whose_parser_raises_is_left_out_and_the_others_stay(capsys):
    from inspector_frontends.cli import build_parser

    def boom(sub):
        sub.add_parser("boom")
        raise RuntimeError("vendor argument table missing")

    pm = create_plugin_manager(plugins=[_command_plugin("boom", add=boom)])
    parser = build_parser(pm)
    err = capsys.readouterr().err
    assert "command 'boom' not added: add_parser raised RuntimeError: vendor argument table missing" in err
    assert parser.parse_args(["history", "out"]).command == "history"
    with pytest.raises(SystemExit):
        parser.parse_args(["boom"])


def test_an_invalid_command_spec_disables_its_plugin():
    with pytest.raises(PluginError, match="command 'Bad Name': name must be a lower-case word"):
        create_plugin_manager(load_entrypoints=False, plugins=[_command_plugin("Bad Name")])


def test_two_plugins_with_one_command_name_are_named_both(tmp_path, monkeypatch):
    src = """
from inspector import hookimpl
from inspector.registry import CommandSpec

@hookimpl
def inspector_register_commands(registry):
    registry.add(CommandSpec("plc", lambda sub: sub.add_parser("plc"), lambda args: 0))
"""
    make_dist(tmp_path, "plc_a", "plc-a", "1.0", src)
    make_dist(tmp_path, "plc_b", "plc-b", "1.0", src)
    monkeypatch.syspath_prepend(str(tmp_path))
    lines: list[str] = []
    pm = create_plugin_manager(warn=lines.append)
    assert "plc" not in pm.commands
    assert lines == ["inspector: warning: command 'plc' is registered twice, by plugin 'plc_a' (plc-a 1.0) and by "
                     "plugin 'plc_b' (plc-b 1.0): neither is used; block one with INSPECTOR_BLOCK_PLUGINS=plc_a or "
                     "INSPECTOR_BLOCK_PLUGINS=plc_b"]
