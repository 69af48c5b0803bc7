"""Input bounds (inspector.limits): JSON size and depth measured before parsing, camera counts
before cameras are built; every refusal one line naming the file, and the batch goes on.

Crafted files only (a 1-camera rig with a real 16x16 PNG): nothing is rendered or inspected.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from inspector.capture_folder import read_capture, read_rig, write_capture
from inspector.errors import CaptureError, InputError
from inspector.limits import MAX_CAMERAS, MAX_JSON_DEPTH, json_depth, limit, load_json
from inspector.model import Camera, Rig


def _capture(folder: Path) -> Path:
    cam = Camera("c0", 16, 16, [[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]], None, np.eye(3), [0.0, 0.0, 100.0])
    return write_capture(folder, Rig((cam,)), {"c0": np.zeros((16, 16), np.uint8)})


def _nested(depth: int, inner: str = "1") -> str:
    """A valid JSON value nested ``depth`` levels (arrays and objects alternating)."""
    opening = "".join("[" if i % 2 else '{"k": ' for i in reversed(range(depth)))
    closing = "".join("]" if i % 2 else "}" for i in range(depth))
    return opening + inner + closing


def _rig_text(n: int) -> str:
    cam = '{{"name": "c{}", "width": 16, "height": 16, "K": [[20, 0, 7.5], [0, 20, 7.5], [0, 0, 1]], ' \
          '"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 100]}}'
    return '{"units": "mm", "cameras": [' + ", ".join(cam.format(i) for i in range(n)) + "]}"


# --------------------------------------------------------------------------- depth


@pytest.mark.parametrize(
    "text, depth",
    [("1", 0), ('"[[["', 0), ("[]", 1), ('{"a": "[[[", "b": [1, {"c": []}]}', 4), (r'["\"[[", "\\", [[]]]', 3),
     ('{"a": "}}}]]]", "b": {"c": {"d": 1}}}', 3), ("[" * 100 + "]" * 100, 100)],
)
def test_json_depth(text, depth):
    assert json_depth(text.encode()) == depth


@settings(max_examples=200, deadline=None, database=None)
@given(st.recursive(st.none() | st.booleans() | st.floats(allow_nan=False) | st.text(alphabet='[]{}"\\ab\n'),
                    lambda kids: st.lists(kids, max_size=3) | st.dictionaries(st.text(alphabet='[]{}"\\ab'), kids, max_size=3),
                    max_leaves=30))
def test_json_depth_matches_the_parsed_document(doc):
    def depth(v):
        if isinstance(v, list):
            return 1 + max(map(depth, v), default=0)
        if isinstance(v, dict):
            return 1 + max(map(depth, v.values()), default=0)
        return 0

    assert json_depth(json.dumps(doc).encode()) == depth(doc)


@pytest.mark.parametrize("text", [b'"' + b'a\\"' * 2**20, b'"' * 2**22, b"[" * 2**22, b'"' + b"\\" * 2**22])
def test_json_depth_is_linear_on_the_worst_text(text):
    """An unterminated string full of escaped quotes made a regex for strings quadratic (4 MiB:
    minutes). This process's CPU time, not the wall clock: a loaded machine does not slow it."""
    t0 = time.process_time()
    json_depth(text)
    assert time.process_time() - t0 < 3.0  # 4 MiB; about 0.1 s


@pytest.mark.parametrize("depth", [500, 700, 900, 5000, 100_000])
@pytest.mark.parametrize("file", ["capture.json", "rig.json", "truth/truth.json"])
def test_deep_json_is_one_line_naming_the_file(tmp_path, depth, file):
    folder = _capture(tmp_path / "cap")
    if file == "rig.json":
        text = '{"units": "mm", "cameras": ' + _nested(depth - 2, "[]") + "}"
    else:
        (folder / file).parent.mkdir(exist_ok=True)
        text = '{"part_id": "p1", "extra": ' + _nested(depth - 1) + "}"
    (folder / file).write_text(text)
    with pytest.raises(CaptureError) as e:
        read_capture(folder)
    assert str(e.value) == (f"{file}: nested {depth} levels deep, more than the {MAX_JSON_DEPTH} "
                            "a JSON input may have (INSPECTOR_MAX_JSON_DEPTH)")


