"""The ``hotfolder`` driver: capture folders dropped in an inbox by another program.

Real folders on disk, real capture files; the driver's clock is virtual where a test needs
"unchanged for N seconds" (no test waits on wall time except the end-to-end one, which only
waits for the work itself).
"""

from __future__ import annotations

import json
import os
import shutil
import threading
import time
from pathlib import Path

import pytest

from inspector.errors import CaptureError, RecipeError
from inspector_drivers.replay.hotfolder import DONE_DIR, PROCESSING_DIR, HotFolderDriver, HotFolderParams

DEFAULT = str(Path(__file__).resolve().parents[2] / "recipes" / "default.toml")


class Clock:
    """Virtual time: sleeping advances it."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


def _driver(inbox: Path, clock: Clock, **params) -> HotFolderDriver:
    return HotFolderDriver(HotFolderParams(folder=str(inbox), **params), clock=clock, sleep=clock.sleep)


def _drop(src: Path, inbox: Path, name: str) -> Path:
    """Copy a capture into the inbox the safe way: under a temporary name, then rename."""
    tmp = inbox / f"{name}.partial"
    shutil.copytree(src, tmp)
    return tmp.rename(inbox / name)


def test_a_complete_folder_is_read_once_quiet_and_then_filed_in_done(tmp_path, small_capture):
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    _drop(small_capture, inbox, "part1")
    clock = Clock()
    gen = _driver(inbox, clock, settle_s=0.5, count=1).acquire()
    acq = next(gen)
    assert acq.name == "part1" and clock.t >= 1000.5  # waited until it had been quiet 0.5 s
    assert acq.load().name == "part1" and len(acq.load().rig) == 8
    assert not (inbox / "part1").exists() and (inbox / PROCESSING_DIR / "part1").is_dir()  # claimed, not done
    with pytest.raises(StopIteration):
        next(gen)  # resumed: the result is written; count reached
    assert not (inbox / "part1").exists() and (inbox / DONE_DIR / "part1" / "rig.json").is_file()


def test_an_incomplete_folder_waits_then_is_handed_over_and_names_the_missing_camera(tmp_path, small_capture):
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    broken = _drop(small_capture, inbox, "part2")
    (broken / "images" / "cam03.png").unlink()  # a writer that died half-way
    clock = Clock()
    acq = next(_driver(inbox, clock, settle_s=0.5, give_up_s=20.0).acquire())
    assert acq.name == "part2" and clock.t >= 1020.0  # not before give_up_s without a change
    with pytest.raises(CaptureError, match="camera cam03 has no image"):
        acq.load()


def test_a_folder_still_being_written_is_not_read(tmp_path, small_capture):
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    part = _drop(small_capture, inbox, "part3")
    clock = Clock()
    d = _driver(inbox, clock, settle_s=0.5)
    assert not d._ready(part, clock())  # first sight
    clock.sleep(0.3)
    (part / "capture.json").write_text(json.dumps({"part_id": "p3", "note": "x" * 100}))  # still writing
    assert not d._ready(part, clock())
    clock.sleep(0.3)
    assert not d._ready(part, clock())  # 0.3 s quiet only
    clock.sleep(0.3)
    assert d._ready(part, clock())


def test_backlog_oldest_first_temporary_and_done_folders_ignored_and_names_kept_unique(tmp_path, small_capture):
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    for i, name in enumerate(("zeta", "alpha")):  # zeta is older
        p = _drop(small_capture, inbox, name)
        os.utime(p, (1_000_000 + i, 1_000_000 + i))
    shutil.copytree(small_capture, inbox / "beta.tmp")
    shutil.copytree(small_capture, inbox / ".hidden")
    shutil.copytree(small_capture, inbox / DONE_DIR / "alpha")  # an earlier alpha, already done
    clock = Clock()
    names = [a.name for a in _driver(inbox, clock, settle_s=0.0, idle_exit_s=5.0).acquire()]
    assert names == ["zeta", "alpha-2"]  # an earlier alpha is in done/: renamed before it is read
    assert sorted(p.name for p in (inbox / DONE_DIR).iterdir()) == ["alpha", "alpha-2", "zeta"]
    assert (inbox / "beta.tmp").is_dir() and (inbox / ".hidden").is_dir()


def test_a_reused_name_is_renamed_before_it_is_read_so_no_result_is_overwritten(tmp_path, small_capture):
    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    (out / "part7").mkdir(parents=True)  # yesterday's part 7
    _drop(small_capture, inbox, "part7")
    clock = Clock()
    d = HotFolderDriver(HotFolderParams(folder=str(inbox), settle_s=0.0, count=1), clock=clock, sleep=clock.sleep,
                        taken=lambda name: (out / name).exists())
    acqs = list(d.acquire())
    assert [a.name for a in acqs] == ["part7-2"]
    assert (inbox / DONE_DIR / "part7-2" / "rig.json").is_file() and not (inbox / "part7").exists()


def test_keep_inspects_each_folder_once_and_leaves_it_in_place(tmp_path, small_capture):
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    _drop(small_capture, inbox, "part4")
    clock = Clock()
    names = [a.name for a in _driver(inbox, clock, settle_s=0.0, idle_exit_s=2.0, after="keep").acquire()]
    assert names == ["part4"] and (inbox / "part4").is_dir() and not (inbox / DONE_DIR).exists()


def test_an_inbox_that_is_not_a_folder_is_a_command_error(tmp_path):
    with pytest.raises(RecipeError, match=f"hotfolder: inbox {tmp_path / 'nope'}: not a folder"):
        HotFolderDriver(HotFolderParams(folder=str(tmp_path / "nope")))


def test_inspector_run_watch_inspects_what_another_program_drops_in(tmp_path, small_capture, capsys):
    # The end to end: `inspector run --watch` in this thread, a writer in another one that
    # drops two captures, the second one file by file with rig.json first (the unsafe order).
    from inspector_frontends.cli import main

    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()

    def writer() -> None:
        _drop(small_capture, inbox, "first")
        time.sleep(0.5)
        slow = inbox / "second"
        (slow / "images").mkdir(parents=True)
        shutil.copy(small_capture / "rig.json", slow / "rig.json")
        for png in sorted((small_capture / "images").iterdir()):
            time.sleep(0.05)
            shutil.copy(png, slow / "images" / png.name)

    t = threading.Thread(target=writer)
    t.start()
    try:
        code = main(["run", DEFAULT, "--watch", str(inbox), "--out", str(out), "--reference", "builtin:cube30",
                     "--count", "2", "--idle-exit", "60"])  # idle-exit: a safety net, not a timing
    finally:
        t.join()
    assert code in (0, 1)
    for name in ("first", "second"):
        res = json.loads((out / name / "result.json").read_text())
        assert res["verdict"] in ("pass", "fail"), res["error"]
        assert (inbox / DONE_DIR / name / "rig.json").is_file()
    text = capsys.readouterr().out
    assert text.startswith(f"watching {inbox} for capture folders (Ctrl-C to stop); results in {out}\n")
    assert "2 inspected" in text


@pytest.mark.parametrize("args, message", [
    (["--watch", "{inbox}", "--out", "{inbox}/results"], "--out {inbox}/results: inside the inbox {inbox} (its result folders would be taken for captures)"),
    (["--watch", "{tmp}/nope", "--out", "{tmp}/o"], "--watch {tmp}/nope: not a folder"),
    (["--capture", "{inbox}", "--count", "2", "--out", "{tmp}/o"], "--count: only with --watch"),
    (["--watch", "{inbox}", "--idle-exit", "0", "--out", "{tmp}/o"], "--idle-exit: expected seconds > 0, got 0.0"),
])
def test_watch_options_are_checked_before_anything_runs(args, message, tmp_path, capsys):
    from inspector_frontends.cli import main

    inbox = tmp_path / "inbox"
    inbox.mkdir()
    fill = {"inbox": str(inbox), "tmp": str(tmp_path)}
    assert main(["run", DEFAULT, *[a.format(**fill) for a in args], "--reference", "builtin:cube30"]) == 2
    assert capsys.readouterr().err.strip() == f"inspector: error: {message.format(**fill)}"
    assert not (tmp_path / "o").exists() and list(inbox.iterdir()) == []


def test_a_recipe_can_use_the_hotfolder_driver(tmp_path, small_capture):
    from inspector_frontends.cli import main

    inbox = tmp_path / "inbox"
    inbox.mkdir()
    _drop(small_capture, inbox, "part9")
    recipe = tmp_path / "watch.toml"
    text = Path(DEFAULT).read_text().replace('use = "replay"', f'use = "hotfolder"\nparams = {{ folder = "{inbox}", count = 1, settle_s = 0.1 }}')
    recipe.write_text(text)
    assert main(["run", str(recipe), "--out", str(tmp_path / "o"), "--reference", "builtin:cube30", "-q"]) in (0, 1)
    assert (tmp_path / "o" / "part9" / "result.json").is_file() and (inbox / DONE_DIR / "part9").is_dir()


def test_ctrl_c_ends_a_watch_like_its_other_ends(tmp_path, small_capture, monkeypatch, capsys):
    # The watch is stopped while it waits (KeyboardInterrupt from its sleep): the summary and
    # the exit status of what was inspected, not an error.
    import inspector_drivers.replay.hotfolder as hf
    from inspector_frontends.cli import main

    inbox, out = tmp_path / "inbox", tmp_path / "out"
    inbox.mkdir()
    _drop(small_capture, inbox, "only")
    naps = []

    def sleep(s):
        naps.append(s)
        if not (inbox / "only").exists():  # inspected and filed: the operator presses Ctrl-C
            raise KeyboardInterrupt

    class Stopping(hf.HotFolderDriver):
        def __post_init__(self):
            super().__post_init__()
            self.sleep = sleep

    monkeypatch.setattr(hf, "HotFolderDriver", Stopping)
    code = main(["run", DEFAULT, "--watch", str(inbox), "--out", str(out), "--reference", "builtin:cube30"])
    text = capsys.readouterr().out
    assert code == (0 if json.loads((out / "only" / "result.json").read_text())["verdict"] == "pass" else 1)
    assert "watch stopped\n1 inspected: " in text


def test_a_watch_that_sees_nothing_ends_quietly(tmp_path, capsys):
    from inspector_frontends.cli import main

    inbox = tmp_path / "inbox"
    inbox.mkdir()
    code = main(["run", DEFAULT, "--watch", str(inbox), "--out", str(tmp_path / "o"), "--reference", "builtin:cube30",
                 "--idle-exit", "0.3"])
    assert code == 0 and capsys.readouterr().out.strip().endswith(f"no capture arrived in {inbox}")
