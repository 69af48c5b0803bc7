"""Aravis session behind the ``aravis`` driver (imports ``gi.repository.Aravis``).

Per trigger (:meth:`AravisSession.trigger`):

1. a camera whose connection was lost (a GVCP command failed, or Aravis reported
   ``control-lost``) is probed with a GVCP discovery (:mod:`.gvcp`) and reopened when it
   answers; the old connection is released in a background thread, since Aravis waits 2.5 s
   per command to a dead camera;
2. completed frames still in the stream's output queue are pushed back unread;
3. ``TriggerSoftware`` goes to every software-triggered camera at once (one pool thread each);
4. one frame per camera is popped before ``timeout_s``. Accepted only when its first packet
   reached the host after the trigger was sent (Aravis' system timestamp), its frame id is new
   and its status is ``success``; anything else is pushed back (stale) or reported (damaged:
   ``missing-packets``, ``timeout``, ``size-mismatch``...). The image is copied out and the
   buffer pushed back in a ``finally`` block;
5. with ``retries``, cameras whose frame was damaged or late are re-triggered alone.

Any camera left without a frame makes the trigger a :class:`~inspector.errors.CaptureError`
naming it; the other cameras and the session are unaffected.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from inspector.errors import CaptureError, InputError
from inspector.model import Rig
from inspector_drivers.aravis import AravisParams
from inspector_drivers.aravis.gvcp import discover
from inspector_drivers.genicam.common import DeviceMatch, Frame, LiveDriver, join_errors
from inspector_drivers.genicam.pixels import UnsupportedPixelFormat, pixel_format_name, to_array

__all__ = ["AravisDriver", "AravisSession"]

DRIVER = "aravis"
#: Aravis stamps frames with g_get_real_time() (microseconds): allow for the truncation.
_STAMP_SLACK_NS = 2_000


def _gi() -> tuple[Any, Any]:
    import gi

    gi.require_version("Aravis", "0.8")
    from gi.repository import Aravis, GLib

    return Aravis, GLib


def _msg(exc: BaseException) -> str:
    text = getattr(exc, "message", None) or str(exc) or type(exc).__name__
    text = " ".join(str(text).split())
    if isinstance(exc, InputError) and text.startswith(f"{DRIVER}: camera "):
        text = text.split(": ", 2)[-1]
    return text[:300]


#: Why a buffer with this status (``ArvBufferStatus`` nick) holds no usable image.
_STATUS = {
    "missing-packets": "incomplete: packets lost and not re-sent",
    "timeout": "incomplete: packets still missing when the frame retention time ran out",
    "size-mismatch": "larger than the stream buffer (payload size changed?)",
    "wrong-packet-id": "corrupt: unexpected packet id",
    "aborted": "aborted",
    "cleared": "cleared",
    "filling": "still filling",
    "payload-not-supported": "payload type not supported",
    "unknown": "in an unknown state",
}


class _Timeout(Exception):
    pass


class _Damaged(Exception):
    def __init__(self, message: str, retry: bool = True) -> None:
        super().__init__(message)
        self.retry = retry


@dataclass(eq=False)
class _Cam:
    name: str
    match: DeviceMatch
    key: str = ""  # what Aravis opens: an IP address (GigE) or a device id
    address: str = ""
    serial: str = ""
    camera: Any = None
    stream: Any = None
    device: Any = None
    handler: int = 0
    mode: str = "software"
    formats: dict[int, str] = field(default_factory=dict)
    lost: str = ""
    control_lost: threading.Event = field(default_factory=threading.Event)
    needs_flush: bool = False
    last_frame_id: int | None = None

    @property
    def label(self) -> str:
        return f"{self.name} ({self.match.describe()})"


class AravisSession:
    """The cameras of one rig, configured and streaming (see the module docstring)."""

    def __init__(self, params: AravisParams, rig: Rig, matches: list[DeviceMatch]) -> None:
        self.Aravis, self.GLib = _gi()
        self.params = params
        self.rig = rig
        self.cams = [_Cam(m.camera, m) for m in matches]
        self._released: list[threading.Thread] = []
        self.pool: ThreadPoolExecutor | None = None
        try:
            self._locate()
            for cam in self.cams:
                self._open(cam)
        except BaseException:
            self.close()
            raise
        self.pool = ThreadPoolExecutor(max_workers=max(1, len(self.cams)), thread_name_prefix="aravis-trigger")
        modes = sorted({c.mode for c in self.cams})
        self.trigger_mode = modes[0] if len(modes) == 1 else "mixed"

    # -- discovery --------------------------------------------------------------------------
    def _locate(self) -> None:
        Aravis = self.Aravis
        fixed = dict(self.params.addresses or {})
        unknown = sorted(set(fixed) - set(self.rig.names))
        if unknown:
            raise InputError(f"{DRIVER}: addresses: camera {unknown[0]} is not in the rig")
        for cam in self.cams:
            if cam.name in fixed:
                cam.key = cam.address = str(fixed[cam.name])
        rest = [c for c in self.cams if not c.key]
        if not rest:
            return
        Aravis.update_device_list()
        devices = []
        for i in range(Aravis.get_n_devices()):
            devices.append(
                {
                    "id": Aravis.get_device_id(i) or "",
                    "serial": Aravis.get_device_serial_nbr(i) or "",
                    "address": Aravis.get_device_address(i) or "",
                    "protocol": Aravis.get_device_protocol(i) or "",
                }
            )
        if any(c.match.by == "user_id" for c in rest):
            for d in devices:
                ans = discover(d["address"], timeout=0.5) if d["protocol"] == "GigEVision" and d["address"] else None
                d["user_id"] = ans.user_name if ans is not None else ""
        for cam in rest:
            key = "serial" if cam.match.by == "serial" else "user_id"
            hits = [d for d in devices if d.get(key) == cam.match.value]
            if not hits:
                found = sorted({d.get(key, "") for d in devices if d.get(key)})
                raise InputError(
                    f"{DRIVER}: camera {cam.name}: no device with {cam.match.describe()} "
                    f"(found: {', '.join(found) or 'no device'})"
                )
            if len(hits) > 1:
                raise InputError(f"{DRIVER}: camera {cam.name}: {len(hits)} devices with {cam.match.describe()}")
            d = hits[0]
            cam.serial = d["serial"]
            cam.address = d["address"] if d["protocol"] == "GigEVision" else ""
            cam.key = cam.address or d["id"]
        seen: dict[str, str] = {}
        for cam in self.cams:
            if cam.key in seen:
                raise InputError(f"{DRIVER}: cameras {seen[cam.key]} and {cam.name} are the same device ({cam.key})")
            seen[cam.key] = cam.name

    # -- one camera ---------------------------------------------------------------------------
    def _open(self, cam: _Cam) -> None:
        Aravis, GLib = self.Aravis, self.GLib
        where = f"{DRIVER}: camera {cam.label}"
        try:
            camera = Aravis.Camera.new(cam.key)
        except GLib.Error as exc:
            raise InputError(f"{where}: cannot open the device at {cam.key}: {_msg(exc)}") from None
        if camera is None:
            raise InputError(f"{where}: cannot open the device at {cam.key}")
        stream = None
        try:
            serial = camera.get_device_serial_number() or cam.serial
            if cam.match.by == "serial" and serial != cam.match.value:
                raise InputError(f"{where}: the device at {cam.key} has serial {serial!r}")
            cam.serial = serial
            mode = self._configure(cam, camera, where)
            p = self.params
            if camera.is_gv_device() and p.packet_size:
                camera.gv_set_packet_size(int(p.packet_size))
            stream = camera.create_stream(None, None)
            if stream is None:
                raise InputError(f"{where}: cannot create a stream")
            self._stream_options(stream)
            payload = camera.get_payload()
            for _ in range(int(p.num_buffers)):
                stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            try:
                codes = list(camera.dup_available_pixel_formats() or [])
                names = list(camera.dup_available_pixel_formats_as_strings() or [])
                cam.formats = dict(zip(codes, names))
            except GLib.Error:
                cam.formats = {}
            device = camera.get_device()
            cam.control_lost.clear()
            handler = device.connect("control-lost", lambda *_a, ev=cam.control_lost: ev.set())
            camera.start_acquisition()
        except InputError:
            self._release([stream, camera])
            raise
        except GLib.Error as exc:
            self._release([stream, camera])
            raise InputError(f"{where}: {_msg(exc)}") from None
        cam.camera, cam.stream, cam.device, cam.handler, cam.mode = camera, stream, device, handler, mode
        cam.lost, cam.needs_flush, cam.last_frame_id = "", False, None

    def _stream_options(self, stream: Any) -> None:
        Aravis, p = self.Aravis, self.params
        names = {s.name for s in stream.list_properties()}
        if "packet-resend" in names and not p.packet_resend:
            stream.set_property("packet-resend", Aravis.GvStreamPacketResend.NEVER)
        if "packet-timeout" in names and p.packet_timeout_ms > 0:
            stream.set_property("packet-timeout", int(p.packet_timeout_ms * 1000))
        if "frame-retention" in names and p.frame_retention_ms > 0:
            stream.set_property("frame-retention", int(p.frame_retention_ms * 1000))
        if "socket-buffer" in names and p.socket_buffer_kb > 0:
            stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.FIXED)
            stream.set_property("socket-buffer-size", int(p.socket_buffer_kb) * 1024)

    def _configure(self, cam: _Cam, camera: Any, where: str) -> str:
        Aravis, GLib, p = self.Aravis, self.GLib, self.params
        try:
            try:
                camera.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
            except GLib.Error:
                pass
            if p.set_size:
                c = self.rig.camera(cam.name)
                camera.set_integer("Width", int(c.width))
                camera.set_integer("Height", int(c.height))
            if p.pixel_format:
                offered = list(camera.dup_available_pixel_formats_as_strings() or [])
                if p.pixel_format not in offered:
                    raise InputError(f"{where}: PixelFormat {p.pixel_format!r} is not available (device offers: {', '.join(offered)})")
                camera.set_pixel_format_from_string(p.pixel_format)
            if p.exposure_us is not None:
                if camera.is_exposure_auto_available():
                    camera.set_exposure_time_auto(Aravis.Auto.OFF)
                if not camera.is_exposure_time_available():
                    raise InputError(f"{where}: the device has no exposure time feature")
                camera.set_exposure_time(float(p.exposure_us))
            if p.gain is not None:
                if camera.is_gain_auto_available():
                    camera.set_gain_auto(Aravis.Auto.OFF)
                if not camera.is_gain_available():
                    raise InputError(f"{where}: the device has no gain feature")
                camera.set_gain(float(p.gain))
            return self._configure_trigger(camera, where)
        except GLib.Error as exc:
            raise InputError(f"{where}: {_msg(exc)}") from None

    def _configure_trigger(self, camera: Any, where: str) -> str:
        GLib, p = self.GLib, self.params

        def has(name: str) -> bool:
            try:
                return bool(camera.is_feature_available(name))
            except GLib.Error:
                return False

        def entries(name: str) -> list[str]:
            try:
                return list(camera.dup_available_enumerations_as_strings(name) or [])
            except GLib.Error:
                return []

        def put(name: str, value: str) -> None:
            offered = entries(name)
            if offered and value not in offered:
                raise InputError(f"{where}: {name} {value!r} is not available (device offers: {', '.join(offered)})")
            camera.set_string(name, value)

        usable = has("TriggerMode")
        if usable and p.trigger == "software":
            usable = has("TriggerSoftware") and (not has("TriggerSource") or "Software" in entries("TriggerSource"))
        selectors = entries("TriggerSelector") if has("TriggerSelector") else []
        if has("TriggerMode"):
            each: list[str | None] = [*selectors] or [None]  # None: a device without trigger selectors
            for s in each:
                try:
                    if s is not None:
                        camera.set_string("TriggerSelector", s)
                    camera.set_string("TriggerMode", "Off")
                except GLib.Error:
                    pass
        if not usable:
            return "free-run"
        if selectors:
            put("TriggerSelector", p.trigger_selector)
        put("TriggerMode", "On")
        if p.trigger == "software":
            if has("TriggerSource"):
                put("TriggerSource", "Software")
            return "software"
        if has("TriggerSource"):
            put("TriggerSource", p.trigger_source)
        if has("TriggerActivation"):
            put("TriggerActivation", p.trigger_activation)
        return "hardware"

    def _release(self, objs: list[Any]) -> None:
        """Drop Aravis objects in a background thread (dead cameras take seconds to let go)."""
        box = [o for o in objs if o is not None]
        objs.clear()  # the thread's list must hold the last references
        if not box:
            return

        def drop(box: list[Any] = box) -> None:
            box.clear()

        t = threading.Thread(target=drop, name="aravis-release", daemon=True)
        t.start()
        self._released = [x for x in self._released if x.is_alive()] + [t]

    def _disconnect(self, cam: _Cam) -> None:
        if cam.device is not None and cam.handler:
            try:
                cam.device.disconnect(cam.handler)
            except Exception:  # noqa: BLE001
                pass
        objs = [cam.stream, cam.camera, cam.device]
        cam.stream = cam.camera = cam.device = None
        cam.handler = 0
        self._release(objs)

    def _reconnect(self, cam: _Cam) -> str:
        """Reopen a lost camera; "" when done, else why not."""
        why = cam.lost or "connection lost"
        self._disconnect(cam)
        if cam.address:
            ans = discover(cam.address, timeout=float(self.params.probe_timeout_s))
            if ans is None:
                return f"disconnected ({why}); no answer at {cam.address}"
            if cam.match.by == "serial" and ans.serial and ans.serial != cam.match.value:
                return f"disconnected; {cam.address} now answers as serial {ans.serial!r}"
        try:
            self._open(cam)
        except InputError as exc:
            cam.lost = _msg(exc)
            return f"disconnected ({why}); reconnect failed: {cam.lost}"
        return ""

    # -- frames -----------------------------------------------------------------------------
    def _drain(self, cam: _Cam) -> int:
        n = 0
        while True:
            buf = cam.stream.try_pop_buffer()
            if buf is None:
                return n
            cam.stream.push_buffer(buf)
            n += 1

    def _software_trigger(self, cam: _Cam) -> str:
        try:
            cam.camera.software_trigger()
        except self.GLib.Error as exc:
            return _msg(exc)
        except Exception as exc:  # noqa: BLE001
            return _msg(exc)
        return ""

    def _fetch(self, cam: _Cam, deadline: float, t_ns: int) -> Frame:
        Aravis, p = self.Aravis, self.params
        stale = skipped = 0
        what = {"software": "of the software trigger", "hardware": "while waiting for the hardware trigger"}.get(cam.mode, "of the trigger (free-run)")
        while True:
            left_us = int((deadline - time.perf_counter()) * 1e6)
            buf = cam.stream.timeout_pop_buffer(left_us) if left_us > 0 else cam.stream.try_pop_buffer()
            if buf is None:
                extra = f" ({stale} stale frame{'s' if stale != 1 else ''} dropped)" if stale else ""
                raise _Timeout(f"no frame within {p.timeout_s:g} s {what}{extra}")
            try:
                fid = int(buf.get_frame_id())
                sys_ts = int(buf.get_system_timestamp())
                if cam.mode != "hardware" and sys_ts < t_ns - _STAMP_SLACK_NS:
                    stale += 1  # began arriving before the trigger was sent
                    continue
                if cam.last_frame_id is not None and fid == cam.last_frame_id:
                    stale += 1
                    continue
                status = buf.get_status()
                if status != Aravis.BufferStatus.SUCCESS:
                    nick = str(getattr(status, "value_nick", status))
                    why = _STATUS.get(nick, "not usable")
                    raise _Damaged(f"frame {fid} {why} [{nick}]{self._loss(cam)}")
                if cam.mode == "free-run" and skipped < int(p.freerun_discard):
                    skipped += 1
                    continue
                return self._frame(cam, buf, fid, sys_ts)
            finally:
                cam.stream.push_buffer(buf)  # always; the image was copied out

    def _loss(self, cam: _Cam) -> str:
        try:
            missing = int(cam.stream.get_info_uint64_by_name("n_missing_packets"))
            resent = int(cam.stream.get_info_uint64_by_name("n_resent_packets"))
        except Exception:  # noqa: BLE001
            return ""
        return f" (stream so far: {missing} packets missing, {resent} re-sent)"

    def _frame(self, cam: _Cam, buf: Any, fid: int, sys_ts: int) -> Frame:
        Aravis = self.Aravis
        ptype = buf.get_payload_type()
        if ptype not in (Aravis.BufferPayloadType.IMAGE, Aravis.BufferPayloadType.EXTENDED_CHUNK_DATA):
            raise _Damaged(f"frame {fid}: payload {ptype.value_nick} holds no image", retry=False)
        code = int(buf.get_image_pixel_format())
        fmt = cam.formats.get(code) or pixel_format_name(code)
        w, h = int(buf.get_image_width()), int(buf.get_image_height())
        try:
            pad = buf.get_image_padding()
            x_pad = int(pad[0] if isinstance(pad, tuple) else pad)
        except Exception:  # noqa: BLE001
            x_pad = 0
        data = buf.get_image_data() if hasattr(buf, "get_image_data") else buf.get_data()
        try:
            img = to_array(data, w, h, fmt, x_padding=x_pad, bayer=self.params.bayer)
        except UnsupportedPixelFormat as exc:
            raise _Damaged(str(exc), retry=False) from None
        except ValueError as exc:
            raise _Damaged(f"frame {fid} ({fmt}) unreadable: {exc}", retry=False) from None
        cam.last_frame_id = fid
        info = {
            "serial": cam.serial,
            "frame_id": fid,
            "pixel_format": fmt,
            "trigger": cam.mode,
            "system_timestamp_ns": sys_ts,
            "device_timestamp_ns": int(buf.get_timestamp()),
        }
        if cam.address:
            info["address"] = cam.address
        return Frame(img, info)

    # -- one trigger --------------------------------------------------------------------------
    def trigger(self) -> tuple[dict[str, Frame], dict[str, Any]]:
        p = self.params
        errors: dict[str, str] = {}
        for cam in self.cams:
            if cam.control_lost.is_set() and not cam.lost:
                cam.lost = "control of the camera was lost"
            if cam.lost or cam.camera is None:
                why = self._reconnect(cam)
                if why:
                    errors[cam.name] = why
            elif cam.needs_flush:
                self._drain(cam)
                cam.needs_flush = False

        frames: dict[str, Frame] = {}
        pending = [c for c in self.cams if c.name not in errors]
        attempts = 0
        t_first = t_last = time.perf_counter()
        while pending:
            attempts += 1
            for cam in pending:
                if cam.mode != "hardware":
                    self._drain(cam)
            t_ns = time.time_ns()
            t0 = time.perf_counter()
            if attempts == 1:
                t_first = t0
            assert self.pool is not None
            futures = {c.name: self.pool.submit(self._software_trigger, c) for c in pending if c.mode == "software"}
            deadline = t0 + float(p.timeout_s)
            failed: dict[str, tuple[str, bool]] = {}
            for cam in pending:
                try:
                    frames[cam.name] = self._fetch(cam, deadline, t_ns)
                except _Timeout as exc:
                    cam.needs_flush = True
                    failed[cam.name] = (str(exc), True)
                except _Damaged as exc:
                    failed[cam.name] = (str(exc), exc.retry)
                except self.GLib.Error as exc:
                    cam.lost = _msg(exc)
                    failed[cam.name] = (cam.lost, False)
            for cam in pending:
                fut = futures.get(cam.name)
                err = fut.result() if fut is not None else ""
                if err:
                    frames.pop(cam.name, None)
                    cam.lost = f"TriggerSoftware failed: {err}"
                    failed[cam.name] = (cam.lost, False)
            t_last = time.perf_counter()
            retry = [c for c in pending if c.name in failed and failed[c.name][1] and c.mode == "software" and attempts <= p.retries]
            for cam in pending:
                if cam.name in failed and cam not in retry:
                    why = failed[cam.name][0]
                    errors[cam.name] = why if attempts == 1 else f"{why} (after {attempts} attempts)"
            pending = retry
        if errors:
            if any(c.mode == "hardware" for c in self.cams):
                for cam in self.cams:  # frames of one hardware trigger must stay together: resync
                    cam.needs_flush = cam.needs_flush or cam.mode == "hardware"
            ordered = {c.label: errors[c.name] for c in self.cams if c.name in errors}
            raise CaptureError(f"{DRIVER}: {join_errors(ordered)}")
        meta = {"latency_ms": round(1e3 * (t_last - t_first), 3), "attempts": attempts}
        arrivals = [int(f.info["system_timestamp_ns"]) for f in frames.values() if "system_timestamp_ns" in f.info]
        if arrivals and attempts == 1:
            # first packet of the last frame to arrive, after the trigger was sent: the
            # cameras' share of the latency (the rest is transfer and this driver)
            meta["last_frame_start_ms"] = round((max(arrivals) - t_ns) / 1e6, 3)
        return frames, meta

    def close(self) -> None:
        for cam in self.cams:
            if cam.camera is not None and not cam.lost:
                try:
                    cam.camera.stop_acquisition()
                except Exception:  # noqa: BLE001
                    pass
            self._disconnect(cam)
        if self.pool is not None:
            self.pool.shutdown(wait=True)
        for t in self._released:
            t.join(timeout=10)
        self._released = []


class AravisDriver(LiveDriver):
    """The ``aravis`` driver: :class:`LiveDriver` over an :class:`AravisSession`."""

    name = DRIVER

    def _open_session(self) -> AravisSession:
        return AravisSession(self.params, self.rig, self.matches)
