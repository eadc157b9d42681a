"""The Aghajanzadeh et al. 2022 baseline law: a box-constrained least-squares step (a small QP).

A re-implementation from published descriptions (docs/baselines.md
section 2.3), not the authors' code: the "optimal deformation control" paper was not available,
so the step is our reconstruction

    min_u 1/2 ||J u - lambda e||^2 + 1/2 u^T R u   s.t.   -max_step <= u <= max_step,

with e = s* - s, R = diag(r_weights) and the loop's per-axis speed limits as bounds.
Assumptions: a diagonal R, box bounds only (no workspace or stretch constraints), the bounds
equal to the loop's saturation, so the loop's saturation never bites on this law.

With q = 3 the QP is solved exactly by enumerating the 3^q active sets (each axis at its lower
bound, free, or at its upper bound): the objective is strictly convex, so exactly one set
satisfies the KKT conditions and its solution is the unique minimiser. No iterative solver, no
tolerance to tune, at most 27 solves of at most 3 x 3 (q = 6, both ends moved: at most 729 of
at most 6 x 6, fewest active bounds first, so usually the first).
"""

from __future__ import annotations

import itertools
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

from rodctl import fixedla as fla
from rodctl.config.base import StrictModel
from rodctl.registry import CONTROLLERS, BuildContext


def solve_box_qp(H: np.ndarray, g: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Exact minimiser of 1/2 u^T H u + g^T u subject to lower <= u <= upper.

    Args:
        H: (q, q) symmetric positive definite.
        g: (q,) linear term.
        lower: (q,) lower bounds.
        upper: (q,) upper bounds, >= lower.

    Returns:
        (q,) the unique minimiser.

    Raises:
        ValueError: q > 8 (3^q active sets) or inconsistent bounds.
    """
    H = np.asarray(H, dtype=float)
    g = np.asarray(g, dtype=float)
    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    q = g.shape[0]
    if q > 8:
        raise ValueError(f"active-set enumeration is for small problems, got q = {q}")
    if np.any(lo > hi):
        raise ValueError("every lower bound must be <= its upper bound")
    reach = float(np.maximum(np.abs(lo), np.abs(hi)).max())
    tol = 1e-9 * (float(np.abs(H).max()) * reach + float(np.abs(g).max()))  # gradient scale
    # States: 0 free, 1 at lower, 2 at upper; fewest active bounds first (all free: the usual
    # case). The objective is strictly convex, so the first set that meets the KKT conditions
    # gives the unique minimiser.
    sets = sorted(itertools.product((0, 1, 2), repeat=q), key=lambda st: sum(x > 0 for x in st))
    for states in sets:
        st = np.array(states)
        u = np.where(st == 1, lo, np.where(st == 2, hi, 0.0))
        free = st == 0
        if free.any():
            rhs = -(g[free] + fla.matvec(H[np.ix_(free, ~free)], u[~free]))
            sol = fla.spd_solve(H[np.ix_(free, free)], rhs)  # a principal block of an SPD H
            if sol is None:
                raise np.linalg.LinAlgError("QP Hessian is not positive definite")
            u[free] = sol
            span = hi[free] - lo[free]
            slack = 1e-12 * (span + 1.0)
            if np.any(u[free] < lo[free] - slack) or np.any(u[free] > hi[free] + slack):
                continue
        grad = fla.matvec(H, u) + g
        # KKT: at a lower bound the objective must rise going up (grad >= 0), at an upper one
        # it must rise going down (grad <= 0).
        if np.any(grad[st == 1] < -tol) or np.any(grad[st == 2] > tol):
            continue
        return np.clip(u, lo, hi)
    raise np.linalg.LinAlgError(  # pragma: no cover - impossible for positive definite H
        "no active set satisfied the KKT conditions"
    )


class QpController:
    """Box-bounded regularised least-squares step towards the target, stateless."""

    def __init__(self, max_step: np.ndarray, **settings: Any) -> None:
        """Args: max_step: (q,) per-axis bound; **settings: fields of `QpControllerConfig`
        (gain lambda, r_weights the diagonal of R): its defaults and checks are the only ones."""
        if "r_weights" in settings:
            settings["r_weights"] = tuple(np.asarray(settings["r_weights"], dtype=float).tolist())
        cfg = QpControllerConfig(**settings)
        self._max = np.asarray(max_step, dtype=float)
        weights = np.asarray(cfg.r_weights, dtype=float)
        if self._max.shape[0] % weights.shape[0]:
            raise ValueError(
                f"r_weights has {weights.shape[0]} values for a {self._max.shape[0]}-DoF command"
            )
        # 3 weights [dx, dy, dtheta] apply to each moved end (q = 6: both ends)
        self._R = np.diag(np.tile(weights, self._max.shape[0] // weights.shape[0]))
        if not np.all(self._max > 0.0):
            raise ValueError(f"max_step must be positive, got {self._max.tolist()}")
        self._gain = float(cfg.gain)

    def reset(self) -> None:
        """Nothing to forget: the law is memoryless."""

    def command(
        self, s: np.ndarray, s_target: np.ndarray, J: np.ndarray, r: np.ndarray
    ) -> np.ndarray:
        """The QP step u (q,) from s, s* (p,) and J (p, q); r is unused."""
        J = np.asarray(J, dtype=float)
        e = np.asarray(s_target, dtype=float) - np.asarray(s, dtype=float)
        JT = np.ascontiguousarray(J.T)
        H = fla.matmul(JT, J) + self._R  # fixed order: the same bits on every machine
        g = -self._gain * fla.matvec(JT, e)
        return solve_box_qp(H, g, -self._max, self._max)


# --- config and registration ------------------------------------------------------------


#: A diagonal entry of R (feature^2 per command^2).
Weight = Annotated[float, Field(gt=0.0, le=1e12)]


class QpControllerConfig(StrictModel):
    """min 1/2 ||J u - lambda e||^2 + 1/2 u^T R u s.t. |u_i| <= max_step_i (our re-implementation).

    The Aghajanzadeh et al. 2022 "optimal deformation control" step as reconstructed from the
    group's published descriptions (docs/baselines.md); the bounds are the loop's
    per-axis speed limits. R = diag(r_weights) in feature^2 per command^2: small against
    J^T J (~1e2-1e4 for latents, ~1e6 for pixel node features), so it only regularises
    directions J barely observes.
    """

    type: Literal["qp"] = "qp"
    gain: float = Field(
        0.3, gt=0.0, le=1.0, description="lambda: the fraction of the error one step aims at."
    )
    r_weights: (
        tuple[Weight, Weight, Weight] | tuple[Weight, Weight, Weight, Weight, Weight, Weight]
    ) = Field(
        (1.0, 1.0, 1.0),
        description="Diagonal of R: penalty on [dx, dy, dtheta] (feature^2/u^2), applied to each "
        "moved end; 6 values set both ends of a dual-arm (q = 6) command apart.",
    )


@CONTROLLERS.register(QpControllerConfig)
def _build(cfg: QpControllerConfig, ctx: BuildContext) -> QpController:
    assert ctx.max_step is not None, "a controller is built with the task's max_step"
    return QpController(ctx.max_step, **cfg.model_dump(exclude={"type"}))
