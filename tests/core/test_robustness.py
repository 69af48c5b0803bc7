"""Nothing a recipe value, a capture's name or a crash can do stops the line or passes a bad
part (issue 15): recipe numbers, result folders, history metadata, traceback files.

No test here inspects an image: the stages that run are a pass-through test stage, so no
Numba kernel is compiled. JSON depth and size bounds: tests/drivers/test_replay_limits.py.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sqlite3
import stat
import time
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args, get_origin

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from inspector import hookimpl
from inspector.errors import CaptureError, InputError, RecipeError
from inspector.manager import create_plugin_manager
from inspector.model import Camera, Capture, InspectionResult, Rig
from inspector.names import RESERVED, check_name, name_problem, printable
from inspector.outputs import one_line, write_result
from inspector.params import INT_BOUND, NoParams
from inspector.recipe import load_recipe, parse_recipe
from inspector.registry import Acquisition, StageSpec
from inspector.runner import exit_status, run_batch

INT64 = (-(2**63), 2**63 - 1)  # what a TOML integer can hold
NON_FINITE = (math.nan, math.inf, -math.inf)


# --------------------------------------------------------------------------- recipe numbers


@dataclass(frozen=True)
class Target:
    """One numeric parameter of a registered stage or driver."""

    where: str  # "stage" | "driver"
    owner: str  # "evaluate.tolerance", "hotfolder"...
    kind: str  # the stage's kind ("" for a driver)
    name: str
    number: type  # int or float
    is_list: bool
    lo: float | None
    hi: float | None
    after: bool = False  # a stage that needs others before it (evaluate.characteristics): added, not swapped

    def __str__(self) -> str:  # pytest ids
        return f"{self.owner}.{self.name}"


def _numeric(tp: Any) -> tuple[type, bool] | None:
    """(int | float, is a list) for a numeric annotation, None for any other."""
    if tp in (int, float):
        return tp, False
    args = [a for a in get_args(tp) if a is not type(None)]
    if get_origin(tp) is tuple and args and args[0] in (int, float):
        return args[0], True
    if get_origin(tp) in (typing.Union, getattr(__import__("types"), "UnionType", None)) and len(args) == 1:
        return _numeric(args[0])
    return None


def _targets() -> list[Target]:
    pm = create_plugin_manager()
    out = []
    for where, registry in (("stage", pm.stages), ("driver", pm.drivers)):
        for owner in registry.names():
            spec = registry[owner]
            if spec.params is NoParams:
                continue
            hints = typing.get_type_hints(spec.params)
            for f in dataclasses.fields(spec.params):
                found = _numeric(hints[f.name])
                if found is not None:
                    out.append(Target(where, owner, getattr(spec, "kind", ""), f.name, *found,
                                      f.metadata.get("min"), f.metadata.get("max"),
                                      bool(getattr(spec, "requires", ()))))
    return out


PM = create_plugin_manager()  # one for the module: Hypothesis reruns a test body many times
TARGETS = _targets()
BASE_STAGES = {"segment": "segment.threshold", "carve": "carve.hull", "align": "align.global_icp",
               "bcps": "bcps.ray", "evaluate": "evaluate.tolerance"}


EXTRA = "extra"  # the name of a stage added after the base stages


def _doc(target: Target | None = None, value: Any = None, tolerance: dict | None = None) -> dict:
    """A valid recipe document, with ``target`` set to ``value``."""
    stages = [{"use": use} for use in BASE_STAGES.values()]
    driver: dict[str, Any] = {"use": "replay"}
    if target is not None:
        table = {"use": target.owner, "params": {target.name: value}}
        if target.where == "driver":
            driver = table
        elif target.after:
            stages.append({"name": EXTRA, **table})
        else:
            stages[list(BASE_STAGES).index(target.kind)] = table
    return {"recipe": {"name": "t", "reference": "builtin:cube30"}, "driver": driver, "stages": stages,
            "tolerance": tolerance or {"default": {"lower": -0.1, "upper": 0.1}}}


def _key(target: Target) -> str:
    """How a message names the parameter."""
    if target.where == "driver":
        return f"<recipe>: driver.params.{target.name}"
    return f"<recipe>: stages.{EXTRA if target.after else target.kind}.params.{target.name}"


def _bad_values(t: Target) -> st.SearchStrategy:
    """Values ``t`` must refuse: non-finite, below its min, above its max (or, for an
    integer without one, beyond INT_BOUND), within what TOML can write."""
    options = []
    if t.number is float:
        options.append(st.sampled_from(NON_FINITE))
        if t.lo is not None:
            options.append(st.floats(max_value=t.lo, exclude_max=True, allow_nan=False, allow_infinity=False))
        if t.hi is not None:
            options.append(st.floats(min_value=t.hi, exclude_min=True, allow_nan=False, allow_infinity=False))
    else:
        lo = math.ceil(t.lo) if t.lo is not None else -INT_BOUND
        hi = math.floor(t.hi) if t.hi is not None else INT_BOUND
        options.append(st.integers(INT64[0], lo - 1))
        options.append(st.integers(hi + 1, INT64[1]))
    bad = st.one_of(options)
    if t.is_list:  # the bad number anywhere in the list
        ok = 0.0 if t.number is float else 0
        return st.tuples(st.integers(0, 4), bad).map(lambda iv: [ok] * iv[0] + [iv[1]])
    return bad


def _good_values(t: Target) -> st.SearchStrategy:
    if t.number is float:
        lo = t.lo if t.lo is not None else -1e12
        hi = t.hi if t.hi is not None else 1e12
        return st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    return st.integers(math.ceil(t.lo) if t.lo is not None else -INT_BOUND, math.floor(t.hi) if t.hi is not None else INT_BOUND)


def test_the_property_tests_see_every_numeric_parameter():
    names = {str(t) for t in TARGETS}
    assert {"evaluate.tolerance.cluster_radius_mm", "evaluate.tolerance.min_points", "hotfolder.poll_s",
            "hotfolder.settle_s", "hotfolder.give_up_s", "sim.dist", "aravis.gain"} <= names
    assert {t.owner for t in TARGETS} >= set(BASE_STAGES.values()) | {"sim", "hotfolder", "genicam", "aravis"}


FUZZ = settings(max_examples=400, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(st.data())
def test_no_non_finite_or_out_of_range_parameter_is_accepted(data):
    target = data.draw(st.sampled_from(TARGETS), label="parameter")
    value = data.draw(_bad_values(target), label="value")
    with pytest.raises(RecipeError) as e:
        parse_recipe(_doc(target, value), PM)
    msg = str(e.value)
    assert msg.startswith(_key(target)), msg
    assert "\n" not in msg


@FUZZ
@given(st.data())
def test_every_finite_in_range_parameter_is_still_accepted(data):
    target = data.draw(st.sampled_from([t for t in TARGETS if not t.is_list]), label="parameter")
    value = data.draw(_good_values(target), label="value")
    recipe = parse_recipe(_doc(target, value), PM)
    step = {s.name: s for s in recipe.steps}.get(EXTRA if target.after else target.kind)
    params = recipe.driver.params if target.where == "driver" else step.params
    assert getattr(params, target.name) == value


@pytest.mark.parametrize("target", TARGETS, ids=str)
def test_each_numeric_parameter_refuses_nan_inf_and_int64_extremes(target):
    """Every parameter, deterministically (the fuzz above samples them)."""
    values: list[Any] = list(NON_FINITE) if target.number is float else [INT64[0], INT64[1]]
    for v in values:
        with pytest.raises(RecipeError, match="^" + _key(target).replace(".", r"\.")):
            parse_recipe(_doc(target, [0.0, v] if target.is_list else v), PM)


@FUZZ
@given(where=st.sampled_from(["default.lower", "default.upper", "region.lower", "region.upper", "box_min", "box_max"]),
       bad=st.sampled_from(NON_FINITE), axis=st.integers(0, 2))
def test_tolerance_numbers_are_finite(where, bad, axis):
    region = {"name": "flange", "box_min": [-15.0, -15.0, 10.0], "box_max": [15.0, 15.0, 15.0], "lower": -0.05, "upper": 0.05}
    tol: dict[str, Any] = {"default": {"lower": -0.1, "upper": 0.1}, "regions": [region]}
    part, _, key = where.partition(".")
    if part == "default":
        tol["default"][key] = bad
        expect = f"<recipe>: tolerance.default.{key}"
    elif part == "region":
        region[key] = bad
        expect = f"<recipe>: tolerance.regions[0].{key}"
    else:
        region[where][axis] = bad
        expect = f"<recipe>: tolerance.regions[0].{where}[{axis}]"
    with pytest.raises(RecipeError) as e:
        parse_recipe(_doc(tolerance=tol), PM)
    assert str(e.value).startswith(expect) and "finite" in str(e.value)


def test_nested_numbers_of_table_parameters_are_checked():
    sim = next(t for t in TARGETS if str(t) == "sim.scale")
    bump = {"at": [15.0, math.nan, 0.0], "radius_mm": 1.5, "kind": "remove"}
    doc = _doc(sim, 1.0)
    doc["driver"]["params"]["bumps"] = [bump]
    with pytest.raises(RecipeError, match=r"^<recipe>: driver\.params\.bumps\[0\]\.at\[1\]: expected a finite number"):
        parse_recipe(doc, PM)
    bump["at"][1], bump["radius_mm"] = 0.0, 2**62
    with pytest.raises(RecipeError, match=r"driver\.params\.bumps\[0\]\.radius_mm: expected a value <= 2147483647"):
        parse_recipe(doc, PM)
    # The dataclass's own checks are a RecipeError too, not an internal error.
    doc["driver"]["params"]["bumps"] = [{"radius_mm": 1.0}]
    with pytest.raises(RecipeError, match=r"^<recipe>: driver\.params: bumps\[0\]: expected"):
        parse_recipe(doc, PM)


# The probes, as a user writes them: TOML literals in a recipe file.
@pytest.mark.parametrize(
    "table, line, key",
    [
        ("stages", 'params = { cluster_radius_mm = nan, min_points = 3 }', "stages.evaluate.params.cluster_radius_mm"),
        ("stages", 'params = { cluster_radius_mm = 1.0, min_points = 9223372036854775807 }', "stages.evaluate.params.min_points"),
        ("stages", 'params = { cluster_radius_mm = inf }', "stages.evaluate.params.cluster_radius_mm"),
        ("stages", 'params = { min_cameras = -9223372036854775808 }', "stages.evaluate.params.min_cameras"),
        ("driver", 'params = { poll_s = nan }', "driver.params.poll_s"),
        ("driver", 'params = { settle_s = inf }', "driver.params.settle_s"),
        ("driver", 'params = { give_up_s = +inf }', "driver.params.give_up_s"),
        ("tolerance", 'default = { lower = -inf, upper = 0.1 }', "tolerance.default.lower"),
        ("tolerance", 'default = { lower = -0.1, upper = nan }', "tolerance.default.upper"),
    ],
)
def test_recipe_files_with_nan_inf_or_huge_values_are_refused_on_load(tmp_path, table, line, key):
    text = (Path(__file__).resolve().parents[2] / "recipes" / "default.toml").read_text()
    if table == "stages":
        text = text.replace("params = { cluster_radius_mm = 1.0, min_points = 3 }", line)
    elif table == "driver":
        text = text.replace('use = "replay"', f'use = "hotfolder"\n{line}')
    else:
        text = text.replace("default = { lower = -0.1, upper = 0.1 }", line)
    assert line in text
    path = tmp_path / "probe.toml"
    path.write_text(text)
    with pytest.raises(RecipeError) as e:
        load_recipe(path, PM, reference="builtin:cube30")
    assert str(e.value).startswith(f"probe.toml: {key}: "), str(e.value)


def test_recipe_check_exits_2_for_a_nan_cluster_radius(tmp_path, capsys):
    from inspector_frontends.cli import main

    text = (Path(__file__).resolve().parents[2] / "recipes" / "default.toml").read_text()
    path = tmp_path / "nan.toml"
    path.write_text(text.replace("cluster_radius_mm = 1.0", "cluster_radius_mm = nan"))
    assert main(["recipe", "check", str(path), "--reference", "builtin:cube30"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err == "inspector: error: nan.toml: stages.evaluate.params.cluster_radius_mm: expected a finite number, got nan\n"


@pytest.mark.parametrize("option, value", [("--idle-exit", "inf"), ("--count", str(2**40))])
def test_watch_options_are_checked_like_recipe_values(tmp_path, capsys, option, value):
    from inspector_frontends.cli import main

    (tmp_path / "inbox").mkdir()
    recipe = tmp_path / "r.toml"
    recipe.write_text(RUN_RECIPE)
    args = ["run", str(recipe), "--watch", str(tmp_path / "inbox"), "--out", str(tmp_path / "out"), option, value]
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("inspector: error: hotfolder.")


def test_a_deeply_nested_recipe_is_one_line(tmp_path, capsys):
    from inspector_frontends.cli import main

    path = tmp_path / "deep.toml"
    path.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    assert main(["recipe", "check", str(path)]) == 2
    assert capsys.readouterr().err.count("\n") == 1


# --------------------------------------------------------------------------- capture names


BAD_NAMES = ["", ".", "..", "a/b", "../x", "a\\b", "a\nb", "tab\there", "bell\x07", "x\u2028y", "bad\udcffbyte", "x" * 256,
             "part\u202egnp.exe", "zero\u200bwidth", "bom\ufeff", ".c0.partial", ".c0.old",
             *sorted(RESERVED)]


@pytest.mark.parametrize("name", BAD_NAMES, ids=ascii)
def test_names_that_cannot_be_a_result_folder(name):
    assert name_problem(name) is not None
    with pytest.raises(CaptureError) as e:
        check_name(name)
    assert "\n" not in str(e.value) and "\u2028" not in str(e.value)
    assert "\n" not in printable(name)


@pytest.mark.parametrize("name", ["part-0001", "cube30-s0021", "Teil ä 2", "history.sqlite-2", "recipes-2", "x" * 255, "..."])
def test_names_that_can(name):
    assert name_problem(name) is None and printable(name) == name


def _result(name: str, verdict: str = "pass") -> InspectionResult:
    return InspectionResult(name, "r", verdict, None if verdict != "error" else "broken", {"total": 0.1})


def _tree(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("name", BAD_NAMES, ids=ascii)
def test_write_result_writes_nothing_for_a_bad_name(tmp_path, name):
    out = tmp_path / "work" / "out"
    out.mkdir(parents=True)
    (out.parent / "result.json").write_text("an earlier result\n")
    (out.parent / "bcps_points.ply").write_text("points\n")
    (out / "history.sqlite").write_text("")
    before = _tree(tmp_path)
    with pytest.raises(InputError) as e:
        write_result(_result(name), out)
    assert "\n" not in str(e.value)
    assert _tree(tmp_path) == before


def test_write_result_refuses_a_result_folder_that_resolves_outside_out(tmp_path):
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (elsewhere / "result.json").write_text("keep\n")
    (out / "p1").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(CaptureError, match=r"^capture 'p1': its result folder .* resolves outside"):
        write_result(_result("p1"), out)
    assert (elsewhere / "result.json").read_text() == "keep\n"
    (out / "p2").write_text("a file\n")
    with pytest.raises(CaptureError, match=r"^capture 'p2': .* exists and is not a folder"):
        write_result(_result("p2"), out)
    # A good name, through a linked --out, is written as before.
    (tmp_path / "linked").symlink_to(out, target_is_directory=True)
    assert write_result(_result("p3"), tmp_path / "linked") == tmp_path / "linked" / "p3"
    assert json.loads((out / "p3" / "result.json").read_text())["verdict"] == "pass"


def _pass_stage(ctx, p):
    return ctx.evolve(silhouettes=())  # a segment stage sets silhouettes (the runner checks)


class Recorder:
    def __init__(self):
        self.results = []

    @hookimpl
    def inspector_register_stages(self, registry):
        registry.add(StageSpec(name="segment.noop", run=_pass_stage, params=NoParams, doc="test stage"))

    @hookimpl
    def inspector_on_result(self, result, outdir):
        self.results.append((result.capture, result.verdict, outdir))


def _capture(name: str) -> Capture:
    return Capture(name=name, rig=Rig(()), images={})


def test_a_batch_goes_on_past_a_capture_whose_result_cannot_be_written(tmp_path):
    rec = Recorder()
    pm = create_plugin_manager(plugins=[rec])
    recipe = parse_recipe({"stages": [{"use": "segment.noop"}]}, pm)
    out = tmp_path / "out"
    acqs = [Acquisition("a", lambda: _capture("a")),
            Acquisition("..", lambda: _capture("..")),  # a driver that lets a bad name through
            Acquisition("history.sqlite-wal", lambda: _capture("history.sqlite-wal")),
            Acquisition("b", lambda: _capture("b"))]
    lines: list[str] = []
    outcomes = list(run_batch(recipe, acqs, pm, reference=None, outdir=out, progress=lines.append))
    assert [(o.result.capture, o.result.verdict) for o in outcomes] == [
        ("a", "pass"), ("..", "error"), ("history.sqlite-wal", "error"), ("b", "pass")]
    assert outcomes[1].result.error == "capture name '..' is not a folder name; rename it"
    assert outcomes[2].result.error.startswith("capture name 'history.sqlite-wal' is reserved")
    assert [o.folder for o in outcomes] == [out / "a", None, None, out / "b"]
    assert sorted(p.name for p in out.iterdir()) == ["a", "b", "history.sqlite"]  # the history is intact
    assert not (tmp_path / "result.json").exists()
    assert ("..", "error", None) in rec.results  # integrators hear of it, with no folder
    assert len(lines) == 4 and all("\n" not in line for line in lines)
    assert exit_status([o.result for o in outcomes]) == 3  # a bad name never passes


def test_one_line_escapes_a_name_with_a_newline():
    assert one_line(_result("a\nb", "error")) == "a\\nb: ERROR broken"


def _fake_capture(folder: Path, *, rig: Any = None) -> Path:
    """A capture folder with a 1-camera rig.json and a real 16x16 PNG (no rendering)."""
    from inspector.capture_folder import write_capture

    cam = Camera("c0", 16, 16, [[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]], None, np.eye(3), [0.0, 0.0, 100.0])
    write_capture(folder, Rig((cam,)), {"c0": np.zeros((16, 16), np.uint8)})
    if rig is not None:
        (folder / "rig.json").write_text(rig)
    return folder


def test_replay_names_a_capture_after_its_absolute_path(tmp_path, monkeypatch):
    from inspector_drivers.replay import ReplayDriver, ReplayParams

    cap = _fake_capture(tmp_path / "somedir" / "cap")
    (cap / "sub").mkdir()
    monkeypatch.chdir(cap)
    drv = ReplayDriver(ReplayParams((".", "sub/..", str(tmp_path / "somedir" / "cap" / "sub" / ".."))))
    names = [a.name for a in drv.acquire()]
    assert names == ["cap", "cap", "cap"]
    assert [a.load().name for a in drv.acquire()] == names  # as read_capture names it
    recipes = _fake_capture(tmp_path / "batch" / "recipes")
    _fake_capture(tmp_path / "batch" / "p1")
    acqs = list(ReplayDriver(ReplayParams((str(tmp_path / "batch"), "/"))).acquire())
    assert [a.name for a in acqs] == ["p1", "recipes", "/"]
    with pytest.raises(CaptureError, match=r"^capture name 'recipes' is reserved in the result folder"):
        acqs[1].load()
    with pytest.raises(CaptureError, match=r"^capture name '' is empty"):
        acqs[2].load()
    assert recipes.is_dir()


class Clock:
    """Virtual time for the hot folder: sleeping advances it."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


