"""`inspector capture` then `inspector run` on the folder gives the live run's result."""

from __future__ import annotations

import json
from pathlib import Path

from inspector_frontends.cli import main

RECIPE = str(Path(__file__).with_name("small_sim.toml"))


def test_captured_folder_replays_to_the_live_result(tmp_path):
    assert main(["capture", "--recipe", RECIPE, "--out", str(tmp_path / "cap"), "-q"]) == 0
    (folder,) = list((tmp_path / "cap").iterdir())
    assert (folder / "rig.json").is_file() and len(list((folder / "images").glob("*.png"))) == 8
    live = main(["run", RECIPE, "--out", str(tmp_path / "live"), "-q"])
    replay = main(["run", RECIPE, "--capture", str(tmp_path / "cap"), "--out", str(tmp_path / "replay"), "-q"])
    assert live == replay == 0
    a = json.loads((tmp_path / "live" / folder.name / "result.json").read_text())
    b = json.loads((tmp_path / "replay" / folder.name / "result.json").read_text())
    for key in ("verdict", "pose", "defects", "stats", "points"):
        assert a[key] == b[key], key
