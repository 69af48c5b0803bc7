"""``inspector bench --gui``: the three figures come out as numbers (tiny run; the real
benchmark is `inspector bench --gui`, not a test)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

#: 8 simulated cameras, reference builtin:cube30, 1 mm voxels: works on the small_capture fixture.
SMALL_RECIPE = Path(__file__).resolve().parents[2] / "drivers" / "small_sim.toml"


@pytest.mark.gui
def test_bench_gui_writes_the_three_figures(qapp, small_capture, tmp_path, capsys):
    from inspector_frontends.cli import build_parser
    from inspector_tools.bench.gui import run_gui_bench

    out = tmp_path / "bench_gui.json"
    args = build_parser().parse_args([
        "bench", "--gui", "--recipe", str(SMALL_RECIPE),
        "--capture", str(small_capture), "--runs", "2", "--gui-inspections", "3",
        "--json", str(out), "--keep", str(tmp_path / "work"),
    ])
    assert run_gui_bench(args, first_sample=1, draw_points=5000) == 0

    doc = json.loads(out.read_text(encoding="utf-8"))
    t = doc["targets"]
    for value in (t["trigger_to_shown"]["value_s"], t["stall"]["value_ms"], t["stall"]["p99_ms"], t["memory"]["value_mb"]):
        assert isinstance(value, (int, float)) and math.isfinite(value)
    assert t["trigger_to_shown"]["value_s"] > -5.0 and t["stall"]["value_ms"] > 0
    assert math.isfinite(doc["stall"]["max_drawing_ms"]) and math.isfinite(doc["stall"]["max_outside_drawing_ms"])
    assert doc["config"]["inspections"] == 3 and doc["trigger_to_shown"]["shown_s"]["n"] == 2
    assert doc["memory"]["first"]["after"] == 1 and doc["memory"]["last"]["after"] == 3
    assert doc["memory"]["first"]["actors"] == doc["memory"]["last"]["actors"] > 0
    assert doc["draw"]["points_big"] == 5000
    assert all(r["verdict"] == "pass" for r in doc["inspections"])
    text = capsys.readouterr().out
    assert "trigger->shown overhead" in text and "event-loop stall" in text and "memory growth" in text
