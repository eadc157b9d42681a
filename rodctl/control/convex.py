"""The Yu et al. 2023 law: a regularised least-squares step in a ball (`controller: yu_convex`).

A re-implementation from the authors' public code (docs/baselines.md "yu2023"; the paper's body,
and so its equation numbers, we could not read). Each step solves the convex problem

    min_v 1/2 ||v_ref - Jn v||^2 + 1/2 lambda ||v||^2   s.t.   ||v|| <= 1,
    v_ref = gain * clip(e),   lambda = reg * ||clip(e)||,   u = max_step * v,

with e = s* - s, clip(e) = e scaled down to norm `error_limit` when longer, Jn = J diag(max_step)
the Jacobian per full step, so the ball is the speed limit in units of `rod.max_step` (the
authors bound the Euclidean norm of the end velocities; with mixed metres and radians we bound
it per axis-normalised command instead). The regularisation shrinks with the error, so the law
is a damped Gauss-Newton step far from the target and an almost plain one near it.

Solved exactly: the unconstrained minimiser when it lies in the ball, else the point on the
sphere where (Jn^T Jn + (lambda + mu) I) v = Jn^T v_ref for the mu >= 0 that gives ||v|| = 1 (the
trust-region condition; ||v(mu)|| decreases with mu), found by bisection. Their constraint
against over-stretching the rod is left out (our single gripper rarely pulls the rod straight;
the workspace's reach limit stops it).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field

from rodctl import fixedla as fla
from rodctl.config.base import StrictModel
from rodctl.registry import CONTROLLERS, BuildContext


def ball_least_squares(A: np.ndarray, b: np.ndarray, lam: float, radius: float = 1.0) -> np.ndarray:
    """argmin 1/2 ||b - A v||^2 + 1/2 lam ||v||^2 subject to ||v|| <= radius (exact).

    Args:
        A: (p, q); b: (p,); lam >= 0; radius > 0.

    Returns:
        (q,) the unique minimiser (the minimum-norm one when A^T A + lam I is singular).
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    q = A.shape[1]
    AT = np.ascontiguousarray(A.T)
    G = fla.matmul(AT, A)
    g = fla.matvec(AT, b)
    scale = max(float(np.trace(G)) / q, 1e-300)
    floor = 1e-12 * scale  # a definite system even when lam = 0 and A is rank deficient

    def solve(mu: float) -> np.ndarray:
        H = G.copy()
        H.flat[:: q + 1] += lam + mu + floor
        v = fla.spd_solve(H, g)
        if v is None:  # pragma: no cover - H is positive definite by construction
            raise np.linalg.LinAlgError("normal matrix not positive definite")
        return v

    v = solve(0.0)
    if fla.norm(v) <= radius:
        return v
    lo, hi = 0.0, scale + fla.norm(g) / radius  # at mu = hi, ||v|| <= ||g|| / mu < radius
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if fla.norm(solve(mid)) > radius:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    v = solve(hi)
    n = fla.norm(v)
    return v * (radius / n) if n > radius else v


class ConvexController:
    """The Yu et al. 2023 step (module docstring): memoryless."""

    def __init__(self, max_step: np.ndarray, **settings: Any) -> None:
        """Args: max_step (q,) the per-axis speed limit; **settings: `YuConvexControllerConfig`
        fields (gain, reg, error_limit)."""
        cfg = YuConvexControllerConfig(**settings)
        self._max = np.asarray(max_step, dtype=float)
        if not np.all(self._max > 0.0):
            raise ValueError(f"max_step must be positive, got {self._max.tolist()}")
        self._gain, self._reg, self._limit = float(cfg.gain), float(cfg.reg), cfg.error_limit

    def reset(self) -> None:
        """Nothing to forget."""

    def command(
        self, s: np.ndarray, s_target: np.ndarray, J: np.ndarray, r: np.ndarray
    ) -> np.ndarray:
        """u (q,) from s, s* (p,) and J (p, q); r is unused."""
        e = np.asarray(s_target, dtype=float) - np.asarray(s, dtype=float)
        n = fla.norm(e)
        if n > self._limit:
            e = e * (self._limit / n)
            n = self._limit
        Jn = np.asarray(J, dtype=float) * self._max[None, :]
        v = ball_least_squares(Jn, self._gain * e, self._reg * n)
        return v * self._max


class YuConvexControllerConfig(StrictModel):
    """min 1/2 ||gain e - J u||^2 + 1/2 reg ||e|| ||u||^2 inside a ball (Yu et al. 2023, ours).

    Our re-implementation of the authors' convex-optimisation law from their public code
    (docs/baselines.md); u is measured in units of `rod.max_step`, the ball is the speed limit.
    """

    type: Literal["yu_convex"] = "yu_convex"
    gain: float = Field(
        0.5, gt=0.0, le=1.0, description="The fraction of the (clipped) error one step aims at."
    )
    reg: float = Field(
        0.1,
        ge=0.0,
        le=1e6,
        description="lambda per unit of error norm: the damping is reg * ||clip(e)|| "
        "(feature units; the authors' 0.1).",
    )
    error_limit: float = Field(
        10.0,
        gt=0.0,
        le=1e9,
        description="The error is scaled down to this norm when longer (feature units).",
    )


@CONTROLLERS.register(YuConvexControllerConfig)
def _build(cfg: YuConvexControllerConfig, ctx: BuildContext) -> ConvexController:
    assert ctx.max_step is not None, "a controller is built with the task's max_step"
    return ConvexController(ctx.max_step, **cfg.model_dump(exclude={"type"}))
