"""Result outputs (CONTRACT): ``result.json``, ``bcps_points.ply``, ``reconstruction.ply``
and, when the reconstruction has faces, ``reconstruction_mesh.ply``.

One folder per capture, ``OUTDIR/<capture name>/``. A result folder appears whole or not at
all: its files are written in a hidden folder beside it (``OUTDIR/.<name>.partial``), which is
then renamed ``OUTDIR/<name>`` (for a re-run, the old folder gives way: its result files go,
anything else in it, an exported report or an operator's note, is kept). A write that fails (a
full disk) removes what it wrote, leaves an earlier result as it was, and is one
:class:`~inspector.errors.CaptureError` naming the capture and the file; what a crash leaves
behind (a hidden folder) is cleared by the next write of that capture
(:func:`discard_result`, for a hot folder's restart).

The PLY files are binary little-endian, with the element and property names and types
that plyfile writes (``element vertex`` then ``element face`` with ``property list uchar
int vertex_indices``). They are written directly, one header and one numpy structured
array per element (plyfile writes list properties row by row, far slower); any PLY reader
(plyfile, Open3D, trimesh) reads them.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import CaptureError
from inspector.kernels.bcps import confidence
from inspector.locale import _, number
from inspector.model import InspectionResult
from inspector.names import check_name, printable

__all__ = ["write_result", "result_folder", "result_written", "discard_result", "clear_leftovers", "result_to_json", "write_ply", "ply_chunks", "read_ply", "one_line"]

BCPS_PLY = "bcps_points.ply"
RECON_PLY = "reconstruction.ply"
RECON_MESH_PLY = "reconstruction_mesh.ply"
RESULT_JSON = "result.json"
TRACEBACK = "traceback.txt"
#: What write_result writes: an earlier result's copies of these never outlive a re-run.
RESULT_FILES = frozenset({RESULT_JSON, BCPS_PLY, RECON_PLY, RECON_MESH_PLY, TRACEBACK})


def _clean(value: Any) -> Any:
    """JSON-safe copy: numpy to Python, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, (np.floating, float)):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    return value


def result_to_json(result: InspectionResult, *, with_points: bool) -> dict[str, Any]:
    """The CONTRACT ``result.json`` document."""
    return _clean(
        {
            "capture": result.capture,
            "recipe": result.recipe,
            "verdict": result.verdict,
            "error": result.error,
            "timings_s": dict(result.timings_s),
            "pose": result.pose if result.pose is not None else None,
            "stats": dict(result.stats),
            "defects": [d.to_json() for d in result.defects],
            "metadata": dict(result.metadata),
            "recipe_path": result.recipe_path,
            "recipe_sha256": result.recipe_sha256,
            "points": {
                "bcps": BCPS_PLY if with_points and result.bcps is not None else None,
                "reconstruction": RECON_PLY if with_points and result.reconstruction is not None else None,
            },
            # issue 16: what stages put in context.extras (already JSON-safe: inspector.runner.json_extras)
            "extras": dict(result.extras),
        }
    )


def _atomic_write(path: Path, *chunks: bytes | memoryview) -> None:
    """Write ``path`` under a temporary name, then rename it: a reader never sees half a
    file, and a failed write (a full disk) leaves no ``*.part`` file behind."""
    tmp = path.with_name(path.name + ".part")
    try:
        with open(tmp, "wb") as f:
            for chunk in chunks:
                f.write(chunk)
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        raise


#: numpy (kind, size) -> PLY type name (plyfile's names).
_PLY_TYPES = {
    ("b", 1): "uchar",
    ("i", 1): "char",
    ("u", 1): "uchar",
    ("i", 2): "short",
    ("u", 2): "ushort",
    ("i", 4): "int",
    ("u", 4): "uint",
    ("f", 4): "float",
    ("f", 8): "double",
}


def _ply_type(dtype: np.dtype, what: str) -> str:
    try:
        return _PLY_TYPES[(dtype.kind, dtype.itemsize)]
    except KeyError:
        raise ValueError(f"{what}: dtype {dtype} has no PLY type") from None