def test_moderate_nesting_is_still_read_and_kept_as_metadata(tmp_path):
    folder = _capture(tmp_path / "cap")
    (folder / "capture.json").write_text('{"part_id": "p1", "extra": ' + _nested(MAX_JSON_DEPTH - 1) + "}")
    cap = read_capture(folder)
    assert cap.metadata["part_id"] == "p1" and json_depth(json.dumps(dict(cap.metadata)).encode()) == MAX_JSON_DEPTH


def test_a_deep_capture_json_is_one_error_and_the_batch_goes_on(tmp_path):
    """Issue 15: a capture.json 500-900 levels deep aborted the whole run (RecursionError)."""
    from inspector.manager import create_plugin_manager
    from inspector.recipe import parse_recipe
    from inspector.runner import run_batch
    from inspector_drivers.replay import ReplayDriver, ReplayParams

    deep = _capture(tmp_path / "batch" / "a-deep")
    (deep / "capture.json").write_text('{"part_id": "p1", "extra": ' + _nested(899) + "}")
    _capture(tmp_path / "batch" / "b-good")
    pm = create_plugin_manager()
    # carve needs a segment: the recipe is valid, and its stages never run on the deep capture.
    recipe = parse_recipe({"stages": [{"use": "segment.threshold"}]}, pm)
    acqs = list(ReplayDriver(ReplayParams((str(tmp_path / "batch"),))).acquire())
    out = tmp_path / "out"
    outcome = next(run_batch(recipe, acqs[:1], pm, reference=None, outdir=out))
    assert outcome.result.verdict == "error" and outcome.result.error.startswith("capture.json: nested 900 levels deep")
    assert json.loads((out / "a-deep" / "result.json").read_text())["verdict"] == "error"
    assert acqs[1].load().name == "b-good"  # the next one reads


def test_the_depth_limit_is_overridable(tmp_path, monkeypatch):
    folder = _capture(tmp_path / "cap")
    (folder / "capture.json").write_text('{"extra": ' + _nested(99) + "}")
    with pytest.raises(CaptureError, match="nested 100 levels"):
        read_capture(folder)
    monkeypatch.setenv("INSPECTOR_MAX_JSON_DEPTH", "100")
    assert read_capture(folder).name == "cap"


# --------------------------------------------------------------------------- size


def test_a_json_file_over_the_size_bound_is_refused_before_it_is_read(tmp_path, monkeypatch):
    folder = _capture(tmp_path / "cap")
    huge = tmp_path / "huge.json"
    with open(huge, "wb") as f:  # sparse: 3 GiB that take no disk and must not be read
        f.truncate(3 * 2**30)
    (folder / "rig.json").unlink()
    (folder / "rig.json").symlink_to(huge)
    t0 = time.process_time()  # CPU time: a loaded machine does not slow it
    with pytest.raises(CaptureError) as e:
        read_capture(folder)
    assert time.process_time() - t0 < 1.0
    assert str(e.value) == (f"rig.json: {3 * 2**30} bytes, more than the {16 * 2**20} a JSON input may have "
                            "(INSPECTOR_MAX_JSON_BYTES)")
    monkeypatch.setenv("INSPECTOR_MAX_JSON_BYTES", "100")
    small = tmp_path / "capture.json"
    small.write_text(json.dumps({"part_id": "x" * 200}))
    with pytest.raises(InputError, match=r"^capture\.json: 215 bytes, more than the 100 a JSON input may have"):
        load_json(small, "capture.json")


