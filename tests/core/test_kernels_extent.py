"""The per-column box of point arrays."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels.extent import bounds_of


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64])
def test_bounds_are_numpys_column_minimum_and_maximum(dtype):
    rng = np.random.default_rng(3)
    P = (rng.normal(scale=50.0, size=(2500, 3)) * 7).astype(dtype)
    P[17] = [-1e6, 5, 2]
    lo, hi = bounds_of(P)
    assert lo.dtype == P.dtype and hi.dtype == P.dtype
    np.testing.assert_array_equal(lo, P.min(axis=0))
    np.testing.assert_array_equal(hi, P.max(axis=0))
    sub = P[::3]  # a strided view
    np.testing.assert_array_equal(bounds_of(sub)[1], sub.max(axis=0))


def test_no_points_have_no_bounds():
    with pytest.raises(ValueError):
        bounds_of(np.zeros((0, 3)))
