"""Broyden rank-1 Jacobian update: the online estimator of our Ma et al. 2022 baseline.

A re-implementation from published descriptions (docs/baselines.md
section 6.2), not the authors' code. Assumptions we made, since the sources do not pin them:
- the plain ("good") Broyden secant update J += gamma (ds - J dr) dr^T / (dr^T dr), no
  forgetting-factor RLS variant and no reset rules;
- a dead zone on ||dr|| (Euclidean over metres and radians) skips uninformative moves;
- J_0 from the same probing least squares as every other online method.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field

from rodctl import fixedla as fla
from rodctl.config.base import StrictModel
from rodctl.estimation.base import DEAD_ZONE_DOC, checked_jacobian
from rodctl.registry import ESTIMATORS, BuildContext


class BroydenJacobian:
    """Rank-1 secant update of J (p, q).

    After an update with gamma = 1 the estimate reproduces the last pair exactly (J dr = ds) and
    is unchanged on directions orthogonal to dr, so q independent moves recover a constant J.
    """

    def __init__(self, p: int, q: int, **settings: Any) -> None:
        """Build the estimator at J = 0 until `reset`.

        Args:
            p: feature dimension.
            q: command dimension.
            **settings: fields of `BroydenEstimatorConfig` (gamma, dead_zone): its defaults
                and checks are the only ones.
        """
        cfg = BroydenEstimatorConfig(**settings)
        self.p, self.q = int(p), int(q)
        self._gamma = float(cfg.gamma)
        self._dead_zone = float(cfg.dead_zone)
        self.reset(np.zeros((self.p, self.q)))

    @property
    def J(self) -> np.ndarray:
        """(p, q) current estimate (a copy)."""
        return self._J.copy()

    def reset(self, J0: np.ndarray) -> None:
        """Restart from J0 (p, q)."""
        self._J = checked_jacobian(J0, self.p, self.q)
        self._info = {"skipped": 0.0, "residual": 0.0}

    def update(self, ds: np.ndarray, dr: np.ndarray) -> np.ndarray:
        """J += gamma (ds - J dr) dr^T / (dr^T dr); ds (p,), dr (q,). Returns (p, q)."""
        dr = np.asarray(dr, dtype=float)
        ds = np.asarray(ds, dtype=float)
        nn = fla.dot(dr, dr)  # fixed-order sums (rodctl.fixedla): no BLAS kernel in the loop
        if np.sqrt(nn) < self._dead_zone:
            self._info = {"skipped": 1.0, "residual": 0.0}
            return self._J.copy()
        resid = ds - fla.matvec(self._J, dr)
        self._J = self._J + (self._gamma / nn) * np.outer(resid, dr)
        self._info = {"skipped": 0.0, "residual": fla.norm(resid)}
        return self._J.copy()

    def info(self) -> dict[str, float]:
        """skipped (1.0 in the dead zone) and residual ||ds - J dr|| before the update."""
        return dict(self._info)


# --- config and registration ------------------------------------------------------------


class BroydenEstimatorConfig(StrictModel):
    """Rank-1 Broyden update J += gamma (ds - J dr) dr^T / (dr^T dr) (docs/baselines.md).

    Part of our re-implementation of the Ma et al. 2022 baseline from its published description.
    """

    type: Literal["broyden"] = "broyden"
    gamma: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description="Step size gamma in (0, 1]; 1 makes each update satisfy the secant exactly.",
    )
    dead_zone: float = Field(1e-4, le=1.0, ge=0.0, description=DEAD_ZONE_DOC)


@ESTIMATORS.register(BroydenEstimatorConfig)
def _build(cfg: BroydenEstimatorConfig, ctx: BuildContext) -> BroydenJacobian:
    return BroydenJacobian(ctx.p, ctx.q, **cfg.model_dump(exclude={"type"}))