def test_a_bad_limit_in_the_environment_is_one_line(monkeypatch):
    monkeypatch.setenv("INSPECTOR_MAX_CAMERAS", "lots")
    with pytest.raises(InputError, match=r"^\$INSPECTOR_MAX_CAMERAS: expected a positive integer, got 'lots'$"):
        limit("MAX_CAMERAS")
    monkeypatch.setenv("INSPECTOR_MAX_CAMERAS", " 12 ")
    assert limit("MAX_CAMERAS") == 12
    monkeypatch.delenv("INSPECTOR_MAX_CAMERAS")
    assert limit("MAX_CAMERAS") == MAX_CAMERAS == 1024


# --------------------------------------------------------------------------- cameras


def test_a_rig_with_too_many_cameras_is_refused_before_they_are_built(tmp_path, monkeypatch):
    path = tmp_path / "rig.json"
    path.write_text(_rig_text(5000))  # 0.75 MB: within the size bound
    t0 = time.process_time()  # CPU time: a loaded machine does not slow it
    with pytest.raises(CaptureError, match=r"^rig\.json: 5000 cameras, more than the 1024 a rig may have \(INSPECTOR_MAX_CAMERAS\)$"):
        read_rig(path)
    assert time.process_time() - t0 < 2.0  # building them took seconds (10^6: minutes, 2 GB)
    monkeypatch.setenv("INSPECTOR_MAX_CAMERAS", "5000")
    assert len(read_rig(path)) == 5000


def test_a_1024_camera_rig_is_read(tmp_path):
    path = tmp_path / "rig.json"
    path.write_text(_rig_text(1024))
    assert len(read_rig(path)) == 1024


# --------------------------------------------------------------------------- hot folder, importers, report


def test_the_hot_folder_waits_on_a_deep_or_huge_rig_json_without_crashing(tmp_path, monkeypatch):
    from inspector_drivers.replay.hotfolder import _complete

    folder = _capture(tmp_path / "inbox" / "p1")
    assert _complete(folder)
    (folder / "rig.json").write_text('{"units": "mm", "cameras": ' + _nested(100_000, "[]") + "}")
    assert not _complete(folder)  # was: RecursionError out of the watcher, at every restart
    (folder / "rig.json").write_text(_rig_text(1))
    assert _complete(folder)
    (folder / "rig.json").write_text(_rig_text(2000))
    (folder / "images" / "c1.png").write_bytes(b"")
    assert not _complete(folder)  # more cameras than a rig may have: never complete, given up later


def test_importers_and_report_bound_their_json(tmp_path):
    from inspector.report import _read_result
    from inspector_tools.importers.datasets import _load_json_file

    deep = tmp_path / "transforms.json"
    deep.write_text(_nested(3000))
    with pytest.raises(InputError, match=r"transforms\.json: nested 3000 levels deep"):
        _load_json_file(deep)
    result = tmp_path / "result.json"
    result.write_text('{"capture": "a", "verdict": "error", "metadata": ' + _nested(5000) + "}")
    with pytest.raises(InputError, match=r"result\.json: cannot read \(nested 5001 levels deep, more than 66"):
        _read_result(result)


def test_load_json_messages(tmp_path):
    p = tmp_path / "x.json"
    p.write_text('{"a": NaN, "b": Infinity}')
    assert str(load_json(p, "x.json")) == "{'a': nan, 'b': inf}"  # Python's own output reads back
    p.write_text("[" + "1" * 5000 + "]")
    with pytest.raises(InputError, match=r"^x\.json: not valid JSON \("):
        load_json(p, "x.json")
    with pytest.raises(InputError, match=r"^nothing\.json: cannot be read \("):
        load_json(tmp_path / "nothing.json", "nothing.json")


def test_a_fifo_named_rig_json_does_not_hang_the_hot_folder(tmp_path):
    import os

    from inspector_drivers.replay.hotfolder import _complete

    folder = _capture(tmp_path / "inbox" / "p1")
    (folder / "rig.json").unlink()
    os.mkfifo(folder / "rig.json")
    assert not _complete(folder)  # was: blocked forever in open(), waiting for a writer
    with pytest.raises(InputError, match=r"^rig\.json: not a file$"):
        load_json(folder / "rig.json", "rig.json")