def _watch(inbox: Path, count: int) -> dict[str, str]:
    """One watch: acquisition name -> the name its capture loaded with, or its refusal
    (loaded before the driver resumes and files the folder in done/)."""
    from inspector_drivers.replay.hotfolder import HotFolderDriver, HotFolderParams

    clock = Clock()
    drv = HotFolderDriver(HotFolderParams(folder=str(inbox), settle_s=0.0, count=count), clock=clock, sleep=clock.sleep)
    out = {}
    for acq in drv.acquire():
        try:
            out[acq.name] = acq.load().name
        except CaptureError as e:
            out[acq.name] = f"error: {e}"
    return out


def test_the_hot_folder_renames_a_reserved_name_and_refuses_an_unprintable_one(tmp_path):
    inbox = tmp_path / "inbox"
    _fake_capture(inbox / "history.sqlite-wal")
    _fake_capture(inbox / "a\nb")
    got = _watch(inbox, 2)
    assert got["history.sqlite-wal-2"] == "history.sqlite-wal-2"  # inspected, under a free name
    assert got["a\\nb"].startswith("error: capture name 'a\\nb' contains a control character")
    assert len(got) == 2
    assert sorted(p.name for p in (inbox / "done").iterdir()) == ["a\nb", "history.sqlite-wal-2"]
    # The same bad name again: filed as a\nb-2, and the watcher goes on.
    _fake_capture(inbox / "a\nb")
    _fake_capture(inbox / "p1")
    assert sorted(_watch(inbox, 2)) == ["a\\nb-2", "p1"]
    assert sorted(p.name for p in (inbox / "done").iterdir()) == ["a\nb", "a\nb-2", "history.sqlite-wal-2", "p1"]