def ply_chunks(columns: dict[str, np.ndarray], faces: np.ndarray | None = None) -> list[bytes | memoryview]:
    """The bytes of a binary little-endian PLY file, as header + one buffer per element.

    Parameters
    ----------
    columns : dict of name -> (N,) array
        Vertex properties in this order; dtypes are kept (any PLY type: int8..uint32,
        float32, float64, bool as uchar).
    faces : (F, K) int, optional
        Vertex indices (K <= 255, triangles: 3), written as ``property list uchar int
        vertex_indices`` (int32).

    Returns
    -------
    list of bytes-like
        Concatenated, the file; byte-identical to what plyfile writes for the same data.
    """
    cols = {str(k): np.asarray(v) for k, v in columns.items()}
    for k in cols:
        if not k or not k.isascii() or any(c.isspace() for c in k):
            raise ValueError(f"column {k!r}: not a PLY property name")
    n = len(next(iter(cols.values())))
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property {_ply_type(v.dtype, f'column {k!r}')} {k}" for k, v in cols.items()]
    vert = np.empty(n, dtype=[(k, v.dtype.newbyteorder("<")) for k, v in cols.items()])
    for k, v in cols.items():
        vert[k] = v
    out: list[bytes | memoryview] = [b"", vert.data.cast("B")]
    if faces is not None:
        f = np.asarray(faces)
        if f.size == 0:
            f = f.reshape(0, 3)
        if f.ndim != 2 or not 0 < f.shape[1] < 256:
            raise ValueError(f"faces: shape {f.shape}, expected (F, K) with 0 < K < 256")
        k = f.shape[1]
        tri = np.empty(len(f), dtype=[("n", "u1"), ("vertex_indices", "<i4", (k,))])
        tri["n"] = k
        tri["vertex_indices"] = f
        header += [f"element face {len(f)}", "property list uchar int vertex_indices"]
        out.append(tri.data.cast("B"))
    out[0] = ("\n".join(header + ["end_header"]) + "\n").encode("ascii")
    return out


def write_ply(path: Path, columns: dict[str, np.ndarray], faces: np.ndarray | None = None) -> None:
    """Write a binary PLY whose vertex element has one property per column.

    Parameters
    ----------
    columns : dict of name -> (N,) array
        ``x``, ``y``, ``z`` first; dtypes are kept (float32 recommended).
    faces : (F, 3) int, optional
    """
    _atomic_write(path, *ply_chunks(columns, faces))


def read_ply(path: Path) -> dict[str, np.ndarray]:
    """The vertex properties of a PLY file, as arrays by name."""
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"].data
    return {name: np.asarray(v[name]) for name in v.dtype.names}


def result_folder(outdir: Path, capture: str) -> Path:
    """``outdir/capture``, the result folder of ``capture``, once it is sure to be one.

    Whatever driver named the capture, a result is written only in a direct child of
    ``outdir`` (resolved, links followed) that is, or can become, a folder.

    Raises
    ------
    CaptureError
        The name cannot name a result folder (:func:`inspector.names.check_name`: ``..``,
        a separator, a control character, ``history.sqlite``...), it resolves outside
        ``outdir``, or something that is not a folder has that name. Nothing is written.
    """
    check_name(capture)
    folder = Path(outdir) / capture
    root = Path(outdir).resolve()
    if folder.resolve().parent != root:
        raise CaptureError(f"capture '{printable(capture)}': its result folder {folder} resolves outside {root}; nothing written")
    if folder.exists() and not folder.is_dir():
        raise CaptureError(f"capture '{printable(capture)}': {folder} exists and is not a folder; nothing written")
    return folder


def _hidden(folder: Path, what: str) -> Path:
    """``OUTDIR/.<name>.<what>``: where a result folder is built (``partial``) or where the
    one it replaces waits (``old``); hashed when the name is too long for it."""
    name = f".{folder.name}.{what}"
    if len(name.encode("utf-8", "surrogateescape")) > 255:
        name = f".{hashlib.sha256(folder.name.encode('utf-8', 'surrogateescape')).hexdigest()[:32]}.{what}"
    return folder.with_name(name)


