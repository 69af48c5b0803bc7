"""What a plugin's stage returns is checked, what it produces is kept, and time is visible
(issue 16, items 2-4): each with a fresh plugin manager holding the built-ins and a test plugin."""

from __future__ import annotations

import json
import sqlite3
import time
from dataclasses import dataclass

import numpy as np
import pytest

from inspector import hookimpl
from inspector.errors import PluginError, RecipeError
from inspector.manager import create_plugin_manager
from inspector.model import BcpsPoints, Capture, DeviationStats, Evaluation, EvaluationSummary, RegionSummary, Rig
from inspector.params import param
from inspector.recipe import parse_recipe
from inspector.registry import Acquisition, StageSpec
from inspector.runner import run_batch


@dataclass(frozen=True)
class Mode:
    broken_on: str = param("", "capture on which the stage misbehaves")
    how: str = param("none", "none | no-output | wrong-type | dict")
    sleep_s: float = param(0.0, "seconds the stage takes", min=0.0, max=10.0)


def _segment(ctx, p):
    time.sleep(p.sleep_s)
    if ctx.capture.name == p.broken_on:
        return {"none": None, "no-output": ctx, "wrong-type": ctx.evolve(silhouettes=["mask"]),
                "dict": {"silhouettes": ()}}[p.how]
    return ctx.evolve(silhouettes=())


def _classify(ctx, p):
    return ctx.evolve(extras={**ctx.extras, "label": "small", "volume_mm3": np.float64(2.5e4),
                              "sizes": np.array([1.0, 2.0, np.nan]), "tags": ("a", "b"),
                              "model": object(), "nested": {"ok": 1, "bad": {1, 2}}})


def _bcps(ctx, p):
    n = 6
    pts = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    dev = np.array([0.01, -0.02, 0.03, -0.3, 0.0, 0.2])
    return ctx.evolve(bcps=BcpsPoints(pts, dev, np.array([0, 0, 1, 1, 0, 1]), np.zeros((n, 2)), np.ones(n), "ray"))


def _evaluate(ctx, p):
    """An evaluate variant that fills the typed summary and no stats at all: what history
    and outputs show must come from the summary."""
    dev = ctx.bcps.deviation
    regions = (RegionSummary("default", -0.1, 0.1, 4, 1, DeviationStats.of(dev[:4])),
               RegionSummary("top", -0.25, 0.25, 2, 0, DeviationStats.of(dev[4:])))
    out = np.array([False, False, False, True, False, False])
    summary = EvaluationSummary(n_points=6, deviation_mm=DeviationStats.of(dev), tolerance_mm=(-0.1, 0.1),
                                within_tolerance=5 / 6, out_of_tolerance_points=1, regions=regions,
                                point_region=np.array([0, 0, 0, 0, 1, 1]))
    if ctx.capture.name == "unsummarised":
        summary = None
    elif ctx.capture.name == "dict-stats":  # loose keys where the typed statistics belong
        summary = EvaluationSummary(6, {"mean": 0.0}, (-0.1, 0.1), 1.0, 0)
    verdict, error = {"declined": ("error", "pose uncertain: a turn of +90 deg fits as well"),
                      "no-reason": ("error", None), "odd": ("maybe", None)}.get(ctx.capture.name, ("pass", None))
    return ctx.evolve(evaluation=Evaluation(verdict, {}, (), out, summary=summary, error=error))


class Plugin:
    """A third-party plugin: stages, and observers recording what they receive."""

    def __init__(self, on_result_s: float = 0.0):
        self.results = []
        self.errors = []
        self.on_result_s = on_result_s

    @hookimpl
    def inspector_register_stages(self, registry):
        registry.add(StageSpec(name="segment.mode", run=_segment, params=Mode))
        registry.add(StageSpec(name="classify.size", run=_classify))
        registry.add(StageSpec(name="bcps.fake", run=_bcps))
        registry.add(StageSpec(name="evaluate.fake", run=_evaluate, requires=("bcps",), summary=EvaluationSummary))

    @hookimpl
    def inspector_on_stage_error(self, context, stage, step, error):
        self.errors.append((context.capture.name, step, str(error)))

    @hookimpl
    def inspector_on_result(self, result, outdir):
        time.sleep(self.on_result_s)
        self.results.append((result.capture, result.verdict, dict(result.extras), outdir is not None))