def test_the_hot_folder_shortens_a_long_reused_name_to_fit(tmp_path):
    """A reused 254-character name once crashed the watcher at every restart (NAME-2 is 256)."""
    inbox = tmp_path / "inbox"
    long = "x" * 254
    _fake_capture(inbox / "done" / long)
    _fake_capture(inbox / long)
    assert _watch(inbox, 1) == {"x" * 253 + "-2": "x" * 253 + "-2"}
    assert (inbox / "done" / ("x" * 253 + "-2")).is_dir()


RUN_RECIPE = """
[recipe]
name = "names"
[[stages]]
use = "segment.threshold"
"""


def test_run_capture_dotdot_writes_nothing_outside_out(tmp_path, capsys):
    """The issue's probe: --capture SOMEDIR/empty/.. once wrote OUTDIR/../result.json."""
    from inspector_frontends.cli import main

    work = tmp_path / "work"
    out = work / "out"
    out.mkdir(parents=True)
    (work / "result.json").write_text('{"verdict": "pass"}\n')
    (work / "bcps_points.ply").write_text("ply\n")
    somedir = tmp_path / "somedir"
    (somedir / "empty").mkdir(parents=True)
    recipe = tmp_path / "r.toml"
    recipe.write_text(RUN_RECIPE)
    before = {p: p.read_bytes() for p in work.iterdir() if p.is_file()}
    args = ["run", str(recipe), "--capture", f"{somedir}/empty/..", str(tmp_path / "gone"), "--out", str(out)]
    assert main(args) == 3
    assert {p: p.read_bytes() for p in work.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in work.iterdir()) == ["bcps_points.ply", "out", "result.json"]
    res = json.loads((out / "somedir" / "result.json").read_text())
    assert res["verdict"] == "error" and res["error"].startswith("rig.json: missing in capture folder")
    assert json.loads((out / "gone" / "result.json").read_text())["verdict"] == "error"  # the batch went on
    stdout = capsys.readouterr().out
    assert "[1/2] somedir: ERROR rig.json: missing" in stdout and "[2/2] gone: ERROR" in stdout


