"""An emulated GigE Vision rig: ``arv-fake-gv-camera-0.8`` processes in a network namespace.

Used by the tests and by benches; needs root (network namespaces), ``ip`` (iproute2),
``arv-fake-gv-camera-0.8`` (Debian ``aravis-tools``) and, for the client, Aravis' typelib
(``gir1.2-aravis-0.8``) with PyGObject. :func:`missing_requirements` says what is missing.

    with EmulatedRig(16) as emu:                  # namespace, 127.0.1.1..16 on lo, 16 cameras
        emu.kill(5); emu.restart(5)               # a camera dies and comes back
        with emu.client() as c:                   # a Python client inside the namespace
            c.request({"cmd": "open", "driver": "aravis", "params": {...}})
            c.request({"cmd": "trigger", "pattern": True})

The fake camera fills Mono8 frames with a diagonal ramp that depends on the frame id only
(:func:`fake_pattern`), so a client can check every pixel of every frame it got.
"""

from __future__ import annotations

import ctypes
import itertools
import json
import math
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from inspector_drivers.aravis import available
from inspector_drivers.aravis.gvcp import discover
from inspector_drivers.sim.rig import sphere_rig

__all__ = [
    "FAKE_CAMERA",
    "missing_requirements",
    "fake_pattern",
    "write_rig",
    "EmulatedRig",
    "Client",
]

FAKE_CAMERA = "arv-fake-gv-camera-0.8"
_CLONE_NEWNET = 0x40000000
_counter = itertools.count()


def missing_requirements(client: bool = True) -> str:
    """"" when an emulated rig can run here, else a one-line reason (for ``pytest.skip``)."""
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "needs root (ip netns add)"
    missing = [b for b in ("ip", FAKE_CAMERA) if shutil.which(b) is None]
    if missing:
        return f"missing {', '.join(missing)} (apt-get install iproute2 aravis-tools)"
    if client:
        why = available()
        if why:
            return why
    return ""


def fake_pattern(width: int, height: int, frame_id: int, exposure_us: float = 10_000.0, gain: float = 0.0) -> np.ndarray:
    """The Mono8 image the fake camera sends for ``frame_id`` (``arv_fake_camera_diagonal_ramp``)."""
    y, x = np.mgrid[0:height, 0:width]
    scale = 1.0 + gain + math.log10(exposure_us / 10_000.0)
    v = ((x + y + int(frame_id)) % 255).astype(np.float64) * scale
    return np.clip(v, 0, 255).astype(np.uint8)  # C's double -> unsigned char truncates


def write_rig(path: str | os.PathLike[str], n: int, width: int = 512, height: int = 512) -> Any:
    """A rig.json for ``n`` emulated cameras (cam00.. on a sphere, ``width`` x ``height``)."""
    rig = sphere_rig(n, radius_mm=400.0, width=width, height=height, mm_per_px=0.1 * 1024 / max(width, height))
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(rig.to_json(), indent=1))
    return rig


_SET_USER_NAME = """
import sys, gi
gi.require_version("Aravis", "0.8")
from gi.repository import Aravis
camera = Aravis.Camera.new(sys.argv[1])
device = camera.get_device()
raw = sys.argv[2].encode("latin-1").ljust(16, b"\\0")
for k in range(4):
    device.write_register(0xE8 + 4 * k, int.from_bytes(raw[4 * k : 4 * k + 4], "big"))
del device, camera  # releases control of the camera now, not at its 3 s heartbeat timeout
"""


