"""Bézier-curve feature for the Ma et al. 2022 baseline (docs/baselines.md).

Ma et al. describe their shape feature as the coefficients of a parametric curve fitted to the
visual points by regression ("optimization-based shape perception"); the full text is not at hand,
so this is our reading: a degree-d Bézier curve in normalised arc length, control points by least
squares. Bernstein polynomials span the same space as monomials of degree d, but their
coefficients are points in the image (the first control point is the clamp end, the last the
gripper end), so the feature has pixel units and a geometric meaning, and the fit is well
conditioned for the small degrees used here.

Truncation error (stated bounds, checked by `tests/features/test_geometric_maps.py` on the
synthetic rod family of `rodctl.features.synthetic`: 300 px curves, C and S shapes whose tip turns
by up to about 5 rad): d = 4 reconstructs with a mean error <= 0.3 px and a worst point <= 10 px
(the most extreme S shapes); d = 6 with <= 0.03 px mean and <= 1.5 px worst. The error falls
monotonically with d.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from rodctl.config.base import StrictModel
from rodctl.features.base import build_checked
from rodctl.features.linear import LinearBasisFeatureMap
from rodctl.registry import FEATURES, BuildContext


def bernstein_basis(degree: int, rho: np.ndarray) -> np.ndarray:
    """Bernstein polynomials B_{k,d}(rho) = C(d, k) rho^k (1 - rho)^(d - k).

    Args:
        degree: d.
        rho: (N,) parameters in [0, 1].

    Returns:
        (N, d + 1) basis matrix.
    """
    k = np.arange(degree + 1)
    binom = np.array([math.comb(degree, i) for i in range(degree + 1)], dtype=np.float64)
    return binom[None, :] * rho[:, None] ** k * (1.0 - rho[:, None]) ** (degree - k)


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


# --- config and registration ------------------------------------------------------------


class BezierFeatureConfig(StrictModel):
    """Least-squares Bézier control points in normalised arc length (the Ma et al. baseline)."""

    type: Literal["bezier"] = "bezier"
    degree: int = Field(
        4, ge=1, le=12, description="Curve degree d; the feature has 2(d+1) components."
    )


@FEATURES.register(BezierFeatureConfig)
def _build(cfg: BezierFeatureConfig, ctx: BuildContext) -> BezierFeatureMap:
    return build_checked(cfg.type, ctx.points, lambda: BezierFeatureMap(cfg.degree, ctx.points))
