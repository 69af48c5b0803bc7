"""The screen's model (Qt-free): what a result shows, from an inspection or a folder."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from inspector.manager import create_plugin_manager
from inspector.recipe import load_recipe
from inspector.reference import Reference
from inspector.runner import inspect_capture
from inspector_frontends.gui.viewmodel import from_folder, from_outcome, reason_text

pytestmark = pytest.mark.slow
DEMO = Path(__file__).resolve().parents[3] / "recipes" / "demo.toml"


def _inspect(capture):
    pm = create_plugin_manager()
    recipe = load_recipe(DEMO, pm)
    ref = Reference.load(recipe.reference)
    return inspect_capture(capture, recipe, ref, pm), ref


def test_a_camera_whose_silhouette_disagrees_is_flagged(sim_captures):
    from inspector.capture_folder import read_capture

    cap = read_capture(sim_captures["good"])
    name = cap.rig.names[5]
    img = np.array(cap.images[name])
    dark = img.min()
    ys, xs = np.nonzero(img < (int(img.min()) + int(img.max())) // 2)
    cy, cx = int(ys.mean()), int(xs.max())
    # A smudge on the lens beside the part: this camera's silhouette grows where no other
    # camera agrees, and a strip reaching the image border.
    img[cy - 40:cy + 40, cx - 5:cx + 60] = dark
    img[cy - 5:cy + 5, cx:] = dark
    cap = dataclasses.replace(cap, images={**cap.images, name: img})
    outcome, ref = _inspect(cap)
    view = from_outcome(outcome, None, ref)
    flagged = {t.name: t.flags for t in view.cameras if t.flags}
    assert set(flagged) == {name}, flagged
    assert any("touches the image border" in f for f in flagged[name])
    assert any("disagrees with the others" in f for f in flagged[name])
    thumb = next(t for t in view.cameras if t.name == name)
    others = [t.unmatched for t in view.cameras if t.name != name]
    assert thumb.unmatched > max(others) + 0.1


def test_views_from_an_inspection_and_from_its_folder_agree(sim_captures, tmp_path):
    from inspector.capture_folder import read_capture
    from inspector.outputs import write_result

    outcome, ref = _inspect(read_capture(sim_captures["notched"]))
    folder = write_result(outcome.result, tmp_path)
    live = from_outcome(outcome, folder, ref)
    past = from_folder(folder, ref)
    assert live.verdict == past.verdict == "fail"
    assert live.reason == past.reason and "missing material" in live.reason
    np.testing.assert_allclose(live.points, past.points, atol=1e-4)
    assert [d.n_points for d in live.defects] == [d.n_points for d in past.defects]
    assert live.defects[0].cameras and len(live.cameras) == 16 and not past.cameras
    assert all(t.image.shape[0] <= 192 and t.image.shape[1] <= 192 for t in live.cameras)
    # The reference is placed on the part: its vertices lie where the points are.
    v, _ = live.reference
    assert np.all(np.abs(v.mean(axis=0) - live.points.mean(axis=0)) < 3.0)


def test_reason_words():
    d = [{"kind": "excess", "region": "bore", "worst_mm": 0.31}, {"kind": "missing", "region": "face", "worst_mm": -0.2}]
    assert reason_text("fail", d, (-0.1, 0.15), None) == (
        "excess material in region 'bore': +0.310 mm, limit +0.150 mm (+1 more defect)")
    assert reason_text("error", [], (-0.1, 0.1), "segment: camera cam03: empty silhouette") == "segment: camera cam03: empty silhouette"
    assert reason_text("pass", [], (-0.1, 0.1), None) == ""


def test_a_camera_the_calibration_health_flags_is_marked(sim_captures, tmp_path):
    """One camera of the rig turned by 1.5 px (the images stay the true rig's): its tile is
    flagged with the calibration's words, the others are not; a view from the folder knows
    the flagged camera too."""
    from scipy.spatial.transform import Rotation

    from inspector.capture_folder import read_capture
    from inspector.model import Rig
    from inspector.outputs import write_result
    from inspector_frontends.gui.viewmodel import calibration_flags

    cap = read_capture(sim_captures["good"])
    name = cap.rig.names[7]
    cam = cap.rig.camera(name)
    D = Rotation.from_rotvec([np.arctan(1.5 / cam.K[0, 0]), 0.0, 0.0]).as_matrix()
    rig = Rig(tuple(dataclasses.replace(c, R=D @ c.R, t=D @ c.t) if c.name == name else c for c in cap.rig.cameras))
    outcome, ref = _inspect(dataclasses.replace(cap, rig=rig))
    view = from_outcome(outcome, None, ref)
    assert list(view.calibration_flagged) == [name]
    assert view.calibration_flagged[name].startswith("calibration: disagrees with the other cameras by ")
    flagged = {t.name: t.flags for t in view.cameras if t.flags}
    assert set(flagged) == {name} and view.calibration_flagged[name] in flagged[name]
    past = from_folder(write_result(outcome.result, tmp_path), ref)
    assert past.calibration_flagged == view.calibration_flagged
    assert calibration_flags({}) == {} and calibration_flags({"calibration": {"cameras": {}, "flagged": []}}) == {}
