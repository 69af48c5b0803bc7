"""Robust weights shared by the fits on BCPS points (pose re-fit, size prior)."""

from __future__ import annotations

import numpy as np


def tukey(r: np.ndarray, c: np.ndarray | float) -> np.ndarray:
    """Tukey biweight of residuals ``r`` at cut-off ``c`` (same units, broadcastable).

    ``(1 - (r/c)^2)^2`` inside the cut-off, 0 beyond it: points farther than ``c`` from
    the model do not pull it at all (a defect does not drag the fit onto itself).
    """
    u = r / c
    return np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)


def tukey_loss(r: np.ndarray, c: np.ndarray | float) -> np.ndarray:
    """Tukey's loss of residuals ``r`` at cut-off ``c``, scaled to [0, 1]: ``1 - (1 - (r/c)^2)^3``
    inside the cut-off, 1 beyond it (the loss whose weight is :func:`tukey`)."""
    u = np.minimum(np.abs(r / c), 1.0)
    return 1.0 - (1.0 - u * u) ** 3
