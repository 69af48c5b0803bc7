"""Isolation at load (issue 16, item 1): one broken plugin never stops the others.

Every plugin here is a real distribution (a ``*.dist-info`` folder with ``entry_points.txt``
and a module beside it) in a temporary folder put on the path: the CLI runs in a subprocess
with it on ``PYTHONPATH``, exactly as an integrator's pip package would be found; the
in-process tests put it on ``sys.path`` and build a fresh plugin manager each.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from inspector.errors import RecipeError
from inspector.manager import create_plugin_manager
from inspector.recipe import parse_recipe

HEADER = """
from dataclasses import dataclass
from inspector import hookimpl
from inspector.params import param
from inspector.registry import StageSpec
"""

#: entry-point name -> (distribution, version, module source). Each module is named after
#: its entry point.
ZOO = {
    # fine: a stage and an on_result hook that leaves a file (proves the others go on)
    "acme_good": ("acme-good", "1.0", HEADER + """
import os
from pathlib import Path

def run(ctx, p):
    return ctx.evolve(extras={**ctx.extras, "good": "yes"})

@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.good", run=run, doc="works"))

@hookimpl
def inspector_on_result(result, outdir):
    if outdir is not None:
        Path(outdir, "acme_good.txt").write_text(result.verdict)
"""),
    # the vendor SDK is missing on the cell PC
    "acme_vendor": ("acme-vendor", "1.2", "import vendor_sdk_that_is_not_installed\n"),
    # a misspelled hook name
    "acme_typo": ("acme-typo", "0.3", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.typo", run=lambda c, p: c))

@hookimpl
def inspector_on_reslt(result, outdir):
    pass
"""),
    # a hook with an argument the hookspec does not have
    "acme_args": ("acme-args", "0.1", HEADER + """
@hookimpl
def inspector_on_result(result, outdir, plc_address):
    pass
"""),
    # a parameter type recipes cannot give
    "acme_params": ("acme-params", "2.0", HEADER + """
@dataclass(frozen=True)
class Params:
    weights: set[int] = param(frozenset(), "weights")

@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.weights", run=lambda c, p: c, params=Params))
"""),
    # an invalid stage spec (no such kind)
    "acme_kind": ("acme-kind", "0.9", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="paint.red", run=lambda c, p: c))
