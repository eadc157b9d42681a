"""Bézier-curve feature for the Ma et al. 2022 baseline (method-notes section 4).

Ma et al. describe their shape feature as the coefficients of a parametric curve fitted to the
visual points by regression ("optimization-based shape perception"); the full text is not at hand,
so this is our reading: a degree-d Bézier curve in normalised arc length, control points by least
squares. Bernstein polynomials span the same space as monomials of degree d, but their
coefficients are points in the image (the first control point is the clamp end, the last the
gripper end), so the feature has pixel units and a geometric meaning, and the fit is well
conditioned for the small degrees used here.

Truncation error (measured, `tests/features/test_geometric_maps.py`): on rod-like planar curves
of 300 px length whose tangent turns by up to pi and reverses curvature once (S shapes), the mean
reconstruction error is below 0.25 px for d = 4 and the maximum below 1.5 px; the error falls as d
rises.
"""

from __future__ import annotations

import numpy as np
from scipy.special import comb

from rodctl.features.linear import LinearBasisFeatureMap


def bernstein_basis(degree: int, rho: np.ndarray) -> np.ndarray:
    """Bernstein polynomials B_{k,d}(rho) = C(d, k) rho^k (1 - rho)^(d - k).

    Args:
        degree: d.
        rho: (N,) parameters in [0, 1].

    Returns:
        (N, d + 1) basis matrix.
    """
    k = np.arange(degree + 1)
    return comb(degree, k)[None, :] * rho[:, None] ** k * (1.0 - rho[:, None]) ** (degree - k)


class BezierFeatureMap(LinearBasisFeatureMap):
    """s = the d + 1 least-squares Bézier control points, flattened [u0, v0, u1, v1, ...] (px).

    Args:
        degree: curve degree d; p = 2(d + 1).
        points: centerline points N.
    """

    kind = "bezier"

    def __init__(self, degree: int, points: int) -> None:
        if points < degree + 1:
            raise ValueError(f"a degree-{degree} fit needs at least {degree + 1} points")
        self.degree = degree
        super().__init__(bernstein_basis(degree, np.linspace(0.0, 1.0, points)))
