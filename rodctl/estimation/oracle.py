"""The oracle Jacobian: the simulator's true Jacobian of the current shape (NOT realisable).

Why: a benchmark needs a reference that separates "the Jacobian estimate was wrong" from "the
law or the task is hard". This estimator is told the true d s / d r at every step, by finite
differences of the simulator itself (`ShapeServoEnv.true_jacobian`): with the paper's law it
is the paper's law told the true Jacobian. It is not a ceiling: it skips the probing every
estimating method pays for, and other methods beat it on some targets. With `rod.engine:
quasistatic` the shape part is exact instead (the implicit-function theorem on the equilibrium,
one linear solve, no settles; docs/engines.md). No robot can run it (it moves a copy of the
world), so it is labelled as not realisable wherever it appears.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np

from rodctl.config.base import StrictModel
from rodctl.estimation.base import checked_jacobian
from rodctl.registry import ESTIMATORS, BuildContext


class OracleJacobian:
    """J_k = the simulator's Jacobian at the current shape, re-evaluated after every move."""

    def __init__(self, p: int, q: int, oracle: Callable[[], np.ndarray]) -> None:
        self.p, self.q = int(p), int(q)
        self._oracle = oracle
        self._J = np.zeros((self.p, self.q))

    @property
    def J(self) -> np.ndarray:
        return self._J.copy()

    def prepare(self, pixels: np.ndarray) -> np.ndarray:
        """The start hook: the true Jacobian at the start shape (no probing needed)."""
        self.reset(self._oracle())
        return self.J

    def reset(self, J0: np.ndarray) -> None:
        self._J = checked_jacobian(J0, self.p, self.q)

    def update(self, ds: np.ndarray, dr: np.ndarray) -> np.ndarray:
        """Ignore the measurement; the true Jacobian at the new shape."""
        self.reset(self._oracle())
        return self.J

    def info(self) -> dict[str, float]:
        return {}


class OracleEstimatorConfig(StrictModel):
    """The simulator's true Jacobian (finite differences of the simulator): a reference, NOT
    realisable on a real robot."""

    type: Literal["oracle"] = "oracle"


@ESTIMATORS.register(OracleEstimatorConfig)
def _build(cfg: OracleEstimatorConfig, ctx: BuildContext) -> OracleJacobian:
    if ctx.oracle is None:
        from rodctl.errors import UserError

        raise UserError("estimator.type=oracle needs the simulator (ShapeServoEnv)")
    return OracleJacobian(ctx.p, ctx.q, ctx.oracle)
