"""Harvesters session behind the ``genicam`` driver (imports harvesters/genicam).

One :class:`ImageAcquirer` per rig camera, acquisition started once and kept running. Per
trigger (:meth:`HarvesterSession.trigger`):

1. a device that failed before is recovered first: restarted (stop/start flushes every
   buffer) after a missed frame, reopened after a transport error;
2. frames already queued are dropped (re-queued unread): they predate the trigger (with a
   hardware trigger they are kept, in order: each belongs to a pulse; after any error every
   hardware-triggered device is restarted so the cameras' frames stay paired);
3. ``TriggerSoftware`` is executed on software-triggered devices; for free-running devices
   the queue is dropped again and ``freerun_discard`` frames completed after the trigger are
   skipped, so the frame kept was exposed after the trigger;
4. one complete frame per device is fetched before ``timeout_s``; its image is copied out
   (:func:`~inspector_drivers.genicam.pixels.to_array`) and the buffer re-queued in a
   ``finally`` block, so no buffer is ever lost and no returned image aliases one.

Any camera without a good frame makes the whole trigger a
:class:`~inspector.errors.CaptureError` naming it; the session stays open.
"""

from __future__ import annotations

import glob
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from inspector.errors import CaptureError, InputError
from inspector.model import Rig
from inspector_drivers.genicam import GenicamParams
from inspector_drivers.genicam.common import DeviceMatch, Frame, LiveDriver, join_errors
from inspector_drivers.genicam.pixels import UnsupportedPixelFormat, to_array

__all__ = ["HarvesterDriver", "HarvesterSession", "cti_files", "configure_trigger"]

DRIVER = "genicam"
_WO, _RO, _RW = 2, 3, 4  # genapi EAccessMode


def cti_files(spec: str) -> list[str]:
    """GenTL producers named by ``spec`` (os.pathsep-separated), else $GENICAM_GENTL64_PATH's."""
    if spec:
        files = [f for f in spec.split(os.pathsep) if f]
        for f in files:
            if not os.path.isfile(f):
                raise InputError(f"{DRIVER}: GenTL producer not found: {f}")
        return files
    found: list[str] = []
    for d in os.environ.get("GENICAM_GENTL64_PATH", "").split(os.pathsep):
        if d and os.path.isdir(d):
            found.extend(sorted(glob.glob(os.path.join(d, "*.cti"))))
    if not found:
        raise InputError(f"{DRIVER}: no GenTL producer: set the 'cti' parameter or $GENICAM_GENTL64_PATH")
    return found


# --------------------------------------------------------------------------- node helpers


def _msg(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, InputError) and text.startswith(f"{DRIVER}: camera "):
        text = text.split(": ", 2)[-1]  # the caller names the camera already
    return text[:300]


def _node(nm: Any, name: str) -> Any:
    try:
        return nm.get_node(name)
    except Exception:  # noqa: BLE001 - genapi LogicalErrorException: node not existing
        return None


def _mode(node: Any) -> int:
    try:
        return int(node.node.get_access_mode())
    except Exception:  # noqa: BLE001
        return 0


def _writable(node: Any) -> bool:
    return node is not None and _mode(node) in (_WO, _RW)


def _readable(node: Any) -> bool:
    return node is not None and _mode(node) in (_RO, _RW)


def _entries(node: Any) -> tuple[str, ...]:
    try:
        return tuple(node.symbolics)
    except Exception:  # noqa: BLE001
        return ()


def _set(nm: Any, name: str, value: Any, where: str) -> None:
    """Set one feature or raise InputError naming the camera and the feature."""
    node = _node(nm, name)
    if node is None:
        raise InputError(f"{where}: the device has no {name} feature")
    if not _writable(node):
        raise InputError(f"{where}: {name} is not writable now")
    entries = _entries(node)
    if entries and isinstance(value, str) and value not in entries:
        raise InputError(f"{where}: {name} {value!r} is not available (device offers: {', '.join(entries)})")
    try:
        node.value = value
    except Exception as exc:  # noqa: BLE001
        raise InputError(f"{where}: cannot set {name} = {value!r}: {_msg(exc)}") from None


