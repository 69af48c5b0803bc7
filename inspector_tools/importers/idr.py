"""Importer ``idr``: ``cameras*.npz`` (IDR / NeuS / VolSDF: DTU, BlendedMVS) -> capture folder."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from inspector.errors import InputError
from inspector.model import Camera, Rig
from inspector_tools.importers.common import (
    _alpha_to_grey,
    _image_size,
    _label,
    _list_images,
    _load_npz,
    _mask_to_coverage,
    _read_image,
    _rotation,
    _scale_of,
    _unique_names,
    _units_note,
    _write,
)

__all__ = ["decompose_projection", "import_idr"]


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``P ~ K [R | t]`` (3x4 or 4x4, any non-zero scale and sign) -> K, R, t.

    Uses ``cv2.decomposeProjectionMatrix`` then normalises: ``fx, fy > 0`` (a negative
    diagonal entry of K is moved into the matching row of R), ``det R = +1`` (P's overall
    sign flipped), ``K[2, 2] = 1``; ``t = -R @ C`` with ``C`` the optical centre, so the
    depth of the points in front of the camera is positive.
    """
    import cv2

    P = np.asarray(P, float)
    if P.shape == (4, 4):
        P = P[:3]
    if P.shape != (3, 4) or not np.all(np.isfinite(P)):
        raise ValueError(f"projection must be 3x4 or 4x4 finite numbers, got shape {P.shape}")
    if abs(np.linalg.det(P[:, :3])) < 1e-300:
        raise ValueError("projection is singular (det of its 3x3 block is 0)")
    out = cv2.decomposeProjectionMatrix(np.ascontiguousarray(P))
    K, R, C4 = np.asarray(out[0], float), np.asarray(out[1], float), np.asarray(out[2], float).ravel()
    if abs(C4[3]) < 1e-300:
        raise ValueError("camera centre at infinity")
    C = C4[:3] / C4[3]
    D = np.diag(np.sign(np.where(np.diag(K) == 0, 1.0, np.diag(K))))
    K, R = K @ D, D @ R
    if np.linalg.det(R) < 0:
        R = -R  # P was scaled by a negative factor: -P = K [-R | ...] is the same camera
    # the decomposition of an exact K [R | t] may leave R orthonormal to ~1e-15 only
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    K = K / K[2, 2]
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError("cannot normalise K to positive focal lengths")
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    t = -R @ C
    return K, R, t


def import_idr(
    src: Path, out: Path, *, scale: float | None = None, frame: str = "world", overwrite: bool = False
) -> list[Path]:
    """IDR/NeuS ``cameras*.npz`` + ``image/`` + ``mask/`` (a folder, or the npz file) -> one capture.

    ``frame``: ``"world"`` (default, the dataset's world: ``world_mat``) or
    ``"normalised"`` (``world_mat @ scale_mat``). Units unknown: kept unless ``scale``.
    """
    if frame not in ("world", "normalised"):
        raise InputError(f"idr frame must be 'world' or 'normalised', got {frame!r}")
    src = Path(src)
    if src.is_dir():
        cands = sorted(p for p in src.glob("cameras*.npz") if p.is_file())
        if not cands:
            raise InputError(f"{_label(src)}: no IDR camera file (cameras*.npz) in this folder")
        pref = [p for p in cands if p.name == "cameras.npz"]
        npz = pref[0] if pref else cands[0]
        root = src
    elif src.is_file():
        npz, root = src, src.parent
    else:
        raise InputError(f"{_label(src)}: does not exist")
    s = _scale_of(scale, 1.0)
    arrays = _load_npz(npz, lambda k: re.fullmatch(r"(world|scale)_mat_\d+", k) is not None)
    idx = sorted(int(m.group(1)) for k in arrays if (m := re.fullmatch(r"world_mat_(\d+)", k)))
    if not idx:
        raise InputError(f"{_label(npz)}: no world_mat_<i> arrays")
    if idx != list(range(len(idx))):
        raise InputError(f"{_label(npz)}: world_mat indices are not 0..{len(idx) - 1}")
    img_dir, mask_dir = root / "image", root / "mask"
    masks = _list_images(mask_dir)
    if not mask_dir.is_dir():
        raise InputError(f"{_label(mask_dir)}: missing (the idr importer takes the silhouettes from the masks)")
    if len(masks) != len(idx):
        raise InputError(f"{_label(mask_dir)}: {len(masks)} mask images for {len(idx)} cameras in {npz.name}")
    photos = _list_images(img_dir)
    if photos and len(photos) != len(idx):
        raise InputError(f"{_label(img_dir)}: {len(photos)} images for {len(idx)} cameras in {npz.name}")
    stems = [p.stem for p in (photos or masks)]
    cam_names = _unique_names([f"cam{st}" if st[:1].isdigit() else st for st in stems])
    cams, images = [], {}
    S0 = None
    for i, cname, mpath in zip(idx, cam_names, masks):
        where = f"{_label(npz)}: world_mat_{i}"
        P = np.asarray(arrays[f"world_mat_{i}"], float)
        if P.shape not in ((3, 4), (4, 4)):
            raise InputError(f"{where}: shape {P.shape}, expected 3x4 or 4x4")
        P = P[:3]
        S = arrays.get(f"scale_mat_{i}")
        if S is not None:
            S = np.asarray(S, float)
            if S.shape != (4, 4) or not np.all(np.isfinite(S)):
                raise InputError(f"{_label(npz)}: scale_mat_{i}: shape {S.shape}, expected finite 4x4")
            S0 = S if S0 is None else S0
        if frame == "normalised":
            if S is None:
                raise InputError(f"{_label(npz)}: scale_mat_{i} missing (needed for frame 'normalised')")
            P = P @ S
        try:
            K, R, t = decompose_projection(P)
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from None
        R = _rotation(R, where)
        cover = _mask_to_coverage(_read_image(mpath))
        h, w = cover.shape[:2]
        if photos:
            pw, ph = _image_size(photos[i])  # only the photograph's size is needed
            if (ph, pw) != (h, w):
                raise InputError(f"{_label(mpath)}: size {w}x{h}, its image {photos[i].name} is {pw}x{ph}")
        cams.append(Camera(cname, w, h, K, np.zeros(5), R, t * s))
        images[cname] = _alpha_to_grey(cover)
    info = {
        "format": "idr",
        "source": str(npz.resolve()),
        "units": _units_note("unknown", s),
        "scale_to_mm": s,
        "world_frame": (
            "the dataset's world frame (world_mat); X_normalised = inv(scale_mat) @ X_world"
            if frame == "world"
            else "IDR's normalised frame (world_mat @ scale_mat, object inside the unit sphere)"
        ),
        "pixel_convention": "as in the dataset (P applied to pixel indices: (0, 0) the centre of the top-left pixel)",
        "images": "silhouettes from mask/: grey = full scale - mask, dark object on white; the photographs are not copied",
        "segment": {"polarity": "dark-object", "threshold": "fixed", "level": 127.5, "median": "off"},
        "fill_holes": False,
    }
    if S0 is not None:
        info["scale_mat"] = S0.tolist()
    return [
        _write(Path(out), Rig(tuple(cams)), images, polarity="dark-object", part_id=root.name or npz.stem, info=info, overwrite=overwrite)
    ]


