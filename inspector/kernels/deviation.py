"""Tolerance kernels: per-point bands, and clusters of out-of-tolerance points."""

from __future__ import annotations

import numpy as np

__all__ = ["cluster_points", "deviation_stats"]


def cluster_points(points: np.ndarray, radius_mm: float) -> np.ndarray:
    """Connected components of points closer than ``radius_mm`` (single linkage).

    Parameters
    ----------
    points : (N, 3) float
        mm.

    Returns
    -------
    (N,) int
        Cluster label per point, 0..K-1.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(points).query_pairs(radius_mm, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels


def deviation_stats(dev: np.ndarray) -> dict[str, float]:
    """Summary of signed deviations (mm): mean, std, min, max, p01, p99, mean |d|."""
    if dev.size == 0:
        return {}
    return {
        "mean": float(dev.mean()),
        "std": float(dev.std()),
        "min": float(dev.min()),
        "max": float(dev.max()),
        "p01": float(np.percentile(dev, 1)),
        "p99": float(np.percentile(dev, 99)),
        "mean_abs": float(np.abs(dev).mean()),
    }