"""),
    # an evaluate variant that does not declare the evaluate contract
    "acme_eval": ("acme-eval", "0.5", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="evaluate.loose", run=lambda c, p: c, requires=("bcps",)))
"""),
    # its registry hook raises
    "acme_raises": ("acme-raises", "4.0", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    raise RuntimeError("licence server unreachable")
"""),
    # two plugins register the same stage name
    "acme_dup_a": ("acme-dup-a", "1.0", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.same", run=lambda c, p: c))
"""),
    "acme_dup_b": ("acme-dup-b", "2.0", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.same", run=lambda c, p: c))
"""),
    # @hookimpl forgotten
    "acme_nohook": ("acme-nohook", "0.1", HEADER + """
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.never", run=lambda c, p: c))
"""),
}

#: The one warning line each broken plugin costs (exact).
EXPECTED = {
    "acme_vendor": "inspector: warning: plugin 'acme_vendor' (acme-vendor 1.2) disabled: cannot be imported: "
                   "ModuleNotFoundError: No module named 'vendor_sdk_that_is_not_installed' (at {root}/acme_vendor.py:1); "
                   "block it with INSPECTOR_BLOCK_PLUGINS=acme_vendor",
    "acme_typo": "inspector: warning: plugin 'acme_typo' (acme-typo 0.3) disabled: implements inspector_on_reslt, which "
                 "is no hook (did you mean inspector_on_result?); block it with INSPECTOR_BLOCK_PLUGINS=acme_typo",
    "acme_params": "inspector: warning: plugin 'acme_params' (acme-params 2.0) disabled: stage 'classify.weights': "
                   "parameter 'weights': type set[int] is not supported (set[int] cannot come from a recipe); "
                   "supported: bool, int, float, str, Path, Literal[...] or Enum choices, tuple[T, ...], tuple[T1, T2], "
                   "list[T], dict[str, T], T | None, Any; block it with INSPECTOR_BLOCK_PLUGINS=acme_params",
    "acme_kind": "inspector: warning: plugin 'acme_kind' (acme-kind 0.9) disabled: stage 'paint.red': kind must be one "
                 "of segment, carve, classify, align, bcps, evaluate; block it with INSPECTOR_BLOCK_PLUGINS=acme_kind",
    "acme_eval": "inspector: warning: plugin 'acme_eval' (acme-eval 0.5) disabled: stage 'evaluate.loose': missing field "
                 "'summary': an evaluate stage declares StageSpec(summary=EvaluationSummary) and fills "
                 "Evaluation(summary=...) (inspector.model), which result.json, the history and the CSV export read; "
                 "block it with INSPECTOR_BLOCK_PLUGINS=acme_eval",
    "acme_raises": "inspector: warning: plugin 'acme_raises' (acme-raises 4.0) disabled: inspector_register_stages "
                   "raised RuntimeError: licence server unreachable; block it with INSPECTOR_BLOCK_PLUGINS=acme_raises",
    "acme_dup": "inspector: warning: stage 'classify.same' is registered twice, by plugin 'acme_dup_a' (acme-dup-a 1.0) "
                "and by plugin 'acme_dup_b' (acme-dup-b 2.0): neither is used; block one with "
                "INSPECTOR_BLOCK_PLUGINS=acme_dup_a or INSPECTOR_BLOCK_PLUGINS=acme_dup_b",
    "acme_nohook": "inspector: warning: plugin 'acme_nohook' (acme-nohook 0.1): defines no hook implementation "
                   "(inspector_register_stages lacks @hookimpl), so it does nothing; mark each hook function with "
                   "@inspector.hookimpl, or block it with INSPECTOR_BLOCK_PLUGINS=acme_nohook",
}


def make_dist(root: Path, entry: str, dist: str, version: str, source: str) -> None:
    """A distribution as pip installs it: ``<dist>-<version>.dist-info`` with METADATA and
    entry_points.txt (group ``inspector``), and its module ``<entry>.py`` beside it."""
    root.mkdir(parents=True, exist_ok=True)
    (root / f"{entry}.py").write_text(source)
    info = root / f"{dist.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(f"[inspector]\n{entry} = {entry}\n")


@pytest.fixture(scope="module")
def zoo(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("site") / "site"
    for entry, (dist, version, source) in ZOO.items():
        make_dist(root, entry, dist, version, source)
    return root


def _expected(root: Path) -> list[str]:
    return sorted(v.format(root=root) for v in EXPECTED.values())


#: acme_args' warning starts so; the rest is pluggy's own message (one line).
ARGS = ("inspector: warning: plugin 'acme_args' (acme-args 0.1) disabled: a hook does not match its hookspec: "
        "Plugin 'acme_args' for hook 'inspector_on_result'")
N_WARNINGS = len(EXPECTED) + 1


def check_warnings(lines: list[str], root: Path) -> None:
    """Exactly one line per broken plugin, each as expected."""
    args = [x for x in lines if "plugin 'acme_args'" in x]
    assert len(args) == 1 and args[0].startswith(ARGS), args
    assert "plc_address" in args[0] and args[0].endswith("; block it with INSPECTOR_BLOCK_PLUGINS=acme_args")
    assert sorted(x for x in lines if x not in args) == _expected(root)


def cli(root: Path, *args: str, env: dict[str, str] | None = None):
    environ = {k: v for k, v in os.environ.items() if k != "INSPECTOR_BLOCK_PLUGINS"}
    environ.update({"PYTHONPATH": str(root), **(env or {})})
    return subprocess.run([sys.executable, "-m", "inspector_frontends.cli", *args], capture_output=True, text=True,
                          env=environ, timeout=300)


# -------------------------------------------------------------------------- subprocess: the CLI


def test_inspector_plugins_goes_on_with_one_warning_per_broken_plugin(zoo):
    proc = cli(zoo, "plugins", "--json")
    assert proc.returncode == 0, proc.stderr
    check_warnings(proc.stderr.splitlines(), zoo)
    doc = json.loads(proc.stdout)
    assert "classify.good" in doc["stages"] and "segment.threshold" in doc["stages"] and "replay" in doc["drivers"]
    for gone in ("classify.typo", "classify.weights", "paint.red", "evaluate.loose", "classify.same"):
        assert gone not in doc["stages"]
    assert "acme_good" in doc["plugins"] and "acme_typo" not in doc["plugins"]
    assert len(doc["problems"]) == N_WARNINGS


def test_blocked_plugins_are_silent(zoo):
    names = ",".join(k for k in EXPECTED if k != "acme_dup") + ",acme_dup_b,acme_args"
    proc = cli(zoo, "plugins", env={"INSPECTOR_BLOCK_PLUGINS": names})
    assert proc.returncode == 0 and proc.stderr == ""
    assert "classify.same" in proc.stdout  # acme_dup_a's, alone now


def _recipe(folder: Path, name: str, stages: list[str], driver: str = "replay") -> Path:
    text = f'[recipe]\nname = "{name}"\n[driver]\nuse = "{driver}"\n'
    text += "".join(f'[[stages]]\nuse = "{s}"\n' for s in stages)
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("stage, message", [
    ("classify.good", None),
    ("classify.typo", "stages[1].use: stage classify.typo is not available: plugin 'acme_typo' (acme-typo 0.3) is "
                      "disabled (implements inspector_on_reslt, which is no hook (did you mean inspector_on_result?))"),
    ("classify.weights", "stages[1].use: stage classify.weights is not available: plugin 'acme_params' (acme-params 2.0) "
                         "is disabled (stage 'classify.weights': parameter 'weights': type set[int] is not supported"),
    ("classify.same", "stages[1].use: stage 'classify.same' is registered twice, by plugin 'acme_dup_a' (acme-dup-a 1.0) "
                      "and by plugin 'acme_dup_b' (acme-dup-b 2.0); block one with INSPECTOR_BLOCK_PLUGINS=acme_dup_a or "
                      "INSPECTOR_BLOCK_PLUGINS=acme_dup_b"),
    ("classify.vendor", "plugin 'acme_vendor' (acme-vendor 1.2) may provide it but is disabled (cannot be imported: "
                        "ModuleNotFoundError: No module named 'vendor_sdk_that_is_not_installed'"),
])
def test_recipe_check_refuses_only_a_recipe_that_uses_a_broken_plugin(zoo, tmp_path, stage, message):
    proc = cli(zoo, "recipe", "check", str(_recipe(tmp_path, "r", ["segment.threshold", stage])))
    check_warnings(proc.stderr.splitlines()[:N_WARNINGS], zoo)  # the warnings, then the verdict
    if message is None:
        assert proc.returncode == 0 and "OK" in proc.stdout, proc.stderr
    else:
        assert proc.returncode == 2
        last = proc.stderr.splitlines()[-1]
        assert last.startswith("inspector: error: r.toml: ") and message in last, last


def test_inspector_run_goes_on_and_the_good_plugin_runs(zoo, tmp_path, small_capture):
    recipe = _recipe(tmp_path, "seg", ["segment.threshold", "classify.good"])
    proc = cli(zoo, "run", str(recipe), "--capture", str(small_capture), "--out", str(tmp_path / "out"))
    assert proc.returncode == 0, proc.stderr
    check_warnings(proc.stderr.splitlines(), zoo)
    folder = tmp_path / "out" / small_capture.name
    assert (folder / "acme_good.txt").read_text() == "pass"  # its on_result hook ran
    res = json.loads((folder / "result.json").read_text())
    assert res["extras"] == {"good": "yes"}
    assert "hook:acme_good:on_result" in res["timings_s"] and "hook:history:on_result" in res["timings_s"]


# -------------------------------------------------------------------------- in process


@pytest.fixture
def on_path(zoo, monkeypatch):
    monkeypatch.syspath_prepend(str(zoo))
    monkeypatch.delenv("INSPECTOR_BLOCK_PLUGINS", raising=False)
    return zoo


def test_each_problem_is_reported_once_and_named(on_path):
    lines: list[str] = []
    pm = create_plugin_manager(warn=lines.append)
    check_warnings(lines, on_path)
    pm.register(object(), name="another")  # the registries are built again: nothing is reported twice
    _ = pm.stages, pm.drivers, pm.problems  # building the registries is what reports
    assert len(lines) == N_WARNINGS + 1 and lines[-1].startswith("inspector: warning: plugin 'another': defines no hook")
    assert "classify.good" in pm.stages and "carve.hull" in pm.stages
    by_name = {p.plugin.name: p for p in pm.problems}
    assert by_name["acme_vendor"].plugin.dist == "acme-vendor" and by_name["acme_vendor"].plugin.version == "1.2"
    assert by_name["acme_nohook"].disabled is False  # reported, nothing to disable
    assert by_name["acme_typo"].provides == ("stage classify.typo",)


def test_a_hook_with_unknown_arguments_disables_its_plugin(on_path):
    lines: list[str] = []
    pm = create_plugin_manager(warn=lines.append)
    assert "acme_args" not in pm.plugin_names() and "acme_good" in pm.plugin_names()
    assert not [n for n, p in pm.pm.list_name_plugin() if n == "acme_args"]  # not left half-registered
    check_warnings(lines, on_path)


def test_duplicates_with_a_builtin_name_both(on_path, tmp_path):
    make_dist(tmp_path / "s", "acme_carve", "acme-carve", "3.1", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="carve.hull", run=lambda c, p: c))
""")
    sys.path.insert(0, str(tmp_path / "s"))
    try:
        lines: list[str] = []
        pm = create_plugin_manager(warn=lines.append)
    finally:
        sys.path.remove(str(tmp_path / "s"))
    assert any("stage 'carve.hull' is registered twice, by plugin 'acme_carve' (acme-carve 3.1) and by plugin 'carve' "
               "(inspector-bcps" in x for x in lines), lines
    assert "carve.hull" not in pm.stages and "segment.threshold" in pm.stages
    with pytest.raises(RecipeError, match="stage 'carve.hull' is registered twice, by plugin 'acme_carve'"):
        parse_recipe({"stages": [{"use": "segment.threshold"}, {"use": "carve.hull"}]}, pm)


