"""What the hardware drivers (``genicam``, ``aravis``) share: rig, camera -> device mapping,
one capture per trigger, and the one-line errors.

A hardware driver opens a *session* (its devices, configured and streaming) and asks it for
one set of frames per trigger (:meth:`Session.trigger`). :class:`LiveDriver` turns that into
the :class:`~inspector.registry.Driver` protocol: ``acquire()`` yields one
:class:`~inspector.registry.Acquisition` per trigger, whose ``load()`` fires the trigger,
gathers a frame from every camera of the rig and returns a
:class:`~inspector.model.Capture` with the rig read from ``rig.json`` (and the cameras'
empty-field images ``background/<camera>.png`` beside it, when there). A trigger that does not
give every camera a good frame raises :class:`~inspector.errors.CaptureError` naming the
camera(s); the driver stays usable and the next trigger is independent.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from inspector.capture_folder import BACKGROUND_DIR, RIG_FILE, _decode_png, read_rig
from inspector.errors import CaptureError, InputError
from inspector.model import Capture, Rig
from inspector.registry import Acquisition

__all__ = ["Frame", "Session", "LiveDriver", "load_rig", "load_backgrounds", "camera_keys", "join_errors", "DeviceMatch"]


@dataclass(frozen=True, eq=False)
class Frame:
    """One camera's image of one trigger, and what is known about it (JSON-able ``info``)."""

    image: np.ndarray
    info: Mapping[str, Any] = field(default_factory=dict)


class Session(Protocol):
    """An open set of devices (one per rig camera)."""

    trigger_mode: str

    def trigger(self) -> tuple[dict[str, Frame], dict[str, Any]]:
        """Fire one trigger; every camera's frame and the trigger's metadata, or CaptureError."""
        ...

    def close(self) -> None:
        ...


def load_rig(path: str, driver: str) -> Rig:
    """The rig of ``params.rig`` (``rig.json``, or a capture folder holding one)."""
    if not path:
        raise InputError(f"{driver}: parameter 'rig' is required (path to a rig.json with the cameras' calibration)")
    p = Path(path).expanduser()
    if p.is_dir():
        p = p / RIG_FILE
    if not p.is_file():
        raise InputError(f"{driver}: rig file not found: {p}")
    try:
        return read_rig(p)
    except CaptureError as exc:
        raise InputError(f"{driver}: {p}: {exc}") from None


def load_backgrounds(path: str, rig: Rig, driver: str) -> dict[str, np.ndarray]:
    """The cameras' empty-field images beside the rig of ``params.rig``: ``background/<camera>.png``
    in the folder that holds ``rig.json`` (``inspector calibrate --background --out FOLDER``),
    attached to every capture so the segment stage flat-fields it. ``{}`` without that folder;
    a camera without its image, or an image that does not fit its camera, is an InputError."""
    p = Path(path).expanduser()
    folder = p if p.is_dir() else p.parent
    d = folder / BACKGROUND_DIR
    if not d.is_dir():
        return {}
    out: dict[str, np.ndarray] = {}
    for cam in rig:
        f = d / f"{cam.name}.png"
        if not f.is_file():
            raise InputError(f"{driver}: {f}: missing (every camera needs its empty-field image, or none: "
                             "inspector calibrate --background)")
        try:
            out[cam.name] = _decode_png(f, str(f), cam, str(d.resolve()))
        except CaptureError as exc:
            raise InputError(f"{driver}: {exc}") from None
    return out


@dataclass(frozen=True)
class DeviceMatch:
    """How a rig camera is found: by ``"serial"`` or ``"user_id"``, and the value."""

    camera: str
    by: str
    value: str

    def describe(self) -> str:
        return f"{ {'serial': 'serial', 'user_id': 'user id'}.get(self.by, self.by)} {self.value!r}"