def _result_file(name: str) -> bool:
    """A file write_result writes, or the temporary name it is written under."""
    return name in RESULT_FILES or (name.endswith(".part") and name[:-5] in RESULT_FILES)


def _carry_over(old: Path, folder: Path) -> None:
    """Move what is not a result file from the replaced folder ``old`` into ``folder``, then
    remove ``old``."""
    for entry in old.iterdir():
        if not _result_file(entry.name) and not os.path.lexists(folder / entry.name):
            os.rename(entry, folder / entry.name)
    shutil.rmtree(old)


def clear_leftovers(folder: Path) -> None:
    """What a crash during an earlier write of ``folder`` left: a partial folder (removed) or
    a replaced folder not yet cleared (its extra files carried over, or put back)."""
    old, partial = _hidden(folder, "old"), _hidden(folder, "partial")
    if os.path.lexists(old):
        if os.path.lexists(folder):
            _carry_over(old, folder)
        else:
            os.rename(old, folder)
    if os.path.lexists(partial):
        shutil.rmtree(partial)


def result_written(outdir: Path, capture: str) -> bool:
    """Whether ``capture``'s result folder in ``outdir`` is in place (it holds its
    ``result.json``: the folder appears whole). A temporary file that a crash while
    ``result.json`` was rewritten left in it (:func:`rewrite_result_json`) is removed: the
    file it was replacing is whole."""
    try:
        folder = result_folder(Path(outdir), capture)
    except CaptureError:
        return False
    if not (folder / RESULT_JSON).is_file():
        return False
    for name in RESULT_FILES:
        try:
            (folder / f"{name}.part").unlink(missing_ok=True)
        except OSError:
            pass
    return True


def discard_result(outdir: Path, capture: str) -> None:
    """Remove the result folder of ``capture`` in ``outdir`` and whatever an unfinished write
    of it left (hidden partial folders). For a hot folder's restart: the capture is inspected
    again, so a result written without its history row must not stay beside the new one.
    A name that cannot be a result folder, or a link, is left alone."""
    try:
        folder = result_folder(Path(outdir), capture)
    except CaptureError:
        return
    for p in (_hidden(folder, "partial"), _hidden(folder, "old"), folder):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)