def _acq(name, cameras=0):
    return Acquisition(name, lambda: Capture(name=name, rig=Rig(()), images={}))


def _run(plugin, stages, names, tmp_path, **recipe):
    pm = create_plugin_manager(plugins=[plugin])
    rec = parse_recipe({"recipe": {"name": "t", "reference": "builtin:cube30"}, "stages": stages, **recipe}, pm)
    out = tmp_path / "out"
    return list(run_batch(rec, [_acq(n) for n in names], pm, reference=None, outdir=out)), out


def _history(out):
    con = sqlite3.connect(out / "history.sqlite")
    con.row_factory = sqlite3.Row
    try:
        return {r["capture"]: dict(r) for r in con.execute("SELECT * FROM inspections")}
    finally:
        con.close()


# ------------------------------------------------------------------ item 2: what a stage returns


@pytest.mark.parametrize("how, problem", [
    ("none", "returned NoneType, not an InspectionContext (return context.evolve(...))"),
    ("no-output", "did not set silhouettes (the output of a segment stage)"),
    ("wrong-type", "set silhouettes to list, not a tuple of Silhouette"),
    ("dict", "returned dict, not an InspectionContext"),
])
def test_a_stage_returning_the_wrong_thing_is_an_error_naming_it_and_the_batch_goes_on(tmp_path, how, problem):
    plugin = Plugin()
    outcomes, out = _run(plugin, [{"use": "segment.mode", "params": {"broken_on": "b", "how": how}}],
                         ["a", "b", "c"], tmp_path)
    assert [o.result.verdict for o in outcomes] == ["pass", "error", "pass"]
    reason = outcomes[1].result.error
    assert reason.startswith(f"segment: stage segment.mode of plugin 'Plugin' {problem}"), reason
    # as for any error: its result folder, its history row, on_result, on_stage_error
    res = json.loads((out / "b" / "result.json").read_text())
    assert res["verdict"] == "error" and res["error"] == reason
    rows = _history(out)
    assert set(rows) == {"a", "b", "c"} and rows["b"]["verdict"] == "error" and rows["b"]["error"] == reason
    assert ("b", "error", {}, True) in plugin.results and len(plugin.results) == 3
    assert plugin.errors == [("b", "segment", reason)]


def test_an_evaluation_without_its_summary_is_an_error(tmp_path):
    outcomes, _ = _run(Plugin(), [{"use": "bcps.fake"}, {"use": "evaluate.fake"}], ["ok", "unsummarised", "dict-stats"],
                       tmp_path)
    assert outcomes[0].result.verdict == "pass"
    assert outcomes[1].result.error == ("evaluate: stage evaluate.fake of plugin 'Plugin' set no evaluation summary "
                                        "(Evaluation(summary=EvaluationSummary(...)))")
    assert outcomes[2].result.error == ("evaluate: stage evaluate.fake of plugin 'Plugin' set the summary's "
                                        "'deviation_mm' to a dict, not a DeviationStats")