def configure_trigger(nm: Any, p: GenicamParams, where: str) -> str:
    """Arm the trigger the recipe asks for; returns the mode used (``free-run`` when none)."""
    tm = _node(nm, "TriggerMode")
    source = _node(nm, "TriggerSource")
    usable = _writable(tm) and "On" in (_entries(tm) or ("On",))
    if usable and p.trigger == "software":
        usable = _node(nm, "TriggerSoftware") is not None and (source is None or "Software" in _entries(source))
    sel = _node(nm, "TriggerSelector")
    selectors = _entries(sel) if _writable(sel) else ()
    # Every trigger off first, so that exactly the armed one is needed per frame.
    if _writable(tm):
        for s in selectors or (None,):
            try:
                if s is not None:
                    sel.value = s
                tm.value = "Off"
            except Exception:  # noqa: BLE001 - some selectors may not be switchable
                pass
    if not usable:
        return "free-run"
    if selectors:
        _set(nm, "TriggerSelector", p.trigger_selector, where)
    _set(nm, "TriggerMode", "On", where)
    if p.trigger == "software":
        if source is not None:
            _set(nm, "TriggerSource", "Software", where)
        return "software"
    if source is not None:
        _set(nm, "TriggerSource", p.trigger_source, where)
    if _writable(_node(nm, "TriggerActivation")):
        _set(nm, "TriggerActivation", p.trigger_activation, where)
    return "hardware"


# --------------------------------------------------------------------------- cameras


class _Timeout(Exception):
    pass


@dataclass(eq=False)
class _Camera:
    name: str
    match: DeviceMatch
    serial: str
    ia: Any = None
    mode: str = "software"
    incomplete: int = 0
    needs_restart: bool = False
    broken: str = ""  # why the device must be reopened
    device_info: Any = None
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f"{self.name} ({self.match.describe()})"


