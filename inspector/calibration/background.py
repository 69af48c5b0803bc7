"""``inspector calibrate --background --captures DIR --out FOLDER``: each camera's empty field.

The segmentation flat-fields a capture against its cameras' empty-field images
(``background/<camera>.png`` in the capture folder, :mod:`inspector_plugins.segment`): the
part's silhouette is then judged against the local background level (vignetting, dust), not a
global one. This command makes those images once, at commissioning:

1. ``DIR`` holds one capture folder per frame of the empty field (``inspector capture --count 8
   --out DIR`` with nothing in the rig), each ``images/<camera>.png``; a camera missing from
   some frames is averaged over the frames it has.
2. Per camera the frames are checked and averaged (float, then rounded to the frames' own bit
   depth and channels: an 8-bit camera gets an 8-bit reference whose noise is that of one frame
   divided by the square root of the frame count):

   * every frame of a camera has the same size, bit depth and channels;
   * **nothing moved** (three frames or more): a frame differing from the per-pixel median of
     the camera's frames by more than :data:`MOVED_SIGMA` times one frame's noise (at least
     :data:`MOVED_MIN_LEVELS` grey levels) over more than :data:`MOVED_PCT` % of the image is
     refused, named ("something moved in the field");
   * **the field is empty** (a bright background, the backlit cell): more than
     :data:`DARK_PCT` % of the averaged field darker than half its 95th percentile is refused
     ("is the rig empty?"); dust specks and vignetting to 50 % pass.

3. ``FOLDER/background/<camera>.png`` (a capture folder's layout, so ``FOLDER`` may be the
   cell's folder holding its ``rig.json``, whose cameras and sizes must then match, or a
   capture folder itself) and ``FOLDER/background.json`` (date, frames, per camera its
   frames, level range and noise). Every file is checked before any is written, and each is
   written whole (temporary file, then rename); existing ones are replaced only with
   ``--force``.

Live drivers whose ``rig`` parameter names ``FOLDER`` (or ``FOLDER/rig.json``) attach these
images to every capture (:class:`inspector_drivers.genicam.common.LiveDriver`), so
``inspector capture`` writes them into each capture folder and ``inspector run`` flat-fields
every part; a capture folder taken without them gets them by copying ``FOLDER/background/``
into it.

Every bad input is one line, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from inspector.calibration.detect import capture_folders, find_cameras
from inspector.capture_folder import BACKGROUND_DIR, RIG_FILE, decode_image, read_rig
from inspector.errors import CaptureError, RecipeError
from inspector.kernels.threads import map_threads

__all__ = ["run_background", "average_fields", "FieldAverage", "MOVED_SIGMA", "MOVED_PCT", "DARK_PCT"]

#: A frame's pixel differs from the median of its camera's frames when off by this many times
#: the frames' noise (robust sigma of the differences) ...
MOVED_SIGMA = 8.0
#: ... and by at least this many grey levels (8-bit scale; a noise-free camera) ...
MOVED_MIN_LEVELS = 12.0
#: ... and a frame with more than this share of its pixels so (%) saw something move.
MOVED_PCT = 0.05
#: More than this share (%) of an averaged bright field darker than half its 95th percentile:
#: something is in the rig (a 30 mm part at 0.1 mm/px covers 8 % of a 1024^2 image; 40 specks
#: of 1-4 px, 0.001 %).
DARK_PCT = 0.5
#: Only a field this bright (95th percentile, 8-bit scale) is checked for being empty: a dark
#: field (bright parts, front light) has no "dark object" to find.
BRIGHT_FIELD = 64.0


def _say(msg: str) -> None:
    print(f"calibrate: {msg}", file=sys.stderr, flush=True)


@dataclass
class FieldAverage:
    """One camera's averaged empty field."""

    name: str
    image: np.ndarray  # (H, W) or (H, W, C), the frames' dtype
    frames: int
    noise: float  # one frame's noise sigma (:func:`_frame_noise`), 8-bit levels (nan below 2 frames)
    level: tuple[float, float]  # 1st and 99th percentile of the averaged grey, 8-bit levels
    dark_pct: float  # share of the averaged field darker than half its 95th percentile, %


def _grey(img: np.ndarray) -> np.ndarray:
    """(H, W[, C]) uint8/uint16 -> (H, W) float32 grey, 8-bit scale (BGR channel order)."""
    a = img.astype(np.float32)
    if a.ndim == 3:
        c = a.shape[2]
        a = a[..., 0] if c == 1 else 0.114 * a[..., 0] + 0.587 * a[..., 1] + 0.299 * a[..., 2]
    return a / np.float32(257.0) if img.dtype == np.uint16 else a


