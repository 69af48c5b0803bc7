"""Driver ``genicam`` (Harvesters + GenTL): pixel formats, trigger set-up, buffer handling,
and the real thing against ``viky.cti`` (the simulated GenTL producer of the ``genicam`` wheel:
three free-running devices, serials 0, 1, 2, 400x400, Mono8 or RGBa8, no trigger features).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import time
from collections import deque
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from inspector.errors import CaptureError, InputError, RecipeError
from inspector.params import build_params
from inspector_drivers.genicam import GenicamParams
from inspector_drivers.genicam.pixels import SUPPORTED, UnsupportedPixelFormat, pixel_format_name, to_array

ROOT = Path(__file__).resolve().parents[2]


def plugin_manager():
    """Entry-point plugins, plus the genicam driver while pyproject does not declare it."""
    import inspector_drivers.genicam as genicam_mod
    from inspector.manager import create_plugin_manager

    pm = create_plugin_manager()
    if "genicam" not in pm.drivers:
        pm = create_plugin_manager(plugins=[genicam_mod])
    return pm


def write_rig(path: Path, n: int = 3, width: int = 400, height: int = 400):
    from inspector_drivers.sim.rig import sphere_rig

    rig = sphere_rig(n, radius_mm=400.0, width=width, height=height, mm_per_px=0.25)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(rig.to_json()))
    return rig


# --------------------------------------------------------------------------- pixel formats


def _mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    idx = {"R": 0, "G": 1, "B": 2}
    m = np.zeros(rgb.shape[:2], rgb.dtype)
    for dy in range(2):
        for dx in range(2):
            m[dy::2, dx::2] = rgb[dy::2, dx::2, idx[pattern[2 * dy + dx]]]
    return m


def test_mono_and_colour_formats_become_contract_arrays():
    rng = np.random.default_rng(0)
    h, w = 6, 8
    g8 = rng.integers(0, 256, (h, w), dtype=np.uint8)
    out = to_array(g8.tobytes(), w, h, "Mono8")
    assert out.dtype == np.uint8 and out.shape == (h, w) and np.array_equal(out, g8)
    g16 = rng.integers(0, 65536, (h, w), dtype=np.uint16)
    for fmt in ("Mono16", "Mono12", "Mono10"):
        out = to_array(g16.astype("<u2").tobytes(), w, h, fmt)
        assert out.dtype == np.uint16 and np.array_equal(out, g16)
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    assert np.array_equal(to_array(rgb.tobytes(), w, h, "RGB8"), rgb)
    assert np.array_equal(to_array(rgb[:, :, ::-1].copy().tobytes(), w, h, "BGR8"), rgb)
    rgba = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    assert np.array_equal(to_array(rgba.tobytes(), w, h, "RGBa8"), rgba)
    bgra = rgba[:, :, [2, 1, 0, 3]].copy()
    assert np.array_equal(to_array(bgra.tobytes(), w, h, "BGRa8"), rgba)
    # an array already expanded by the transport library (Harvesters) works the same
    assert np.array_equal(to_array(g16.ravel(), w, h, "Mono16"), g16)


def test_result_owns_its_memory_and_is_read_only():
    raw = bytearray(np.arange(48, dtype=np.uint8).tobytes())
    out = to_array(memoryview(raw), 8, 6, "Mono8")
    raw[:] = b"\0" * 48  # the acquisition buffer is reused after re-queueing
    assert out[5, 7] == 47 and not out.flags.writeable and out.flags.owndata


def test_line_padding_is_removed():
    h, w, pad = 3, 5, 3
    img = np.arange(h * w, dtype=np.uint8).reshape(h, w)
    padded = np.concatenate([img, np.full((h, pad), 255, np.uint8)], axis=1)
    assert np.array_equal(to_array(padded.tobytes(), w, h, "Mono8", x_padding=pad), img)


@pytest.mark.parametrize("pattern", ["RG", "GR", "GB", "BG"])
@pytest.mark.parametrize("bits", [8, 12])
def test_bayer_patterns_demosaic_to_the_right_colours(pattern, bits):
    h, w = 8, 10
    colour = (200, 100, 50) if bits == 8 else (3000, 1500, 700)
    dtype = np.uint8 if bits == 8 else np.uint16
    rgb = np.empty((h, w, 3), dtype)
    rgb[...] = colour
    pfnc = {"RG": "RGGB", "GR": "GRBG", "GB": "GBRG", "BG": "BGGR"}[pattern]
    raw = _mosaic(rgb, pfnc)
    out = to_array(raw.astype("<u2" if bits > 8 else np.uint8).tobytes(), w, h, f"Bayer{pattern}{bits}")
    assert out.shape == (h, w, 3) and out.dtype == dtype
    assert tuple(int(v) for v in out[4, 4]) == colour
    grey = to_array(raw.tobytes() if bits == 8 else raw.astype("<u2").tobytes(), w, h, f"Bayer{pattern}{bits}", bayer="raw")
    assert np.array_equal(grey, raw)


def _pack_lsb(values: np.ndarray, bits: int) -> bytes:
    acc, n, out = 0, 0, bytearray()
    for v in values.ravel():
        acc |= int(v) << n
        n += bits
        while n >= 8:
            out.append(acc & 0xFF)
            acc >>= 8
            n -= 8
    return bytes(out)


def test_packed_mono_formats():
    rng = np.random.default_rng(1)
    h, w = 3, 8
    v10 = rng.integers(0, 1024, (h, w), dtype=np.uint16)
    assert np.array_equal(to_array(_pack_lsb(v10, 10), w, h, "Mono10p"), v10)
    v12 = rng.integers(0, 4096, (h, w), dtype=np.uint16)
    assert np.array_equal(to_array(_pack_lsb(v12, 12), w, h, "Mono12p"), v12)
    a, b = v12[:, 0::2], v12[:, 1::2]  # GigE Vision Mono12Packed
    gev = np.stack([a >> 4, (b & 0xF) << 4 | (a & 0xF), b >> 4], axis=-1).astype(np.uint8)
    assert np.array_equal(to_array(gev.tobytes(), w, h, "Mono12Packed"), v12)


def test_unsupported_or_short_data_is_refused():
    with pytest.raises(UnsupportedPixelFormat, match="YUV422_8"):
        to_array(b"\0" * 100, 5, 5, "YUV422_8")
    with pytest.raises(ValueError, match="RGB8"):
        to_array(b"\0" * 25, 5, 5, "RGB8")  # a Mono8-sized payload announced as RGB8
    assert {"Mono8", "Mono16", "RGB8", "RGBa8", "BayerRG8"} <= set(SUPPORTED)
    assert pixel_format_name(0x01080001) == "Mono8" and pixel_format_name(0x0108000B) == "BayerBG8"


# --------------------------------------------------------------------------- trigger set-up (fake node map)


class _Node:
    def __init__(self, nm, name, value=None, entries=None, access=4):
        self.nm, self.name, self._value, self.entries, self.access = nm, name, value, entries, access
        self.node = SimpleNamespace(get_access_mode=lambda: self.access)

    @property
    def symbolics(self):
        if self.entries is None:
            raise AttributeError("not an enumeration")
        return tuple(self.entries)

    @property
    def value(self):
        if self.name == "TriggerMode":
            return self.nm.modes.get(self.nm.selector(), "Off")
        return self._value

    @value.setter
    def value(self, v):
        if self.entries is not None and v not in self.entries:
            raise ValueError(f"{v} not an entry")
        if self.name == "TriggerMode":
            self.nm.modes[self.nm.selector()] = v
        else:
            self._value = v
        self.nm.log.append((self.name, v))

    def execute(self):
        self.nm.log.append((self.name, "execute"))


class _NodeMap:
    def __init__(self, **features):
        self.log, self.modes, self.nodes = [], {}, {}
        for name, spec in features.items():
            self.nodes[name] = _Node(self, name, *spec)

    def selector(self):
        sel = self.nodes.get("TriggerSelector")
        return sel.value if sel is not None else None

    def get_node(self, name):
        if name not in self.nodes:
            raise LookupError("Node not existing")
        return self.nodes[name]

    def __getattr__(self, name):
        try:
            return self.__dict__["nodes"][name]
        except KeyError:
            raise AttributeError(name) from None


def _full_trigger_nm():
    return _NodeMap(
        TriggerSelector=("FrameStart", ["AcquisitionStart", "FrameStart"]),
        TriggerMode=(None, ["Off", "On"]),
        TriggerSource=("Line0", ["Line0", "Line1", "Software"]),
        TriggerActivation=("RisingEdge", ["RisingEdge", "FallingEdge"]),
        TriggerSoftware=(None, None, 2),
    )


def test_software_trigger_arms_framestart_only():
    from inspector_drivers.genicam.harvester import configure_trigger

    nm = _full_trigger_nm()
    nm.modes["AcquisitionStart"] = "On"  # left over from another application
    assert configure_trigger(nm, GenicamParams(), "cam") == "software"
    assert nm.modes == {"AcquisitionStart": "Off", "FrameStart": "On"}
    assert nm.TriggerSource.value == "Software"


def test_hardware_trigger_sets_selector_source_activation():
    from inspector_drivers.genicam.harvester import configure_trigger

    nm = _full_trigger_nm()
    p = GenicamParams(trigger="hardware", trigger_source="Line1", trigger_activation="FallingEdge")
    assert configure_trigger(nm, p, "cam") == "hardware"
    assert nm.modes["FrameStart"] == "On" and nm.TriggerSource.value == "Line1"
    assert nm.TriggerActivation.value == "FallingEdge"
    # a device with TriggerMode only (no selector/source/activation) is armed as it can be
    nm2 = _NodeMap(TriggerMode=(None, ["Off", "On"]))
    assert configure_trigger(nm2, p, "cam") == "hardware"


def test_missing_trigger_features_mean_free_run_and_bad_values_are_named():
    from inspector_drivers.genicam.harvester import configure_trigger

    assert configure_trigger(_NodeMap(), GenicamParams(), "cam") == "free-run"
    no_soft = _NodeMap(TriggerMode=(None, ["Off", "On"]), TriggerSource=("Line0", ["Line0"]))
    assert configure_trigger(no_soft, GenicamParams(), "cam") == "free-run"
    assert no_soft.modes == {None: "Off"}
    with pytest.raises(InputError, match=r"camera cam07.*TriggerSource 'Line5'.*Line0, Line1, Software"):
        configure_trigger(_full_trigger_nm(), GenicamParams(trigger="hardware", trigger_source="Line5"), "genicam: camera cam07")


# --------------------------------------------------------------------------- frame handling (fake acquirer)


class _Buffer:
    def __init__(self, ia, frame_id, fmt="Mono8"):
        self.ia, self.frame_id = ia, frame_id
        data = np.full(ia.w * ia.h, frame_id % 256, np.uint8)
        comp = SimpleNamespace(data=data, width=ia.w, height=ia.h, data_format=fmt, x_padding=0)
        self.payload = SimpleNamespace(components=[comp])
        self.module = SimpleNamespace(frame_id=frame_id)

    def queue(self):
        self.ia.queued.append(self)


class _Acquirer:
    """A software-triggered device: TriggerSoftware produces one frame (unless told not to)."""

    def __init__(self, w=8, h=6):
        self.w, self.h = w, h
        self.out: deque[_Buffer] = deque()
        self.delivered, self.queued = [], []
        self.fid = 0
        self.drop_next = False
        self.next_format = "Mono8"
        self.stops = 0
        self.num_buffers, self.min_num_buffers = 4, 1
        soft = SimpleNamespace(execute=self._trigger)
        self.remote_device = SimpleNamespace(node_map=SimpleNamespace(TriggerSoftware=soft))

    def produce(self):
        self.fid += 1
        self.out.append(_Buffer(self, self.fid, self.next_format))

    def _trigger(self):
        if self.drop_next:
            self.drop_next = False
            return
        self.produce()

    def try_fetch(self, timeout):
        if self.out:
            b = self.out.popleft()
            self.delivered.append(b)
            return b
        time.sleep(min(timeout, 0.002))
        return None

    def stop(self):
        self.stops += 1
        self.out.clear()

    def start(self):
        if getattr(self, "pulse_after_start", False):
            self.pulse_after_start = False
            self.produce()

    def destroy(self):
        pass


def _fake_session(n=2, **params):
    from inspector_drivers.genicam.common import DeviceMatch
    from inspector_drivers.genicam.harvester import HarvesterSession, _Camera
    from inspector_drivers.sim.rig import sphere_rig

    s = HarvesterSession.__new__(HarvesterSession)
    s.params = GenicamParams(**{"timeout_s": 0.2, **params})
    s.rig = sphere_rig(max(n, 3), width=8, height=6, mm_per_px=1.0)
    s.h = None
    s.cams = [_Camera(f"cam{i:02d}", DeviceMatch(f"cam{i:02d}", "serial", str(i)), str(i), ia=_Acquirer()) for i in range(n)]
    s.trigger_mode = "software"
    return s


def _all_requeued(session):
    for cam in session.cams:
        ia = cam.ia
        assert sorted(map(id, ia.delivered)) == sorted(map(id, ia.queued)), f"{cam.name}: a buffer was not re-queued"
        assert len(set(map(id, ia.queued))) == len(ia.queued), f"{cam.name}: a buffer was queued twice"


def test_stale_frames_are_dropped_and_every_buffer_requeued():
    s = _fake_session()
    late = s.cams[0].ia
    late.produce()  # a frame delivered before this trigger (e.g. late from the last one)
    frames, meta = s.trigger()
    assert frames["cam00"].info["frame_id"] == 2 and frames["cam01"].info["frame_id"] == 1
    assert int(frames["cam00"].image[0, 0]) == 2 and not frames["cam00"].image.flags.writeable
    assert meta["latency_ms"] >= 0
    _all_requeued(s)


def test_a_missed_frame_is_an_error_naming_the_camera_then_the_device_recovers():
    s = _fake_session()
    s.cams[1].ia.drop_next = True
    with pytest.raises(CaptureError, match=r"camera cam01 \(serial '1'\): no complete frame within 0.2 s") as e:
        s.trigger()
    assert "cam00" not in str(e.value) and "\n" not in str(e.value)
    assert s.cams[1].needs_restart
    s.cams[1].ia.produce()  # the missed frame (id 1) arrives late: it must never be returned
    frames, _ = s.trigger()
    assert s.cams[1].ia.stops == 1  # restarted: buffers flushed
    assert frames["cam01"].info["frame_id"] == 2
    _all_requeued(s)


def test_unconvertible_frame_is_named_and_its_buffer_requeued():
    s = _fake_session()
    s.cams[0].ia.next_format = "YUV411_8_UYYVYY"
    with pytest.raises(CaptureError, match=r"camera cam00 .*unsupported pixel format 'YUV411_8_UYYVYY'"):
        s.trigger()
    _all_requeued(s)


# --------------------------------------------------------------------------- light import, registration


def test_import_is_light_and_driver_is_registered():
    code = (
        "import sys, inspector, inspector_drivers.genicam, inspector_drivers.aravis, inspector_drivers.capture_cmd\n"
        "bad = [m for m in ('harvesters', 'genicam', 'gi') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == ""
    pm = plugin_manager()
    spec = pm.driver("genicam")
    from inspector.params import describe_params

    names = {d["name"] for d in describe_params(spec.params)}
    assert {"rig", "serials", "user_ids", "cti", "trigger", "exposure_us", "gain_db", "timeout_s", "count"} <= names
    with pytest.raises(RecipeError, match="trigger"):
        build_params(spec.params, {"trigger": "sometimes"}, "recipe.toml: driver.params")


def test_missing_rig_or_mapping_is_an_input_error(tmp_path):
    from inspector_drivers.genicam import open_driver

    with pytest.raises(InputError, match="'rig' is required"):
        open_driver(GenicamParams())
    write_rig(tmp_path / "rig.json")
    with pytest.raises(InputError, match="serials"):
        open_driver(GenicamParams(rig=str(tmp_path / "rig.json")))
    with pytest.raises(InputError, match="camera cam09 is not in the rig"):
        open_driver(GenicamParams(rig=str(tmp_path / "rig.json"), serials={"cam09": "1"}))
    with pytest.raises(InputError, match="cam02 of the rig has no device"):
        open_driver(GenicamParams(rig=str(tmp_path / "rig.json"), serials={"cam00": "0", "cam01": "1"}))


# --------------------------------------------------------------------------- viky.cti (simulated GenTL devices)


@pytest.fixture(scope="module")
def viky(tmp_path_factory):
    pytest.importorskip("harvesters.core", reason="harvesters is not installed")
    pytest.importorskip("genicam.gentl", reason="genicam is not installed")
    from inspector_drivers.genicam import viky_cti

    root = tmp_path_factory.mktemp("viky")
    write_rig(root / "rig.json")
    base = {
        "rig": str(root / "rig.json"),
        "cti": viky_cti(),
        "serials": {"cam00": "0", "cam01": "1", "cam02": "2"},
        "pixel_format": "Mono8",
    }
    return SimpleNamespace(root=root, base=base, cti=viky_cti())


def _open(viky, **kw):
    spec = plugin_manager().driver("genicam")
    return spec.open(build_params(spec.params, {**viky.base, **kw}, "test"))


def _count_requeues(driver):
    """Record every buffer the driver fetches and every buffer it re-queues."""
    log = {}
    for cam in driver.session.cams:
        ia = cam.ia
        fetched, queued = [], []
        real = ia.try_fetch

        def try_fetch(*a, real=real, fetched=fetched, queued=queued, **k):
            b = real(*a, **k)
            if b is not None:
                fetched.append(b)
                q = b.queue

                def queue(q=q, b=b):
                    queued.append(b)
                    return q()

                b.queue = queue
            return b

        ia.try_fetch = try_fetch
        log[cam.name] = (fetched, queued)
    return log


def test_viky_devices_are_mapped_and_captured(viky):
    d = _open(viky, count=3)
    try:
        assert d.session.trigger_mode == "free-run"  # viky has no trigger features
        log = _count_requeues(d)
        caps = [acq.load() for acq in d.acquire()]
    finally:
        d.close()
    assert len(caps) == 3 and len({c.name for c in caps}) == 3
    for cap in caps:
        assert cap.rig.names == ("cam00", "cam01", "cam02")
        assert set(cap.images) == set(cap.rig.names)
        for cam, img in cap.images.items():
            assert img.shape == (400, 400) and img.dtype == np.uint8 and not img.flags.writeable
            info = cap.metadata["frames"][cam]
            assert info["serial"] == cam[-1] and info["pixel_format"] == "Mono8" and info["trigger"] == "free-run"
        assert cap.metadata["trigger"] == "free-run" and cap.metadata["latency_ms"] > 0
    for cam, (fetched, queued) in log.items():
        assert fetched and sorted(map(id, fetched)) == sorted(map(id, queued)), cam
    ids = [[c.metadata["frames"][cam]["frame_id"] for c in caps] for cam in ("cam00", "cam01", "cam02")]
    assert all(a < b for seq in ids for a, b in zip(seq, seq[1:]))


def test_viky_returns_the_newest_frame_never_a_queued_one(viky):
    d = _open(viky, count=0, num_buffers=4)
    try:
        first = d.capture()
        time.sleep(1.0)  # ~20 frames are produced meanwhile at 20 fps; 4 buffers fill up
        second = d.capture()
        for _ in range(12):  # many more triggers than buffers: they must all come back
            d.capture()
    finally:
        d.close()
    for cam in ("cam00", "cam01", "cam02"):
        a = first.metadata["frames"][cam]["frame_id"]
        b = second.metadata["frames"][cam]["frame_id"]
        assert b - a >= 10, f"{cam}: frame {b} after {a}: a queued (stale) frame was returned"


def test_viky_rgba_and_set_size(viky, tmp_path):
    write_rig(tmp_path / "small.json", width=320, height=240)
    d = _open(viky, pixel_format="RGBa8", rig=str(tmp_path / "small.json"), set_size=True)
    try:
        cap = d.capture()
    finally:
        d.close()
    for img in cap.images.values():
        assert img.shape == (240, 320, 4) and img.dtype == np.uint8


def test_viky_timeout_names_cameras_and_driver_goes_on(viky):
    d = _open(viky, timeout_s=0.001, freerun_discard=3)
    try:
        with pytest.raises(CaptureError) as e:
            d.capture()
        msg = str(e.value)
        assert msg.startswith("genicam: camera cam00 (serial '0'): no complete frame within 0.001 s")
        assert "cam01" in msg and "cam02" in msg and "\n" not in msg
        d.session.params = dataclasses.replace(d.session.params, timeout_s=2.0)
        cap = d.capture()  # restarted devices, fresh frames
        assert len(cap.images) == 3
    finally:
        d.close()


def test_viky_configuration_errors_name_the_camera(viky, tmp_path):
    with pytest.raises(InputError, match=r"camera cam01: no device with serial '7' \(found: 0, 1, 2\)"):
        _open(viky, serials={"cam00": "0", "cam01": "7", "cam02": "2"})
    with pytest.raises(InputError, match=r"camera cam00 \(serial '0'\): the device has no ExposureTime"):
        _open(viky, exposure_us=1000.0)
    with pytest.raises(InputError, match=r"PixelFormat 'Mono16' is not available \(device offers: RGBa8, Mono8\)"):
        _open(viky, pixel_format="Mono16")
    with pytest.raises(InputError, match="no device with user id 'left'"):
        _open(viky, serials=None, user_ids={"cam00": "left", "cam01": "mid", "cam02": "right"})
    write_rig(tmp_path / "big.json", width=512, height=512)
    d = _open(viky, rig=str(tmp_path / "big.json"))
    try:
        with pytest.raises(CaptureError, match=r"camera cam00: image 400x400, rig.json says 512x512"):
            d.capture()
    finally:
        d.close()


def test_capture_command_writes_replayable_folders(viky, tmp_path):
    from inspector.capture_folder import read_capture, read_rig
    from inspector_drivers import capture_cmd

    ap = argparse.ArgumentParser(prog="inspector")
    capture_cmd.add_parser(ap.add_subparsers(dest="command"))
    out = tmp_path / "captures"
    argv = ["capture", "--driver", "genicam", "--out", str(out), "--count", "2", "--param", f"rig={viky.base['rig']}"]
    argv += ["--param", f"cti={viky.cti}", "--param", 'serials={cam00="0", cam01="1", cam02="2"}', "--param", "pixel_format=RGBa8"]
    assert capture_cmd.run(ap.parse_args(argv), pm=plugin_manager()) == 0
    folders = sorted(p for p in out.iterdir() if p.is_dir())
    assert len(folders) == 2
    rig = read_rig(Path(viky.base["rig"]))
    for f in folders:
        cap = read_capture(f)  # CONTRACT: replayable
        assert cap.rig.names == rig.names
        assert all(np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and np.allclose(a.t, b.t) for a, b in zip(cap.rig, rig))
        assert all(img.shape == (400, 400, 4) for img in cap.images.values())
        assert cap.metadata["driver"] == "genicam" and set(cap.metadata["frames"]) == set(rig.names)
    # invalid parameters: nothing acquired, status 2, one line
    bad = ap.parse_args(["capture", "--driver", "genicam", "--out", str(out), "--param", "trigger=never"])
    assert capture_cmd.run(bad, pm=plugin_manager()) == 2


def test_capture_command_from_a_recipe(viky, tmp_path, capsys):
    from inspector_drivers import capture_cmd

    recipe = tmp_path / "live.toml"
    b = viky.base
    recipe.write_text(
        "[driver]\nuse = \"genicam\"\n"
        f"params = {{ rig = \"{b['rig']}\", cti = \"{viky.cti}\", serials = {{ cam00 = \"0\", cam01 = \"1\", cam02 = \"2\" }} }}\n"
        "[[stages]]\nuse = \"segment.threshold\"\n"
    )
    ap = argparse.ArgumentParser(prog="inspector")
    capture_cmd.add_parser(ap.add_subparsers(dest="command"))
    args = ap.parse_args(["capture", "--recipe", str(recipe), "--out", str(tmp_path / "o"), "--count", "1"])
    assert capture_cmd.run(args, pm=plugin_manager()) == 0
    assert "wrote" in capsys.readouterr().out
    args = ap.parse_args(["capture", "--recipe", str(recipe), "--driver", "aravis", "--out", str(tmp_path / "o")])
    assert capture_cmd.run(args, pm=plugin_manager()) == 2


def test_live_inspector_run_path_with_genicam(viky, tmp_path):
    """A recipe whose driver is genicam runs like `inspector run RECIPE --out OUT`."""
    from inspector.recipe import load_recipe
    from inspector.runner import exit_status, run_batch

    b = viky.base
    recipe_path = tmp_path / "live.toml"
    recipe_path.write_text(
        "[recipe]\nname = \"live-viky\"\n[driver]\nuse = \"genicam\"\n"
        f"params = {{ rig = \"{b['rig']}\", cti = \"{viky.cti}\", serials = {{ cam00 = \"0\", cam01 = \"1\", cam02 = \"2\" }}, count = 2 }}\n"
        "[[stages]]\nuse = \"segment.threshold\"\n"
    )
    pm = plugin_manager()
    recipe = load_recipe(recipe_path, pm)
    driver = recipe.driver.spec.open(recipe.driver.params)
    try:
        outcomes = list(run_batch(recipe, driver.acquire(), pm, reference=None, outdir=tmp_path / "out"))
    finally:
        driver.close()
    assert len(outcomes) == 2
    for o in outcomes:
        assert "load" in o.result.timings_s and o.result.rig is not None
        assert (tmp_path / "out" / o.result.capture / "result.json").is_file()
    assert exit_status([o.result for o in outcomes]) in (0, 3)


def test_hardware_trigger_keeps_queued_pulses_and_resyncs_after_a_miss():
    s = _fake_session()
    for cam in s.cams:
        cam.mode = "hardware"
        cam.ia.produce()  # a pulse fired before the capture was asked for: its frames count
    frames, _ = s.trigger()
    assert [frames[c].info["frame_id"] for c in ("cam00", "cam01")] == [1, 1]
    s.cams[0].ia.produce()  # the next pulse: cam01 misses it
    with pytest.raises(CaptureError, match=r"camera cam01 .*while waiting for the hardware trigger"):
        s.trigger()
    assert all(c.needs_restart for c in s.cams)  # cam00's frame of that pulse must not pair with cam01's next
    for cam in s.cams:
        cam.ia.stops = 0
        cam.ia.pulse_after_start = True  # the next pulse comes once the devices are re-armed
    frames, _ = s.trigger()  # restarts (flushes) both first: no pair of frames from different pulses
    assert s.cams[0].ia.stops == 1 and s.cams[1].ia.stops == 1
    assert frames["cam00"].info["frame_id"] == 3 and frames["cam01"].info["frame_id"] == 2  # cam00's frame 2 is gone
    _all_requeued(s)


def test_gentl_producers_from_parameter_or_environment(tmp_path, monkeypatch):
    from inspector_drivers.genicam.harvester import cti_files

    (tmp_path / "b.cti").write_bytes(b"")
    (tmp_path / "a.cti").write_bytes(b"")
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path))
    assert cti_files("") == [str(tmp_path / "a.cti"), str(tmp_path / "b.cti")]
    assert cti_files(str(tmp_path / "b.cti")) == [str(tmp_path / "b.cti")]
    with pytest.raises(InputError, match="GenTL producer not found: .*nope.cti"):
        cti_files(str(tmp_path / "nope.cti"))
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path / "empty"))
    with pytest.raises(InputError, match="no GenTL producer"):
        cti_files("")
