"""Polyline helpers shared by the simulator, the vision front end, the ASAP model and the logs.

One implementation of arc-length resampling, so that "point i of the centerline" means the same
thing to every stage that produces or compares centerlines.
"""

from __future__ import annotations

import numpy as np


def polyline_length(points: np.ndarray) -> float:
    """Total length of a (M, 2) polyline."""
    return float(np.hypot(*np.diff(np.asarray(points, dtype=np.float64), axis=0).T).sum())


def resample_polyline(points: np.ndarray, n: int) -> np.ndarray:
    """`n` points equally spaced in arc length along a polyline, both ends kept.

    A polyline of zero length (all points equal) gives `n` copies of its point.

    Args:
        points: (M, 2) ordered points, M >= 2.
        n: number of output points, n >= 2.

    Returns:
        (n, 2) float64 points.

    Raises:
        ValueError: `points` is not (M >= 2, 2) or n < 2.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2:
        raise ValueError(f"points must be (M >= 2, 2), got {pts.shape}")
    if n < 2:
        raise ValueError(f"need n >= 2 points, got {n}")
    seg = np.hypot(*np.diff(pts, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0.0:
        return np.repeat(pts[:1], n, axis=0)
    q = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(q, s, pts[:, 0]), np.interp(q, s, pts[:, 1])])
