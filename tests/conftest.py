"""Shared fixtures: a fresh plugin manager per test, paths to recipes and shared data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# The stage watchdog's limits (120 s a stage, 300 s an inspection) are a production cell's;
# a test machine under load (two make test runs at once: load 30 on 2 cores) takes longer
# than that for an honest inspection, which would then be 'error'. Tests of the watchdog set
# their own limits; every other test, and the processes it starts, runs without a deadline.
os.environ.setdefault("INSPECTOR_STAGE_LIMIT_S", "86400")
os.environ.setdefault("INSPECTOR_INSPECTION_LIMIT_S", "86400")

ROOT = Path(__file__).resolve().parent.parent
RECIPES = ROOT / "recipes"
SHARED = ROOT.parent / "shared"


@pytest.fixture
def pm():
    """A fresh plugin manager (built-ins loaded through the entry-point group)."""
    from inspector.manager import create_plugin_manager

    return create_plugin_manager()


@pytest.fixture
def recipes_dir() -> Path:
    return RECIPES


def _simulate_to(folder: Path, **params):
    from inspector.capture_folder import save_capture
    from inspector.params import build_params
    from inspector_drivers.sim.simulate import SimParams, simulate

    return save_capture(simulate(build_params(SimParams, params, "test"), 0, name=folder.name), folder, overwrite=True)


@pytest.fixture(scope="session")
def sim_captures(tmp_path_factory):
    """Capture folders written by the simulator (CONTRACT format), made once per session.

    ``good``: 30 mm cube at scale 1.00, random pose and offset, noise sigma 2;
    ``notched``: the same cube with a 1.5 mm-radius bump removed at an edge midpoint.
    """
    root = tmp_path_factory.mktemp("captures")
    return {
        "good": _simulate_to(root / "good", part="cube30", seed=21),
        "notched": _simulate_to(
            root / "notched", part="cube30", seed=22, bumps=({"at": [15.0, 15.0, 0.0], "radius_mm": 1.5, "kind": "remove"},)
        ),
    }


@pytest.fixture(scope="session")
def small_capture(tmp_path_factory):
    """A quick capture (8 cameras, 256x256 at 0.4 mm/px) for error-path tests."""
    root = tmp_path_factory.mktemp("small")
    return _simulate_to(root / "small", part="cube30", seed=5, cameras=8, width=256, height=256, mm_per_px=0.4)