def test_a_driver_of_a_disabled_plugin_is_refused_naming_it(on_path, tmp_path):
    make_dist(tmp_path / "s", "acme_cam", "acme-cam", "7.0", HEADER + """
from inspector.registry import DriverSpec

@dataclass(frozen=True)
class CamParams:
    exposure_us: float = param(-5.0, "exposure", min=0.0)

@hookimpl
def inspector_register_drivers(registry):
    registry.add(DriverSpec(name="acmecam", open=lambda p: None, params=CamParams))
""")
    sys.path.insert(0, str(tmp_path / "s"))
    try:
        lines: list[str] = []
        pm = create_plugin_manager(warn=lines.append)
    finally:
        sys.path.remove(str(tmp_path / "s"))
    assert ("inspector: warning: plugin 'acme_cam' (acme-cam 7.0) disabled: driver 'acmecam': parameter 'exposure_us' "
            "default: expected a value >= 0.0, got -5.0; block it with INSPECTOR_BLOCK_PLUGINS=acme_cam") in lines
    with pytest.raises(RecipeError, match=r"driver.use: driver acmecam is not available: plugin 'acme_cam' "
                                          r"\(acme-cam 7.0\) is disabled"):
        parse_recipe({"driver": {"use": "acmecam"}, "stages": [{"use": "segment.threshold"}]}, pm)


