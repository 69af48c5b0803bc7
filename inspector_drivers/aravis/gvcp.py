"""A GigE Vision discovery probe in plain Python (no Aravis): is a camera answering, and who is it.

A unicast GVCP ``DISCOVERY_CMD`` to a device's address is answered by any GigE Vision device,
controlled or not, within a millisecond on a LAN. The driver uses it before reconnecting a
lost camera (Aravis itself waits 2.5 s per failed GVCP command), and to read user-defined
names for ``user_ids`` mapping; the emulator fixtures use it to wait for their cameras.
"""

from __future__ import annotations

import os
import socket
import struct
import time
from dataclasses import dataclass

__all__ = ["GVCP_PORT", "DeviceAnswer", "discover"]

GVCP_PORT = 3956
_KEY = 0x42
_FLAG_ACK = 0x01
_DISCOVERY_CMD = 0x0002
_DISCOVERY_ACK = 0x0003


@dataclass(frozen=True)
class DeviceAnswer:
    """The bootstrap fields of a discovery acknowledge."""

    address: str
    serial: str
    user_name: str
    vendor: str
    model: str
    mac: str


def _text(data: bytes, offset: int, size: int) -> str:
    return data[offset : offset + size].split(b"\0", 1)[0].decode("latin-1").strip()


def _parse(address: str, data: bytes) -> DeviceAnswer | None:
    if len(data) < 8:
        return None
    _status, answer, length, _ack_id = struct.unpack(">HHHH", data[:8])
    if answer != _DISCOVERY_ACK:
        return None
    body = data[8 : 8 + length]
    if len(body) < 0xF8:
        return None
    mac_hi, mac_lo = struct.unpack(">HI", body[0x0A:0x10])
    mac = ":".join(f"{b:02x}" for b in ((mac_hi << 32) | mac_lo).to_bytes(6, "big"))
    return DeviceAnswer(
        address=address,
        serial=_text(body, 0xD8, 16),
        user_name=_text(body, 0xE8, 16),
        vendor=_text(body, 0x48, 32),
        model=_text(body, 0x68, 32),
        mac=mac,
    )


def discover(
    address: str,
    timeout: float = 0.2,
    attempts: int = 2,
    sock: socket.socket | None = None,
    port: int = GVCP_PORT,
) -> DeviceAnswer | None:
    """Ask the device at ``address`` who it is; None when nothing answers within ``timeout``.

    ``sock`` lets a caller use a socket created elsewhere (e.g. inside a network namespace).
    """
    own = sock is None
    s = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        req_id = (os.getpid() ^ int(time.monotonic() * 1e3)) & 0xFFFF or 1
        packet = struct.pack(">BBHHH", _KEY, _FLAG_ACK, _DISCOVERY_CMD, 0, req_id)
        per_try = max(timeout / max(attempts, 1), 0.001)
        if own:
            try:  # a connected socket hears ICMP "port unreachable" at once
                s.connect((address, port))
            except OSError:
                return None
        for _ in range(max(attempts, 1)):
            try:
                if own:
                    s.send(packet)
                else:
                    s.sendto(packet, (address, port))
            except OSError:
                return None
            deadline = time.monotonic() + per_try
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                s.settimeout(left)
                try:
                    data, peer = s.recvfrom(2048)
                except TimeoutError:
                    break
                except OSError:  # ICMP port unreachable: nobody there
                    return None
                if peer[0] != address:
                    continue
                ans = _parse(address, data)
                if ans is not None:
                    return ans
        return None
    finally:
        if own:
            s.close()
