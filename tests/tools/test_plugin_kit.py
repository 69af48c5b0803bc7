"""The plugin author's kit (issue 16, item 5): ``inspector plugin new`` and the pytest plugin
shipped with the product (``inspector_tools.testing``: inspector_pm, inspector_capture,
inspector_recipe, inspector_run)."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import sysconfig
from dataclasses import dataclass
from pathlib import Path

import pytest
from test_plugin_isolation import make_dist

from inspector import hookimpl
from inspector.errors import PluginError, RecipeError
from inspector.manager import create_plugin_manager
from inspector.params import param
from inspector.registry import SettingsRegistry, StageRegistry, StageSpec
from inspector_frontends.cli import main
from inspector_tools.scaffold import write_plugin
from inspector_tools.testing import make_plugin_manager

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable


# --------------------------------------------------------------------------- plugin new
def _throwaway_venv(where: Path) -> Path:
    """A venv whose site-packages also reach this one's (numpy, the product, pytest).

    ``--system-site-packages`` from a venv's Python only reaches the *base* interpreter's
    packages, not this venv's, so a ``.pth`` line adds this venv's site-packages with
    ``site.addsitedir`` (which also runs its ``.pth`` files: the product's editable install).
    ``--without-pip``: this venv's pip, reached the same way, installs into the new one.
    """
    subprocess.run([PY, "-m", "venv", "--system-site-packages", "--without-pip", str(where)], check=True)
    ours = sysconfig.get_paths()["purelib"]
    theirs = subprocess.run([str(where / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                            check=True, capture_output=True, text=True).stdout.strip()
    Path(theirs, "_inspector_parent.pth").write_text(f"import site; site.addsitedir({ours!r})\n")
    return where / "bin" / "python"


@pytest.mark.slow
def test_plugin_new_installs_with_pip_and_passes_its_own_tests(tmp_path):
    """`inspector plugin new acme`, then `pip install -e acme && pytest acme` in a fresh venv:
    the generated stage's output is in result.json and the history (the package's own tests
    check it), and `inspector plugins` there lists the plugin with its distribution."""
    out = subprocess.run([PY, "-m", "inspector_frontends.cli", "plugin", "new", "acme", "--out", str(tmp_path)],
                         capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert f"pip install -e {tmp_path / 'acme'}" in out.stdout
    python = _throwaway_venv(tmp_path / "venv")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "INSPECTOR_BLOCK_PLUGINS")}
    pip = subprocess.run([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check", "--no-deps",
                          "--no-build-isolation", "-e", str(tmp_path / "acme")], capture_output=True, text=True, env=env)
    assert pip.returncode == 0, pip.stdout + pip.stderr
    tests = subprocess.run([str(python), "-m", "pytest", "-q", "-p", "no:cacheprovider", "acme"],
                           capture_output=True, text=True, cwd=tmp_path, env=env)
    assert tests.returncode == 0, tests.stdout[-3000:] + tests.stderr[-2000:]
    assert "6 passed" in tests.stdout
    listing = subprocess.run([str(python), "-m", "inspector_frontends.cli", "plugins", "--json"], capture_output=True, text=True,
                             env=env)
    assert listing.returncode == 0, listing.stderr
    info = {p["name"]: p for p in json.loads(listing.stdout)["plugin_info"]}
    assert info["acme"]["dist"] == "inspector-acme" and info["acme"]["version"] == "0.1.0"
    assert info["acme"]["provides"]["stage"] == ["classify.acme"] and info["acme"]["provides"]["driver"] == ["acme"]
    assert info["acme"]["provides"]["settings"] == ["acme"] and info["acme"]["provides"]["hook"] == ["on_result"]
    assert listing.stderr == ""  # no plugin problem
    # ... and this venv is untouched
    assert "acme" not in create_plugin_manager().plugin_names()


def _import_generated(folder: Path, name: str, monkeypatch):
    monkeypatch.syspath_prepend(str(folder))
    for mod in [m for m in sys.modules if m.startswith(f"inspector_{name}")]:
        del sys.modules[mod]
    return importlib.import_module(f"inspector_{name}")


@pytest.mark.parametrize("part", ["stage", "driver", "hook"])
def test_plugin_new_writes_each_example_alone(tmp_path, monkeypatch, part):
    folder = write_plugin(f"only_{part}", tmp_path, {part})
    module = _import_generated(folder, f"only_{part}", monkeypatch)
    pm = make_plugin_manager(modules=[module])
    provides = pm.provides(module.__name__)
    assert pm.problems == ()
    assert bool(provides["stage"]) == (part == "stage")
    assert bool(provides["driver"]) == (part == "driver")
    assert provides["hook"] == (["on_result"] if part == "hook" else [])
    tests = (folder / "tests" / "test_plugin.py").read_text()
    assert ("def test_the_stage_output" in tests) == (part == "stage")
    assert ("def test_the_driver" in tests) == (part == "driver")
    assert ("def test_the_hook" in tests) == (part == "hook")
    compile(tests, "test_plugin.py", "exec")


def test_plugin_new_refuses_a_bad_name_or_an_existing_folder(tmp_path, capsys):
    assert main(["plugin", "new", "Acme-Corp", "--out", str(tmp_path)]) == 2
    assert "is not a lower-case identifier" in capsys.readouterr().err
    assert main(["plugin", "new", "acme", "--out", str(tmp_path)]) == 0
    assert main(["plugin", "new", "acme", "--out", str(tmp_path)]) == 2
    assert "exists" in capsys.readouterr().err


# --------------------------------------------------------------------------- pytest plugin
@dataclass(frozen=True)
class SizerSettings:
    label: str = param("L1", "a label the stage copies")


class Sizer:
    """A plugin under test, registered from code: a classify stage writing extras, its settings."""

    @hookimpl
    def inspector_register_stages(self, registry: StageRegistry) -> None:
        def run(ctx, params):
            n = len(ctx.need("bcps", "classify.sizer").points)
            return ctx.evolve(extras={**ctx.extras, "sizer.points": n, "sizer.label": ctx.settings["Sizer"].label})

        registry.add(StageSpec("classify.sizer", run, requires=("bcps",), doc="counts the BCPS points"))

    @hookimpl
    def inspector_register_settings(self, registry: SettingsRegistry) -> None:
        registry.add(SizerSettings, "the sizer's label")


@pytest.fixture
def broken_installed(tmp_path, monkeypatch):
    """A broken plugin installed on this machine (another integrator's)."""
    make_dist(tmp_path / "site", "acme_broken", "acme-broken", "0.1", "import vendor_sdk_not_here\n")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))


