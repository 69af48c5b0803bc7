"""Result folders are written whole or not at all, and a full disk is one line naming the file
and the capture (issue 15: "No space left on device" named neither and left ``*.part`` files).

Real files and processes: a file-size limit (``RLIMIT_FSIZE``) on a real ``inspector run``
process, and, where the tests may mount one (root), a small tmpfs that is really full.
"""

from __future__ import annotations

import json
import os
import resource
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from inspector.errors import CaptureError
from inspector.model import BcpsPoints, InspectionResult
from inspector.outputs import discard_result, write_result

RECIPE = """
[recipe]
name = "writes"
[[stages]]
use = "segment.threshold"
"""


def _result(name: str, *, points: int = 0) -> InspectionResult:
    bcps = None
    if points:
        z = np.zeros(points)
        bcps = BcpsPoints(points=np.zeros((points, 3)), deviation=z, camera=z.astype(int), pixel=np.zeros((points, 2)),
                          segment_mm=z, method="ray")
    return InspectionResult(name, "r", "pass", None, {"total": 0.1}, bcps=bcps)


def _tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def _leftovers(root: Path) -> list[str]:
    """Temporary files and folders anywhere under ``root``."""
    return [p for p in _tree(root) if p.endswith((".part", ".partial", ".old")) or "/." in f"/{p}"]


def test_a_rerun_replaces_the_result_files_and_keeps_the_others(tmp_path):
    out = tmp_path / "out"
    write_result(_result("p1", points=5), out)
    assert _tree(out) == ["p1", "p1/bcps_points.ply", "p1/result.json"]
    (out / "p1" / "report.pdf").write_text("exported")
    (out / "p1" / "note.txt").write_text("operator's note")
    write_result(_result("p1"), out)  # this time without points: the old ply must go
    assert _tree(out) == ["p1", "p1/note.txt", "p1/report.pdf", "p1/result.json"]
    assert json.loads((out / "p1" / "result.json").read_text())["points"]["bcps"] is None


def test_what_a_crash_left_is_cleared_by_the_next_write(tmp_path):
    out = tmp_path / "out"
    (out / ".p1.partial").mkdir(parents=True)  # a crash while p1 was written
    (out / ".p1.partial" / "result.json.part").write_text("{")
    (out / ".p2.old").mkdir()  # a crash while a re-run of p2 swapped its folder
    (out / ".p2.old" / "result.json").write_text('{"verdict": "fail"}')
    (out / ".p2.old" / "note.txt").write_text("keep me")
    write_result(_result("p1"), out)
    write_result(_result("p2"), out)
    assert _tree(out) == ["p1", "p1/result.json", "p2", "p2/note.txt", "p2/result.json"]
    assert json.loads((out / "p2" / "result.json").read_text())["verdict"] == "pass"
    discard_result(out, "p1")
    discard_result(out, "..")  # never outside OUTDIR
    assert _tree(out) == ["p2", "p2/note.txt", "p2/result.json"]


def test_a_long_name_has_a_temporary_folder_that_fits(tmp_path):
    name = "x" * 255
    assert write_result(_result(name), tmp_path) == tmp_path / name
    assert _tree(tmp_path) == [name, f"{name}/result.json"]


def _small_capture(folder: Path) -> Path:
    import cv2

    from inspector.capture_folder import write_capture
    from inspector.model import Camera, Rig

    img = np.full((48, 64), 220.0, np.float32)
    cv2.circle(img, (32, 24), 12, 30.0, -1)
    img = cv2.GaussianBlur(img, (0, 0), 0.8).round().astype(np.uint8)
    cam = Camera("c0", 64, 48, [[80.0, 0, 31.5], [0, 80.0, 23.5], [0, 0, 1]], None, np.eye(3), [0.0, 0.0, 100.0])
    return write_capture(folder, Rig((cam,)), {"c0": img})


def _limited(limit: int):
    def preexec() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return preexec


