"""Simulated captures of a ChArUco calibration target (``inspector_drivers/sim/target.py``).

Real images, fixed seeds: OpenCV's own ChArUco detector must find the corners where the
true cameras project them.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from inspector.calibration.target import load_target, parse_target
from inspector.model import Camera
from inspector_drivers.sim.rig import sphere_rig
from inspector_drivers.sim.target import render_target, sample_offsets, simulate_target, target_poses

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "calibration"
CUBE = EXAMPLES / "charuco_cube.toml"
BOARD = EXAMPLES / "charuco_board.toml"


# ------------------------------------------------------------------------ helpers


def _camera(size: int, f: float, dist=(0.0,), distance: float = 400.0, roll_deg: float = 0.0) -> Camera:
    """A camera at (0, 0, -distance) looking along +z (rolled about it), principal point at the centre."""
    K = np.array([[f, 0.0, (size - 1) / 2.0], [0.0, f, (size - 1) / 2.0], [0.0, 0.0, 1.0]])
    R = Rotation.from_euler("z", roll_deg, degrees=True).as_matrix()
    return Camera("c", size, size, K, np.asarray(dist, float), R, np.array([0.0, 0.0, distance]))


def _facing_pose(target, b: int, tilt_deg: float = 0.0, axis=(1.0, 0.0, 0.0), inplane_deg: float = 0.0,
                 centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Body -> world pose putting board ``b``'s centre at ``centre`` with its axes along the
    world's (so a camera with R = I at z = -d sees its print frontally), then turned by
    ``inplane_deg`` about its normal and tilted by ``tilt_deg`` about ``axis``."""
    F = target.faces[b]
    turn = (Rotation.from_rotvec(np.radians(tilt_deg) * np.asarray(axis, float) / np.linalg.norm(axis))
            * Rotation.from_euler("z", inplane_deg, degrees=True)).as_matrix()
    R = turn @ F[:3, :3].T
    w, h = target.board_size_mm
    c_body = F[:3, :3] @ np.array([w / 2.0, h / 2.0, 0.0]) + F[:3, 3]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(centre, float) - R @ c_body
    return T


def _truth(target, b: int, cam: Camera, pose: np.ndarray, local_ids: np.ndarray) -> np.ndarray:
    X = target.object_points()[target.corner_ids(b, local_ids)]
    return cam.project(X @ pose[:3, :3].T + pose[:3, 3])[0]


