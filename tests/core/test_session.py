"""Session: the Qt-free run loop that the CLI and the GUI drive (start, stop, cancel, hooks)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pytest

from inspector import hookimpl
from inspector.errors import RecipeError
from inspector.manager import create_plugin_manager
from inspector.model import Capture, Rig
from inspector.params import param
from inspector.registry import Acquisition, DriverSpec, StageSpec
from inspector.session import Inspected, RunEnded, RunStarted, Session, Source


@dataclass(frozen=True)
class ListParams:
    count: int = param(3, "captures to yield", min=1)


@dataclass
class ListDriver:
    params: ListParams
    closed: bool = False

    def acquire(self):
        for i in range(self.params.count):
            name = f"part{i:02d}"
            yield Acquisition(name, lambda name=name: Capture(name=name, rig=Rig(()), images={}))

    def close(self):
        self.closed = True


class Plugin:
    """A driver of empty captures, two stages, and a record of every lifecycle hook."""

    def __init__(self):
        self.events = []
        self.gate = threading.Event()  # the first stage waits on it when `block` is set
        self.entered = threading.Event()
        self.block = False
        self.drivers = []

    @hookimpl
    def inspector_register_drivers(self, registry):
        def open_(p):
            self.drivers.append(ListDriver(p))
            return self.drivers[-1]

        registry.add(DriverSpec(name="list", open=open_, params=ListParams, doc="test driver"))

    @hookimpl
    def inspector_register_stages(self, registry):
        def first(ctx, p):
            if self.block:
                self.entered.set()
                assert self.gate.wait(10)
            return ctx.evolve(silhouettes=())  # a segment stage sets silhouettes (the runner checks)

        registry.add(StageSpec(name="segment.first", run=first, doc="test stage"))
        registry.add(StageSpec(name="classify.second", run=lambda ctx, p: ctx, doc="test stage"))

    @hookimpl
    def inspector_on_run_start(self, recipe, outdir, source):
        self.events.append(("run-start", recipe.name, outdir.name, source))

    @hookimpl
    def inspector_on_run_end(self, recipe, outdir, summary):
        self.events.append(("run-end", summary.ended, dict(summary.counts)))

    @hookimpl
    def inspector_before_stage(self, context, stage, step):
        self.events.append(("stage", context.capture.name, step))

    @hookimpl
    def inspector_on_result(self, result, outdir):
        self.events.append(("result", result.capture, result.verdict))


RECIPE = """
[recipe]
name = "session-test"
[driver]
use = "list"
params = { count = 3 }
[[stages]]
use = "segment.first"
[[stages]]
name = "carve"
use = "classify.second"
"""


@pytest.fixture
def setup(tmp_path):
    plugin = Plugin()
    pm = create_plugin_manager(plugins=[plugin])
    recipe = tmp_path / "r.toml"
    recipe.write_text(RECIPE)
    session = Session.open(recipe, tmp_path / "out", pm=pm)
    events = []
    session.subscribe(events.append)
    yield session, plugin, events, tmp_path / "out"
    session.close()


def test_a_run_calls_the_run_hooks_and_writes_every_result(setup):
    session, plugin, events, out = setup
    summary = session.run()
    assert summary.ended == "done" and summary.counts["pass"] == 3 and summary.exit_status == 0
    assert plugin.events[0] == ("run-start", "session-test", "out", "driver list")
    assert plugin.events[-1] == ("run-end", "done", {"pass": 3, "fail": 0, "error": 0, "aborted": 0})
    assert [e[1] for e in plugin.events if e[0] == "result"] == ["part00", "part01", "part02"]
    assert all((out / f"part0{i}" / "result.json").is_file() for i in range(3))
    assert (out / "history.sqlite").is_file()
    assert isinstance(events[0], RunStarted) and events[0].total == 3
    assert [e.index for e in events if isinstance(e, Inspected)] == [1, 2, 3]
    assert isinstance(events[-1], RunEnded) and events[-1].summary is summary
    # The recipe's identity travels with every result.
    import json

    doc = json.loads((out / "part00" / "result.json").read_text())
    assert doc["recipe_sha256"] == session.recipe.sha256 and len(doc["recipe_sha256"]) == 64


def test_limit_continues_the_recipes_driver_where_the_last_run_stopped(setup):
    session, plugin, events, out = setup
    names = []
    for _ in range(3):
        s = session.run(Source(limit=1))
        assert s.counts["pass"] == 1
        names.append([e for e in plugin.events if e[0] == "result"][-1][1])
    assert names == ["part00", "part01", "part02"]
    assert len(plugin.drivers) == 1  # one driver, kept open across runs
    session.run(Source(limit=1))  # it ran out: reopened, starts again
    assert len(plugin.drivers) == 2 and plugin.drivers[0].closed


def test_cancel_between_stages_aborts_and_writes_nothing(setup):
    session, plugin, events, out = setup
    plugin.block = True
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("s", session.run()))
    t.start()
    assert plugin.entered.wait(10)
    session.cancel()  # while the first stage runs: the second must not start
    plugin.gate.set()
    t.join(10)
    summary = box["s"]
    assert summary.ended == "cancelled"
    assert summary.counts == {"pass": 0, "fail": 0, "error": 0, "aborted": 1}
    assert ("stage", "part00", "carve") not in plugin.events
    assert not any(e[0] == "result" for e in plugin.events)  # no on_result: no history row, no PLC message
    assert not (out / "part00").exists()
    assert not (out / "history.sqlite").exists()
    aborted = [e for e in events if isinstance(e, Inspected)]
    assert len(aborted) == 1 and aborted[0].outcome.result.verdict == "aborted" and aborted[0].folder is None
    assert "cancelled before stage carve" in aborted[0].outcome.result.error
    assert plugin.events[-1][:2] == ("run-end", "cancelled")
    # The next run starts clean and inspects the next part.
    plugin.block = False
    assert session.run(Source(limit=1)).counts["pass"] == 1


def test_stop_ends_after_the_capture_in_progress(setup):
    session, plugin, events, out = setup
    session.subscribe(lambda e: session.stop() if isinstance(e, Inspected) else None)
    summary = session.run()
    assert summary.ended == "stopped" and summary.counts["pass"] == 1
    assert (out / "part00" / "result.json").is_file()


def test_stop_wakes_a_waiting_hot_folder(setup, tmp_path):
    session, plugin, events, out = setup
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("s", session.run(Source(watch={"folder": str(inbox), "poll_s": 0.05}))))
    t.start()
    for _ in range(100):
        if any(isinstance(e, RunStarted) for e in events):
            break
        threading.Event().wait(0.02)
    session.stop()
    t.join(5)
    assert not t.is_alive() and box["s"].ended == "stopped" and box["s"].inbox == inbox


def test_bad_sources_are_refused_before_anything_runs(setup, tmp_path):
    session, plugin, events, out = setup
    with pytest.raises(RecipeError, match="not both"):
        Source(captures=("a",), watch={"folder": "b"})
    with pytest.raises(RecipeError, match="not a folder"):
        session.run(Source(watch={"folder": str(tmp_path / "missing")}))
    (tmp_path / "afile").write_text("x")
    s2 = Session.open(tmp_path / "r.toml", tmp_path / "afile", pm=session.pm)
    with pytest.raises(RecipeError, match="is a file"):
        s2.run()
    assert not any(e[0] == "result" for e in plugin.events)


def test_a_subscriber_that_raises_loses_nothing(setup, capsys):
    session, plugin, events, out = setup
    session.subscribe(lambda e: 1 / 0)
    assert session.run().counts["pass"] == 3
    assert "a session subscriber failed" in capsys.readouterr().err


class AheadExecutor:
    """An executor of its own (as a cluster's): it inspects every capture before handing any
    back, returns them in reverse order without their context, and warns about the run."""

    def __init__(self):
        self.closed = False
        self.handed = 0

    def warnings(self):
        return ["this executor works ahead"]

    def execute(self, recipe, acquisitions, pm, *, reference, should_abort=None):
        from inspector.runner import Outcome, inspect_acquisition

        outcomes = [inspect_acquisition(a, recipe, reference, pm) for a in acquisitions]
        try:
            for o in reversed(outcomes):
                self.handed += 1
                yield Outcome(o.result, None, o.trace)
        finally:
            self.closed = True


def _results(out):
    import json

    docs = {p.parent.name: json.loads(p.read_text()) for p in out.glob("*/result.json")}
    return {name: ({k: v for k, v in d.items() if k != "timings_s"}, sorted(d["timings_s"])) for name, d in docs.items()}


def _rows(out):
    from inspector.history_store import read_history

    varying = {"id", "uid", "inspected_at", "total_s", "chain"}
    return sorted(({k: v for k, v in r.items() if k not in varying} for r in read_history(out)), key=lambda r: r["capture"])


def test_a_custom_executor_s_outcomes_are_recorded_by_the_session_as_local_ones(setup, tmp_path):
    from inspector.session import Warned

    session, plugin, events, out = setup
    local = session.run()
    other = Session.open(tmp_path / "r.toml", tmp_path / "out2", pm=session.pm)
    seen = []
    other.subscribe(seen.append)
    executor = AheadExecutor()
    try:
        summary = other.run(executor=executor)
    finally:
        other.close()
    assert executor.closed
    assert summary.counts == local.counts and summary.ended == "done" and summary.exit_status == 0
    assert _results(tmp_path / "out2") == _results(out) and len(_results(out)) == 3
    assert _rows(tmp_path / "out2") == _rows(out) and len(_rows(out)) == 3
    # The same events, in the executor's order; its warning first, as a run warning.
    assert seen[0] == Warned("run", "this executor works ahead") and isinstance(seen[1], RunStarted)
    inspected = [e for e in seen if isinstance(e, Inspected)]
    assert [(e.index, e.total, e.outcome.result.capture) for e in inspected] == [(1, 3, "part02"), (2, 3, "part01"), (3, 3, "part00")]
    assert all(e.folder == tmp_path / "out2" / e.outcome.result.capture for e in inspected)
    assert isinstance(seen[-1], RunEnded) and seen[-1].summary is summary
    assert [type(e) for e in events] == [type(e) for e in seen[1:]]
    assert [e[1:] for e in plugin.events if e[0] == "result"][-3:] == [("part02", "pass"), ("part01", "pass"), ("part00", "pass")]


def test_a_run_that_ends_early_closes_its_executor_first(setup):
    session, plugin, events, out = setup
    executor = AheadExecutor()
    closed_at_end = []

    def interrupt(event):
        if isinstance(event, Inspected):
            raise KeyboardInterrupt  # Ctrl-C while the first result is printed
        if isinstance(event, RunEnded):
            closed_at_end.append(executor.closed)

    session.subscribe(interrupt)
    with pytest.raises(KeyboardInterrupt):
        session.run(executor=executor)
    assert closed_at_end == [True] and executor.handed == 1  # its other work given up (a cluster's tasks cancelled)
    assert [p.name for p in out.iterdir() if p.is_dir()] == ["part02"]


def test_stop_ends_a_run_whose_executor_works_ahead_after_the_capture_in_progress(setup):
    session, plugin, events, out = setup
    session.subscribe(lambda e: session.stop() if isinstance(e, Inspected) else None)
    executor = AheadExecutor()
    summary = session.run(executor=executor)
    assert summary.ended == "stopped" and summary.counts["pass"] == 1 and executor.closed
    assert [p.name for p in out.iterdir() if p.is_dir()] == ["part02"]
