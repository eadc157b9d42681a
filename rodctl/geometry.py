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
    d = pts[1:] - pts[:-1]
    s = np.empty(len(pts))
    s[0] = 0.0
    np.cumsum(np.hypot(d[:, 0], d[:, 1]), out=s[1:])
    total = float(s[-1])
    if total <= 0.0:
        return np.repeat(pts[:1], n, axis=0)
    q = linspace_from_zero(total, n)
    out = np.empty((n, 2))
    out[:, 0] = np.interp(q, s, pts[:, 0])
    out[:, 1] = np.interp(q, s, pts[:, 1])
    return out


#: np.arange(n, dtype=float) for the last few n (`linspace_from_zero`); do not modify.
_ARANGES: dict[int, np.ndarray] = {}


def linspace_from_zero(stop: float, n: int) -> np.ndarray:
    """``np.linspace(0.0, stop, n)`` bit for bit (numpy's own steps: arange(n) times
    stop / (n - 1), the last value set to `stop`), without its per-call overhead."""
    step = stop / (n - 1)
    if step == 0.0:  # numpy's branch for subnormal steps
        return np.linspace(0.0, stop, n)
    ramp = _ARANGES.get(n)
    if ramp is None:
        if len(_ARANGES) >= 16:
            _ARANGES.clear()
        ramp = _ARANGES[n] = np.arange(n, dtype=np.float64)
    q = ramp * step
    q[-1] = stop
    return q
