"""The hot folder's hand-off, crash-safe and exclusive (issue 15).

* One watcher per inbox: a second one is refused in one line, exit 2.
* A capture is either waiting (in the inbox or ``processing/``) or done with exactly one
  result and one history row, whatever point a crash hits: checked by crashing at each step
  of the hand-off in this process, and by ``kill -9`` of a real ``inspector run --watch`` at
  random points (several seeds), each followed by a restart.
* A writer that stalls inside an image does not turn a good part into an error.
* A capture name with a newline is one line.

Captures are real capture folders of one 64x48 camera (written in milliseconds); the recipe
has one stage, so a capture takes a few milliseconds and most of a cycle is the hand-off.
"""

from __future__ import annotations

import json
import os
import queue
import random
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from inspector.errors import RecipeError
from inspector_drivers.replay.hotfolder import DONE_DIR, PROCESSING_DIR, HotFolderDriver, HotFolderParams

RECIPE = """
[recipe]
name = "handoff"
[[stages]]
use = "segment.threshold"
"""


def _capture(folder: Path) -> Path:
    import cv2

    from inspector.capture_folder import write_capture
    from inspector.model import Camera, Rig

    img = np.full((48, 64), 220.0, np.float32)
    cv2.circle(img, (32, 24), 12, 30.0, -1)
    img = cv2.GaussianBlur(img, (0, 0), 0.8).round().astype(np.uint8)
    cam = Camera("c0", 64, 48, [[80.0, 0, 31.5], [0, 80.0, 23.5], [0, 0, 1]], None, np.eye(3), [0.0, 0.0, 100.0])
    return write_capture(folder, Rig((cam,)), {"c0": img})


@pytest.fixture
def setup(tmp_path):
    """(inbox, out, recipe, a prototype capture to copy)."""
    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    recipe = tmp_path / "r.toml"
    recipe.write_text(RECIPE)
    return inbox, out, recipe, _capture(tmp_path / "proto")


def _drop(proto: Path, inbox: Path, name: str) -> Path:
    tmp = inbox / f"{name}.partial"
    shutil.copytree(proto, tmp)
    return tmp.rename(inbox / name)


def _history(out: Path) -> list[str]:
    path = out / "history.sqlite"
    if not path.exists():
        return []
    con = sqlite3.connect(path)
    try:
        return [r[0] for r in con.execute("SELECT capture FROM inspections ORDER BY id")]
    finally:
        con.close()


def assert_exactly_once(inbox: Path, out: Path, names: list[str]) -> None:
    """Every capture done, with exactly one result folder (its own name: no NAME-2) and one
    history row; nothing waiting, nothing partial, no temporary file anywhere."""
    assert sorted(p.name for p in inbox.iterdir()) in ([DONE_DIR], [DONE_DIR, PROCESSING_DIR])
    assert not (inbox / PROCESSING_DIR).exists() or not any((inbox / PROCESSING_DIR).iterdir())
    assert sorted(p.name for p in (inbox / DONE_DIR).iterdir()) == sorted(names)
    results = sorted(p.name for p in out.iterdir() if p.name != "history.sqlite" and not p.name.startswith("history.sqlite-"))
    assert results == sorted(names)
    for name in names:
        assert sorted(p.name for p in (out / name).iterdir()) == ["result.json"]
        assert json.loads((out / name / "result.json").read_text())["verdict"] == "pass"
    assert Counter(_history(out)) == Counter(names)


def _watch(recipe: Path, inbox: Path, out: Path, *extra: str) -> list[str]:
    return ["run", str(recipe), "--watch", str(inbox), "--out", str(out), *extra]


# --------------------------------------------------------------------------- one watcher


def test_a_second_watcher_on_the_same_inbox_is_refused_in_one_line(setup, capsys):
    from inspector_frontends.cli import main

    inbox, out, recipe, proto = setup
    _drop(proto, inbox, "p1")
    first = HotFolderDriver(HotFolderParams(folder=str(inbox)))
    try:
        with pytest.raises(RecipeError, match=r"^hotfolder: inbox .*: another watcher \(pid \d+\) is already inspecting it;"):
            HotFolderDriver(HotFolderParams(folder=str(inbox)))
        assert main(_watch(recipe, inbox, out, "--idle-exit", "1")) == 2
        err = capsys.readouterr().err
        assert err == (f"inspector: error: hotfolder: inbox {inbox}: another watcher (pid {os.getpid()}) is already "
                       "inspecting it; stop it first (two would inspect every capture twice)\n")
        assert (inbox / "p1").is_dir() and not out.exists()
    finally:
        first.close()
    assert main(_watch(recipe, inbox, out, "--idle-exit", "1", "-q")) == 0  # released: the next one runs
    assert_exactly_once(inbox, out, ["p1"])


