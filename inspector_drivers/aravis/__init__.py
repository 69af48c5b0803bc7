"""Driver ``aravis``: GigE Vision (and USB3 Vision) cameras through Aravis (PyGObject).

Cameras are discovered, mapped to the rig's cameras by serial number (or user-defined name,
or a fixed address), configured from the recipe, and triggered together: every trigger gives
one :class:`~inspector.model.Capture` with the rig of ``rig.json``.

Recipe::

    [driver]
    use = "aravis"
    params = { rig = "rig/rig.json", serials = { cam00 = "SN0001", cam01 = "SN0002" },
               exposure_us = 3000.0, timeout_s = 1.0 }

Per trigger: stale frames are dropped, ``TriggerSoftware`` is sent to all cameras at once
(one thread each), and one frame per camera is gathered. A frame is accepted only when its
buffer status is *success* (lost packets that the camera re-sent on request are fine), its
first packet reached the host after the trigger was sent, and its frame id is new; its image is
copied out and the buffer pushed back to the stream at once. Any camera without such a frame
makes that trigger a :class:`~inspector.errors.CaptureError` naming the camera and why
(``missing-packets``, timeout, lost connection...). A camera whose connection was lost is
probed (GVCP discovery, milliseconds) before every later trigger and reconnected as soon as it
answers, so the program keeps running and recovers by itself.

Aravis (``gi.repository.Aravis``, ``gir1.2-aravis-0.8``) is imported only when a driver is
opened; :func:`available` tells whether it can be.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from inspector import hookimpl
from inspector.errors import InputError
from inspector.params import param
from inspector.registry import DriverRegistry, DriverSpec

__all__ = ["AravisParams", "open_driver", "available"]


@dataclass(frozen=True)
class AravisParams:
    rig: str = param("", "rig.json with the cameras' names, image sizes and calibration (or a capture folder holding one)")
    serials: dict | None = param(None, "camera name -> device serial number, e.g. {cam00 = \"SN0001\"}")
    user_ids: dict | None = param(None, "camera name -> device user-defined name (GigE discovery), instead of serials")
    addresses: dict | None = param(None, "camera name -> IP address: open it there without discovery (GigE)")
    count: int = param(1, "triggers to acquire (0: until stopped)", min=0)
    trigger: Literal["software", "hardware"] = param("software", "trigger: software command to all cameras, or a hardware line (free-run where a camera has no trigger)")
    trigger_selector: str = param("FrameStart", "TriggerSelector to arm")
    trigger_source: str = param("Line0", "TriggerSource of the hardware trigger")
    trigger_activation: str = param("RisingEdge", "TriggerActivation of the hardware trigger")
    exposure_us: float | None = param(None, "exposure time, us (auto exposure off); none: as configured", min=0.0, max=1e8)
    gain: float | None = param(None, "gain in the camera's unit (Gain: dB; GainRaw: raw), auto gain off; none: as configured")
    pixel_format: str = param("", "PixelFormat to set (e.g. Mono8, Mono16, BayerRG8); empty: as configured")
    set_size: bool = param(False, "set Width/Height of every camera to its rig camera's image size")
    bayer: Literal["rgb", "raw"] = param("rgb", "Bayer formats: demosaic to RGB, or keep the raw mosaic as grey")
    timeout_s: float = param(2.0, "seconds to wait for every camera's frame after a trigger", min=0.001, max=3600.0)
    retries: int = param(0, "software trigger: re-trigger a camera whose frame was lost or damaged, up to this many times (only for a part at rest)", min=0, max=100)
    num_buffers: int = param(4, "stream buffers per camera", min=2, max=1024)
    freerun_discard: int = param(1, "free-running cameras: frames arriving after the trigger that are dropped (in flight at the trigger)", min=0, max=1000)
    packet_size: int = param(0, "GVSP packet size, bytes (0: as negotiated by Aravis)", min=0, max=65535)
    packet_resend: bool = param(True, "ask the camera to re-send lost packets (where it supports it)")
    packet_timeout_ms: float = param(0.0, "wait before asking for a lost packet, ms (0: Aravis default, 20)", min=0.0, max=60000.0)
    frame_retention_ms: float = param(0.0, "wait for the missing packets of a frame, ms (0: Aravis default, 100)", min=0.0, max=60000.0)
    socket_buffer_kb: int = param(0, "stream socket receive buffer, KiB (0: Aravis default)", min=0, max=1048576)
    probe_timeout_s: float = param(0.2, "GVCP probe of a lost camera before reconnecting, s", min=0.001, max=60.0)
    polarity: Literal["dark-object", "bright-object"] = param("dark-object", "the captures' polarity (capture.json)")


def available() -> str:
    """"" when Aravis 0.8 can be imported, else why not (one line)."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis  # noqa: F401
    except ImportError as exc:
        return f"PyGObject is not installed ({exc})"
    except ValueError as exc:
        return f"Aravis 0.8 introspection data is missing (apt-get install gir1.2-aravis-0.8): {exc}"
    except Exception as exc:  # noqa: BLE001 - gi raises assorted errors when typelibs are broken
        return f"Aravis cannot be loaded: {exc}"
    return ""


def open_driver(params: AravisParams):
    """``DriverSpec.open``: discover, map, configure and start every camera."""
    why = available()
    if why:
        raise InputError(f"aravis: {why}")
    from inspector_drivers.aravis.session import AravisDriver

    return AravisDriver(params)


@hookimpl
def inspector_register_drivers(registry: DriverRegistry) -> None:
    registry.add(
        DriverSpec(
            name="aravis",
            open=open_driver,
            params=AravisParams,
            doc="GigE Vision / USB3 Vision cameras through Aravis; all triggered together, one capture per trigger, rig from rig.json",
        )
    )