def _write_files(result: InspectionResult, partial: Path, folder: Path, trace: str | None, writing: list[Path]) -> None:
    """Write the result files into ``partial``, the folder to become ``folder``; ``writing[0]``
    is set to each file's final path before it is written (for the message if it fails)."""

    def at(name: str) -> Path:
        writing[0] = folder / name
        return partial / name

    if result.bcps is not None:
        b = result.bcps
        cols: dict[str, np.ndarray] = {
            "x": b.points[:, 0].astype(np.float32),
            "y": b.points[:, 1].astype(np.float32),
            "z": b.points[:, 2].astype(np.float32),
            "deviation": b.deviation.astype(np.float32),
            "camera": b.camera.astype(np.int16),
            "u": b.pixel[:, 0].astype(np.float32),
            "v": b.pixel[:, 1].astype(np.float32),
            "segment_mm": b.segment_mm.astype(np.float32),
        }
        if result.rig is not None and len(result.rig):
            cols["confidence"] = confidence(b.segment_mm, result.rig.footprint_mm()).astype(np.float32)
        write_ply(at(BCPS_PLY), cols)
    if result.reconstruction is not None:
        r = result.reconstruction
        write_ply(
            at(RECON_PLY),
            {
                "x": r.points[:, 0].astype(np.float32),
                "y": r.points[:, 1].astype(np.float32),
                "z": r.points[:, 2].astype(np.float32),
                "nx": r.normals[:, 0].astype(np.float32),
                "ny": r.normals[:, 1].astype(np.float32),
                "nz": r.normals[:, 2].astype(np.float32),
            },
        )
        if len(r.faces):
            v = r.vertices.astype(np.float32)
            write_ply(at(RECON_MESH_PLY), {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, faces=r.faces)
    if trace:
        _atomic_write(at(TRACEBACK), trace.encode("utf-8"))
    doc = result_to_json(result, with_points=True)
    _atomic_write(at(RESULT_JSON), (json.dumps(doc, indent=2) + "\n").encode())


def write_result(result: InspectionResult, outdir: Path, *, trace: str | None = None) -> Path:
    """Write one capture's result folder, ``outdir/<capture>``, and return it.

    Built in a hidden folder and renamed into place, so it appears whole or not at all; an
    earlier result folder of the same capture is replaced (its non-result files are kept).

    Raises
    ------
    CaptureError
        From :func:`result_folder`, before anything is written; or the write failed (a full
        disk: one line naming the capture and the file, nothing of this result left behind,
        an earlier result as it was).
    """
    folder = result_folder(Path(outdir), result.capture)
    partial, old = _hidden(folder, "partial"), _hidden(folder, "old")
    writing = [folder]  # what is being written, as the message names it
    try:
        clear_leftovers(folder)
        partial.mkdir(parents=True)
        _write_files(result, partial, folder, trace, writing)
        writing[0] = folder
        if os.path.lexists(folder):
            os.rename(folder, old)
        os.rename(partial, folder)
    except OSError as exc:
        shutil.rmtree(partial, ignore_errors=True)
        if not os.path.lexists(folder) and os.path.lexists(old):
            try:  # the earlier result stays as it was
                os.rename(old, folder)
            except OSError:
                pass
        raise CaptureError(f"capture '{printable(result.capture)}': result not written: "
                           f"{writing[0]}: {exc.strerror or exc}") from None
    if os.path.lexists(old):  # the result is in place; what is left of the old one can wait
        try:
            _carry_over(old, folder)
        except OSError:
            pass  # cleared by the next write of this capture
    return folder


def one_line(result: InspectionResult) -> str:
    """A progress/summary line for one result, in the headless language (:mod:`inspector.locale`:
    English unless ``inspector run --lang`` or ``$INSPECTOR_LANG`` chose another)."""
    name = printable(result.capture)  # one line whatever the capture's name holds
    if result.verdict == "error":
        return _("{name}: ERROR {error}").format(name=name, error=result.error)
    dev = ""
    d = result.summary.deviation_mm if result.summary is not None else None  # the evaluate contract
    if d is not None:
        dev = _("  deviation mean {mean} min {min} max {max} mm").format(
            mean=number(d.mean, "+.4f"), min=number(d.min, "+.4f"), max=number(d.max, "+.4f"))
    n = len(result.defects)
    defects = (_("  {n} defect") if n == 1 else _("  {n} defects")).format(n=n) if n else ""
    chars = result.stats.get("characteristics") if isinstance(result.stats, Mapping) else None
    nok = list(chars.get("nok_ids", ())) if isinstance(chars, Mapping) else []
    if nok:  # a part failed by a characteristic alone must not read "FAIL ... 0 defects"
        defects += (_("  {n} NOK characteristic ({ids})") if len(nok) == 1 else
                    _("  {n} NOK characteristics ({ids})")).format(n=len(nok), ids=", ".join(map(str, nok)))
    verdict = {"pass": _("PASS"), "fail": _("FAIL")}.get(result.verdict, result.verdict.upper())
    return f"{name}: {verdict}{dev}{defects}  ({number(result.timings_s.get('total', 0.0), '.2f')} s)"


# -- issue 16: result.json rewritten once the inspector_on_result hooks have run ---------------
def rewrite_result_json(result: InspectionResult, folder: Path) -> None:
    """Write ``folder/result.json`` again for ``result`` (its ``timings_s`` now holding the
    ``inspector_on_result`` hooks' time); the point files are not touched.

    If it cannot be written (a full disk), the result.json already there stays, whole, and
    a warning line names the capture and the file: the hooks' times are not worth the batch.
    """
    import sys

    doc = result_to_json(result, with_points=True)
    path = Path(folder) / RESULT_JSON
    try:
        _atomic_write(path, (json.dumps(doc, indent=2) + "\n").encode())
    except OSError as exc:
        print(f"inspector: warning: capture '{printable(result.capture)}': result.json kept without the hooks' "
              f"times: {path}: {exc.strerror or exc}", file=sys.stderr, flush=True)