def _frame_noise(greys: np.ndarray) -> float:
    """One frame's noise sigma from ``greys`` (N >= 2, H, W) float frames of a still field:
    the median over pixels of their sample variance (ddof 1), divided by the median of
    chi2(N - 1) / (N - 1) (unbiased for Gaussian noise, and robust: a speck or a moving hand
    changes the variance of few pixels)."""
    from scipy.stats import chi2

    n = greys.shape[0]
    var = greys.var(axis=0, ddof=1).ravel()
    if var.size > 1_000_000:
        var = var[:: var.size // 1_000_000]
    return float(np.sqrt(np.median(var) / (chi2.median(n - 1) / (n - 1))))


def average_fields(name: str, frames: Sequence[tuple[str, np.ndarray]]) -> FieldAverage:
    """Average one camera's empty-field frames after the checks of the module docstring.

    Parameters
    ----------
    name : str
        The camera (for the messages).
    frames : sequence of (label, (H, W) or (H, W, C) uint8/uint16 array)
        The frames, each with the label a message names it by (``frame_003/images/cam02.png``).

    Returns
    -------
    FieldAverage

    Raises
    ------
    RecipeError
        One line naming the camera (and the frame) when the frames disagree in kind, something
        moved between them, or the field is not empty.
    """
    first_label, first = frames[0]
    for label, img in frames[1:]:
        if img.shape != first.shape or img.dtype != first.dtype:
            raise RecipeError(f"{label}: {_kind(img)}, but camera {name} is {_kind(first)} in {first_label}")
    stack = np.stack([np.asarray(img) for _, img in frames]).astype(np.float32)  # (N, H, W[, C])
    mean = stack.mean(axis=0)
    noise = float("nan")
    if len(frames) >= 2:
        greys = np.stack([_grey(img) for _, img in frames])
        med = np.median(greys, axis=0)
        noise = _frame_noise(greys)
        if len(frames) >= 3:
            # the median of three or more frames is what stayed still: a frame off it over an
            # area saw something move (a hand, a part falling through); two frames cannot say which
            limit = max(MOVED_SIGMA * noise, MOVED_MIN_LEVELS)
            for (label, _), g in zip(frames, greys):
                pct = 100.0 * float(np.mean(np.abs(g - med) > limit))
                if pct > MOVED_PCT:
                    raise RecipeError(f"{label}: differs from the other frames of camera {name} over {pct:.2f} % of the "
                                      "image (something moved in the empty field): take that frame again or remove it")
    dtype = first.dtype
    top = 65535.0 if dtype == np.uint16 else 255.0
    image = np.clip(np.rint(mean), 0.0, top).astype(dtype)
    g = _grey(image)
    p95 = float(np.percentile(g, 95))
    dark = 100.0 * float(np.mean(g < 0.5 * p95)) if p95 >= BRIGHT_FIELD else 0.0
    if dark > DARK_PCT:
        raise RecipeError(f"camera {name}: {dark:.1f} % of its empty field is darker than half the background level "
                          f"({p95:.0f}): is the rig empty? Clear the field of view and take the frames again")
    lo, hi = (float(v) for v in np.percentile(g, [1, 99]))
    return FieldAverage(name, image, len(frames), noise, (lo, hi), dark)


def _kind(img: np.ndarray) -> str:
    ch = 1 if img.ndim == 2 else img.shape[2]
    return f"{img.shape[1]}x{img.shape[0]}, {8 * img.dtype.itemsize}-bit, {ch} channel{'s' * (ch != 1)}"


def _check_rig(folder: Path, names: Sequence[str], sizes: dict[str, tuple[int, int]]) -> None:
    """A ``rig.json`` in ``folder`` must list exactly the cameras of the frames, at their sizes."""
    p = folder / RIG_FILE
    if not p.is_file():
        return
    try:
        rig = read_rig(p)
    except CaptureError as e:
        raise RecipeError(f"{p}: {e}") from None
    for cam in rig.cameras:
        if cam.name not in sizes:
            raise RecipeError(f"{p}: camera {cam.name} has no empty-field frame in --captures (images/{cam.name}.png)")
        if sizes[cam.name] != (cam.width, cam.height):
            w, h = sizes[cam.name]
            raise RecipeError(f"{p}: camera {cam.name} is {cam.width}x{cam.height}, its empty-field frames are {w}x{h}")
    extra = [n for n in names if n not in set(rig.names)]
    if extra:
        raise RecipeError(f"{p}: no camera {extra[0]}, but the empty-field frames have images/{extra[0]}.png")


def run_background(args: argparse.Namespace) -> int:
    """``inspector calibrate --background --captures DIR --out FOLDER [--force] [--json]``."""
    import cv2

    for flag in ("target", "rig", "correct", "reference", "recipe", "report"):
        if getattr(args, flag, None):
            what = "TARGET.toml" if flag == "target" else f"--{flag}"
            raise RecipeError(f"calibrate --background: {what} is not used here (--captures DIR of empty-field frames, "
                              "--out FOLDER)")
    if getattr(args, "intrinsics", False):
        raise RecipeError("calibrate --background: --intrinsics is not used here")
    if not getattr(args, "out", None):
        raise RecipeError("calibrate --background: --out FOLDER is required (it receives background/<camera>.png)")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise RecipeError(f"--out {out}: is a file, not a folder")
    if not out.exists() and not out.parent.is_dir():
        raise RecipeError(f"--out {out}: no such folder {out.parent}")
    root = Path(args.captures)
    folders = capture_folders(root)
    names, sizes, images = find_cameras(folders)
    if out.is_dir():
        _check_rig(out, names, sizes)
    bg_dir = out / BACKGROUND_DIR
    targets = [bg_dir / f"{n}.png" for n in names] + [out / "background.json"]
    if not getattr(args, "force", False):
        for t in targets:
            if t.exists():
                raise RecipeError(f"{t}: exists (use --force to replace the empty-field reference)")
    _say(f"averaging the empty field of {len(names)} cameras over {len(folders)} frame{'s' * (len(folders) != 1)}")
    def one(name: str) -> FieldAverage:
        frames = []
        for i, f in enumerate(folders):
            p = images.get((i, name))
            if p is None:
                continue
            label = f"{f.name}/images/{name}.png"
            try:
                frames.append((label, decode_image(p, label, CaptureError, size=sizes[name], camera=name)))
            except CaptureError as e:
                raise RecipeError(str(e)) from None
        return average_fields(name, frames)

    fields = map_threads(one, names)
    notes = []
    if len(folders) < 4:
        notes.append(f"{len(folders)} frame{'s' * (len(folders) != 1)}: the reference keeps "
                     f"{100 / np.sqrt(len(folders)):.0f} % of one frame's noise; 4 or more frames halve it")
    for fa in fields:
        if fa.frames < len(folders):
            notes.append(f"{fa.name}: {fa.frames} of {len(folders)} frames (averaged over those)")

    # everything checked: write, each file whole
    bg_dir.mkdir(parents=True, exist_ok=True)
    for fa in fields:
        p = bg_dir / f"{fa.name}.png"
        tmp = p.with_name(f".{p.name}.partial")
        ok, buf = cv2.imencode(".png", fa.image)
        if not ok:  # pragma: no cover - cv2 encodes any uint8/uint16 array
            raise RecipeError(f"{p}: could not be encoded")
        tmp.write_bytes(buf.tobytes())
        os.replace(tmp, p)
    summary: dict[str, Any] = {
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "captures": str(root),
        "frames": len(folders),
        "folder": str(bg_dir),
        "cameras": {fa.name: {"frames": fa.frames, "level": [round(fa.level[0], 1), round(fa.level[1], 1)],
                              "noise": None if not np.isfinite(fa.noise) else round(fa.noise, 3),
                              "dark_pct": round(fa.dark_pct, 4), "width": sizes[fa.name][0], "height": sizes[fa.name][1]}
                    for fa in fields},
        "notes": notes,
    }
    meta = out / "background.json"
    tmp = meta.with_name(f".{meta.name}.partial")
    tmp.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, meta)
    if getattr(args, "json", False):
        print(json.dumps(summary, indent=1))
        return 0
    lines = [f"Empty field of {len(fields)} cameras, {len(folders)} frame{'s' * (len(folders) != 1)} averaged",
             "", f"{'camera':<10} {'frames':>6} {'level 1-99 %':>14} {'frame noise':>12}"]
    for fa in fields:
        noise = "-" if not np.isfinite(fa.noise) else f"{fa.noise:.2f}"
        lines.append(f"{fa.name:<10} {fa.frames:>6d} {fa.level[0]:>6.0f} - {fa.level[1]:<5.0f} {noise:>12}")
    lines += [f"note: {n}" for n in notes]
    lines += ["", f"Wrote {bg_dir}/<camera>.png and {meta.name}: a capture folder holding background/<camera>.png is "
                  "flat-fielded against it by the segment stage (live drivers whose rig parameter names "
                  f"{out} attach it to every capture)"]
    print("\n".join(lines))
    return 0
