"""Driver ``genicam``: any GenICam camera through Harvesters and a GenTL producer (``.cti``).

Each rig camera (``rig.json``) is mapped to a device by serial number or user id; every
trigger gives one :class:`~inspector.model.Capture` whose images are the cameras' frames and
whose rig is the calibrated ``rig.json``, so ``inspector run`` inspects live captures exactly
like replayed ones, and ``inspector capture`` writes them as capture folders.

Recipe::

    [driver]
    use = "genicam"
    params = { rig = "rig/rig.json", cti = "/opt/mvIMPACT/lib/x86_64/mvGenTLProducer.cti",
               serials = { cam00 = "21345678", cam01 = "21345679" },
               trigger = "hardware", trigger_source = "Line0", exposure_us = 4000.0 }

Trigger (per device, from the recipe): ``"software"`` (TriggerMode On, TriggerSource
Software, one TriggerSoftware per capture) or ``"hardware"`` (TriggerSelector /
TriggerSource / TriggerActivation set where the device has those features). A device without
trigger features runs free: the frame returned is the newest one whose exposure follows the
trigger (``freerun_discard`` frames completed after the trigger are dropped first). Stale
frames are never returned: queued frames are dropped before every trigger, a device that
missed a frame is restarted (buffers flushed) before the next, and every buffer is re-queued
after its image was copied out, whatever happens.

Harvesters and genicam are imported only when a driver is opened.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from inspector import hookimpl
from inspector.params import param
from inspector.registry import DriverRegistry, DriverSpec

__all__ = ["GenicamParams", "open_driver", "viky_cti"]


@dataclass(frozen=True)
class GenicamParams:
    rig: str = param("", "rig.json with the cameras' names, image sizes and calibration (or a capture folder holding one)")
    serials: dict | None = param(None, "camera name -> device serial number, e.g. {cam00 = \"21345678\"}")
    user_ids: dict | None = param(None, "camera name -> device user id (DeviceUserID), instead of serials")
    cti: str = param("", "GenTL producer .cti file(s), ':'-separated; empty: every .cti in $GENICAM_GENTL64_PATH")
    count: int = param(1, "triggers to acquire (0: until stopped)", min=0)
    trigger: Literal["software", "hardware"] = param("software", "trigger: software command, or a hardware line (free-run where the device has no trigger)")
    trigger_selector: str = param("FrameStart", "TriggerSelector to arm (hardware and software trigger)")
    trigger_source: str = param("Line0", "TriggerSource of the hardware trigger")
    trigger_activation: str = param("RisingEdge", "TriggerActivation of the hardware trigger")
    exposure_us: float | None = param(None, "exposure time, us (ExposureTime/ExposureTimeAbs; ExposureAuto off); none: as configured", min=0.0, max=1e8)
    gain_db: float | None = param(None, "gain, dB (Gain; GainAuto off); none: as configured")
    pixel_format: str = param("", "PixelFormat to set (e.g. Mono8, Mono16, BayerRG8); empty: as configured")
    set_size: bool = param(False, "set Width/Height of every device to its rig camera's image size")
    bayer: Literal["rgb", "raw"] = param("rgb", "Bayer formats: demosaic to RGB, or keep the raw mosaic as grey")
    timeout_s: float = param(2.0, "seconds to wait for every camera's frame after a trigger", min=0.001, max=3600.0)
    num_buffers: int = param(4, "buffers announced per device", min=1, max=1024)
    freerun_discard: int = param(1, "free-running devices: frames completed after the trigger that are dropped (in flight at the trigger)", min=0, max=1000)
    polarity: Literal["dark-object", "bright-object"] = param("dark-object", "the captures' polarity (capture.json)")


def viky_cti() -> str:
    """Path of ``viky.cti``, the simulated GenTL producer shipped in the ``genicam`` wheel."""
    import os

    import genicam

    return os.path.join(os.path.dirname(genicam.__file__), "viky.cti")


def open_driver(params: GenicamParams):
    """``DriverSpec.open``: connect and configure every device (InputError naming the camera)."""
    from inspector_drivers.genicam.harvester import HarvesterDriver

    return HarvesterDriver(params)


@hookimpl
def inspector_register_drivers(registry: DriverRegistry) -> None:
    registry.add(
        DriverSpec(
            name="genicam",
            open=open_driver,
            params=GenicamParams,
            doc="GenICam cameras through Harvesters and a GenTL producer (.cti); one capture per trigger, rig from rig.json",
        )
    )
