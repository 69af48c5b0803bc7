from __future__ import annotations

import numpy as np

from inspector.kernels.robust import tukey


def test_tukey_is_one_at_zero_falls_smoothly_and_ignores_points_beyond_the_cutoff():
    r = np.array([0.0, 0.05, -0.05, 0.1, 0.2, -3.0])
    w = tukey(r, 0.1)
    np.testing.assert_allclose(w, [1.0, 0.5625, 0.5625, 0.0, 0.0, 0.0])


def test_tukey_broadcasts_one_cutoff_per_row():
    r = np.array([[0.5, 1.5], [0.5, 1.5]])
    w = tukey(r, np.array([[1.0], [2.0]]))
    np.testing.assert_allclose(w, [[0.5625, 0.0], [(1 - 0.0625) ** 2, (1 - 0.5625) ** 2]])
