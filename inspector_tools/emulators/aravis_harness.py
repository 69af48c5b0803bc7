"""A driver client driven by JSON lines on stdin (one answer line on stdout per request).

Runs where the cameras are reachable, e.g. inside an :class:`~.emulator.EmulatedRig`'s
network namespace (``ip netns exec NS python -m inspector_tools.emulators.aravis_harness``), so a test
or a bench in another process can open a driver, trigger it, kill cameras under it and watch it
recover, while this process stays up. Requests:

``{"cmd": "open", "driver": "aravis", "params": {...}}``
    Open the driver (params as in a recipe). Answer: ``ok``, ``open_s``, ``trigger_mode``.
``{"cmd": "trigger", "pattern": true}``
    Load the next acquisition. Answer: ``ok``, ``name``, ``error``, ``elapsed_s``, ``meta``
    (capture metadata), ``frames`` (per camera: ``frame_id``, ``serial``, ``address``,
    ``shape``, ``dtype``, ``sum``,
    and with ``pattern`` whether the image is exactly the fake camera's frame).
``{"cmd": "latency", "triggers": 50, "warmup": 3}``
    :func:`~inspector_tools.bench.aravis.trigger_latency` on the open driver.
``{"cmd": "capture", "argv": [...]}``
    ``inspector capture ARGV`` (:mod:`inspector_drivers.capture_cmd`). Answer: ``rc``, ``output``.
``{"cmd": "close"}``
    Close the driver and exit.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
import traceback
from collections.abc import Iterator
from typing import Any

import inspector_drivers.aravis as aravis_mod
import inspector_drivers.genicam as genicam_mod
from inspector.errors import InspectorError
from inspector.manager import PluginManager, create_plugin_manager
from inspector.params import build_params
from inspector.registry import Acquisition
from inspector_drivers import capture_cmd
from inspector_tools.bench.aravis import trigger_latency
from inspector_tools.emulators.aravis import fake_pattern

__all__ = ["plugin_manager", "main"]


def plugin_manager() -> PluginManager:
    """The entry-point plugin manager, plus the hardware drivers if not yet registered."""
    pm = create_plugin_manager()
    extra = [m for m, name in ((aravis_mod, "aravis"), (genicam_mod, "genicam")) if name not in pm.drivers]
    if extra:
        pm = create_plugin_manager(plugins=extra)
    return pm


def _frame_report(cap: Any, pattern: bool) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for cam, img in cap.images.items():
        info = dict(cap.metadata.get("frames", {}).get(cam, {}))
        rep = {
            "frame_id": info.get("frame_id"),
            "serial": info.get("serial"),
            "address": info.get("address"),
            "shape": list(img.shape),
            "dtype": str(img.dtype),
            "sum": int(img.sum()),
        }
        if pattern:
            ok = img.ndim == 2 and img.dtype.name == "uint8" and info.get("frame_id") is not None
            rep["pattern_ok"] = bool(ok and (img == fake_pattern(img.shape[1], img.shape[0], info["frame_id"])).all())
        out[cam] = rep
    return out


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
    pm = plugin_manager()
    # The aravis or genicam driver: its ``session`` (trigger mode, triggers) is more than the
    # Driver protocol has.
    driver: Any = None
    acquisitions: Iterator[Acquisition] | None = None

    def answer(obj: dict[str, Any]) -> None:
        sys.stdout.write(json.dumps(obj, default=str) + "\n")
        sys.stdout.flush()

    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        t0 = time.perf_counter()
        try:
            req = json.loads(line)
            cmd = req.get("cmd")
            if cmd == "open":
                if driver is not None:
                    driver.close()
                spec = pm.driver(req.get("driver", "aravis"))
                params = build_params(spec.params, req.get("params", {}), "harness")
                driver = spec.open(params)
                acquisitions = iter(driver.acquire())
                answer({"ok": True, "open_s": time.perf_counter() - t0, "trigger_mode": driver.session.trigger_mode})
            elif cmd == "trigger":
                if driver is None or acquisitions is None:  # both set by "open"
                    raise RuntimeError("no driver open")
                acq = next(acquisitions, None)
                if acq is None:
                    answer({"ok": False, "error": "no more acquisitions (count reached)"})
                    continue
                try:
                    cap = acq.load()
                except InspectorError as exc:
                    answer({"ok": False, "name": acq.name, "error": str(exc), "elapsed_s": time.perf_counter() - t0})
                    continue
                answer(
                    {
                        "ok": True,
                        "name": cap.name,
                        "elapsed_s": time.perf_counter() - t0,
                        "meta": {k: v for k, v in cap.metadata.items() if k != "frames"},
                        "frames": _frame_report(cap, bool(req.get("pattern"))),
                    }
                )
            elif cmd == "latency":
                if driver is None:
                    raise RuntimeError("no driver open")
                stats = trigger_latency(driver, triggers=int(req.get("triggers", 50)), warmup=int(req.get("warmup", 3)))
                answer({"ok": True, **stats})
            elif cmd == "capture":
                ap = argparse.ArgumentParser(prog="inspector")
                capture_cmd.add_parser(ap.add_subparsers(dest="command"))
                args = ap.parse_args(["capture", *req["argv"]])
                buf = io.StringIO()
                with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                    rc = capture_cmd.run(args, pm=pm)
                answer({"ok": rc == 0, "rc": rc, "output": buf.getvalue()})
            elif cmd == "close":
                if driver is not None:
                    driver.close()
                    driver = None
                answer({"ok": True})
                return 0
            else:
                answer({"ok": False, "error": f"unknown command {cmd!r}"})
        except InspectorError as exc:
            answer({"ok": False, "error": str(exc), "kind": type(exc).__name__})
        except Exception as exc:  # noqa: BLE001 - report, keep serving
            answer({"ok": False, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()})
    if driver is not None:
        driver.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
