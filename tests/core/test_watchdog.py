"""The stage watchdog (issue 27 finding 2): a stage that never returns ends its part as
``error`` within its limit and the batch goes on; an abort acts while a stage runs."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import pytest

from inspector import hookimpl
from inspector.manager import create_plugin_manager
from inspector.model import Capture, Rig
from inspector.params import param
from inspector.recipe import parse_recipe
from inspector.registry import Acquisition, StageSpec
from inspector.runner import ABORTED, run_batch
from inspector.watchdog import StageAborted, StageTimeout, abandoned, call_with_limit

RELEASE = threading.Event()  # lets the stuck stages end when the module's tests are done


@pytest.fixture(autouse=True, scope="module")
def _release_stuck_threads():
    yield
    RELEASE.set()


@dataclass(frozen=True)
class SpinParams:
    spin_on: str = param("", "capture name whose stage never returns")


def _spin_stage(ctx, p):
    if ctx.capture.name == p.spin_on:
        while not RELEASE.is_set():  # a plugin's endless loop (busy, then blocking)
            RELEASE.wait(0.05)
    return ctx.evolve(silhouettes=())


class Spinner:
    @hookimpl
    def inspector_register_stages(self, registry):
        registry.add(StageSpec(name="segment.spin", run=_spin_stage, params=SpinParams, doc="test stage"))


def _acq(name):
    return Acquisition(name, lambda: Capture(name=name, rig=Rig(()), images={}))


def _recipe(pm, **budget):
    return parse_recipe({"stages": [{"use": "segment.spin", "params": {"spin_on": "stuck"}}], "budget": budget}, pm)


def test_a_spinning_stage_ends_its_part_as_error_within_the_limit_and_the_batch_goes_on(tmp_path):
    pm = create_plugin_manager(plugins=[Spinner()])
    recipe = _recipe(pm, stage_limit_s=0.5)
    t0 = time.monotonic()
    outcomes = list(run_batch(recipe, [_acq("a"), _acq("stuck"), _acq("b")], pm, reference=None, outdir=tmp_path))
    elapsed = time.monotonic() - t0
    verdicts = {o.result.capture: o.result.verdict for o in outcomes}
    assert verdicts == {"a": "pass", "stuck": "error", "b": "pass"}
    err = next(o.result.error for o in outcomes if o.result.capture == "stuck")
    assert err == ("segment: stage segment.spin of plugin 'Spinner' exceeded 0.5 s (the stage_limit_s of [budget]); "
                   "the part is given up, the cell goes on")
    assert (tmp_path / "stuck" / "result.json").is_file() and (tmp_path / "b" / "result.json").is_file()
    assert elapsed < 0.5 + 1.0 + 5.0  # the limit + 1 s, and generous room for a loaded machine
    assert abandoned() >= 1


def test_the_inspection_limit_counts_every_stage(tmp_path):
    pm = create_plugin_manager(plugins=[Spinner()])
    recipe = _recipe(pm, stage_limit_s=60.0, inspection_limit_s=0.3)
    (outcome,) = run_batch(recipe, [_acq("stuck")], pm, reference=None, outdir=tmp_path)
    assert outcome.result.verdict == "error"
    assert outcome.result.error == ("segment: stage segment.spin of plugin 'Spinner': the inspection exceeded 0.3 s (the "
                                    "inspection_limit_s of [budget]); the part is given up, the cell goes on")


def test_an_abort_acts_while_a_stage_runs(tmp_path):
    pm = create_plugin_manager(plugins=[Spinner()])
    recipe = _recipe(pm)  # default limits: minutes
    asked = threading.Event()
    threading.Timer(0.3, asked.set).start()
    (outcome,) = run_batch(recipe, [_acq("stuck")], pm, reference=None, outdir=tmp_path, should_abort=asked.is_set)
    assert outcome.result.verdict == ABORTED
    assert outcome.result.error == "cancelled during stage segment"
    assert not (tmp_path / "stuck").exists()  # an aborted part writes nothing


def test_call_with_limit_returns_raises_and_gives_up():
    assert call_with_limit(lambda x: x + 1, 41, limit_s=5.0) == 42
    with pytest.raises(ZeroDivisionError):
        call_with_limit(lambda: 1 / 0, limit_s=5.0)
    with pytest.raises(StageTimeout, match="exceeded 0.2 s"):
        call_with_limit(RELEASE.wait, limit_s=0.2)
    with pytest.raises(StageAborted):
        call_with_limit(RELEASE.wait, limit_s=None, should_abort=lambda: True)
    assert call_with_limit(lambda: "direct", limit_s=None) == "direct"  # no limit, no abort: no thread


def test_the_limits_are_recipe_and_environment_settings(monkeypatch):
    pm = create_plugin_manager(plugins=[Spinner()])
    monkeypatch.setenv("INSPECTOR_STAGE_LIMIT_S", "7.5")
    assert _recipe(pm).budget.stage_limit_s == 7.5
    assert _recipe(pm, stage_limit_s=2.0).budget.stage_limit_s == 2.0
    monkeypatch.setenv("INSPECTOR_INSPECTION_LIMIT_S", "nan")
    from inspector.errors import RecipeError

    with pytest.raises(RecipeError, match="INSPECTOR_INSPECTION_LIMIT_S"):
        _recipe(pm)
