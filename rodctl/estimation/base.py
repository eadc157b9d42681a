"""The JacobianEstimator protocol: online (or offline) estimate of J in Delta s ~ J Delta r."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


class JacobianEstimator(Protocol):
    """Estimates the deformation Jacobian J (p x q) from (Delta s, Delta r) pairs.

    The optional hooks a method reads are declared on `PreparingEstimator` (`prepare`: J from
    the first frame, no probing) and `ObservingEstimator` (`observe`: the state before each
    update).
    """

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
        """Scalar diagnostics for the log (e.g. adaptive factor, innovation statistic).

        Called for every step's record from the first frame on, so also before `reset`
        (during the probing moves that give J0): return {} (or the initial values) then."""
        ...


@runtime_checkable
class PreparingEstimator(Protocol):
    """An estimator with the start hook `prepare` (the offline ASAP model, the learned model,
    the oracle): it builds J from the first frame, so the online probing is skipped."""

    def prepare(self, pixels: np.ndarray) -> np.ndarray | None:
        """The (p, q) Jacobian from the first extracted centerline (N, 2) pixels, or None when
        there is no model to build (then the method probes as for an online estimator)."""
        ...


@runtime_checkable
class ObservingEstimator(Protocol):
    """An estimator with the hook `observe`: a state-dependent model (the learned one) is told
    the state after each move, before `update` folds in the move's (Delta s, Delta r)."""

    def observe(self, pixels: np.ndarray, gripper: np.ndarray) -> None:
        """The new state: its centerline (N, 2) pixels and the gripper pose (q,)."""
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