def camera_keys(
    rig: Rig,
    serials: Mapping[str, Any] | None,
    user_ids: Mapping[str, Any] | None,
    driver: str,
    addresses: Mapping[str, Any] | None = None,
) -> list[DeviceMatch]:
    """One :class:`DeviceMatch` per rig camera, in rig order (InputError naming the key).

    A camera is found by serial, else by user id, else (drivers that have them) by address.
    """
    serials = dict(serials or {})
    user_ids = dict(user_ids or {})
    addresses = dict(addresses or {})
    if not serials and not user_ids and not addresses:
        raise InputError(f"{driver}: give 'serials' or 'user_ids' (camera name -> device), e.g. serials = {{cam00 = \"21345678\"}}")
    names = set(rig.names)
    for what, table in (("serials", serials), ("user_ids", user_ids), ("addresses", addresses)):
        unknown = sorted(set(table) - names)
        if unknown:
            raise InputError(f"{driver}: {what}: camera {unknown[0]} is not in the rig (cameras: {', '.join(rig.names)})")
        for k, v in table.items():
            if not isinstance(v, (str, int)) or isinstance(v, bool) or str(v) == "":
                raise InputError(f"{driver}: {what}.{k}: expected a non-empty string, got {v!r}")
    out: list[DeviceMatch] = []
    for cam in rig.names:
        if cam in serials and cam in user_ids:
            raise InputError(f"{driver}: camera {cam} is in both serials and user_ids")
        if cam in serials:
            out.append(DeviceMatch(cam, "serial", str(serials[cam])))
        elif cam in user_ids:
            out.append(DeviceMatch(cam, "user_id", str(user_ids[cam])))
        elif cam in addresses:
            out.append(DeviceMatch(cam, "address", str(addresses[cam])))
        else:
            raise InputError(f"{driver}: camera {cam} of the rig has no device (add it to serials or user_ids)")
    seen: dict[tuple[str, str], str] = {}
    for m in out:
        key = (m.by, m.value)
        if key in seen:
            raise InputError(f"{driver}: cameras {seen[key]} and {m.camera} name the same device ({m.describe()})")
        seen[key] = m.camera
    return out


def join_errors(errors: Mapping[str, str]) -> str:
    """``{camera: reason}`` -> one line, cameras in the given order."""
    return "; ".join(f"camera {cam}: {why}" for cam, why in errors.items())


class LiveDriver:
    """Driver protocol over a :class:`Session` (see the module docstring).

    Subclasses set :attr:`name` and implement :meth:`_open_session`.
    """

    name = "live"

    def __init__(self, params: Any) -> None:
        self.params = params
        self.rig = load_rig(getattr(params, "rig", ""), self.name)
        self.backgrounds = load_backgrounds(getattr(params, "rig", ""), self.rig, self.name)
        self.matches = camera_keys(
            self.rig,
            getattr(params, "serials", None),
            getattr(params, "user_ids", None),
            self.name,
            getattr(params, "addresses", None),
        )
        self._stamp = datetime.now().strftime("%Y%m%dT%H%M%S")
        self._index = 0
        self.session: Session | None = self._open_session()

    # -- to implement ------------------------------------------------------------------
    def _open_session(self) -> Session:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- Driver protocol -----------------------------------------------------------------
    def acquire(self) -> Iterator[Acquisition]:
        """One acquisition per trigger: ``params.count`` of them (0: until closed)."""
        count = int(getattr(self.params, "count", 1) or 0)
        n = 0
        while count == 0 or n < count:
            if self.session is None:
                return
            self._index += 1
            n += 1
            name = f"{self.name}-{self._stamp}-{self._index:04d}"

            def load(name: str = name) -> Capture:
                return self.capture(name)

            yield Acquisition(name, load)

    def capture(self, name: str | None = None) -> Capture:
        """Fire one trigger now and return the capture (CaptureError naming the camera)."""
        if self.session is None:
            raise CaptureError(f"{self.name}: driver is closed")
        if name is None:
            self._index += 1
            name = f"{self.name}-{self._stamp}-{self._index:04d}"
        when = datetime.now().astimezone()
        t0 = time.perf_counter()
        frames, meta = self.session.trigger()
        images: dict[str, np.ndarray] = {}
        errors: dict[str, str] = {}
        for cam in self.rig:
            fr = frames.get(cam.name)
            if fr is None:
                errors[cam.name] = "no frame"
                continue
            h, w = fr.image.shape[:2]
            if (w, h) != (cam.width, cam.height):
                errors[cam.name] = f"image {w}x{h}, rig.json says {cam.width}x{cam.height}"
                continue
            images[cam.name] = fr.image
        if errors:
            raise CaptureError(f"{self.name}: {join_errors(errors)}")
        metadata: dict[str, Any] = {
            "timestamp": when.isoformat(timespec="milliseconds"),
            "driver": self.name,
            "trigger": self.session.trigger_mode,
            "acquire_ms": round(1e3 * (time.perf_counter() - t0), 3),
            **meta,
            "frames": {cam: dict(frames[cam].info) for cam in self.rig.names},
        }
        return Capture(
            name=name,
            rig=self.rig,
            images=images,
            backgrounds=self.backgrounds,
            polarity=getattr(self.params, "polarity", "dark-object"),
            metadata=metadata,
        )

    def close(self) -> None:
        s, self.session = self.session, None
        if s is not None:
            s.close()

    def __enter__(self) -> LiveDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
