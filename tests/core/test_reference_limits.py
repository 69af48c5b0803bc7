"""Reference meshes above a size are refused in one line, before they are parsed when the
file says how big it is (issue 15: a 5.24M-triangle reference took 8.9 GB and 233 s, unwarned).

Real files: sparse binary STLs and PLYs whose headers declare millions of triangles (no disk
used), and small real meshes under a lowered bound.
"""

from __future__ import annotations

import struct
import tracemalloc
from pathlib import Path

import pytest

from inspector.errors import ReferenceMeshError
from inspector.limits import MAX_REFERENCE_BYTES, MAX_REFERENCE_TRIANGLES
from inspector.parts import load_reference


def _sparse(path: Path, head: bytes, size: int) -> Path:
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def _refusal(path: Path) -> str:
    # Nothing parsed: a parse of millions of facets allocates hundreds of MB (numpy registers
    # its buffers with tracemalloc); counting them in bounded memory stays far below 64 MB.
    tracemalloc.start()
    try:
        with pytest.raises(ReferenceMeshError) as e:
            load_reference(str(path))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20, f"{peak / 2**20:.0f} MB allocated while refusing {path}"
    assert "\n" not in str(e.value)
    return str(e.value)


def test_a_binary_stl_declaring_millions_of_triangles_is_refused_before_parsing(tmp_path):
    n = 5_240_000
    stl = _sparse(tmp_path / "big.stl", b"solid-ish binary header".ljust(80) + struct.pack("<I", n), 84 + 50 * n)
    assert _refusal(stl) == (f"reference mesh {stl}: {n} triangles, more than the {MAX_REFERENCE_TRIANGLES} a reference "
                             "mesh may have (INSPECTOR_MAX_REFERENCE_TRIANGLES; decimate the mesh, or raise the bound)")


def test_a_ply_declaring_millions_of_faces_is_refused_before_parsing(tmp_path):
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 2620002\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 5240000\nproperty list uchar int vertex_indices\nend_header\n")
    ply = _sparse(tmp_path / "big.ply", head, 100 << 20)
    assert _refusal(ply).startswith(f"reference mesh {ply}: 5240000 triangles, more than the {MAX_REFERENCE_TRIANGLES}")


def test_a_file_larger_than_the_bound_is_refused_before_it_is_read(tmp_path):
    obj = _sparse(tmp_path / "huge.obj", b"v 0 0 0\n", MAX_REFERENCE_BYTES + 1)
    assert _refusal(obj) == (f"reference mesh {obj}: {MAX_REFERENCE_BYTES + 1} bytes, more than the {MAX_REFERENCE_BYTES} "
                             "a reference mesh may have (INSPECTOR_MAX_REFERENCE_BYTES; decimate the mesh, or raise the bound)")


@pytest.mark.parametrize("suffix", ["stl", "ply", "obj"])
def test_every_format_is_counted_and_the_bound_is_overridable(tmp_path, monkeypatch, suffix):
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=10.0)  # 1280 triangles
    path = tmp_path / f"sphere.{suffix}"
    mesh.export(str(path))
    monkeypatch.setenv("INSPECTOR_MAX_REFERENCE_TRIANGLES", "1000")
    assert _refusal(path).startswith(f"reference mesh {path}: 1280 triangles, more than the 1000 a reference mesh may have")
    monkeypatch.setenv("INSPECTOR_MAX_REFERENCE_TRIANGLES", "1280")
    assert len(load_reference(str(path)).faces) == 1280


def test_run_with_a_huge_reference_is_a_command_error_in_one_line(tmp_path, capsys):
    from inspector_frontends.cli import main

    n = 3_000_000
    stl = _sparse(tmp_path / "big.stl", bytes(80) + struct.pack("<I", n), 84 + 50 * n)
    recipe = Path(__file__).resolve().parents[2] / "recipes" / "default.toml"
    assert main(["run", str(recipe), "--capture", str(tmp_path), "--out", str(tmp_path / "out"), "--reference", str(stl)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"inspector: error: reference mesh {stl}: {n} triangles, more than the {MAX_REFERENCE_TRIANGLES} a "
                   "reference mesh may have (INSPECTOR_MAX_REFERENCE_TRIANGLES; decimate the mesh, or raise the bound)"]
    assert not (tmp_path / "out").exists()


def test_an_obj_with_millions_of_faces_is_counted_before_it_is_parsed(tmp_path):
    """Issue 27 finding 5: a 60 M-face OBJ was parsed (9.3 GB, 128 s) before it was counted."""
    n = MAX_REFERENCE_TRIANGLES + 5
    obj = tmp_path / "many.obj"
    obj.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * n)
    assert _refusal(obj).startswith(f"reference mesh {obj}: {n} triangles, more than the {MAX_REFERENCE_TRIANGLES}")


def test_an_ascii_stl_with_millions_of_facets_is_counted_before_it_is_parsed(tmp_path):
    facet = b"facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 1 0\n endloop\nendfacet\n"
    stl = tmp_path / "many.stl"
    with open(stl, "wb") as f:
        f.write(b"solid many\n")
        for _ in range((MAX_REFERENCE_TRIANGLES + 5) // 10000 + 1):
            f.write(facet * 10000)
        f.write(b"endsolid many\n")
    assert "triangles, more than the" in _refusal(stl)


def test_a_binary_stl_with_one_byte_too_many_is_refused_not_parsed_as_ascii(tmp_path):
    """Issue 27 finding 5: parsed as ASCII it took 1.8 GB to say "no triangles"."""
    import trimesh

    good = tmp_path / "sphere.stl"
    trimesh.creation.icosphere(subdivisions=2, radius=10.0).export(str(good))
    bad = tmp_path / "padded.stl"
    bad.write_bytes(good.read_bytes() + b"\0")
    size = bad.stat().st_size
    assert _refusal(bad) == (f"reference mesh {bad}: a binary STL declaring 320 triangles ({size - 1} bytes) but the file "
                             f"has {size} bytes (truncated or padded: export it again)")
    assert len(load_reference(str(good)).faces) == 320