def _start_watcher(recipe: Path, inbox: Path, out: Path, *extra: str) -> tuple[subprocess.Popen, queue.Queue]:
    """A real ``inspector run --watch`` process; its stdout lines arrive in the queue."""
    proc = subprocess.Popen([sys.executable, "-m", "inspector_frontends.cli", *_watch(recipe, inbox, out, *extra)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in proc.stdout:
            lines.put(line.rstrip("\n"))
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return proc, lines


def _next_line(lines: queue.Queue, timeout: float = 120.0) -> str | None:
    return lines.get(timeout=timeout)


def test_a_second_watcher_process_is_refused_while_the_first_runs(setup, capsys):
    from inspector_frontends.cli import main

    inbox, out, recipe, proto = setup
    proc, lines = _start_watcher(recipe, inbox, out, "--idle-exit", "60")
    try:
        assert _next_line(lines).startswith(f"watching {inbox}")
        assert main(_watch(recipe, inbox, tmp_out := out.with_name("out2"), "--idle-exit", "1")) == 2
        err = capsys.readouterr().err.splitlines()
        assert err == [f"inspector: error: hotfolder: inbox {inbox}: another watcher (pid {proc.pid}) is already "
                       "inspecting it; stop it first (two would inspect every capture twice)"]
        assert not tmp_out.exists()
        _drop(proto, inbox, "p1")  # the first watcher still works
        assert _next_line(lines).startswith("[1] p1: PASS")
    finally:
        proc.kill()
        proc.wait()


# --------------------------------------------------------------------------- crashes


class Crash(BaseException):
    """A crash at a chosen point: nothing catches it (like a kill, minus the process)."""


def _crash_while_writing_the_result(monkeypatch):
    import inspector.outputs as outputs

    write = outputs._write_files

    def crash(*args, **kwargs):
        write(*args, **kwargs)  # the hidden folder is complete, not renamed into place
        raise Crash

    monkeypatch.setattr(outputs, "_write_files", crash)


def _crash_before_the_history_row(monkeypatch):
    import inspector_plugins.history as history

    def crash(*args, **kwargs):
        raise Crash

    monkeypatch.setattr(history, "record", crash)


def _crash_after_the_history_row(monkeypatch):
    import inspector_plugins.history as history

    record = history.record

    def crash(*args, **kwargs):
        record(*args, **kwargs)
        raise Crash

    monkeypatch.setattr(history, "record", crash)


def _crash_before_the_move_to_done(monkeypatch):
    def crash(self, folder):
        raise Crash

    monkeypatch.setattr(HotFolderDriver, "_file_away", crash)


def _crash_while_claiming(monkeypatch):
    real = os.rename

    def crash(src, dst, *args, **kwargs):
        if Path(dst).parent.name == PROCESSING_DIR:
            raise Crash
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "rename", crash)


@pytest.mark.parametrize("crash", [_crash_while_claiming, _crash_while_writing_the_result, _crash_before_the_history_row,
                                   _crash_after_the_history_row, _crash_before_the_move_to_done],
                         ids=lambda f: f.__name__.strip("_"))
def test_a_crash_at_each_step_of_the_hand_off_then_a_restart_inspects_each_capture_once(setup, monkeypatch, crash):
    from inspector_frontends.cli import main

    inbox, out, recipe, proto = setup
    names = ["p1", "p2", "p3"]
    for name in names:
        _drop(proto, inbox, name)
    with monkeypatch.context() as m:
        crash(m)
        with pytest.raises(Crash):
            main(_watch(recipe, inbox, out, "--idle-exit", "5", "-q"))
    assert main(_watch(recipe, inbox, out, "--idle-exit", "1", "-q")) == 0
    assert_exactly_once(inbox, out, names)


def test_kill_9_at_random_points_then_restart_inspects_each_capture_exactly_once(setup):
    """The issue's probe: kill -9 of a real watcher while it works through a backlog, at
    random points, several times, then a restart that finishes the work. Seeds 1..3, two
    kills each: about 20 s per seed (each start loads the kernels)."""
    inbox, out, recipe, proto = setup
    names = [f"p{i:02d}" for i in range(12)]
    for name in names:
        _drop(proto, inbox, name)
    for seed in (1, 2, 3):
        rng = random.Random(seed)
        for _ in range(2):
            proc, lines = _start_watcher(recipe, inbox, out, "--idle-exit", "60")
            try:
                assert _next_line(lines).startswith("watching ")
                for _ in range(rng.randint(0, 2)):  # a few captures into the run...
                    line = _next_line(lines)
                    if line is None:
                        break
                time.sleep(rng.uniform(0.0, 0.08))  # ...then anywhere in the next hand-off
            finally:
                proc.send_signal(signal.SIGKILL)
                proc.wait()
        names += [f"s{seed}-{i}" for i in range(4)]  # more work for the next seed
        for name in names[-4:]:
            _drop(proto, inbox, name)
    proc, lines = _start_watcher(recipe, inbox, out, "--idle-exit", "2", "-q")
    assert proc.wait(timeout=300) == 0
    assert_exactly_once(inbox, out, names)


def test_what_a_crash_left_in_processing_goes_first_and_a_settled_one_is_only_filed(setup, capsys):
    from inspector_frontends.cli import main

    inbox, out, recipe, proto = setup
    _drop(proto, inbox, "new")
    assert main(_watch(recipe, inbox, out, "--count", "1", "-q")) == 0
    shutil.move(inbox / DONE_DIR / "new", inbox / PROCESSING_DIR / "new")  # as if killed before the move
    shutil.copytree(proto, inbox / PROCESSING_DIR / "half")  # killed before its result was in place
    (out / ".half.partial").mkdir()
    (out / ".half.partial" / "result.json.part").write_text("{")
    _drop(proto, inbox, "later")
    assert main(_watch(recipe, inbox, out, "--idle-exit", "1")) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines[1:3]] == ["[1] half", "[2] later"]
    assert_exactly_once(inbox, out, ["new", "half", "later"])