@pytest.mark.inspector_plugins(modules=[Sizer()])
def test_inspector_pm_holds_the_builtins_and_the_plugin_under_test_only(broken_installed, inspector_pm, capsys):
    assert "classify.sizer" in inspector_pm.stages
    assert {"segment.threshold", "bcps.ray", "evaluate.tolerance"} <= set(inspector_pm.stages.names())
    assert "acme_broken" not in inspector_pm.plugin_names() and inspector_pm.problems == ()
    assert capsys.readouterr().err == ""
    # what a plugin's tests would see without the fixture: the other plugin's problem
    lines: list[str] = []
    create_plugin_manager(warn=lines.append)
    assert any("acme_broken" in x for x in lines)


@pytest.mark.inspector_plugins("builtin_only_stage")
def test_the_marker_names_the_plugins_under_test(inspector_plugins_under_test):
    assert inspector_plugins_under_test == (("builtin_only_stage",), ())


def test_a_plugin_under_test_that_is_not_installed_fails_with_a_clear_message():
    with pytest.raises(PluginError, match="plugin 'nope' is not installed .*pip install -e"):
        make_plugin_manager(["nope"])


def test_a_plugin_under_test_that_is_broken_fails_with_its_message(broken_installed):
    with pytest.raises(PluginError, match="plugin 'acme_broken' .*cannot be imported: ModuleNotFoundError"):
        make_plugin_manager(["acme_broken"])


@pytest.mark.slow
@pytest.mark.inspector_plugins(modules=[Sizer()])
def test_inspector_run_returns_the_result_its_json_and_history(inspector_run, inspector_recipe, inspector_capture):
    capture = inspector_capture("part", seed=4)
    assert inspector_capture("part", seed=4) == capture  # made once per session
    recipe = inspector_recipe({"use": "classify.sizer"}, plugins={"Sizer": {"label": "L9"}})
    run = inspector_run(recipe, capture)
    assert run.exit_status == 0 and run.result.verdict == "pass"
    assert run.result.extras["sizer.label"] == "L9"
    assert run.result.extras["sizer.points"] == run.result.json["stats"]["n_points"] > 100
    assert run.result.result.extras == run.result.extras  # what on_result received
    assert run.history()[0]["extras"] == {"sizer.points": run.result.extras["sizer.points"], "sizer.label": "L9"}
    with pytest.raises(RecipeError, match=r"plugins\.Sizer\.label"):
        inspector_run(inspector_recipe(plugins={"Sizer": {"label": 1}}), capture)


def test_the_pytest_plugin_is_registered_and_imports_nothing_heavy():
    import importlib.metadata

    eps = [e for e in importlib.metadata.entry_points(group="pytest11") if e.value == "inspector_tools.testing"]
    assert eps, "no pytest11 entry point for inspector_tools.testing"
    code = ("import sys, inspector_tools.testing; heavy = [m for m in ('numpy', 'cv2', 'open3d', 'inspector.model', "
            "'inspector_drivers', 'inspector_plugins') if m in sys.modules]; print(heavy)")
    out = subprocess.run([PY, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
