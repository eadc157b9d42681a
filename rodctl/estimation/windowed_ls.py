"""Sliding-window least-squares Jacobian: the alternative online estimator of the Ma baseline.

A re-implementation from published descriptions (docs/baselines.md), not the authors'
code. Assumptions we made:
- the window holds the last `window` informative pairs (moves outside the dead zone), all
  weighted equally;
- a ridge mu ||J - J_prev||^2 towards the previous estimate keeps the fit defined when the
  window's moves do not span all q axes, which is the usual case near convergence, where a
  controller keeps moving along one direction. Closed form:
  J = (dS^T dR + mu J_prev)(dR^T dR + mu I)^-1.
"""

from __future__ import annotations

from collections import deque
from typing import Any, Literal

import numpy as np
from pydantic import Field

from rodctl import fixedla as fla
from rodctl.config.base import StrictModel
from rodctl.estimation.base import DEAD_ZONE_DOC, checked_jacobian
from rodctl.registry import ESTIMATORS, BuildContext


class WindowedLsJacobian:
    """Least squares over the most recent `window` (dr, ds) pairs, ridge towards J_prev."""

    def __init__(self, p: int, q: int, **settings: Any) -> None:
        """Build the estimator at J = 0 until `reset`.

        Args:
            p: feature dimension.
            q: command dimension.
            **settings: fields of `WindowedLsEstimatorConfig` (window, ridge, dead_zone): its
                defaults and checks are the only ones. ridge = 0 falls back to plain least
                squares once the window spans all axes and keeps J_prev until then.
        """
        cfg = WindowedLsEstimatorConfig(**settings)
        self.p, self.q = int(p), int(q)
        self._window = int(cfg.window)
        self._ridge = float(cfg.ridge)
        self._dead_zone = float(cfg.dead_zone)
        self.reset(np.zeros((self.p, self.q)))

    @property
    def J(self) -> np.ndarray:
        """(p, q) current estimate (a copy)."""
        return self._J.copy()

    def reset(self, J0: np.ndarray) -> None:
        """Restart from J0 (p, q) with an empty window."""
        self._J = checked_jacobian(J0, self.p, self.q)
        self._dR: deque[np.ndarray] = deque(maxlen=self._window)
        self._dS: deque[np.ndarray] = deque(maxlen=self._window)
        self._info = {"skipped": 0.0, "window": 0.0}

    def update(self, ds: np.ndarray, dr: np.ndarray) -> np.ndarray:
        """Add the pair ds (p,), dr (q,) to the window and refit. Returns (p, q)."""
        dr = np.asarray(dr, dtype=float)
        ds = np.asarray(ds, dtype=float)
        if fla.norm(dr) < self._dead_zone:
            self._info = {"skipped": 1.0, "window": float(len(self._dR))}
            return self._J.copy()
        self._dR.append(dr.copy())
        self._dS.append(ds.copy())
        R = np.asarray(self._dR)  # (w, q)
        S = np.asarray(self._dS)  # (w, p)
        # Fixed-order arithmetic (rodctl.fixedla), not BLAS/LAPACK: the same bits everywhere.
        A = fla.matmul(R.T, R) + self._ridge * np.eye(self.q)  # (q, q)
        B = fla.matmul(S.T, R) + self._ridge * self._J  # (p, q)
        if self._ridge > 0.0 or _full_rank(A):
            sol = fla.spd_solve(A, np.ascontiguousarray(B.T))
            if sol is not None:
                self._J = sol.T
        self._info = {"skipped": 0.0, "window": float(len(self._dR))}
        return self._J.copy()

    def info(self) -> dict[str, float]:
        """skipped (1.0 in the dead zone) and the number of pairs in the window."""
        return dict(self._info)


def _full_rank(a: np.ndarray) -> bool:
    """Whether the Gram matrix dR^T dR has full rank: every eigenvalue above 64 q eps times the
    largest (rounding leaves about eps * lambda_max where the moves have no extent).
    """
    w, _ = fla.eigh_small(a, vectors=False)
    top = float(w[-1])
    return top > 0.0 and float(w[0]) > top * 64 * a.shape[0] * np.finfo(float).eps


# --- config and registration ------------------------------------------------------------


class WindowedLsEstimatorConfig(StrictModel):
    """Least squares over the last `window` (dr, ds) pairs (docs/baselines.md).

    The alternative online estimator of the Ma et al. 2022 baseline (our re-implementation).
    """

    type: Literal["windowed_ls"] = "windowed_ls"
    window: int = Field(
        10, le=10_000, ge=1, description="Number of most recent informative pairs fitted."
    )
    ridge: float = Field(
        1e-6,
        le=1e6,
        ge=0.0,
        description="Weight mu of mu ||J - J_prev||^2 in the fit (m^2): a pseudo-move of "
        "sqrt(mu) per axis that keeps the fit defined when the window's moves are collinear.",
    )
    dead_zone: float = Field(1e-4, le=1.0, ge=0.0, description=DEAD_ZONE_DOC)


@ESTIMATORS.register(WindowedLsEstimatorConfig)
def _build(cfg: WindowedLsEstimatorConfig, ctx: BuildContext) -> WindowedLsJacobian:
    return WindowedLsJacobian(ctx.p, ctx.q, **cfg.model_dump(exclude={"type"}))
