"""The axis-aligned box of a point array, per column.

numpy reduces an (N, 3) array over its rows one row at a time (its inner loop is the three
columns): ``points.min(axis=0)`` on the 26 000 hull points of a 1 MP inspection takes
0.7 ms, the same minimum over a transposed copy 0.05 ms. The boxes of the hull, its cells and
its rays are taken several times an inspection, on one core.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bounds_of"]


def bounds_of(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest value of each column of ``points`` (N, D), any real dtype:
    ``(points.min(axis=0), points.max(axis=0))``, the same numbers. ValueError when N = 0."""
    cols = np.ascontiguousarray(np.asarray(points).T)
    return cols.min(axis=1), cols.max(axis=1)