def _run(*args: str) -> None:
    r = subprocess.run(list(args), capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: {r.stderr.strip() or r.returncode}")


class EmulatedRig:
    """``n`` fake GigE cameras at ``subnet + 1 .. n`` inside a private network namespace.

    Parameters
    ----------
    n : int
        Cameras (at most 254).
    lost_per_thousand : int
        GVSP packets each camera drops, per thousand (``-r``); per camera via ``start_camera``.
    serial_format : str
        Serial of camera ``i`` (0-based): ``serial_format.format(i)``.
    log_dir : path, optional
        Where each camera's stderr goes (``cam{i}.log``); default: discarded.
    """

    def __init__(
        self,
        n: int = 16,
        *,
        lost_per_thousand: int = 0,
        subnet: str = "127.0.1.",
        serial_format: str = "EMU{:04d}",
        name: str | None = None,
        log_dir: str | os.PathLike[str] | None = None,
    ) -> None:
        if not 1 <= n <= 254:
            raise ValueError("n must be 1..254")
        self.n = n
        self.ns = name or f"inspector-arv-{os.getpid()}-{next(_counter)}"
        self.addresses = [f"{subnet}{i + 1}" for i in range(n)]
        self.serials = [serial_format.format(i) for i in range(n)]
        self.names = [f"cam{i:02d}" for i in range(n)]
        self.lost_per_thousand = int(lost_per_thousand)
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self.procs: list[subprocess.Popen | None] = [None] * n
        self._ns_created = False
        self._sock: socket.socket | None = None

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self, timeout: float = 20.0) -> EmulatedRig:
        why = missing_requirements(client=False)
        if why:
            raise RuntimeError(why)
        try:
            _run("ip", "netns", "add", self.ns)
            self._ns_created = True
            _run("ip", "-n", self.ns, "link", "set", "lo", "up")
            for a in self.addresses:
                _run("ip", "-n", self.ns, "addr", "add", f"{a}/32", "dev", "lo")
            for i in range(self.n):
                self.start_camera(i, wait=False)
            self.wait_ready(timeout=timeout)
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        for i in range(self.n):
            self.kill(i)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if self._ns_created:
            subprocess.run(["ip", "netns", "del", self.ns], capture_output=True)
            self._ns_created = False

    def __enter__(self) -> EmulatedRig:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- cameras ------------------------------------------------------------------------------
    def start_camera(self, i: int, lost_per_thousand: int | None = None, wait: bool = True, timeout: float = 10.0) -> None:
        """Start (or restart) camera ``i``; waits until it answers discovery."""
        self.kill(i)
        lost = self.lost_per_thousand if lost_per_thousand is None else int(lost_per_thousand)
        cmd = ["ip", "netns", "exec", self.ns, FAKE_CAMERA, "-i", self.addresses[i], "-s", self.serials[i]]
        if lost:
            cmd += ["-r", str(lost)]
        err: Any = subprocess.DEVNULL
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            err = open(self.log_dir / f"cam{i:02d}.log", "ab")
        try:
            self.procs[i] = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
        finally:
            if err is not subprocess.DEVNULL:
                err.close()
        if wait:
            self.wait_ready([i], timeout=timeout)

    restart = start_camera

    def kill(self, i: int) -> None:
        """Kill camera ``i`` at once (SIGKILL), as a camera losing power."""
        p = self.procs[i]
        self.procs[i] = None
        if p is not None and p.poll() is None:
            p.send_signal(signal.SIGKILL)
            p.wait(timeout=10)

    def running(self, i: int) -> bool:
        p = self.procs[i]
        return p is not None and p.poll() is None

    # -- inside the namespace -----------------------------------------------------------------
    def ns_socket(self) -> socket.socket:
        """A UDP socket created inside the namespace (usable from this process)."""
        if self._sock is None:
            box: dict[str, Any] = {}

            def enter() -> None:  # setns() changes the calling thread only
                fd = os.open(f"/run/netns/{self.ns}", os.O_RDONLY)
                try:
                    libc = ctypes.CDLL(None, use_errno=True)
                    if libc.setns(fd, _CLONE_NEWNET) != 0:
                        raise OSError(ctypes.get_errno(), "setns")
                    box["sock"] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                except BaseException as exc:  # noqa: BLE001
                    box["err"] = exc
                finally:
                    os.close(fd)

            t = threading.Thread(target=enter)
            t.start()
            t.join()
            if "err" in box:
                raise box["err"]
            self._sock = box["sock"]
        return self._sock

    def answers(self, i: int, timeout: float = 0.2) -> bool:
        return discover(self.addresses[i], timeout=timeout, sock=self.ns_socket()) is not None

    def wait_ready(self, indices: list[int] | None = None, timeout: float = 10.0) -> None:
        todo = set(range(self.n) if indices is None else indices)
        deadline = time.monotonic() + timeout
        while todo:
            for i in sorted(todo):
                if not self.running(i):
                    raise RuntimeError(f"fake camera {i} ({self.addresses[i]}) exited")
                if self.answers(i, timeout=0.1):
                    todo.discard(i)
            if todo and time.monotonic() > deadline:
                raise TimeoutError(f"fake cameras {sorted(todo)} do not answer discovery")

    def set_user_name(self, i: int, name: str) -> None:
        """Give camera ``i`` a user-defined name (GigE bootstrap register 0xE8, 16 bytes)."""
        raw = name.encode("latin-1")
        if len(raw) > 15:
            raise ValueError("a GigE Vision user-defined name has at most 15 characters")
        r = subprocess.run(
            self.exec_prefix() + [sys.executable, "-c", _SET_USER_NAME, self.addresses[i], name],
            capture_output=True,
            text=True,
            timeout=60,
        )
        if r.returncode != 0:
            raise RuntimeError(f"cannot set the user name of camera {i}: {r.stderr.strip()[-500:]}")

    def exec_prefix(self) -> list[str]:
        return ["ip", "netns", "exec", self.ns]

    def serials_table(self) -> dict[str, str]:
        return dict(zip(self.names, self.serials))

    def client(self, timeout: float = 60.0) -> Client:
        """A :mod:`inspector_tools.emulators.aravis_harness` process inside the namespace."""
        return Client(self.exec_prefix() + [sys.executable, "-m", "inspector_tools.emulators.aravis_harness"], timeout=timeout)


class Client:
    """Line-oriented JSON requests to a harness process (see :mod:`.harness`)."""

    def __init__(self, argv: list[str], timeout: float = 60.0) -> None:
        self.timeout = timeout
        self.proc = subprocess.Popen(
            argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1
        )
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._err: list[str] = []
        threading.Thread(target=self._pump, args=(self.proc.stdout, self._lines), daemon=True).start()
        threading.Thread(target=self._drain_err, daemon=True).start()

    @staticmethod
    def _pump(stream: Any, out: queue.Queue) -> None:
        for line in stream:
            out.put(line)
        out.put(None)

    def _drain_err(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self._err.append(line)
            del self._err[:-200]

    @property
    def stderr(self) -> str:
        return "".join(self._err)

    def request(self, req: dict[str, Any], timeout: float | None = None) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"harness: no answer to {req.get('cmd')} within {timeout or self.timeout} s\n{self.stderr[-3000:]}")
            try:
                line = self._lines.get(timeout=left)
            except queue.Empty:
                continue
            if line is None:
                raise RuntimeError(f"harness exited ({self.proc.wait()}):\n{self.stderr[-3000:]}")
            line = line.strip()
            if line.startswith("{"):
                return json.loads(line)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> int:
        if self.proc.poll() is None:
            try:
                self.request({"cmd": "close"}, timeout=30)
            except Exception:  # noqa: BLE001
                pass
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        return self.proc.wait()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