def test_a_file_size_limit_names_the_file_and_the_capture_and_leaves_nothing(tmp_path):
    """A real ``inspector run`` under RLIMIT_FSIZE (writes beyond it fail, as on a full disk):
    one line per capture naming it and the file, exit 3, no ``*.part``, no partial folder; the
    same run without the limit writes every result."""
    batch = tmp_path / "batch"
    for name in ("p1", "p2"):
        _small_capture(batch / name)
    recipe = tmp_path / "r.toml"
    recipe.write_text(RECIPE)
    out = tmp_path / "out"
    args = [sys.executable, "-m", "inspector_frontends.cli", "run", str(recipe), "--capture", str(batch), "--out", str(out)]
    p = subprocess.run(args, capture_output=True, text=True, timeout=300, preexec_fn=_limited(200))
    assert p.returncode == 3, p.stderr
    lines = p.stdout.splitlines()
    for i, name in enumerate(("p1", "p2")):
        assert lines[i] == f"[{i + 1}/2] {name}: ERROR capture '{name}': result not written: {out / name / 'result.json'}: File too large"
    assert "Traceback" not in p.stderr and _tree(out) == []  # nothing partial, no history row without a result
    p = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    assert _tree(out) == ["history.sqlite", "p1", "p1/result.json", "p2", "p2/result.json"]


@pytest.fixture
def small_disk(tmp_path):
    """A 256 KiB tmpfs (root only, where mounts are allowed), and a way to fill it."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(disk)],
                                          capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root); the RLIMIT_FSIZE test covers the message")

    def fill() -> Path:
        filler = disk / "filler"
        with open(filler, "wb", buffering=0) as f:
            try:
                while True:
                    f.write(b"\0" * 4096)
            except OSError:
                pass
        return filler

    try:
        yield disk, fill
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def test_a_full_disk_is_one_line_and_an_earlier_result_stays(small_disk):
    disk, fill = small_disk
    out = disk / "out"
    write_result(_result("p1"), out)
    before = (out / "p1" / "result.json").read_bytes()
    filler = fill()
    for name in ("p1", "p2"):
        with pytest.raises(CaptureError) as e:
            write_result(_result(name, points=2000), out)
        assert str(e.value) == f"capture '{name}': result not written: {out / name / 'bcps_points.ply'}: No space left on device"
    assert _tree(out) == ["p1", "p1/result.json"] and (out / "p1" / "result.json").read_bytes() == before
    filler.unlink()
    write_result(_result("p2", points=2000), out)
    assert _tree(out) == ["p1", "p1/result.json", "p2", "p2/bcps_points.ply", "p2/result.json"]


def test_a_full_disk_keeps_a_watched_capture_for_the_next_start(small_disk, tmp_path, capsys):
    """The hot folder on a full disk: the capture's line names it and the file, it stays in
    ``processing/`` (not filed in done/ without a result), and once there is room again the
    next start inspects it: one result, one history row."""
    from inspector_frontends.cli import main

    disk, fill = small_disk
    inbox, out = tmp_path / "inbox", disk / "out"
    _small_capture(inbox / "p1")
    recipe = tmp_path / "r.toml"
    recipe.write_text(RECIPE)
    out.mkdir()
    filler = fill()
    watch = ["run", str(recipe), "--watch", str(inbox), "--out", str(out), "--count", "1", "--idle-exit", "5"]
    assert main(watch) == 3
    text = capsys.readouterr().out
    assert f"[1/1] p1: ERROR capture 'p1': result not written: {out / 'p1' / 'result.json'}: No space left on device" in text
    assert (inbox / "processing" / "p1").is_dir() and not (inbox / "done").exists()
    assert _leftovers(out) == []
    filler.unlink()
    assert main(watch) == 0
    assert (inbox / "done" / "p1").is_dir() and not any((inbox / "processing").iterdir())
    rows = sqlite3.connect(out / "history.sqlite").execute("SELECT capture, verdict FROM inspections").fetchall()
    assert rows == [("p1", "pass")] and json.loads((out / "p1" / "result.json").read_text())["verdict"] == "pass"