def test_a_forgotten_hookimpl_among_others_is_named(on_path, tmp_path):
    make_dist(tmp_path / "s", "acme_half", "acme-half", "1.1", HEADER + """
@hookimpl
def inspector_register_stages(registry):
    registry.add(StageSpec(name="classify.half", run=lambda c, p: c))

def inspector_on_result(result, outdir):
    pass
""")
    sys.path.insert(0, str(tmp_path / "s"))
    try:
        lines: list[str] = []
        pm = create_plugin_manager(warn=lines.append)
    finally:
        sys.path.remove(str(tmp_path / "s"))
    assert ("inspector: warning: plugin 'acme_half' (acme-half 1.1): inspector_on_result lacks @hookimpl and never "
            "runs; mark it with @inspector.hookimpl, or block it with INSPECTOR_BLOCK_PLUGINS=acme_half") in lines
    assert "classify.half" in pm.stages  # the rest of it works


def test_a_plugin_registered_from_code_still_raises():
    """Tests and embedding applications hear of their own mistakes at once."""
    from inspector import hookimpl
    from inspector.errors import PluginError
    from inspector.registry import StageSpec

    class Raises:
        @hookimpl
        def inspector_register_stages(self, registry):
            raise RuntimeError("boom")

    with pytest.raises(PluginError, match="inspector_register_stages raised RuntimeError: boom"):
        create_plugin_manager(load_entrypoints=False, plugins=[Raises()])

    class Typo:
        @hookimpl
        def inspector_on_reslt(self, result, outdir):
            pass

    import pluggy

    with pytest.raises(pluggy.PluginValidationError, match="did you mean inspector_on_result"):
        create_plugin_manager(load_entrypoints=False, plugins=[Typo()])

    class Dup:
        @hookimpl
        def inspector_register_stages(self, registry):
            registry.add(StageSpec(name="carve.hull", run=lambda c, p: c))

    with pytest.raises(PluginError, match=r"stage 'carve.hull' is registered twice, by plugin 'Dup' and by plugin 'carve' \(inspector-bcps"):
        create_plugin_manager(plugins=[Dup()])


