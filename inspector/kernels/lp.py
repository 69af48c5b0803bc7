"""Small linear programmes, solved by HiGHS through its own Python binding (``highspy``).

The minimum-zone form characteristics (flatness, roundness, cylindricity) solve linear
programmes of a few hundred rows and a few columns, several per part. SciPy's ``linprog``
wraps the same solver but builds a new one, runs presolve and checks its options on every
call: about 4.5 ms of CPU for a 513 x 7 programme, against 1.1 ms for the same solve on a
solver kept per thread with presolve off and the primal simplex (measured; the solve itself
takes a dozen simplex iterations). At 20 characteristics a part that difference is most of
what the form characteristics cost, hence this module instead of ``linprog``.
"""

from __future__ import annotations

import threading
from typing import Any

import highspy
import numpy as np

__all__ = ["LPError", "minimize_free"]


class LPError(RuntimeError):
    """The solver found no optimum (infeasible, unbounded, or it failed)."""


_LOCAL = threading.local()


def _solver() -> highspy.Highs:
    h = getattr(_LOCAL, "highs", None)
    if h is None:
        h = highspy.Highs()
        h.setOptionValue("output_flag", False)
        # Presolve costs more than it saves on a programme of a few hundred rows; these
        # programmes have many more rows than columns, where the primal simplex (strategy 4)
        # needs fewer iterations than the dual (measured: 1.1 ms against 1.9 ms a solve), and
        # fewer again on the dualised programme (zone programmes of 80-1200 rows: 24 against
        # 35 iterations, 42 against 23; 9.4 ms against 14.3 ms for four of them).
        h.setOptionValue("presolve", "off")
        h.setOptionValue("simplex_strategy", 4)
        h.setOptionValue("simplex_dualize_strategy", 1)
        h.setOptionValue("threads", 1)
        _LOCAL.highs = h
    return h


def minimize_free(cost: np.ndarray, A_ub: Any, b_ub: np.ndarray) -> np.ndarray:
    """``argmin cost @ x`` subject to ``A_ub @ x <= b_ub``, every variable free.

    Parameters
    ----------
    cost : (n,) float
    A_ub : (m, n) float, dense or a scipy.sparse matrix or array
    b_ub : (m,) float

    Returns
    -------
    (n,) float
        An optimal ``x``.

    Raises
    ------
    LPError
        No optimum (the message is the solver's status).
    """
    c = np.ascontiguousarray(cost, dtype=np.float64)
    b = np.ascontiguousarray(b_ub, dtype=np.float64)
    start, index, value, (m, n) = _columns(A_ub)
    if c.shape != (n,) or b.shape != (m,):
        raise ValueError(f"cost must be ({n},) and b_ub ({m},), got {c.shape} and {b.shape}")
    inf = highspy.kHighsInf
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = n, m
    lp.col_cost_ = c
    lp.col_lower_ = np.full(n, -inf)
    lp.col_upper_ = np.full(n, inf)
    lp.row_lower_ = np.full(m, -inf)
    lp.row_upper_ = b
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = start
    lp.a_matrix_.index_ = index
    lp.a_matrix_.value_ = value
    h = _solver()
    h.clearSolver()
    h.passModel(lp)
    h.run()
    status = h.getModelStatus()
    if status != highspy.HighsModelStatus.kOptimal:
        raise LPError(h.modelStatusToString(status))
    return np.asarray(h.getSolution().col_value, dtype=np.float64)


def _columns(A: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """Column-wise compressed (start, row index, value) of ``A`` and its shape. A dense matrix
    is compressed with numpy: scipy.sparse's conversion costs ten times more on these sizes
    (and importing scipy.sparse here would cost 0.2 s wherever fits are loaded); a sparse one
    is recognised by its ``tocsc``."""
    if hasattr(A, "tocsc"):
        S = A.tocsc()
        return S.indptr, S.indices, S.data.astype(np.float64, copy=False), S.shape
    D = np.asarray(A, dtype=np.float64)
    if D.ndim != 2:
        raise ValueError(f"A_ub must be 2-D, got {D.shape}")
    At = D.T  # a column of A is a row of At: nonzero() walks them in order
    nz = At != 0
    col, row = np.nonzero(nz)
    start = np.zeros(D.shape[1] + 1, dtype=np.int32)
    np.cumsum(np.bincount(col, minlength=D.shape[1]), out=start[1:])
    return start, row.astype(np.int32), At[nz], D.shape
