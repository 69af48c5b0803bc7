"""Runner: every stage timed, lifecycle hooks called, one failing capture isolated."""

from __future__ import annotations

import json
from dataclasses import dataclass

import pytest

from inspector import hookimpl
from inspector.errors import StageError
from inspector.manager import create_plugin_manager
from inspector.model import Capture, Rig
from inspector.params import param
from inspector.recipe import parse_recipe
from inspector.registry import Acquisition, StageSpec
from inspector.runner import exit_status, run_batch


@dataclass(frozen=True)
class FlagParams:
    fail_on: str = param("", "capture name on which to fail")
    crash_on: str = param("", "capture name on which to raise a bug")


def _flag_stage(ctx, p):
    if ctx.capture.name == p.fail_on:
        raise StageError("camera cam00: empty silhouette")
    if ctx.capture.name == p.crash_on:
        raise ZeroDivisionError("boom")
    return ctx.evolve(silhouettes=(), extras={"seen": True})  # a segment stage sets silhouettes


class Recorder:
    """A third-party plugin publishing results (like a PLC/MES integration)."""

    def __init__(self):
        self.events = []

    @hookimpl
    def inspector_register_stages(self, registry):
        registry.add(StageSpec(name="segment.flag", run=_flag_stage, params=FlagParams, doc="test stage"))

    @hookimpl
    def inspector_before_stage(self, context, stage, step):
        self.events.append(("before", context.capture.name, step))

    @hookimpl
    def inspector_after_stage(self, context, stage, step, seconds):
        # Recorded, not asserted: a hook's exception is a warning, not a test failure.
        ok = seconds >= 0 and context.extras.get("seen")
        self.events.append(("after" if ok else "after-without-output", context.capture.name, step))

    @hookimpl
    def inspector_on_stage_error(self, context, stage, step, error):
        self.events.append(("error", context.capture.name, type(error).__name__))

    @hookimpl
    def inspector_on_result(self, result, outdir):
        self.events.append(("result", result.capture, result.verdict, outdir is not None))


def _capture(name):
    return Capture(name=name, rig=Rig(()), images={})


def _acq(name):
    return Acquisition(name, lambda: _capture(name))


def test_batch_isolates_failures_and_calls_hooks(tmp_path):
    rec = Recorder()
    pm = create_plugin_manager(plugins=[rec])
    recipe = parse_recipe({"stages": [{"use": "segment.flag", "params": {"fail_on": "b", "crash_on": "c"}}]}, pm)

    def broken():
        from inspector.errors import CaptureError

        raise CaptureError("images/cam07.png: truncated PNG")

    acqs = [_acq("a"), _acq("b"), _acq("c"), Acquisition("d", broken), _acq("e")]
    lines = []
    outcomes = list(run_batch(recipe, acqs, pm, reference=None, outdir=tmp_path, progress=lines.append))
    verdicts = {o.result.capture: o.result.verdict for o in outcomes}
    assert verdicts == {"a": "pass", "b": "error", "c": "error", "d": "error", "e": "pass"}
    errors = {o.result.capture: o.result.error for o in outcomes}
    assert errors["b"] == "segment: camera cam00: empty silhouette"
    assert errors["c"].startswith("segment: internal error ZeroDivisionError: boom")
    assert errors["d"] == "images/cam07.png: truncated PNG"
    # A bug's traceback goes to a file, never to the user.
    assert "ZeroDivisionError" in (tmp_path / "c" / "traceback.txt").read_text()
    assert all("\n" not in line for line in lines) and len(lines) == 5
    assert ("before", "a", "segment") in rec.events and ("after", "a", "segment") in rec.events
    assert ("error", "b", "StageError") in rec.events
    assert ("result", "e", "pass", True) in rec.events
    res = json.loads((tmp_path / "a" / "result.json").read_text())
    assert res["verdict"] == "pass" and "segment" in res["timings_s"] and "total" in res["timings_s"]
    assert exit_status([o.result for o in outcomes]) == 3


def test_exit_status_order():
    from inspector.model import InspectionResult

    def r(v):
        return InspectionResult("x", "r", v, None, {})

    assert exit_status([r("pass"), r("pass")]) == 0
    assert exit_status([r("pass"), r("fail")]) == 1
    assert exit_status([r("fail"), r("error")]) == 3


def test_stage_order_requirement_is_checked_at_load():
    pm = create_plugin_manager()
    from inspector.errors import RecipeError

    with pytest.raises(RecipeError, match="needs a 'segment' stage"):
        parse_recipe({"recipe": {"reference": "builtin:cube30"}, "stages": [{"use": "carve.hull"}]}, pm)


class Broken:
    """An integration whose every observer raises (a PLC off the network)."""

    @hookimpl
    def inspector_before_stage(self, context, stage, step):
        raise RuntimeError("before\nboom")

    @hookimpl
    def inspector_on_result(self, result, outdir):
        raise ConnectionError("PLC 10.0.0.5 unreachable")


def test_a_failing_observer_is_one_warning_and_stops_nothing(tmp_path, capsys):
    rec = Recorder()
    pm = create_plugin_manager(plugins=[rec])
    pm.register(Broken(), name="plc")
    recipe = parse_recipe({"stages": [{"use": "segment.flag"}]}, pm)
    outcomes = list(run_batch(recipe, [_acq("a"), _acq("b")], pm, reference=None, outdir=tmp_path))
    assert [o.result.verdict for o in outcomes] == ["pass", "pass"]  # the inspection is not touched
    assert ("result", "a", "pass", True) in rec.events and ("result", "b", "pass", True) in rec.events
    assert ("after", "b", "segment") in rec.events  # the other plugin got everything
    assert capsys.readouterr().err.splitlines() == [
        "inspector: warning: plugin 'plc' failed on a/segment (inspector_before_stage): RuntimeError: before boom",
        "inspector: warning: plugin 'plc' failed on a (inspector_on_result): ConnectionError: PLC 10.0.0.5 unreachable",
        "inspector: warning: plugin 'plc' failed on b/segment (inspector_before_stage): RuntimeError: before boom",
        "inspector: warning: plugin 'plc' failed on b (inspector_on_result): ConnectionError: PLC 10.0.0.5 unreachable",
    ]