def test_a_stage_of_a_blocked_plugin_is_refused_saying_it_is_blocked(on_path, monkeypatch):
    monkeypatch.setenv("INSPECTOR_BLOCK_PLUGINS", "acme_good")
    pm = create_plugin_manager(warn=lambda line: None)
    assert "acme_good" not in pm.plugin_names() and pm.blocked == ("acme_good",)
    with pytest.raises(RecipeError, match=r"unknown stage 'classify.good' \(known: .*\); .*"
                                          r"blocked by INSPECTOR_BLOCK_PLUGINS: acme_good$"):
        parse_recipe({"stages": [{"use": "segment.threshold"}, {"use": "classify.good"}]}, pm)


def test_two_distributions_with_one_entry_point_name_are_named(on_path, tmp_path):
    make_dist(tmp_path / "s", "acme_good", "acme-copycat", "0.1", HEADER)
    sys.path.insert(0, str(tmp_path / "s"))
    try:
        lines: list[str] = []
        pm = create_plugin_manager(warn=lines.append)
    finally:
        sys.path.remove(str(tmp_path / "s"))
    # the first one found on the path is loaded (pluggy's rule); the other is named, not silent
    assert any(line.startswith("inspector: warning: plugin 'acme_good' (acme-") and "its entry-point name is also "
               "plugin 'acme_good' (acme-" in line and "rename one of the entry points" in line for line in lines), lines
    assert "acme_good" in pm.plugin_names()
