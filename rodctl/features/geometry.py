"""Centerline checks and arc-length resampling shared by the geometric feature maps.

The extractor hands over N ordered pixel points, clamp end first. The Bézier, Fourier and node
features are defined as functions of the *normalised arc length* rho in [0, 1] (docs/baselines.md,
Ma et al.: "a parametric curve in normalised arc length"), so every map first resamples
the polyline to N points equally spaced in arc length. After that the least-squares fit is one
fixed (K, N) matrix product: the fit's pseudo-inverse is computed once, which keeps `encode` to a
few microseconds and makes it exactly linear in the resampled points.
"""

from __future__ import annotations

import numpy as np


def check_centerlines(centerlines_px: np.ndarray, points: int, *, batch: bool) -> np.ndarray:
    """Validate and convert centerlines to float64.

    Args:
        centerlines_px: (N, 2) one centerline, or (B, N, 2) when `batch` is True; pixels.
        points: the expected N.
        batch: whether a leading batch axis is expected.

    Returns:
        (B, N, 2) float64 array (B = 1 when `batch` is False).

    Raises:
        ValueError: wrong shape or non-finite values.
    """
    arr = np.asarray(centerlines_px, dtype=np.float64)
    want = "(B, N, 2)" if batch else "(N, 2)"
    ndim = 3 if batch else 2
    if arr.ndim != ndim or arr.shape[-2:] != (points, 2):
        raise ValueError(f"expected centerline(s) of shape {want} with N={points}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("centerline contains NaN or infinite values")
    return arr if batch else arr[None]


def arclength_parameter(centerlines: np.ndarray) -> np.ndarray:
    """Normalised cumulative chord length of each polyline.

    Args:
        centerlines: (B, N, 2) points.

    Returns:
        (B, N) rho, 0 at the first point and 1 at the last.

    Raises:
        ValueError: a polyline of zero length.
    """
    seg = np.linalg.norm(np.diff(centerlines, axis=1), axis=2)  # (B, N-1)
    cum = np.concatenate([np.zeros((seg.shape[0], 1)), np.cumsum(seg, axis=1)], axis=1)
    total = cum[:, -1:]
    if np.any(total <= 0.0):
        raise ValueError("centerline has zero length (all points coincide)")
    return cum / total


def resample_uniform(centerlines: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Points at the given normalised arc lengths, by linear interpolation along each polyline.

    Args:
        centerlines: (B, N, 2) ordered points.
        rho: (M,) target normalised arc lengths in [0, 1].

    Returns:
        (B, M, 2) the resampled points.
    """
    t = arclength_parameter(centerlines)
    out = np.empty((centerlines.shape[0], rho.shape[0], 2))
    for b in range(centerlines.shape[0]):
        out[b, :, 0] = np.interp(rho, t[b], centerlines[b, :, 0])
        out[b, :, 1] = np.interp(rho, t[b], centerlines[b, :, 1])
    return out