def _detect(target, image: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Local corner ids (N,) and detected pixels (N, 2) of board ``b``."""
    corners, ids, _, _ = cv2.aruco.CharucoDetector(target.board(b)).detectBoard(image)
    if ids is None:
        return np.zeros(0, int), np.zeros((0, 2))
    return ids.ravel().astype(int), corners.reshape(-1, 2).astype(float)


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


# ------------------------------------------------------------------------ poses


def test_poses_are_deterministic_random_and_centred():
    cube, board = load_target(CUBE), load_target(BOARD)
    a = target_poses(cube, 20, seed=4)
    assert a.shape == (20, 4, 4)
    np.testing.assert_array_equal(a, target_poses(cube, 20, seed=4))
    np.testing.assert_array_equal(a[:5], target_poses(cube, 5, seed=4))
    assert not np.allclose(a, target_poses(cube, 20, seed=5))
    for T in a:
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
        assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
        assert np.linalg.norm(T[:3, 3]) <= 8.0 + 1e-9  # the cube's centre is its body origin
    # the planar board turns about its middle, which stays within offset_mm of the rig centre
    w, h = board.board_size_mm
    P = target_poses(board, 200, seed=1, offset_mm=3.0)
    mid = P[:, :3, :3] @ np.array([w / 2, h / 2, 0.0]) + P[:, :3, 3]
    assert np.linalg.norm(mid, axis=1).max() <= 3.0 + 1e-9
    normals = P[:, :3, :3] @ board.board_normals()[0]
    assert np.linalg.norm(normals.mean(axis=0)) < 0.2  # print faces every way


def test_sample_offsets_are_centred_and_resolve_both_axes():
    for s in (1, 2, 3, 4):
        o = sample_offsets(s)
        assert o.shape == (s * s, 2)
        np.testing.assert_allclose(o.mean(axis=0), 0.0, atol=1e-12)
        assert np.all(np.abs(o) < 0.5)
        assert len(np.unique(o[:, 0])) == s * s and len(np.unique(o[:, 1])) == s * s


# ------------------------------------------------------------------------ geometry


def test_frontal_cube_face_corners_where_the_camera_projects_them():
    cube = load_target(CUBE)
    cam = _camera(320, 2000.0, roll_deg=23.0)  # 0.2 mm/px at the rig centre
    for b, inplane, centre in ((0, 0.0, (0.13, -0.07, 0.0)), (3, 31.0, (-0.31, 0.22, 1.0))):
        pose = _facing_pose(cube, b, inplane_deg=inplane, centre=centre)
        img = render_target(cube, cam, pose, rng=np.random.default_rng(b))
        assert img.shape == (320, 320) and img.dtype == np.uint8
        ids, uv = _detect(cube, img, b)
        assert len(ids) == cube.corners_per_board
        assert _rms(uv - _truth(cube, b, cam, pose, ids)) < 0.1
        # the other boards show nothing here (their faces are edge-on or hidden)
        for other in range(cube.n_boards):
            if other != b:
                assert len(_detect(cube, img, other)[0]) == 0


def test_planar_board_front_and_back():
    board = load_target(BOARD)
    cam = _camera(400, 2000.0, roll_deg=-12.0)
    pose = _facing_pose(board, 0, tilt_deg=10.0, axis=(1.0, 1.0, 0.0), inplane_deg=8.0, centre=(0.21, -0.4, 0.0))
    img = render_target(board, cam, pose, rng=np.random.default_rng(3))
    ids, uv = _detect(board, img, 0)
    assert len(ids) == board.corners_per_board
    assert _rms(uv - _truth(board, 0, cam, pose, ids)) < 0.1
    # turned over: the camera sees the plain back, ~150 grey where the board is
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    back = render_target(board, cam, pose @ _about_middle(board, flip), noise_sigma=0.0)
    assert len(_detect(board, back, 0)[0]) == 0
    assert back[200, 200] == pytest.approx(150, abs=1)
    assert back[2, 2] == 90


def _about_middle(target, M: np.ndarray) -> np.ndarray:
    w, h = target.board_size_mm
    c = np.array([w / 2, h / 2, 0.0])
    T1, T2 = np.eye(4), np.eye(4)
    T1[:3, 3], T2[:3, 3] = c, -c
    return T1 @ M @ T2


def test_lens_distortion_is_honoured():
    # a 6 x 6 board near the image corner of a wide camera with k1 = 0.1
    small = parse_target({"target": {"kind": "charuco", "dictionary": "DICT_5X5_1000", "squares": [6, 6],
                                     "square_mm": 6.0, "marker_mm": 4.5}}, "small")
    cam = _camera(512, 1000.0, dist=(0.1, 0.0, 0.0, 0.0, 0.0), distance=200.0)
    flat = Camera("u", cam.width, cam.height, cam.K, np.zeros(5), cam.R, cam.t)
    pose = _facing_pose(small, 0, tilt_deg=10.0, inplane_deg=5.0, centre=(29.0, 28.0, 0.0))
    img = render_target(small, cam, pose, rng=np.random.default_rng(7))
    ids, uv = _detect(small, img, 0)
    assert len(ids) >= small.corners_per_board - 2
    assert _rms(uv - _truth(small, 0, cam, pose, ids)) < 0.15
    shift = np.linalg.norm(uv - _truth(small, 0, flat, pose, ids), axis=1)
    assert shift.max() > 1.5  # the undistorted projection is pixels away near the corner


def test_cube_shows_one_to_three_boards_to_every_camera():
    cube = load_target(CUBE)
    rig = sphere_rig(16, width=384, height=384, mm_per_px=0.2)
    aruco = cv2.aruco.ArucoDetector(cube.cv_dictionary())
    for pose in target_poses(cube, 2, seed=11, offset_mm=2.0):
        for j, cam in enumerate(rig.cameras):
            img = render_target(cube, cam, pose, rng=np.random.default_rng(j))
            _, ids, _ = aruco.detectMarkers(img)
            assert ids is not None, cam.name
            boards = set((ids.ravel() // cube.markers_per_board).tolist())
            assert 1 <= len(boards) <= 3, (cam.name, boards)
            # every board seen is one the camera faces
            n_world = cube.board_normals() @ pose[:3, :3].T  # outward normals, world
            origins = cube.faces[:, :3, 3] @ pose[:3, :3].T + pose[:3, 3]  # a point of each face
            facing = {b for b in range(cube.n_boards) if n_world[b] @ (cam.centre - origins[b]) > 0}
            assert boards <= facing


# ------------------------------------------------------------------------ captures and command


def test_simulate_target_captures():
    cube = load_target(CUBE)
    rig = sphere_rig(4, width=128, height=128, mm_per_px=0.8)
    caps = list(simulate_target(cube, rig, 2, seed=5, noise_sigma=1.0))
    assert [c.name for c in caps] == ["pose_000", "pose_001"]
    poses = target_poses(cube, 2, seed=5)
    for c, pose in zip(caps, poses):
        assert set(c.images) == set(rig.names)
        assert all(im.shape == (128, 128) and im.dtype == np.uint8 for im in c.images.values())
        assert c.polarity == "dark-object" and c.metadata["part_id"] == "calibration-target"
        assert c.truth is not None and c.truth.mesh_path is None
        np.testing.assert_array_equal(np.asarray(c.truth.info["target_pose"]), pose)
        assert c.truth.info["target"] == cube.to_json()
    again = next(iter(simulate_target(cube, rig, 1, seed=5, noise_sigma=1.0)))
    for name in rig.names:  # deterministic, noise included
        np.testing.assert_array_equal(again.images[name], caps[0].images[name])


def test_command_writes_capture_folders(tmp_path, capsys):
    from inspector.capture_folder import read_capture
    from inspector_frontends.cli import main

    out = tmp_path / "cal"
    code = main(["simulate", "--target", str(CUBE), "--poses", "2", "--cameras", "4", "--width", "128",
                 "--height", "128", "--mm-per-px", "0.8", "--seed", "3", "--dist", "0.05", "0", "0", "0", "0",
                 "--out", str(out)])
    assert code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines == [f"[1/2] wrote {out / 'pose_000'}", f"[2/2] wrote {out / 'pose_001'}"]
    cube = load_target(CUBE)
    poses = target_poses(cube, 2, seed=3, offset_mm=8.0)
    for i in range(2):
        cap = read_capture(out / f"pose_{i:03d}")
        assert len(cap.rig) == 4 and cap.rig.cameras[0].dist[0] == pytest.approx(0.05)
        assert cap.polarity == "dark-object" and cap.metadata["part_id"] == "calibration-target"
        assert (out / f"pose_{i:03d}" / "truth" / "truth.json").is_file()
        np.testing.assert_allclose(np.asarray(cap.truth.info["target_pose"]), poses[i], atol=1e-12)
        assert cap.truth.info["target"]["kind"] == "charuco_cube"
        assert any(im.min() < 60 for im in cap.images.values())  # the print is there

    # --rig: the cameras of a rig file
    rig_out = tmp_path / "cal2"
    assert main(["simulate", "--target", str(BOARD), "--poses", "1", "--rig", str(out / "pose_000" / "rig.json"),
                 "--out", str(rig_out)]) == 0
    assert read_capture(rig_out / "pose_000").rig.names == read_capture(out / "pose_000").rig.names


@pytest.mark.parametrize(("extra", "message"), [
    ([], "unknown key target.colour"),
    (["--part", "cube30"], "--part: not with --target"),
])
def test_command_bad_target_exits_2_with_one_line(tmp_path, capsys, extra, message):
    from inspector_frontends.cli import main

    bad = tmp_path / "bad.toml"
    bad.write_text('[target]\nkind = "charuco"\ndictionary = "DICT_5X5_1000"\nsquares = [5, 5]\n'
                   'square_mm = 7.0\nmarker_mm = 5.0\ncolour = "red"\n' if not extra else CUBE.read_text())
    assert main(["simulate", "--target", str(bad), *extra, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "o").exists()


def test_command_target_options_only_with_target(tmp_path, capsys):
    from inspector_frontends.cli import main

    assert main(["simulate", "--poses", "3", "--out", str(tmp_path / "o")]) == 2
    assert "--poses: only with --target" in capsys.readouterr().err
