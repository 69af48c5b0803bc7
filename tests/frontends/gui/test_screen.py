"""The operator window fits the screen it opens on: under Xvfb without a window manager at
1024x768, 1366x768, 1920x1080, 3840x2160 at scale 2 and a portrait panel, the whole window
and every button are on the screen, and INSPECT is visible, enabled, focused and reached by
Space and F5. In kiosk mode the window is the whole screen, without decorations.

Each size is its own X server (``xvfb-run``) and process (``tests/gui/screen_probe.py``).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="xvfb-run is not installed (apt install xvfb)")]

PROBE = Path(__file__).with_name("screen_probe.py")


def probe(tmp_path: Path, width: int, height: int, *args: str, scale: float | None = None) -> dict:
    """Run the probe on a fresh Xvfb screen of ``width`` x ``height`` pixels."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "QT_QPA_PLATFORM", "QT_SCALE_FACTOR",
                                                            "WAYLAND_DISPLAY")}
    if scale is not None:
        env["QT_SCALE_FACTOR"] = str(scale)
    out = tmp_path / f"probe-{width}x{height}.json"
    done = subprocess.run(["xvfb-run", "-a", "-s", f"-screen 0 {width}x{height}x24", sys.executable, str(PROBE), str(out),
                           *args], env=env, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(out.read_text())


def _inside(rect: list[int], area: list[int]) -> bool:
    x, y, w, h = rect
    ax, ay, aw, ah = area
    return w > 0 and h > 0 and x >= ax and y >= ay and x + w <= ax + aw and y + h <= ay + ah


@pytest.mark.parametrize(("width", "height", "scale"), [(1024, 768, None), (1366, 768, None), (1920, 1080, None),
                                                        (3840, 2160, 2.0), (768, 1024, None), (1080, 1920, None)],
                         ids=["1024x768", "1366x768", "1920x1080", "3840x2160@2", "portrait-768x1024",
                              "portrait-1080x1920"])
def test_the_window_and_every_button_are_on_the_screen(tmp_path, width, height, scale):
    d = probe(tmp_path, width, height, scale=scale)
    logical = [0, 0, round(width / (scale or 1)), round(height / (scale or 1))]
    assert d["screen"] == logical and d["ratio"] == (scale or 1.0)  # HiDPI: logical pixels
    assert _inside(d["window"], d["available"]), (d["window"], d["available"])
    # It uses the screen, too: no small window in a corner of a large screen.
    assert d["window"][2] * d["window"][3] >= 0.9 * d["available"][2] * d["available"][3]
    assert {"inspect", "live", "cancel"} <= set(d["buttons"])
    for name, rect in d["buttons"].items():
        assert _inside(rect, d["window"]) and _inside(rect, d["screen"]), (name, rect, d["screen"])
    for part in ("menubar", "statusbar"):
        assert _inside(d[part], d["screen"]), (part, d[part])
    assert d["inspect_enabled"] and d["inspect_focus"] and d["active"]
    assert d["keys_reaching_inspect"] == ["F5", "Space"]
    assert d["portrait"] == (height > width)
    if height > width:  # portrait: the buttons side by side under the banner
        ys = {d["buttons"][b][1] for b in ("inspect", "live", "cancel")}
        assert len(ys) == 1


def test_kiosk_is_the_whole_screen_without_decorations(tmp_path):
    d = probe(tmp_path, 1366, 768, "--kiosk")
    assert d["fullscreen"] and d["frameless"]
    assert d["window"] == d["screen"] == [0, 0, 1366, 768]
    for name, rect in d["buttons"].items():
        assert _inside(rect, d["screen"]), (name, rect)
    assert d["keys_reaching_inspect"] == ["F5", "Space"]
