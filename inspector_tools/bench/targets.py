"""The bench's targets (issue 26: 1 MP and the 5 MP path) and the simulated image size.

Per camera count and image size: the median cycle and peak memory targets; ``--size N|WxH``;
and the table of targets met (:func:`targets`) that ``inspector bench`` reports.
"""

from __future__ import annotations

import argparse
from typing import Any

__all__ = [
    "CYCLE_TARGET_S",
    "MEMORY_TARGET_MB",
    "CARVE_RATIO_TARGET",
    "CYCLE_TARGET_5MP_S",
    "MEMORY_TARGET_5MP_MB",
    "COLD_START_TARGET_S",
    "FIRST_RUN_TARGET_S",
    "ONE_MP",
    "FIVE_MP",
    "TARGET_CAMERAS",
    "SizeAction",
    "cycle_target_s",
    "memory_target_mb",
    "parse_size",
    "image_size",
    "targets",
    "word",
]

#: Median cycle target, seconds: 16 cameras of 1 MP (issue 26).
CYCLE_TARGET_S = 0.5
#: Peak memory target, MB (1.5 GB = 1.5e9 bytes): 16 cameras of 1 MP.
MEMORY_TARGET_MB = 1500.0
#: Issue 26, 16 cameras of 5 MP (2448 x 2048): median cycle, s, and peak memory, MB.
CYCLE_TARGET_5MP_S = 1.0
MEMORY_TARGET_5MP_MB = 2500.0
#: Pixels of the largest image each pair of targets is for.
ONE_MP = 1024 * 1024
FIVE_MP = 2448 * 2048
#: The camera count the targets are for (others: the cycle target scaled with the count).
TARGET_CAMERAS = 16
#: Open3D (``--open3d-voxel``) carving time over ours (``--carve-voxel``).
CARVE_RATIO_TARGET = 10.0
#: Issue 15: a new process (kernels cached) reaches its first verdict within this, s.
COLD_START_TARGET_S = 3.0
#: Issue 15: the kernels' first compile (an empty Numba cache; ``make setup`` does it once,
#: with a progress line per kernel), s.
FIRST_RUN_TARGET_S = 60.0


def cycle_target_s(width: int, height: int, cameras: int = TARGET_CAMERAS) -> float | None:
    """The median cycle target (s) for ``cameras`` images of ``width`` x ``height`` px:
    :data:`CYCLE_TARGET_S` up to 1 MP, :data:`CYCLE_TARGET_5MP_S` up to 5 MP (None beyond:
    no target), times ``cameras / 16`` (cost linear in the camera count)."""
    px = width * height
    base = CYCLE_TARGET_S if px <= ONE_MP else CYCLE_TARGET_5MP_S if px <= FIVE_MP else None
    return None if base is None else base * cameras / TARGET_CAMERAS


def memory_target_mb(width: int, height: int) -> float | None:
    """The peak memory target (MB) for images of ``width`` x ``height`` px (None beyond 5 MP)."""
    px = width * height
    return MEMORY_TARGET_MB if px <= ONE_MP else MEMORY_TARGET_5MP_MB if px <= FIVE_MP else None


def parse_size(text: str) -> tuple[int, int]:
    """``"N"`` or ``"WxH"`` (``x`` or ``X``) -> ``(width, height)`` px; ValueError otherwise."""
    parts = str(text).lower().split("x")
    if len(parts) not in (1, 2) or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"expected N or WxH in pixels (e.g. 1024 or 2448x2048), got {text!r}")
    w = int(parts[0])
    return w, (int(parts[1]) if len(parts) == 2 else w)


class SizeAction(argparse.Action):
    """``--size N|WxH``: ``args.size`` the width (an int, as before), ``args.height`` the height."""

    def __call__(self, parser: Any, namespace: argparse.Namespace, values: Any, option_string: str | None = None) -> None:
        try:
            w, h = parse_size(values)
        except ValueError as e:
            parser.error(f"{option_string}: {e}")
        namespace.size, namespace.height = w, h


def image_size(args: argparse.Namespace) -> tuple[int, int]:
    """``(width, height)`` of the simulated images from ``--size``."""
    h = getattr(args, "height", None)
    return int(args.size), int(h if h is not None else args.size)


def targets(cycles: dict[str, Any], carving: dict[str, Any] | None, startup: dict[str, Any] | None = None, *,
            size: tuple[int, int] = (1024, 1024), cameras: int = TARGET_CAMERAS) -> dict[str, Any]:
    t: dict[str, Any] = {}
    cyc = cycles["stages"].get("cycle")
    ct = cycle_target_s(size[0], size[1], cameras)
    load = cycles.get("loadavg")
    t["cycle"] = {"target": f"median cycle <= {ct:.3g} s" if ct is not None else "no cycle target beyond 5 MP",
                  "target_s": ct, "value_s": cyc["median"] if cyc else None,
                  "met": (cyc["median"] <= ct) if cyc and ct is not None else None, "loadavg": load,
                  "steal": cycles.get("steal")}
    peak = cycles["memory"].get("peak_mb")
    mt = memory_target_mb(*size)
    t["memory"] = {"target": f"peak memory <= {mt / 1000:g} GB" if mt is not None else "no memory target beyond 5 MP",
                   "target_mb": mt, "value_mb": peak, "met": (peak <= mt) if peak is not None and mt is not None else None}
    for key, what, target in (("cold_start", "verdict_s", COLD_START_TARGET_S), ("first_run", "seconds", FIRST_RUN_TARGET_S)):
        got = (startup or {}).get(key) or {}
        value = got.get(what) if (got.get("exit") == 0 or key == "cold_start") else None  # a verdict line is one
        t[key] = {"target": f"{key.replace('_', ' ')} <= {target:g} s", "value_s": value,
                  "met": (value <= target) if value is not None else None}
    ratio = carving.get("ratio") if carving else None
    t["carve_ratio"] = {"target": f"carve ratio >= {CARVE_RATIO_TARGET:g}", "value": ratio,
                        "met": (ratio >= CARVE_RATIO_TARGET) if ratio is not None else None}
    return t


def word(met: bool | None) -> str:
    return "MET" if met else ("NOT MEASURED" if met is None else "NOT MET")
