"""Small linear programmes through highspy, against SciPy's linprog (the same solver behind
its own wrapper)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.optimize import linprog

from inspector.kernels import lp


def _zone_programme(rng, n=300):
    # the minimum zone of noisy line heights: min U - L, L <= y_i - a x_i - b <= U
    x = rng.uniform(-10, 10, n)
    y = 0.3 * x + 2.0 + rng.uniform(-0.05, 0.05, n)
    G = np.column_stack([x, np.ones(n)])
    A = np.block([[-G, -np.ones((n, 1)), np.zeros((n, 1))], [G, np.zeros((n, 1)), np.ones((n, 1))]])
    return np.array([0.0, 0.0, 1.0, -1.0]), A, np.r_[-y, y]


def test_minimize_free_matches_linprog_dense_and_sparse():
    cost, A, b = _zone_programme(np.random.default_rng(5))
    ref = linprog(cost, A_ub=A, b_ub=b, bounds=[(None, None)] * 4, method="highs")
    assert ref.status == 0
    for mat in (A, sparse.csr_array(A)):
        x = lp.minimize_free(cost, mat, b)
        assert cost @ x == pytest.approx(ref.fun, abs=1e-10)
        assert (A @ x <= b + 1e-9).all()
    assert 0.09 < cost @ x <= 0.1  # the noise's width, at most


def test_minimize_free_says_why_it_has_no_optimum():
    with pytest.raises(lp.LPError):  # x <= -1 and -x <= -1 (x >= 1): infeasible
        lp.minimize_free(np.array([1.0]), np.array([[1.0], [-1.0]]), np.array([-1.0, -1.0]))
    with pytest.raises(lp.LPError):  # min x, x <= 1: unbounded below
        lp.minimize_free(np.array([1.0]), np.array([[1.0]]), np.array([1.0]))
    with pytest.raises(ValueError):
        lp.minimize_free(np.array([1.0, 2.0]), np.array([[1.0]]), np.array([1.0]))
