"""Trigger-to-all-frames latency of a live driver (``aravis`` or ``genicam``).

Latency of one trigger: from just before the first trigger command is sent to the moment the
last camera's frame has been received, checked and copied out (``latency_ms`` of the session's
trigger metadata). Triggers that fail are counted, not timed.

    from inspector_tools.bench.aravis import trigger_latency
    stats = trigger_latency({"rig": "rig.json", "serials": {...}}, triggers=100)
    print(stats["median_ms"])
"""

from __future__ import annotations

import statistics
import time
from typing import Any

from inspector.errors import CaptureError
from inspector.params import build_params
from inspector_drivers.aravis import AravisParams, open_driver

__all__ = ["trigger_latency"]


def _percentile(values: list[float], q: float) -> float:
    s = sorted(values)
    if not s:
        return float("nan")
    k = (len(s) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


def trigger_latency(
    driver: Any,
    *,
    triggers: int = 50,
    warmup: int = 3,
    pause_s: float = 0.0,
) -> dict[str, Any]:
    """Fire ``warmup + triggers`` triggers and return latency statistics (ms).

    Parameters
    ----------
    driver
        An open driver (``aravis``/``genicam``, it is left open), or the ``aravis`` driver's
        parameters (an :class:`~inspector_drivers.aravis.AravisParams` or a mapping like a
        recipe's ``[driver] params`` table): the driver is then opened and closed here.
    triggers, warmup : int
        Timed triggers, and untimed ones fired first.
    pause_s : float
        Sleep between triggers.

    Returns
    -------
    dict
        ``cameras``, ``triggers``, ``ok``, ``failed``, ``median_ms``, ``p10_ms``,
        ``p90_ms``, ``min_ms``, ``max_ms``, ``mean_ms``, ``wall_s``, ``first_error``,
        ``trigger_mode``, ``camera_median_ms`` / ``overhead_median_ms`` (aravis: the
        cameras' and the driver's share of the median) and ``latencies_ms`` (every timed
        trigger, in order).
    """
    own = False
    if not hasattr(driver, "session"):
        params = driver if isinstance(driver, AravisParams) else build_params(AravisParams, dict(driver), "trigger_latency")
        driver = open_driver(params)
        own = True
    lat: list[float] = []
    cam_share: list[float] = []
    failed = 0
    first_error = ""
    t_start = time.perf_counter()
    try:
        session = driver.session
        for i in range(int(warmup) + int(triggers)):
            if i and pause_s > 0:
                time.sleep(pause_s)
            try:
                _frames, meta = session.trigger()
            except CaptureError as exc:
                if i >= warmup:
                    failed += 1
                    first_error = first_error or str(exc)
                continue
            if i >= warmup:
                lat.append(float(meta["latency_ms"]))
                if "last_frame_start_ms" in meta:
                    cam_share.append(float(meta["last_frame_start_ms"]))
        mode = getattr(session, "trigger_mode", "")
        n = len(driver.rig)
    finally:
        if own:
            driver.close()
    return {
        "cameras": n,
        "trigger_mode": mode,
        "triggers": int(triggers),
        "ok": len(lat),
        "failed": failed,
        "median_ms": statistics.median(lat) if lat else float("nan"),
        "p10_ms": _percentile(lat, 0.10),
        "p90_ms": _percentile(lat, 0.90),
        "min_ms": min(lat) if lat else float("nan"),
        "max_ms": max(lat) if lat else float("nan"),
        "mean_ms": statistics.fmean(lat) if lat else float("nan"),
        "wall_s": time.perf_counter() - t_start,
        "first_error": first_error,
        # aravis only: when the last camera's frame began to arrive (the cameras' share), and
        # the rest (transfer of the last frame, checks, copies: this driver's share)
        "camera_median_ms": statistics.median(cam_share) if cam_share else None,
        "overhead_median_ms": statistics.median([a - b for a, b in zip(lat, cam_share)]) if cam_share and len(cam_share) == len(lat) else None,
        "latencies_ms": lat,
    }