class HarvesterSession:
    """The devices of one rig, configured and streaming (see the module docstring)."""

    def __init__(self, params: GenicamParams, rig: Rig, matches: list[DeviceMatch]) -> None:
        from harvesters.core import Harvester

        self.params = params
        self.rig = rig
        self.h = Harvester()
        self.cams: list[_Camera] = []
        try:
            for f in cti_files(params.cti):
                self.h.add_file(f, check_existence=True)
            self.h.update()
            for m in matches:
                cam = _Camera(m.camera, m, serial="")
                info = self._find(m)
                twin = next((c for c in self.cams if c.device_info is info), None)
                if twin is not None:
                    raise InputError(f"{DRIVER}: cameras {twin.name} and {cam.name} are the same device ({cam.match.describe()})")
                self._open(cam)
                self.cams.append(cam)
        except BaseException:
            self.close()
            raise
        modes = sorted({c.mode for c in self.cams})
        self.trigger_mode = modes[0] if len(modes) == 1 else "mixed"

    # -- devices --------------------------------------------------------------------------
    def _find(self, m: DeviceMatch) -> Any:
        key = "serial_number" if m.by == "serial" else "user_defined_name"
        infos = list(self.h.device_info_list)
        hits = [i for i in infos if str(i.property_dict.get(key) or "") == m.value]
        if len(hits) == 1:
            return hits[0]
        if not hits:
            seen = sorted({str(i.property_dict.get(key)) for i in infos if i.property_dict.get(key)})
            raise InputError(f"{DRIVER}: camera {m.camera}: no device with {m.describe()} (found: {', '.join(seen) or 'no device'})")
        raise InputError(f"{DRIVER}: camera {m.camera}: {len(hits)} devices with {m.describe()}")

    def _open(self, cam: _Camera) -> None:
        info = self._find(cam.match)
        cam.device_info = info
        cam.serial = str(info.property_dict.get("serial_number") or "")
        where = f"{DRIVER}: camera {cam.label}"
        main = threading.current_thread() is threading.main_thread()
        old = signal.getsignal(signal.SIGINT) if main else None
        try:
            ia = self.h.create(info)
        except Exception as exc:  # noqa: BLE001 - GenTL: access denied, busy, ...
            raise InputError(f"{where}: cannot open the device: {_msg(exc)}") from None
        finally:
            if main and old is not None:
                signal.signal(signal.SIGINT, old)  # Harvesters replaces Ctrl-C handling
        cam.ia = ia
        try:
            cam.mode = self._configure(cam, ia, where)
            self._watch_incomplete(cam)
            ia.start()
        except InputError:
            self._destroy(cam)
            raise
        except Exception as exc:  # noqa: BLE001
            self._destroy(cam)
            raise InputError(f"{where}: cannot start acquisition: {_msg(exc)}") from None
        cam.needs_restart = False
        cam.broken = ""

    def _configure(self, cam: _Camera, ia: Any, where: str) -> str:
        p = self.params
        nm = ia.remote_device.node_map
        if p.set_size:
            c = self.rig.camera(cam.name)
            _set(nm, "Width", int(c.width), where)
            _set(nm, "Height", int(c.height), where)
        if p.pixel_format:
            _set(nm, "PixelFormat", p.pixel_format, where)
        if p.exposure_us is not None:
            if _writable(_node(nm, "ExposureAuto")):
                _set(nm, "ExposureAuto", "Off", where)
            names = [n for n in ("ExposureTime", "ExposureTimeAbs") if _node(nm, n) is not None]
            if not names:
                raise InputError(f"{where}: the device has no ExposureTime or ExposureTimeAbs feature")
            _set(nm, names[0], float(p.exposure_us), where)
        if p.gain_db is not None:
            if _writable(_node(nm, "GainAuto")):
                _set(nm, "GainAuto", "Off", where)
            _set(nm, "Gain", float(p.gain_db), where)
        mode = configure_trigger(nm, p, where)
        am = _node(nm, "AcquisitionMode")
        if _writable(am) and "Continuous" in _entries(am):
            am.value = "Continuous"
        ia.num_buffers = max(int(p.num_buffers), int(ia.min_num_buffers))
        return mode

    def _watch_incomplete(self, cam: _Camera) -> None:
        from harvesters.core import Callback

        class _Count(Callback):
            def emit(self, context: Any = None) -> None:
                cam.incomplete += 1

        cam.ia.add_callback(cam.ia.Events.INCOMPLETE_BUFFER, _Count())

    def _destroy(self, cam: _Camera) -> None:
        ia, cam.ia = cam.ia, None
        if ia is None:
            return
        for step in (ia.stop, ia.destroy):
            try:
                step()
            except Exception:  # noqa: BLE001 - a dead device: nothing more to release
                pass

    def _recover(self, cam: _Camera) -> str:
        """Make ``cam`` usable again; returns why it cannot be ("" when it can)."""
        if cam.broken or cam.ia is None:
            self._destroy(cam)
            try:
                try:
                    self._open(cam)
                except Exception:  # noqa: BLE001 - maybe a new device handle: rescan its interface
                    self._rescan(cam)
                    self._open(cam)
            except Exception as exc:  # noqa: BLE001 - InputError or GenTL error
                cam.broken = _msg(exc)
                return f"device unavailable ({cam.broken})"
            return ""
        if cam.needs_restart:
            try:
                cam.ia.stop()  # flushes every queued and delivered buffer
                cam.ia.start()
            except Exception as exc:  # noqa: BLE001
                cam.broken = _msg(exc)
                return f"restart failed ({cam.broken})"
            cam.needs_restart = False
        return ""

    def _rescan(self, cam: _Camera) -> None:
        """Refresh the device list of ``cam``'s interface only.

        ``Harvester.update()`` would destroy every open device; the GenTL interface's own
        update leaves them alone.
        """
        from harvesters.core import DeviceInfo

        if cam.device_info is None:
            return
        iface = cam.device_info.parent
        iface.update_device_info_list(self.h.timeout_for_update)
        fresh = [DeviceInfo(module=d, parent=iface) for d in iface.device_info_list]
        others = [i for i in self.h.device_info_list if i.parent is not iface]
        # harvesters offers no way to refresh one interface's devices: its list (the property
        # returns the Harvester's own list, not a copy), updated in place
        self.h.device_info_list[:] = others + fresh

    # -- frames -------------------------------------------------------------------------
    def _drain(self, cam: _Camera) -> int:
        """Re-queue every frame already delivered (they predate the trigger)."""
        dropped = 0
        for _ in range(4 * cam.ia.num_buffers + 4):
            before = cam.incomplete
            buf = cam.ia.try_fetch(timeout=0.0005)
            if buf is None:
                if cam.incomplete == before:
                    break
                continue
            dropped += 1
            buf.queue()
        return dropped

    def _fetch(self, cam: _Camera, deadline: float, discard: int) -> Frame:
        skipped = 0
        incomplete0 = cam.incomplete
        while True:
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                bad = cam.incomplete - incomplete0
                extra = f" ({bad} incomplete frame{'s' if bad != 1 else ''} dropped)" if bad else ""
                what = {"software": "of the software trigger", "hardware": "while waiting for the hardware trigger"}.get(cam.mode, "of the trigger (free-run)")
                raise _Timeout(f"no complete frame within {self.params.timeout_s:g} s {what}{extra}")
            buf = cam.ia.try_fetch(timeout=remaining)
            if buf is None:
                continue  # timed out, or an incomplete buffer (already re-queued by Harvesters)
            try:
                if skipped < discard:
                    skipped += 1
                    continue
                return self._frame(cam, buf)
            finally:
                buf.queue()  # always, and only after the image was copied out

    def _frame(self, cam: _Camera, buf: Any) -> Frame:
        comps = list(buf.payload.components)
        if not comps:
            raise CaptureError("buffer without an image")
        c = comps[0]
        fmt = str(c.data_format)
        try:
            pad = int(c.x_padding)
        except Exception:  # noqa: BLE001
            pad = 0
        try:
            img = to_array(c.data, int(c.width), int(c.height), fmt, x_padding=pad, bayer=self.params.bayer)
        except UnsupportedPixelFormat as exc:
            raise CaptureError(str(exc)) from None
        except ValueError as exc:
            raise CaptureError(f"{fmt} frame unreadable: {exc}") from None
        info: dict[str, Any] = {"serial": cam.serial, "pixel_format": fmt, "trigger": cam.mode}
        for key, attr in (("frame_id", "frame_id"), ("device_timestamp_ns", "timestamp_ns")):
            try:
                info[key] = int(getattr(buf.module, attr))
            except Exception:  # noqa: BLE001 - not every producer has them
                pass
        return Frame(img, info)

    def trigger(self) -> tuple[dict[str, Frame], dict[str, Any]]:
        p = self.params
        errors: dict[str, str] = {}
        for cam in self.cams:
            if cam.broken or cam.needs_restart or cam.ia is None:
                why = self._recover(cam)
                if why:
                    errors[cam.name] = why
        live = [c for c in self.cams if c.name not in errors]
        for cam in live:
            if cam.mode == "hardware":
                continue  # frames queued since the last capture belong to pulses already fired
            try:
                self._drain(cam)
            except Exception as exc:  # noqa: BLE001
                cam.broken = _msg(exc)
                errors[cam.name] = cam.broken
        live = [c for c in live if c.name not in errors]

        t0 = time.perf_counter()
        for cam in live:
            if cam.mode != "software":
                continue
            try:
                cam.ia.remote_device.node_map.TriggerSoftware.execute()
            except Exception as exc:  # noqa: BLE001
                cam.broken = _msg(exc)
                errors[cam.name] = f"TriggerSoftware failed: {cam.broken}"
        for cam in live:
            if cam.mode == "free-run" and cam.name not in errors:
                self._drain(cam)  # completed before the trigger

        deadline = t0 + float(p.timeout_s)
        frames: dict[str, Frame] = {}
        for cam in live:
            if cam.name in errors:
                continue
            discard = int(p.freerun_discard) if cam.mode == "free-run" else 0
            try:
                frames[cam.name] = self._fetch(cam, deadline, discard)
            except _Timeout as exc:
                cam.needs_restart = True
                errors[cam.name] = str(exc)
            except CaptureError as exc:
                cam.needs_restart = True
                errors[cam.name] = str(exc)
            except Exception as exc:  # noqa: BLE001 - transport error: reopen next time
                cam.broken = _msg(exc)
                errors[cam.name] = cam.broken
        latency_ms = 1e3 * (time.perf_counter() - t0)
        if errors:
            for cam in self.cams:  # frames of one hardware pulse must stay together: resync
                if cam.mode == "hardware" and cam.ia is not None:
                    cam.needs_restart = True
            ordered = {c.label: errors[c.name] for c in self.cams if c.name in errors}
            raise CaptureError(f"{DRIVER}: {join_errors(ordered)}")
        return frames, {"latency_ms": round(latency_ms, 3)}

    def close(self) -> None:
        for cam in self.cams:
            self._destroy(cam)
        try:
            self.h.reset()
        except Exception:  # noqa: BLE001
            pass


class HarvesterDriver(LiveDriver):
    """The ``genicam`` driver: :class:`LiveDriver` over a :class:`HarvesterSession`."""

    name = DRIVER

    def _open_session(self) -> HarvesterSession:
        return HarvesterSession(self.params, self.rig, self.matches)
