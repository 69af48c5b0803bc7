"""Result outputs (CONTRACT): ``result.json``, ``bcps_points.ply``, ``reconstruction.ply``
and, when the reconstruction has faces, ``reconstruction_mesh.ply``.

One folder per capture, ``OUTDIR/<capture name>/``. Files are written to a temporary name
and renamed, so a reader never sees half a file.

The PLY files are binary little-endian, with the element and property names and types
that plyfile writes (``element vertex`` then ``element face`` with ``property list uchar
int vertex_indices``). They are written directly, one header and one numpy structured
array per element (plyfile writes list properties row by row, far slower); any PLY reader
(plyfile, Open3D, trimesh) reads them.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import CaptureError
from inspector.model import InspectionResult
from inspector.names import check_name, printable

__all__ = ["write_result", "result_folder", "result_to_json", "write_ply", "ply_chunks", "read_ply", "one_line"]

BCPS_PLY = "bcps_points.ply"
RECON_PLY = "reconstruction.ply"
RECON_MESH_PLY = "reconstruction_mesh.ply"


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
        }
    )


def _atomic_write(path: Path, *chunks: bytes | memoryview) -> None:
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as f:
        for chunk in chunks:
            f.write(chunk)
    os.replace(tmp, path)


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
    out: list[bytes | memoryview] = [b"", memoryview(vert).cast("B")]
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
        out.append(memoryview(tri).cast("B"))
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


def write_result(result: InspectionResult, outdir: Path, *, trace: str | None = None) -> Path:
    """Write one capture's result folder, ``outdir/<capture>``, and return it.

    Raises
    ------
    CaptureError
        From :func:`result_folder`, before anything is written.
    """
    folder = result_folder(Path(outdir), result.capture)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in (BCPS_PLY, RECON_PLY, RECON_MESH_PLY, "traceback.txt"):
        (folder / stale).unlink(missing_ok=True)
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
            from inspector.kernels.bcps import confidence

            cols["confidence"] = confidence(b.segment_mm, result.rig.footprint_mm()).astype(np.float32)
        write_ply(folder / BCPS_PLY, cols)
    if result.reconstruction is not None:
        r = result.reconstruction
        write_ply(
            folder / RECON_PLY,
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
            write_ply(folder / RECON_MESH_PLY, {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, faces=r.faces)
    if trace:
        (folder / "traceback.txt").write_text(trace, encoding="utf-8")
    doc = result_to_json(result, with_points=True)
    _atomic_write(folder / "result.json", (json.dumps(doc, indent=2) + "\n").encode())
    return folder


def one_line(result: InspectionResult) -> str:
    """A progress/summary line for one result."""
    name = printable(result.capture)  # one line whatever the capture's name holds
    if result.verdict == "error":
        return f"{name}: ERROR {result.error}"
    s = result.stats
    dev = ""
    if "deviation_mm" in s:
        d = s["deviation_mm"]
        dev = f"  deviation mean {d['mean']:+.4f} min {d['min']:+.4f} max {d['max']:+.4f} mm"
    n = len(result.defects)
    defects = f"  {n} defect{'s' if n != 1 else ''}" if n else ""
    return f"{name}: {result.verdict.upper()}{dev}{defects}  ({result.timings_s.get('total', 0.0):.2f} s)"
