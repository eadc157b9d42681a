"""The paper's MFAC velocity law with performance regulation (eqs. 19-24, docs/method.md §5).

The law is the exact minimiser of a quadratic cost in the next command u_k,

    Q(u) = w1 ||e_{k-1} - J_k u||^2 + w2 ||s_{k-1} + J_k u||^2 + w3 ||J_k u||^2
         + w4 ||J_k u - J_{k-1} u_{k-1}||^2 + w5 ||r_{k-1} + u||^2 + w6 ||u||^2
         + w7 ||u - u_{k-1}||^2,

so it is written as the closed form of eq. 24 (`mfac_step`) beside the cost (`mfac_cost`) that
tests compare it with. The controller keeps what the law needs from the previous step: J_{k-1}
and u_{k-1}. It takes u_{k-1} as the difference of the poses it was given (r_{k-1} - r_{k-2}),
not as its own last output, because the loop saturates and may clip the command: the ω4 and ω7
terms concern the increment the gripper really made (docs/method.md §5: u_k = Delta r_k).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator

from rodctl import fixedla as fla
from rodctl.config.base import StrictModel
from rodctl.registry import CONTROLLERS, BuildContext


def _check_weights(weights: Sequence[float]) -> np.ndarray:
    w = np.asarray(weights, dtype=float)
    if w.shape != (7,):
        raise ValueError(f"MFAC needs 7 weights, got {w.shape}")
    if not np.all(w > 0.0):
        raise ValueError(f"MFAC weights must be positive, got {w.tolist()}")
    if abs(float(w.sum()) - 1.0) > 1e-6:
        raise ValueError(f"MFAC weights must sum to 1, got {float(w.sum())}")
    return w


def mfac_cost(
    u: np.ndarray,
    *,
    J: np.ndarray,
    J_prev: np.ndarray,
    e: np.ndarray,
    s: np.ndarray,
    r: np.ndarray,
    u_prev: np.ndarray,
    weights: Sequence[float] | np.ndarray,
) -> float:
    """The cost Q(u) of paper eq. 22 (docs/method.md §5).

    Args:
        u: (q,) candidate command u_k.
        J: (p, q) estimate J_k.
        J_prev: (p, q) estimate J_{k-1}.
        e: (p,) error e_{k-1} = s* - s_{k-1}.
        s: (p,) feature s_{k-1}.
        r: (q,) pose r_{k-1} relative to home.
        u_prev: (q,) previous increment u_{k-1}.
        weights: (7,) omega_1..omega_7.

    Returns:
        Q(u) >= 0.
    """
    w = np.asarray(weights, dtype=float)
    Ju = J @ u
    terms = (
        e - Ju,
        s + Ju,
        Ju,
        Ju - J_prev @ u_prev,
        r + u,
        u,
        u - u_prev,
    )
    return float(sum(wi * float(t @ t) for wi, t in zip(w, terms, strict=True)))


def mfac_step(
    *,
    J: np.ndarray,
    J_prev: np.ndarray,
    e: np.ndarray,
    s: np.ndarray,
    r: np.ndarray,
    u_prev: np.ndarray,
    weights: Sequence[float] | np.ndarray,
) -> np.ndarray:
    """Closed-form minimiser of `mfac_cost` (paper eq. 24; I is the q x q identity).

        u_k = G_k (w1 J^T e - w2 J^T s - w5 r + (w4 J^T J_prev + w7 I) u_prev)
        G_k = ((w1 + w2 + w3 + w4) J^T J + (w5 + w6 + w7) I)^-1

    Arguments as in `mfac_cost`. Returns the (q,) command u_k.
    """
    # Fixed-order arithmetic (rodctl.fixedla), not BLAS/LAPACK: the command must be the same
    # bits on every machine (docs/reproducibility.md); a 3 x 3 Cholesky in Python floats is
    # also faster than a LAPACK call.
    w1, w2, w3, w4, w5, w6, w7 = (float(x) for x in weights)
    q = J.shape[1]
    JT = np.ascontiguousarray(J.T)
    H = (w1 + w2 + w3 + w4) * fla.matmul(JT, J)  # G_k^-1 (eq. 24) ...
    H.flat[:: q + 1] += w5 + w6 + w7  # ... + (w5 + w6 + w7) I_q
    rhs = fla.matvec(JT, w1 * e - w2 * s + w4 * fla.matvec(J_prev, u_prev)) - w5 * r + w7 * u_prev
    u = fla.spd_solve(H, rhs)  # H is symmetric positive definite
    if u is None:
        raise np.linalg.LinAlgError("MFAC normal matrix not positive definite")
    return u


class MfacController:
    """MFAC shape servo: u_k = argmin Q(u) (eq. 24), before the loop's saturation.

    At rest (u_k = u_{k-1} = 0) the law satisfies w1 J^T e = w2 J^T s + w5 r: w2 and w5 pull
    towards s = 0 and towards home and so leave a steady-state error (docs/method.md §5).
    """

    def __init__(self, weights: Sequence[float]) -> None:
        """Args: weights: (7,) omega_1..omega_7, positive, summing to 1."""
        self._w = _check_weights(weights)
        self.reset()

    @property
    def weights(self) -> np.ndarray:
        """(7,) omega_1..omega_7."""
        return self._w.copy()

    def reset(self) -> None:
        """Forget u_{k-1}, r_{k-2} and J_{k-1} (start of a run): the first step has u_prev = 0."""
        self._r_prev: np.ndarray | None = None
        self._J_prev: np.ndarray | None = None

    def command(
        self, s: np.ndarray, s_target: np.ndarray, J: np.ndarray, r: np.ndarray
    ) -> np.ndarray:
        """Next pose increment u_k (q,) from s (p,), s* (p,), J_k (p, q), r_{k-1} (q,) rel. home."""
        s = np.asarray(s, dtype=float)
        J = np.asarray(J, dtype=float)
        r = np.asarray(r, dtype=float)
        u_prev = np.zeros_like(r) if self._r_prev is None else r - self._r_prev
        J_prev = J if self._J_prev is None else self._J_prev
        u = mfac_step(
            J=J,
            J_prev=J_prev,
            e=np.asarray(s_target, dtype=float) - s,
            s=s,
            r=r,
            u_prev=u_prev,
            weights=self._w,
        )
        self._r_prev = r.copy()
        self._J_prev = J.copy()
        return u


# --- config and registration ------------------------------------------------------------


#: Default MFAC weights (omega_1..omega_7), see `MfacControllerConfig`.
DEFAULT_MFAC_WEIGHTS = (0.55, 1e-4, 0.2, 0.05, 1e-4, 0.0998, 0.1)


#: One MFAC weight: they are positive and sum to 1.
Omega = Annotated[float, Field(le=1.0)]


class MfacControllerConfig(StrictModel):
    """MFAC velocity law with seven performance weights (paper eq. 24, docs/method.md §5).

    Weights omega_1..omega_7 weigh: error, feature amplitude, feature rate, feature acceleration,
    distance from home, speed, acceleration. They must be positive and sum to 1.

    Default (0.55, 1e-4, 0.2, 0.05, 1e-4, 0.0998, 0.1): one step removes about
    omega_1 / (omega_1 + ... + omega_4) ~ 0.69 of the linearised error (fast), omega_3 and
    omega_7 smooth it. omega_2 and omega_5 are tiny because at rest omega_1 J^T e =
    omega_2 J^T s + omega_5 r (docs/method.md §5): they leave a steady-state error of order
    (omega_2/omega_1) ||s|| ~ 2e-4 for order-1 features. omega_6 and omega_7 act in command
    units (m^2) against J^T J ~ 1e2-1e4 in feature units, so at ~0.1 they damp only directions
    J barely observes (singular values below ~1), which is where a noisy estimate would
    otherwise ask for large moves.
    """

    type: Literal["mfac"] = "mfac"
    weights: tuple[Omega, Omega, Omega, Omega, Omega, Omega, Omega] = Field(
        DEFAULT_MFAC_WEIGHTS,
        description="omega_1..omega_7 of eq. 24: error, feature amplitude, feature rate, feature "
        "acceleration, distance from home, speed, acceleration. Positive, summing to 1.",
    )

    @field_validator("weights")
    @classmethod
    def _positive_sum_one(cls, w: tuple[float, ...]) -> tuple[float, ...]:
        bad = [f"omega_{i + 1}={v}" for i, v in enumerate(w) if not v > 0.0]
        if bad:
            raise ValueError(
                "every MFAC weight must be positive (the paper's eq. 20); got " + ", ".join(bad)
            )
        total = sum(w)
        if abs(total - 1.0) > 1e-6:
            raise ValueError(
                f"the seven MFAC weights must sum to 1 (eq. 20), they sum to {total:.6g}; "
                "when you change one, lower or raise another by the same amount"
            )
        return w


@CONTROLLERS.register(MfacControllerConfig)
def _build(cfg: MfacControllerConfig, ctx: BuildContext) -> MfacController:
    return MfacController(cfg.weights)