# --------------------------------------------------------------------------- stalled writers


def test_a_writer_that_stalls_inside_an_image_is_waited_for_not_failed(setup, capsys):
    """The issue's probe: a writer stalling 2 s inside an image turned a good part into an
    error that was never retried. Written in place, rig.json first (the unsafe order), with
    the default settle time of 0.5 s."""
    from inspector_frontends.cli import main

    inbox, out, recipe, proto = setup
    png = (proto / "images" / "c0.png").read_bytes()

    def writer() -> None:
        folder = inbox / "slow"
        (folder / "images").mkdir(parents=True)
        shutil.copy(proto / "rig.json", folder / "rig.json")
        with open(folder / "images" / "c0.png", "wb") as f:
            f.write(png[: len(png) // 2])
            f.flush()
            time.sleep(2.0)
            f.write(png[len(png) // 2:])

    t = threading.Thread(target=writer)
    t.start()
    try:
        code = main(_watch(recipe, inbox, out, "--count", "1", "--idle-exit", "30"))
    finally:
        t.join()
    assert code == 0, capsys.readouterr()
    assert json.loads((out / "slow" / "result.json").read_text())["verdict"] == "pass"
    assert_exactly_once(inbox, out, ["slow"])


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


def test_a_writer_that_died_inside_an_image_is_an_error_after_give_up(setup):
    from inspector.errors import CaptureError

    inbox, out, recipe, proto = setup
    cut = _drop(proto, inbox, "cut")
    png = cut / "images" / "c0.png"
    png.write_bytes(png.read_bytes()[:100])
    clock = Clock()
    d = HotFolderDriver(HotFolderParams(folder=str(inbox), settle_s=0.5, give_up_s=20.0), clock=clock, sleep=clock.sleep)
    try:
        acq = next(d.acquire())
        assert acq.name == "cut" and clock.t >= 1020.0  # looked at again and again, then handed over
        with pytest.raises(CaptureError, match=r"^images/c0.png: truncated PNG \(no IEND chunk\)$"):
            acq.load()
    finally:
        d.close()


# --------------------------------------------------------------------------- names


def test_a_capture_name_with_a_newline_is_one_line_and_the_others_go_on(setup, capsys):
    from inspector_frontends.cli import main

    inbox, out, recipe, proto = setup
    _drop(proto, inbox, "a\nb")
    _drop(proto, inbox, "good")
    assert main(_watch(recipe, inbox, out, "--count", "2", "-q")) == 3
    err = capsys.readouterr().err.splitlines()
    assert err == ["inspector: error: a\\nb: capture name 'a\\nb' contains a control character or bytes that are not "
                   "UTF-8; rename it"]
    assert sorted(p.name for p in (inbox / DONE_DIR).iterdir()) == ["a\nb", "good"]
    assert _history(out) == ["good"]
    # The same through --capture.
    assert main(["run", str(recipe), "--capture", str(inbox / DONE_DIR / "a\nb"), str(inbox / DONE_DIR / "good"),
                 "--out", str(out.with_name("o2"))]) == 3
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == ("[1/2] a\\nb: ERROR capture name 'a\\nb' contains a control character or bytes that are not "
                        "UTF-8; rename it") and lines[1].startswith("[2/2] good: PASS")