def test_a_variant_may_declare_its_own_summary_class_with_the_contract_fields(tmp_path):
    @dataclass(frozen=True)
    class FormSummary:  # not a subclass: the same fields, and one more
        n_points: int
        deviation_mm: DeviationStats | None
        tolerance_mm: tuple
        within_tolerance: float
        out_of_tolerance_points: int
        flatness_mm: float

    def form(ctx, p):
        s = FormSummary(3, DeviationStats.of(np.array([0.0, 0.01, -0.01])), (-0.05, 0.05), 1.0, 0, 0.02)
        return ctx.evolve(evaluation=Evaluation("pass", {"flatness_mm": 0.02}, (), np.zeros(3, bool), summary=s))

    class Form:
        @hookimpl
        def inspector_register_stages(self, registry):
            registry.add(StageSpec(name="evaluate.form", run=form, requires=("bcps",), summary=FormSummary))

    pm = create_plugin_manager(plugins=[Plugin(), Form()])
    rec = parse_recipe({"recipe": {"reference": "builtin:cube30"},
                        "stages": [{"use": "bcps.fake"}, {"use": "evaluate.form"}]}, pm)
    (o,) = run_batch(rec, [_acq("a")], pm, reference=None, outdir=tmp_path / "out")
    assert o.result.verdict == "pass", o.result.error
    row = _history(tmp_path / "out")["a"]
    assert row["n_points"] == 3 and row["tolerance_upper_mm"] == 0.05
    assert o.result.stats["n_points"] == 3 and o.result.stats["flatness_mm"] == 0.02


# ------------------------------------------------------------------ item 3: plugin output kept


def test_extras_reach_result_json_history_and_on_result_and_non_json_is_a_warning(tmp_path):
    plugin = Plugin()
    outcomes, out = _run(plugin, [{"use": "segment.mode"}, {"use": "classify.size"}], ["a"], tmp_path)
    kept = {"label": "small", "volume_mm3": 25000.0, "sizes": [1.0, 2.0, None], "tags": ["a", "b"]}
    res = json.loads((out / "a" / "result.json").read_text())
    assert res["verdict"] == "pass" and res["extras"] == kept
    assert json.loads(_history(out)["a"]["extras"]) == kept
    assert plugin.results == [("a", "pass", kept, True)]
    assert res["stats"]["warnings"] == [
        "stage 'classify': extras['model'] is of type object, not JSON; left out of result.json and history",
        "stage 'classify': extras['nested']['bad'] is of type set, not JSON; left out of result.json and history",
    ]
    # every key the CONTRACT names is still there, unchanged
    assert {"capture", "recipe", "verdict", "error", "timings_s", "pose", "stats", "defects", "points"} <= set(res)


def test_history_and_outputs_read_the_typed_evaluation_summary(tmp_path):
    outcomes, out = _run(Plugin(), [{"use": "bcps.fake"}, {"use": "evaluate.fake"}], ["a"], tmp_path)
    row = _history(out)["a"]
    assert row["n_points"] == 6 and row["tolerance_lower_mm"] == -0.1 and row["tolerance_upper_mm"] == 0.1
    assert row["deviation_min_mm"] == pytest.approx(-0.3) and row["deviation_max_mm"] == pytest.approx(0.2)
    res = json.loads((out / "a" / "result.json").read_text())
    assert res["stats"]["n_points"] == 6 and res["stats"]["tolerance_mm"] == {"lower": -0.1, "upper": 0.1}
    assert res["stats"]["deviation_mm"]["min"] == pytest.approx(-0.3)
    from inspector.outputs import one_line

    assert "deviation mean -0.0133 min -0.3000 max +0.2000 mm" in one_line(outcomes[0].result)


def test_an_evaluation_may_decline_with_a_reason_but_not_without(tmp_path):
    """Verdict "error" from an evaluate stage (e.g. a pose it cannot trust) carries its reason
    into result.json and history; without a reason, or with another word, the stage is at fault."""
    outcomes, out = _run(Plugin(), [{"use": "bcps.fake"}, {"use": "evaluate.fake"}], ["declined", "no-reason", "odd"],
                         tmp_path)
    declined, no_reason, odd = (o.result for o in outcomes)
    assert declined.verdict == "error" and declined.error == "pose uncertain: a turn of +90 deg fits as well"
    res = json.loads((out / "declined" / "result.json").read_text())
    assert res["verdict"] == "error" and res["error"] == declined.error
    assert _history(out)["declined"]["error"] == declined.error
    assert no_reason.error.endswith("set the verdict 'error' without its reason (Evaluation(error=...)), or a reason "
                                    "without it")
    assert odd.error.endswith("set the verdict 'maybe', not 'pass', 'fail' or 'error'")


