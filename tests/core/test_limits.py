"""inspector.limits: reading a file never past its bound."""

from __future__ import annotations

import os

import pytest

from inspector import limits
from inspector.errors import InputError


def _file(tmp_path, n: int):
    p = tmp_path / "f.bin"
    p.write_bytes(bytes(range(256)) * (n // 256) + bytes(n % 256))
    return p


@pytest.mark.parametrize("n", [0, 1, 1000, 4096])
def test_read_bounded_reads_the_whole_file_within_its_bound(tmp_path, n):
    p = _file(tmp_path, n)
    assert limits.read_bounded(p, "f.bin", 4096) == p.read_bytes()


def test_read_bounded_refuses_a_file_over_its_bound_naming_it(tmp_path):
    p = _file(tmp_path, 4097)
    with pytest.raises(InputError, match=r"^f\.bin: 4097 bytes, more than the 4096 a test file may have \(VAR\)$"):
        limits.read_bounded(p, "f.bin", 4096, what="a test file", variable="VAR")


@pytest.mark.parametrize(("real", "told", "most", "grows_past"), [
    (3000, 1000, 4096, False),  # grew after it was measured, still within the bound: read whole
    (4096, 10, 4096, False),
    (5000, 1000, 4096, True),  # grew past the bound while read: refused
    (4097, 4096, 4096, True),
])
def test_a_file_that_grows_while_it_is_read_is_read_whole_or_refused(tmp_path, monkeypatch, real, told, most,
                                                                     grows_past):
    """fstat reports ``told`` bytes, the file holds ``real`` (it grew in between)."""
    p = _file(tmp_path, real)
    true_fstat = os.fstat

    class Smaller:
        def __init__(self, st):
            self._st = st

        def __getattr__(self, name):
            return told if name == "st_size" else getattr(self._st, name)

    monkeypatch.setattr(limits.os, "fstat", lambda fd: Smaller(true_fstat(fd)))
    if grows_past:
        with pytest.raises(InputError, match=rf"^f\.bin: {most + 1} bytes, more than the {most} "):
            limits.read_bounded(p, "f.bin", most)
    else:
        assert limits.read_bounded(p, "f.bin", most) == p.read_bytes()
