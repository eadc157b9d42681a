"""The JacobianEstimator protocol: online (or offline) estimate of J in Delta s ~ J Delta r."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class JacobianEstimator(Protocol):
    """Estimates the deformation Jacobian J (p x q) from (Delta s, Delta r) pairs."""

    @property
    def J(self) -> np.ndarray:
        """(p, q) current estimate."""
        ...

    def reset(self, J0: np.ndarray) -> None:
        """Start from the initial estimate J0 (p, q), e.g. from probing least squares."""
        ...

    def update(self, ds: np.ndarray, dr: np.ndarray) -> np.ndarray:
        """Fold in one measurement ds (p,) = s_k - s_{k-1} caused by dr (q,) = r_k - r_{k-1}.

        Returns the updated (p, q) estimate. A move inside the dead zone leaves J unchanged.
        """
        ...

    def info(self) -> dict[str, float]:
        """Scalar diagnostics for the log (e.g. adaptive factor, innovation statistic)."""
        ...


def checked_jacobian(J0: np.ndarray, p: int, q: int) -> np.ndarray:
    """A float64 copy of J0, which must have shape (p, q): what every `reset` starts from.

    Raises:
        ValueError: J0 has another shape.
    """
    J0 = np.array(J0, dtype=float)
    if J0.shape != (p, q):
        raise ValueError(f"J0 must have shape {(p, q)}, got {J0.shape}")
    return J0


#: The description every online estimator's `dead_zone` field shares.
DEAD_ZONE_DOC = (
    "Skip the update when ||dr|| (Euclidean, metres and radians mixed) is below this: a tiny "
    "move carries no information about J and would amplify feature noise."
)


class EstimatorDiverged(ArithmeticError):
    """An estimator's state left the finite numbers (a NaN or infinite J or covariance).

    The named failure an estimator raises instead of a numerical library's error: the closed
    loop ends the episode with it (outcome "error", this message), `rodctl estimate` ends that
    estimator's row with outcome "diverged" and keeps its errors up to the step before.
    """