def test_an_evaluate_variant_without_the_contract_is_refused_at_registration():
    @dataclass(frozen=True)
    class Partial:  # no deviation_mm
        n_points: int
        tolerance_mm: tuple
        within_tolerance: float
        out_of_tolerance_points: int

    for summary, message in ((None, "stage 'evaluate.mine': missing field 'summary'"),
                             (Partial, "stage 'evaluate.mine': summary Partial is missing field 'deviation_mm'")):
        class Variant:
            @hookimpl
            def inspector_register_stages(self, registry):
                registry.add(StageSpec(name="evaluate.mine", run=lambda c, p: c, requires=("bcps",), summary=summary))  # noqa: B023 - used in this iteration

        with pytest.raises(PluginError, match=message):
            create_plugin_manager(load_entrypoints=False, plugins=[Variant()])


def test_the_csv_exports_follow_the_recipe_option(tmp_path):
    outcomes, out = _run(Plugin(), [{"use": "bcps.fake"}, {"use": "evaluate.fake"}], ["a"], tmp_path,
                         outputs={"csv": True})
    points = (out / "a" / "bcps_points.csv").read_text().splitlines()
    assert points[0] == ("x_mm,y_mm,z_mm,deviation_mm,camera,u_px,v_px,segment_mm,confidence,region,lower_mm,upper_mm,"
                         "out_of_tolerance")
    assert len(points) == 7
    assert points[4] == "3.000000,0.000000,0.000000,-0.300000,1,0.0000,0.0000,1.000000,,default,-0.100000,0.100000,1"
    assert points[6].endswith(",top,-0.250000,0.250000,0")  # 0.2 mm is within the top region's band
    regions = [line.split(",") for line in (out / "a" / "regions.csv").read_text().splitlines()]
    assert regions[0][:6] == ["region", "lower_mm", "upper_mm", "n_points", "out_of_tolerance_points", "within_tolerance"]
    assert [r[0] for r in regions[1:]] == ["default", "top", "all"]
    assert regions[1][3:5] == ["4", "1"] and regions[3][3:5] == ["6", "1"]
    # the next run without the option leaves no stale CSV beside the new PLY
    _run(Plugin(), [{"use": "bcps.fake"}, {"use": "evaluate.fake"}], ["a"], tmp_path)
    assert not (out / "a" / "bcps_points.csv").exists() and not (out / "a" / "regions.csv").exists()


def test_outputs_table_is_validated():
    pm = create_plugin_manager(plugins=[Plugin()])
    with pytest.raises(RecipeError, match=r"outputs.csv: expected bool, got 'yes'"):
        parse_recipe({"stages": [{"use": "segment.mode"}], "outputs": {"csv": "yes"}}, pm)


# ------------------------------------------------------------------ item 4: time visible


def test_hook_times_are_in_timings_and_slow_ones_are_warned_about(tmp_path):
    plugin = Plugin(on_result_s=0.05)
    outcomes, out = _run(plugin, [{"use": "segment.mode", "params": {"sleep_s": 0.05}}], ["a"], tmp_path,
                         budget={"stage_s": 0.01, "hook_s": 0.02})
    res = json.loads((out / "a" / "result.json").read_text())  # rewritten after on_result
    t = res["timings_s"]
    assert {"segment", "total", "hook:Plugin:on_result", "hook:history:on_result"} <= set(t)
    assert t["hook:Plugin:on_result"] >= 0.05 and t["segment"] >= 0.05
    expected = [
        "stage 'segment' (segment.mode of plugin 'Plugin') took longer than its 0.01 s budget (timings_s['segment']); "
        "raise it with [budget] stage_s or INSPECTOR_STAGE_BUDGET_S",
        "plugin 'Plugin' took longer than the 0.02 s hook budget in inspector_on_result "
        "(timings_s['hook:Plugin:on_result']); raise it with [budget] hook_s or INSPECTOR_HOOK_BUDGET_S",
    ]
    warnings = res["stats"]["warnings"]
    assert warnings[:2] == expected
    assert all("plugin 'history'" in w for w in warnings[2:])  # a loaded machine: SQLite may take 20 ms too
    assert outcomes[0].result.timings_s["hook:Plugin:on_result"] == t["hook:Plugin:on_result"]