def test_run_refuses_a_reserved_capture_name_and_inspects_the_rest(tmp_path, capsys):
    from inspector_frontends.cli import main

    batch = tmp_path / "batch"
    _fake_capture(batch / "recipes")
    _fake_capture(batch / "history.sqlite-wal")
    _fake_capture(batch / "p1", rig='{"units": "mm", "cameras": []}')
    recipe = tmp_path / "r.toml"
    recipe.write_text(RUN_RECIPE)
    out = tmp_path / "out"
    assert main(["run", str(recipe), "--capture", str(batch), "--out", str(out), "-q"]) == 3
    assert sorted(p.name for p in out.iterdir()) == ["history.sqlite", "p1"]
    assert (out / "history.sqlite").is_file()
    err = capsys.readouterr().err.splitlines()
    assert "inspector: error: history.sqlite-wal: capture name 'history.sqlite-wal' is reserved" in err[0]
    assert err[1].startswith("inspector: error: p1: rig.json: cameras is empty")
    assert err[2].startswith("inspector: error: recipes: capture name 'recipes' is reserved")
    rows = sqlite3.connect(out / "history.sqlite").execute("SELECT capture FROM inspections").fetchall()
    assert rows == [("p1",)]  # a refused capture has no result folder, so no history row


def test_a_lone_surrogate_part_id_is_an_error_with_its_history_row(tmp_path, capsys):
    """Issue 27 finding 8: ``"part_id": "\\ud800x"`` lost the history row and exited 0."""
    from inspector_frontends.cli import main

    batch = tmp_path / "batch"
    bad = _fake_capture(batch / "p1")
    (bad / "capture.json").write_text('{"part_id": "\\ud800x"}')
    (_fake_capture(batch / "p2") / "capture.json").write_text('{"part_id": "ok", "note": {"k": ["\\udfff"]}}')
    recipe = tmp_path / "r.toml"
    recipe.write_text(RUN_RECIPE)
    out = tmp_path / "out"
    assert main(["run", str(recipe), "--capture", str(batch), "--out", str(out), "-q"]) == 3
    err = capsys.readouterr().err.splitlines()
    assert err[0] == ("inspector: error: p1: capture.json: part_id is not valid Unicode text (a lone surrogate at "
                      "character 0)")
    assert err[1].startswith("inspector: error: p2: capture.json: note is not valid Unicode text")
    rows = sqlite3.connect(out / "history.sqlite").execute("SELECT capture, verdict FROM inspections ORDER BY capture")
    assert rows.fetchall() == [("p1", "error"), ("p2", "error")]


