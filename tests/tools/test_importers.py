"""Dataset importers (inspector_tools.importers.datasets).

Each third-party format is exercised on a small synthetic dataset written here with that
format's own conventions (NeRF: OpenGL camera->world matrices and pixel-corner principal
point; IDR: scaled projection matrices; OpenCV: FileStorage YAML with rvec or R), rendered
from a known mesh with Open3D ray casting (:func:`render_coverage`) through cameras
defined here. The imported rig must reproject known 3D points to the same pixels within
1e-6 px and the leave-one-out IoU of the imported capture must reach 0.95. The real
Middlebury dinoSparseRing (``../shared``) is used when present, else skipped.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from inspector.capture_folder import read_capture
from inspector.errors import InputError
from inspector.model import Camera, Rig
from inspector_drivers.sim.render import render_coverage
from inspector_drivers.sim.rig import look_at_rotation, sphere_directions
from inspector_tools.importers.datasets import (
    IMPORTERS,
    add_parser,
    close_mask,
    decompose_projection,
    fill_holes,
    import_idr,
    import_middlebury,
    import_nerf,
    import_opencv,
    leave_one_out_iou,
    run,
)

SHARED = Path(__file__).resolve().parents[3] / "shared"
DINO = SHARED / "data" / "middlebury-dinoSparseRing"

W, H = 160, 128
N_CAMS = 12
VOXEL = 0.8  # 2 px at the rig centre


# ------------------------------------------------------------------------------ scene


def _part() -> trimesh.Trimesh:
    """An irregular convex polytope (about 50 x 35 x 25 mm, no symmetry).

    Convex, so that 11 views carve a hull close to the part (a concave part's hull keeps
    its notches filled and the IoU measures the method, not the import); large enough
    that it leaves the image of a few of the 12 cameras (clipped views are exercised).
    """
    p = np.random.default_rng(4).normal(size=(40, 3)) * np.array([12.0, 8.0, 6.0])
    return trimesh.convex.convex_hull(p)


def _cameras(*, square: bool = False, dist: bool = False) -> list[Camera]:
    """12 cameras around the origin at 300 mm, ~0.4 mm/px; varied intrinsics."""
    cams = []
    rng = np.random.default_rng(7)
    for i, d in enumerate(sphere_directions(N_CAMS, seed=3)):
        R = look_at_rotation(d, roll=0.7 * i)
        C = 300.0 * d
        f = 750.0 + (0.0 if square else 5.0 * i)  # NeRF: one focal length for all frames
        if square:
            K = np.array([[f, 0.0, W / 2 - 0.5], [0.0, f, H / 2 - 0.5], [0.0, 0.0, 1.0]])
        else:
            K = np.array([[f, 0.3, W / 2 - 0.5 + rng.uniform(-3, 3)], [0.0, f * 1.01, H / 2 - 0.5 + rng.uniform(-3, 3)], [0.0, 0.0, 1.0]])
        dv = np.array([-0.08, 0.02, 1e-3, -5e-4, 0.0]) if dist else np.zeros(5)
        cams.append(Camera(f"c{i:02d}", W, H, K, dv, R, -R @ C))
    return cams


@pytest.fixture(scope="module")
def part() -> trimesh.Trimesh:
    return _part()


def _coverage(part: trimesh.Trimesh, cams: list[Camera]) -> dict[str, np.ndarray]:
    return render_coverage(part, Rig(tuple(cams)), supersample=4)


def _points() -> np.ndarray:
    return np.random.default_rng(1).uniform(-15.0, 15.0, size=(200, 3))


def _assert_same_projection(truth: list[Camera], rig: Rig, scale: float = 1.0) -> None:
    """Imported cameras (world scaled by ``scale``) project like the true ones, 1e-6 px."""
    X = _points()
    assert len(rig) == len(truth)
    for t, c in zip(truth, rig):
        uv0, z0 = t.project(X)
        uv1, z1 = c.project(X * scale)
        assert np.all(z1 > 0)
        np.testing.assert_allclose(z1, z0 * scale, rtol=1e-9)
        err = float(np.max(np.abs(uv1 - uv0)))
        assert err < 1e-6, f"{c.name}: reprojection error {err:.3g} px"


def _loo(folder: Path) -> dict[str, float]:
    """Leave-one-out IoU over every view: median >= 0.95 (the views the part leaves are clipped)."""
    det: dict = {}
    res = leave_one_out_iou(folder, voxel_mm=VOXEL, details=det)
    views = {k: v for k, v in res.items() if k not in ("median", "mean", "min")}
    assert len(views) == N_CAMS
    assert 1 <= len(det["clipped"]) <= 4 and all(f"clipped/{n}" in res for n in det["clipped"])
    assert res["median"] >= 0.95, res
    assert res["min"] >= 0.9, res  # the worst view: hull excess of 11 views at the part's edges
    return res


def _u8(cov: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(255.0 * cov), 0, 255).astype(np.uint8)


# ------------------------------------------------------------------------------ nerf


def _write_nerf(root: Path, cams: list[Camera], cov: dict[str, np.ndarray], *, unit: float, split: str = "train", intr: str = "angle") -> Path:
    """Blender/NeRF synthetic layout: transforms_<split>.json + <split>/r_i.png (RGBA)."""
    (root / split).mkdir(parents=True, exist_ok=True)
    frames = []
    for i, c in enumerate(cams):
        c2w_cv = np.eye(4)
        c2w_cv[:3, :3] = c.R.T
        c2w_cv[:3, 3] = c.centre * unit
        c2w_gl = c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL: y up, looking down -z
        rgba = np.zeros((H, W, 4), np.uint8)
        rgba[..., :3] = (90, 140, 200)
        rgba[..., 3] = _u8(cov[c.name])
        cv2.imwrite(str(root / split / f"r_{i}.png"), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
        frames.append({"file_path": f"./{split}/r_{i}", "rotation": 0.0, "transform_matrix": c2w_gl.tolist()})
    fx = cams[0].K[0, 0]
    meta: dict = {"frames": frames}
    if intr == "angle":
        meta["camera_angle_x"] = 2.0 * np.arctan(0.5 * W / fx)
    else:  # instant-ngp keys, principal point in NeRF's pixel-corner convention
        meta.update(fl_x=fx, fl_y=cams[0].K[1, 1], cx=cams[0].K[0, 2] + 0.5, cy=cams[0].K[1, 2] + 0.5, w=W, h=H)
    path = root / f"transforms_{split}.json"
    path.write_text(json.dumps(meta))
    return path


def test_nerf_roundtrip_and_leave_one_out(tmp_path, part):
    cams = _cameras(square=True)
    cov = _coverage(part, cams)
    # scene units = decimetres: the importer keeps unknown units unless told the scale
    src = _write_nerf(tmp_path / "lego", cams, cov, unit=0.01)
    (out,) = import_nerf(src, tmp_path / "cap", scale=100.0)
    assert out == tmp_path / "cap"
    cap = read_capture(out)
    _assert_same_projection(cams, cap.rig)
    assert cap.polarity == "dark-object"
    assert cap.metadata["import"]["format"] == "nerf"
    assert cap.metadata["import"]["scale_to_mm"] == 100.0
    img = cap.images["r_0"]
    assert img.ndim == 2 and img.dtype == np.uint8
    np.testing.assert_array_equal(img, 255 - _u8(cov["c00"]))  # grey = 255 * (1 - alpha)
    _loo(out)

    # default: unknown units kept (and said so)
    (out2,) = IMPORTERS["nerf"](src.parent, tmp_path / "cap2")
    cap2 = read_capture(out2)
    _assert_same_projection(cams, cap2.rig, scale=0.01)
    assert cap2.metadata["import"]["units"].startswith("unknown")


def test_nerf_intrinsics_keys_and_several_splits(tmp_path, part):
    cams = _cameras(square=True)[:4]
    cams = [Camera(c.name, W, H, np.array([[700.0, 0, 81.25], [0, 705.0, 62.0], [0, 0, 1]]), np.zeros(5), c.R, c.t) for c in cams]
    cov = {c.name: np.zeros((H, W), np.float32) for c in cams}
    for c in cams:
        cov[c.name][40:80, 50:100] = 1.0
    _write_nerf(tmp_path / "ds", cams, cov, unit=1.0, split="train", intr="ngp")
    _write_nerf(tmp_path / "ds", cams[:2], cov, unit=1.0, split="test", intr="ngp")
    outs = import_nerf(tmp_path / "ds", tmp_path / "caps")
    assert [p.name for p in outs] == ["test", "train"]
    _assert_same_projection(cams, read_capture(outs[1]).rig)
    _assert_same_projection(cams[:2], read_capture(outs[0]).rig)


def test_nerf_errors(tmp_path):
    with pytest.raises(InputError, match="no NeRF transforms file"):
        import_nerf(tmp_path, tmp_path / "o")
    bad = tmp_path / "transforms.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match=r"transforms\.json: not valid JSON"):
        import_nerf(bad, tmp_path / "o")
    bad.write_text(json.dumps({"camera_angle_x": 0.7, "frames": [{"file_path": "./x", "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(InputError, match="missing image"):
        import_nerf(bad, tmp_path / "o")
    cv2.imwrite(str(tmp_path / "x.png"), np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(InputError, match="no alpha channel"):
        import_nerf(bad, tmp_path / "o")
    bad.write_text(json.dumps({"camera_angle_x": 0.7, "frames": [{"file_path": "./x", "transform_matrix": [[1, 2], [3, 4]]}]}))
    with pytest.raises(InputError, match="transform_matrix must be a 4x4"):
        import_nerf(bad, tmp_path / "o")
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    bad.write_text(json.dumps({"camera_angle_x": 0.7, "frames": [{"file_path": "./x.png", "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(InputError, match=r"x\.png: truncated PNG"):
        import_nerf(bad, tmp_path / "o")


# ------------------------------------------------------------------------------ idr


def _write_idr(root: Path, cams: list[Camera], cov: dict[str, np.ndarray], S: np.ndarray) -> None:
    (root / "image").mkdir(parents=True)
    (root / "mask").mkdir()
    mats = {}
    rng = np.random.default_rng(3)
    for i, c in enumerate(cams):
        P = np.eye(4)
        P[:3] = c.K @ np.hstack([c.R, c.t[:, None]])
        lam = rng.uniform(0.5, 2.0) * (-1.0 if i % 3 == 1 else 1.0)  # P is defined up to scale and sign
        mats[f"world_mat_{i}"] = lam * P
        mats[f"scale_mat_{i}"] = S
        m = _u8(cov[c.name])
        cv2.imwrite(str(root / "mask" / f"{i:03d}.png"), np.dstack([m, m, m]))  # DTU masks are 3-channel
        photo = np.full((H, W, 3), 30, np.uint8)
        photo[m > 127] = 180
        cv2.imwrite(str(root / "image" / f"{i:06d}.png"), photo)
    np.savez(root / "cameras.npz", **mats)


def test_idr_roundtrip_and_leave_one_out(tmp_path, part):
    cams = _cameras()
    cov = _coverage(part, cams)
    S = np.diag([20.0, 20.0, 20.0, 1.0])
    S[:3, 3] = (1.0, -2.0, 0.5)
    _write_idr(tmp_path / "scan1", cams, cov, S)
    (out,) = import_idr(tmp_path / "scan1", tmp_path / "cap")
    cap = read_capture(out)
    _assert_same_projection(cams, cap.rig)
    assert cap.rig.names[0] == "cam000000"
    np.testing.assert_allclose(cap.metadata["import"]["scale_mat"], S)
    _loo(out)

    # IDR's normalised frame: X_normalised = inv(S) @ X_world
    (outn,) = import_idr(tmp_path / "scan1" / "cameras.npz", tmp_path / "capn", frame="normalised")
    rn = read_capture(outn).rig
    X = _points()
    Xn = (X - S[:3, 3]) / 20.0
    for t, c in zip(cams, rn):
        np.testing.assert_allclose(c.project(Xn)[0], t.project(X)[0], atol=1e-6, rtol=0)


def test_decompose_projection_normalises_signs():
    rng = np.random.default_rng(0)
    for k in range(20):
        R = look_at_rotation(rng.normal(size=3), roll=rng.uniform(0, 6))
        K = np.array([[rng.uniform(200, 3000), rng.uniform(-2, 2), rng.uniform(0, 600)], [0, rng.uniform(200, 3000), rng.uniform(0, 400)], [0, 0, 1]])
        t = rng.normal(size=3) * 100
        P = K @ np.hstack([R, t[:, None]]) * (rng.uniform(0.01, 100) * (-1) ** k)
        K1, R1, t1 = decompose_projection(P)
        np.testing.assert_allclose(K1, K, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(R1, R, atol=1e-12)
        np.testing.assert_allclose(t1, t, atol=1e-9)
        assert np.linalg.det(R1) > 0 and K1[2, 2] == 1.0


def test_idr_errors(tmp_path):
    with pytest.raises(InputError, match=r"no IDR camera file"):
        import_idr(tmp_path, tmp_path / "o")
    (tmp_path / "cameras.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match=r"cameras\.npz: unreadable npz"):
        import_idr(tmp_path, tmp_path / "o")
    np.savez(tmp_path / "cameras.npz", world_mat_0=np.eye(4))
    with pytest.raises(InputError, match=r"mask: missing"):
        import_idr(tmp_path, tmp_path / "o")
    (tmp_path / "mask").mkdir()
    with pytest.raises(InputError, match=r"0 mask images for 1 cameras"):
        import_idr(tmp_path, tmp_path / "o")
    cv2.imwrite(str(tmp_path / "mask" / "000.png"), np.zeros((8, 8), np.uint8))
    np.savez(tmp_path / "cameras.npz", world_mat_0=np.zeros((3, 4)))
    with pytest.raises(InputError, match=r"world_mat_0: projection is singular"):
        import_idr(tmp_path, tmp_path / "o")
    np.savez(tmp_path / "cameras.npz", world_mat_0=np.eye(4))
    with pytest.raises(InputError, match=r"scale_mat_0 missing"):
        import_idr(tmp_path, tmp_path / "o", frame="normalised")


def test_idr_bombs_are_refused_from_their_headers(tmp_path):
    """Issue 27 finding 5: a 4 MB npz inflating to 4 GB, a PNG photograph decoded to learn
    its size (3 MB: 6.2 GB), a huge text file: each one line, before any of it is inflated."""
    import zlib

    (tmp_path / "mask").mkdir()
    (tmp_path / "image").mkdir()
    cv2.imwrite(str(tmp_path / "mask" / "000.png"), np.zeros((8, 8), np.uint8))
    # An npz member whose .npy header declares 3.2 GB (its data need not be there: only the
    # header may be read).
    import io
    import zipfile

    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False, "shape": (20_000, 20_000)})
    with zipfile.ZipFile(tmp_path / "cameras.npz", "w") as zf:
        zf.writestr("world_mat_0.npy", head.getvalue() + bytes(64))
    with pytest.raises(InputError, match=r"cameras\.npz: array world_mat_0 is \(20000, 20000\) float64 \(3200000000 "
                                         r"bytes\), more than the"):
        import_idr(tmp_path, tmp_path / "o")
    # A PNG that declares 100000 x 100000 pixels: its header says so, nothing is decoded.
    np.savez(tmp_path / "cameras.npz", world_mat_0=np.eye(4), unused=np.zeros(3))
    ihdr = b"IHDR" + (100_000).to_bytes(4, "big") * 2 + bytes([8, 0, 0, 0, 0])
    png = (b"\x89PNG\r\n\x1a\n" + (13).to_bytes(4, "big") + ihdr + zlib.crc32(ihdr).to_bytes(4, "big")
           + (0).to_bytes(4, "big") + b"IEND" + zlib.crc32(b"IEND").to_bytes(4, "big"))
    (tmp_path / "image" / "000.png").write_bytes(png)
    with pytest.raises(InputError, match=r"000\.png: 10000000000 pixels, more than the"):
        import_idr(tmp_path, tmp_path / "o")


def test_a_huge_text_file_is_measured_before_it_is_read(tmp_path):
    from inspector.limits import MAX_JSON_BYTES
    from inspector_tools.importers.datasets import _read_text

    big = tmp_path / "dino_par.txt"
    with open(big, "wb") as f:
        f.truncate(MAX_JSON_BYTES + 1)
    with pytest.raises(InputError) as e:
        _read_text(big)
    assert str(e.value) == (f"{big}: {MAX_JSON_BYTES + 1} bytes, more than the {MAX_JSON_BYTES} a dataset text file may "
                            "have (INSPECTOR_MAX_JSON_BYTES)")


# ------------------------------------------------------------------------------ opencv


def _write_opencv(root: Path, cams: list[Camera], cov: dict[str, np.ndarray]) -> None:
    root.mkdir(parents=True)
    for i, c in enumerate(cams):
        fs = cv2.FileStorage(str(root / f"{c.name}.yml"), cv2.FILE_STORAGE_WRITE)
        if i % 2:  # the two common spellings
            fs.write("camera_matrix", c.K)
            fs.write("distortion_coefficients", c.dist.reshape(1, 5))
            fs.write("rvec", cv2.Rodrigues(c.R)[0])
            fs.write("tvec", c.t.reshape(3, 1))
            fs.write("image_width", W)
            fs.write("image_height", H)
        else:
            fs.write("K", c.K)
            fs.write("D", c.dist[:4].copy())
            fs.write("R", c.R)
            fs.write("T", c.t.copy())
        fs.write("units", "mm")
        fs.release()
        grey = np.clip(np.rint(200.0 - 160.0 * cov[c.name]), 0, 255).astype(np.uint8)  # backlit: dark object
        cv2.imwrite(str(root / f"{c.name}.png"), grey)


def test_opencv_roundtrip_and_leave_one_out(tmp_path, part):
    cams = _cameras(dist=True)
    cams = [Camera(c.name, W, H, c.K, c.dist if i % 2 else np.r_[c.dist[:4], 0.0], c.R, c.t) for i, c in enumerate(cams)]
    cov = _coverage(part, cams)
    _write_opencv(tmp_path / "calib", cams, cov)
    (out,) = import_opencv(tmp_path / "calib", tmp_path / "cap")
    cap = read_capture(out)
    _assert_same_projection(cams, cap.rig)
    assert cap.polarity == "dark-object"
    assert cap.metadata["import"]["units"].startswith("mm")
    _loo(out)


def test_opencv_errors(tmp_path):
    with pytest.raises(InputError, match="no OpenCV calibration files"):
        import_opencv(tmp_path, tmp_path / "o")
    (tmp_path / "a.yml").write_text("%YAML:1.0\n---\nfoo: [1, 2\n")
    with pytest.raises(InputError, match=r"a\.yml: not a readable OpenCV FileStorage"):
        import_opencv(tmp_path, tmp_path / "o")
    (tmp_path / "a.yml").write_text("%YAML:1.0\n---\nfoo: 1\n")
    with pytest.raises(InputError, match=r"a\.yml: no camera matrix"):
        import_opencv(tmp_path, tmp_path / "o")
    fs = cv2.FileStorage(str(tmp_path / "a.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("K", np.array([[100.0, 0, 4], [0, 100, 4], [0, 0, 1]]))
    fs.write("R", np.diag([1.0, 1.0, -1.0]))
    fs.write("t", np.zeros(3))
    fs.release()
    with pytest.raises(InputError, match=r"a\.yml: R: not a rotation matrix"):
        import_opencv(tmp_path, tmp_path / "o")
    fs = cv2.FileStorage(str(tmp_path / "a.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("K", np.array([[100.0, 0, 4], [0, 100, 4], [0, 0, 1]]))
    fs.write("rvec", np.zeros(3))
    fs.write("t", np.array([0, 0, 50.0]))
    fs.write("image_width", 16)
    fs.write("image_height", 8)
    fs.release()
    with pytest.raises(InputError, match=r"a\.yml: no image a\."):
        import_opencv(tmp_path, tmp_path / "o")
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((8, 8), np.uint8))
    with pytest.raises(InputError, match=r"a\.png: size 8x8, the calibration says 16x8"):
        import_opencv(tmp_path, tmp_path / "o")


# ------------------------------------------------------------------------------ middlebury


def _write_middlebury(root: Path, cams: list[Camera], cov: dict[str, np.ndarray]) -> Path:
    root.mkdir(parents=True)
    lines = [str(len(cams))]
    for c in cams:
        img = np.clip(np.rint(10.0 + 200.0 * cov[c.name]), 0, 255).astype(np.uint8)  # bright on black
        cv2.imwrite(str(root / f"{c.name}.png"), np.dstack([img] * 3))
        vals = list(c.K.ravel()) + list(c.R.ravel()) + list(c.t / 1000.0)  # metres
        lines.append(f"{c.name}.png " + " ".join(repr(float(v)) for v in vals))
    par = root / "toy_par.txt"
    par.write_text("\n".join(lines) + "\n")
    (root / "toy_good_silhouette_images.txt").write_text("c00.png\nc02.png\n")
    return par


def test_middlebury_synthetic(tmp_path, part):
    cams = _cameras()
    cov = _coverage(part, cams)
    par = _write_middlebury(tmp_path / "toy", cams, cov)
    (out,) = import_middlebury(par, tmp_path / "cap")
    cap = read_capture(out)
    _assert_same_projection(cams, cap.rig)  # metres -> mm
    assert cap.polarity == "bright-object"
    assert cap.metadata["import"]["good_silhouettes"] == ["c00", "c02"]
    assert cap.images["c00"].shape == (H, W, 3)
    with pytest.raises(InputError, match="folder exists and is not empty"):
        import_middlebury(par, tmp_path / "cap")
    assert import_middlebury(par, tmp_path / "cap", overwrite=True) == [tmp_path / "cap"]


def test_middlebury_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        import_middlebury(tmp_path / "nope_par.txt", tmp_path / "o")
    par = tmp_path / "x_par.txt"
    par.write_text("2\nimg.png 1 0 0 0 1 0 0 0 1 1 0 0 0 1 0 0 0 1 0 0 1\n")
    with pytest.raises(InputError, match=r"x_par\.txt: says 2 images but has 1 camera lines"):
        import_middlebury(par, tmp_path / "o")
    par.write_text("1\nimg.png 1 0 0 0 1 0 0 0 1 1 0 0 0 1 0 0 0 1 0 0\n")
    with pytest.raises(InputError, match=r"x_par\.txt: line 2: expected .* \(22 fields\), got 21"):
        import_middlebury(par, tmp_path / "o")
    par.write_text("1\nimg.png 1 0 0 0 1 0 0 0 1 1 0 0 0 1 0 0 0 2 0 0 1\n")
    with pytest.raises(InputError, match=r"line 2 \(img\.png\): not a rotation matrix"):
        import_middlebury(par, tmp_path / "o")
    par.write_text("1\nimg.png 1 0 0 0 1 0 0 0 1 1 0 0 0 1 0 0 0 1 0 0 1\n")
    with pytest.raises(InputError, match=r"img\.png: missing image"):
        import_middlebury(par, tmp_path / "o")
    (tmp_path / "img.png").write_bytes(b"")
    with pytest.raises(InputError, match=r"img\.png: empty file"):
        import_middlebury(par, tmp_path / "o")


@pytest.mark.shared
@pytest.mark.slow
def test_middlebury_dino_leave_one_out(tmp_path):
    if not DINO.is_dir():
        pytest.skip(f"shared data not available ({DINO})")
    (out,) = import_middlebury(DINO, tmp_path / "dino")
    cap = read_capture(out)
    assert len(cap.rig) == 16 and cap.polarity == "bright-object"
    assert 600.0 < np.linalg.norm(cap.rig.cameras[0].centre) < 800.0  # metres -> mm
    det: dict = {}
    res = leave_one_out_iou(out, voxel_mm=2.0, details=det)
    assert set(det["clipped"]) == {"dinoSR0002", "dinoSR0003"}  # the object leaves the top of these images
    assert "clipped/dinoSR0002" in res and "dinoSR0002" not in res
    assert res["median"] >= 0.9, res


# ------------------------------------------------------------------------------ helpers, CLI


def test_mask_helpers():
    m = np.zeros((20, 20), bool)
    m[2:15, 2:15] = True
    m[6:9, 6:9] = False  # a hole
    m[2:5, 10:12] = False  # a notch open to the outside
    f = fill_holes(m)
    assert f[6:9, 6:9].all() and not f[2:5, 10:12].any()
    c = close_mask(f, 2)
    assert c[3:5, 10:12].all() and not c[16:, :].any()  # closed below its mouth, no growth
    edge = np.zeros((10, 10), bool)
    edge[:, :4] = True
    np.testing.assert_array_equal(close_mask(edge, 3), edge)  # no growth from the border


def test_cli_import(tmp_path, part, capsys):
    cams = _cameras()[:3]
    cov = {c.name: np.zeros((H, W), np.float32) for c in cams}
    par = _write_middlebury(tmp_path / "toy", cams, cov)
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="command")
    add_parser(sub)
    args = ap.parse_args(["import", "middlebury", str(par.parent), "--out", str(tmp_path / "cap")])
    assert run(args) == 0
    assert "wrote" in capsys.readouterr().out
    assert run(args) == 2  # exists
    assert "not empty" in capsys.readouterr().err
    args = ap.parse_args(["import", "middlebury", str(par.parent), "--out", str(tmp_path / "cap"), "--force", "--scale", "1"])
    assert run(args) == 0
    assert read_capture(tmp_path / "cap").metadata["import"]["scale_to_mm"] == 1.0
    args = ap.parse_args(["import", "idr", str(tmp_path / "none"), "--out", str(tmp_path / "o")])
    assert run(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err
    assert sorted(IMPORTERS) == ["idr", "middlebury", "nerf", "opencv"]