def test_the_budget_comes_from_the_recipe_else_the_environment(monkeypatch):
    pm = create_plugin_manager(plugins=[Plugin()])
    base = {"stages": [{"use": "segment.mode"}]}
    assert parse_recipe(base, pm).budget.hook_s == 1.0  # the default
    monkeypatch.setenv("INSPECTOR_HOOK_BUDGET_S", "0.25")
    assert parse_recipe(base, pm).budget.hook_s == 0.25
    assert parse_recipe({**base, "budget": {"hook_s": 3.0}}, pm).budget.hook_s == 3.0
    monkeypatch.setenv("INSPECTOR_STAGE_BUDGET_S", "soon")
    with pytest.raises(RecipeError, match="^INSPECTOR_STAGE_BUDGET_S: expected seconds, got 'soon'$"):
        parse_recipe(base, pm)
    monkeypatch.setenv("INSPECTOR_STAGE_BUDGET_S", "0")
    with pytest.raises(RecipeError, match="^INSPECTOR_STAGE_BUDGET_S: expected a value >= 0.001, got 0.0$"):
        parse_recipe(base, pm)
    monkeypatch.delenv("INSPECTOR_STAGE_BUDGET_S")
    with pytest.raises(RecipeError, match=r"<recipe>: budget.hook_s: expected a value >= 0.001, got -1"):
        parse_recipe({**base, "budget": {"hook_s": -1}}, pm)


def test_a_slow_run_hook_is_warned_about_by_the_session(tmp_path, monkeypatch):
    from inspector.session import Session, Source, Warned

    class SlowStart:
        @hookimpl
        def inspector_on_run_start(self, recipe, outdir, source):
            time.sleep(0.03)

    monkeypatch.setenv("INSPECTOR_HOOK_BUDGET_S", "0.01")
    pm = create_plugin_manager(plugins=[Plugin(), SlowStart()])
    recipe = tmp_path / "r.toml"
    recipe.write_text('[[stages]]\nuse = "segment.mode"\n')
    session = Session.open(recipe, tmp_path / "out", pm=pm)
    events = []
    session.subscribe(events.append)
    session.run(Source(captures=()))  # no capture: the run hooks run all the same
    warned = [e.text for e in events if isinstance(e, Warned)]
    assert warned == ["plugin 'SlowStart' took longer than the 0.01 s hook budget in inspector_on_run_start "
                      "(timings_s['hook:SlowStart:on_run_start']); raise it with [budget] hook_s or "
                      "INSPECTOR_HOOK_BUDGET_S"]


def test_a_csv_export_that_cannot_be_written_is_a_warning_not_a_lost_result(tmp_path, monkeypatch, capsys):
    from inspector import exports

    def full(result, folder):
        raise OSError(28, "No space left on device", str(folder / exports.POINTS_CSV))

    monkeypatch.setattr(exports, "write_csv", full)
    outcomes, out = _run(Plugin(), [{"use": "bcps.fake"}, {"use": "evaluate.fake"}], ["a", "b"], tmp_path,
                         outputs={"csv": True})
    assert [o.result.verdict for o in outcomes] == ["pass", "pass"]
    assert (out / "b" / "result.json").is_file() and set(_history(out)) == {"a", "b"}
    assert capsys.readouterr().err.splitlines() == [
        f"inspector: warning: capture '{n}': CSV export not written: {out / n / 'bcps_points.csv'}: "
        "No space left on device" for n in ("a", "b")]