# --------------------------------------------------------------------------- history metadata


def test_history_metadata_is_valid_json_with_nan_and_inf(tmp_path):
    from inspector.history_store import read_history, record

    meta = {"part_id": "p1", "temp_c": math.nan, "limits": [math.inf, -math.inf, 1.5],
            "nested": {"x": np.float64("nan"), "y": np.float32("inf"), "z": np.float32(2.0)}, "when": time.gmtime(0)[:3]}
    res = dataclasses.replace(_result("p1"), metadata=meta)
    record(res, tmp_path)
    con = sqlite3.connect(tmp_path / "history.sqlite")
    (text, valid), = con.execute("SELECT metadata, json_valid(metadata) FROM inspections").fetchall()
    assert valid == 1

    def strict(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    assert json.loads(text, parse_constant=strict) == {
        "part_id": "p1", "temp_c": None, "limits": [None, None, 1.5],
        "nested": {"x": None, "y": None, "z": "2.0"}, "when": [1970, 1, 1]}
    assert read_history(tmp_path)[0]["metadata"] == text


def test_history_metadata_of_finite_values_is_unchanged(tmp_path):
    from inspector.history_store import record

    meta = {"part_id": "p1", "timestamp": "2026-12-01T10:00:00", "x": 1.5, "n": 3, "tags": ["a", "b"], "obj": Path("/p")}
    record(dataclasses.replace(_result("p1"), metadata=meta), tmp_path)
    (text,), = sqlite3.connect(tmp_path / "history.sqlite").execute("SELECT metadata FROM inspections").fetchall()
    assert text == json.dumps(meta, default=str, sort_keys=True)


# --------------------------------------------------------------------------- traceback files


def test_save_traceback_makes_a_new_private_file(tmp_path):
    from inspector.tracebacks import save_traceback

    a = save_traceback("Traceback (most recent call last):\n  boom\n", directory=tmp_path)
    b = save_traceback("second\n", directory=tmp_path)
    assert a != b and Path(a).parent == tmp_path and Path(a).name.startswith("inspector-traceback-")
    assert Path(a).read_text() == "Traceback (most recent call last):\n  boom\n"
    assert stat.S_IMODE(os.stat(a).st_mode) == 0o600 and not Path(a).is_symlink()


def test_save_traceback_never_writes_through_a_planted_link(tmp_path):
    """The old name was the time and the pid: guessable, so a link could be planted there."""
    from inspector.tracebacks import save_traceback

    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    for t in (time.time() + d for d in range(-2, 5)):  # every name the old scheme could pick now
        link = tmp_path / f"inspector-traceback-{time.strftime('%Y%m%d-%H%M%S', time.localtime(t))}-{os.getpid()}.txt"
        link.symlink_to(victim)
    path = save_traceback("secret traceback\n", directory=tmp_path)
    assert victim.read_text() == "precious\n"
    assert not Path(path).is_symlink() and Path(path).read_text() == "secret traceback\n"


def test_save_traceback_of_the_current_exception_and_when_it_cannot_write(tmp_path):
    from inspector.tracebacks import NOT_WRITTEN, save_traceback

    try:
        raise ZeroDivisionError("boom")
    except ZeroDivisionError:
        path = save_traceback()
    try:
        assert "ZeroDivisionError: boom" in Path(path).read_text()
    finally:
        Path(path).unlink()
    assert save_traceback("x", directory=tmp_path / "missing") == NOT_WRITTEN
