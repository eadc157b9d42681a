"""The paper's adaptive Kalman filter (AKF) estimate of the deformation Jacobian.

Implements docs/method.md §3 (paper eqs. 8-18 as printed, with their typos corrected): the state
is J stacked by rows, x = vec_rows(J) in R^{pq}, under a random walk (A = I), observed through
y_k = Delta s_k = M_k x with M_k = I_p kron u_k^T.

Why it is written the way it is:
- Reproducibility (issue #18). No BLAS or LAPACK call: the products are `einsum` or
  elementwise, S^-1 comes from a Cholesky factor in Python floats and the eigenvalue clip from
  `rodctl.fixedla`, all in a fixed order of operations, so a run gives the same bits under every
  BLAS kernel (docs/reproducibility.md). The clip is what that costs most (an 18 x 18
  eigenproblem at nearly every step; `benchmarks/bench_estimation_control.py`).
- Speed. M_k is never formed: with the Kronecker structure, P M^T is P.reshape(pq, p, q) u and
  M (P M^T) is u against (.).reshape(p, q, p), each one small einsum (p = 6, q = 3: an
  18-dimensional state); no scipy.
- Robustness. The noise estimates Q and R (eqs. 17-18) are fading-memory sums that can lose
  definiteness (eq. 17 subtracts a matrix, Q's increment contains P_k - P_{k|k-1}), so after each
  update they are symmetrised and their eigenvalues clipped to a floor (`clip_psd`).
- The adaptive factor alpha of eq. 14 reaches 0 for gross outliers, and the filter divides by
  it; it is clamped to `alpha_floor` instead (a config value).
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import Field, PositiveFloat, model_validator

from rodctl import fixedla
from rodctl.config.base import StrictModel
from rodctl.estimation.base import DEAD_ZONE_DOC, EstimatorDiverged, checked_jacobian
from rodctl.registry import ESTIMATORS, BuildContext


def igg3_factor(stat: float, c0: float, c1: float, floor: float) -> float:
    """The IGG-III adaptive factor alpha of paper eq. 14, with the c1 typo fixed.

    alpha = 1 if |stat| <= c0; (c0/|stat|) ((c1 - |stat|)/(c1 - c0))^2 if c0 < |stat| <= c1;
    0 beyond. The paper prints (c0 - |stat|) in the middle branch, which jumps at c1; the
    intended (c1 - |stat|) makes alpha continuous and monotone (docs/method.md §3). Since
    alpha divides P, the result is clamped below at `floor` (alpha = 0 becomes `floor`).

    Args:
        stat: the innovation statistic Delta epsilon_k (eq. 15).
        c0: threshold below which the measurement is fully trusted (paper: c0 in [1, 1.5]).
        c1: threshold beyond which it is treated as an outlier (paper: c1 in [3, 8]).
        floor: smallest value returned, > 0.

    Returns:
        alpha in [floor, 1].
    """
    a = abs(stat)
    if a <= c0:
        return 1.0
    if a <= c1:
        alpha = (c0 / a) * ((c1 - a) / (c1 - c0)) ** 2
        return max(alpha, floor)
    return floor


def clip_psd(a: np.ndarray, floor: float, test_first: bool = True) -> np.ndarray:
    """Symmetrise `a` and raise any eigenvalue below `floor` to `floor`, kernel-independent.

    out = a + sum over {w_i < floor} of (floor - w_i) v_i v_i^T (w_i, v_i the eigenpairs of
    the symmetrised a): the nearest matrix in the Frobenius norm whose eigenvalues are all
    >= floor. Computed by `rodctl.fixedla` (fixed-order Householder tridiagonalisation, QL
    eigenvalues, then only the eigenvectors below the floor), no LAPACK, so the result has the
    same bits under every BLAS kernel (issue #18).

    Args:
        a: (n, n) nearly symmetric matrix.
        floor: eigenvalue floor (> 0 keeps the result positive definite).
        test_first: first try a Cholesky factorisation of a - floor I (Python floats, fixed
            order): it succeeds iff every eigenvalue is above the floor, and then nothing is
            computed. Worth it for R (6 x 6, almost never clipped); not for Q, which is clipped
            at nearly every step (docs/reproducibility.md).

    Returns:
        (n, n) exactly symmetric matrix whose eigenvalues are all >= floor (to rounding, about
        eps * ||a||); equal to the symmetrised input when they already were.
    """
    a = 0.5 * (a + a.T)
    if test_first:
        n = a.shape[0]
        if fixedla.cholesky(a - floor * np.eye(n)) is not None:
            return a
    return fixedla.clip_eigenvalues(a, floor)


def _joseph(
    P_pred: np.ndarray, inv_a: float, PMt: np.ndarray, Li: np.ndarray, R: np.ndarray, u: np.ndarray
) -> np.ndarray:
    """The Joseph form of the covariance update, (I - K M) P' (I - K M)^T + K R K^T.

    P' = (1/alpha) P- is the inflated prior of eq. 13, K = P' M^T S^-1 its gain (S^-1 =
    Li^T Li) and M = I_p kron u^T. Equal to (I - K M) P' in exact arithmetic (K is the optimal
    gain) but a sum of two positive semidefinite products, so rounding cannot make it
    indefinite the way the subtraction can; fixed-order `einsum` throughout (no BLAS).
    """
    n = PMt.shape[0]
    Sinv = fixedla.einsum("ki,kj->ij", Li, Li)
    K = inv_a * fixedla.einsum("nk,kj->nj", PMt, Sinv)  # (n, p)
    A = np.eye(n) - fixedla.einsum("ai,j->aij", K, u).reshape(n, n)  # I - K M
    AP = fixedla.einsum("ab,bc->ac", A, inv_a * P_pred)
    out = fixedla.einsum("ac,dc->ad", AP, A) + fixedla.einsum("ai,ij,bj->ab", K, R, K)
    return 0.5 * (out + out.T)


class AdaptiveKalmanJacobian:
    """Adaptive Kalman filter estimate of J (p, q) from (Delta s, Delta r) pairs.

    Per informative step (docs/method.md §3; paper eqs. 13-18):

        P- = P + Q                          (random walk, A = I)
        eps = ds - J u,  G = M P- M^T,  d_eps = sqrt(eps^T eps / tr G)       (eqs. 15-16)
        alpha = IGG-III(d_eps; c0, c1), clamped to >= alpha_floor            (eq. 14)
        K = (1/alpha) P- M^T ((1/alpha) G + R)^-1                             (eq. 13)
        x += K eps,  P = (1/alpha) (I - K M) P-
        d = (1 - b)/(1 - b^(k+1))
        R = (1 - d) R + d eps eps^T          (eq. 18; eq. 17 also subtracts d G)
        Q = (1 - d) Q + d (K eps eps^T K^T + P - P-)

    Q and R are then symmetrised and eigenvalue-clipped to `q_min` / `r_min`. alpha = 0 (a gross
    outlier, d_eps > c1) is clamped to `alpha_floor`: the prior covariance is inflated by
    1/alpha_floor, so the filter follows the new measurement almost entirely, which is also
    what lets it track an abrupt change of J. k counts informative updates since `reset`,
    starting at 1 (so d_1 = 1/(1 + b) blends the configured R_0, Q_0 with the first sample
    instead of discarding them, as d_0 = 1 would).

    A step with ||u|| < dead_zone carries no information about J and is skipped entirely
    (no prediction either), so Q does not inflate P while the gripper stands still.

    Attributes:
        p: feature dimension.
        q: command dimension.
    """

    def __init__(self, p: int, q: int, **settings: Any) -> None:
        """Build the filter; it starts at J = 0 until `reset` gives it J_0.

        Args:
            p: feature dimension.
            q: command dimension.
            **settings: fields of `AkfEstimatorConfig` (p0, q0, r0, c0, c1, alpha_floor,
                forgetting, r_update, q_min, r_min, dead_zone); its defaults and checks are the
                only ones (an unknown or out-of-range setting is a `ValueError`).
        """
        cfg = AkfEstimatorConfig(**settings)
        self.p, self.q = int(p), int(q)
        self._n = self.p * self.q
        self._p0, self._q0, self._r0 = cfg.p0, cfg.q0, cfg.r0
        self._c0, self._c1, self._floor = cfg.c0, cfg.c1, cfg.alpha_floor
        self._b = cfg.forgetting
        self._eq32 = cfg.r_update == "eq32"
        self._q_min, self._r_min = cfg.q_min, cfg.r_min
        self._dead_zone = cfg.dead_zone
        self.reset(np.zeros((self.p, self.q)))

    @property
    def J(self) -> np.ndarray:
        """(p, q) current estimate (a copy)."""
        return self._J.copy()

    @property
    def P(self) -> np.ndarray:
        """(pq, pq) state covariance, rows of J stacked."""
        return self._P.copy()

    @property
    def Q(self) -> np.ndarray:
        """(pq, pq) process-noise estimate Q_k."""
        return self._Q.copy()

    @property
    def R(self) -> np.ndarray:
        """(p, p) measurement-noise estimate R_k."""
        return self._R.copy()

    def reset(self, J0: np.ndarray) -> None:
        """Restart from J0 (p, q) with P, Q, R at their configured initial values."""
        self._J = checked_jacobian(J0, self.p, self.q)
        self._P = self._p0 * np.eye(self._n)
        self._Q = self._q0 * np.eye(self._n)
        self._R = self._r0 * np.eye(self.p)
        self._k = 0
        self._info = {"alpha": 1.0, "innovation": 0.0, "skipped": 0.0}

    def update(self, ds: np.ndarray, dr: np.ndarray) -> np.ndarray:
        """Fold in ds (p,) = s_k - s_{k-1} caused by dr (q,) = u_k; return the (p, q) estimate."""
        u = np.asarray(dr, dtype=float)
        y = np.asarray(ds, dtype=float)
        if math.sqrt(fixedla.dot(u, u)) < self._dead_zone:
            self._info = {"alpha": 1.0, "innovation": 0.0, "skipped": 1.0}
            return self._J.copy()
        p, q, n = self.p, self.q, self._n

        # Every product below is `einsum` or elementwise and the solve is a Cholesky factor in
        # Python floats (rodctl.fixedla): no BLAS/LAPACK, the same bits under every kernel.
        P_pred = self._P + self._Q  # A = I (eq. 11)
        eps = y - fixedla.matvec(self._J, u)  # eq. 16: z_k - C_k x_{k|k-1}
        PMt = fixedla.matvec(P_pred.reshape(n, p, q), u)  # (n, p) = P- M^T, M = I_p kron u^T
        G = fixedla.einsum("j,ijk->ik", u, PMt.reshape(p, q, p))  # (p, p) = M P- M^T (eq. 16)
        trG = float(G.trace())
        stat = math.sqrt(fixedla.dot(eps, eps) / trG) if trG > 0.0 else 0.0  # eq. 15
        alpha = igg3_factor(stat, self._c0, self._c1, self._floor)  # eq. 14
        inv_a = 1.0 / alpha

        S = inv_a * G + self._R  # eq. 13; symmetric positive definite (R is clipped to r_min)
        factor = fixedla.cholesky_inverse_factor(0.5 * (S + S.T))  # S^-1 = Li^T Li
        if factor is None:  # only if P lost definiteness to rounding: make S PD again
            factor = fixedla.cholesky_inverse_factor(clip_psd(S, self._r_min, test_first=False))
        Li = np.array(factor)
        W = fixedla.einsum("ik,jk->ij", Li, PMt)  # (p, n) = L^-1 M P-
        Keps = inv_a * fixedla.einsum("ki,k->i", W, fixedla.matvec(Li, eps))  # K eps (eq. 13)
        self._J = self._J + Keps.reshape(p, q)
        # (1/alpha)(I - K M) P- with K M P- = (1/alpha) P- M^T S^-1 M P- = (1/alpha) W^T W
        # (exactly symmetric as computed: entry (i, j) and (j, i) sum the same products)
        P_new = inv_a * (P_pred - inv_a * fixedla.einsum("ki,kj->ij", W, W))
        repaired = 0.0
        if not fixedla.cholesky_ok(P_new):
            # The subtraction cancelled below rounding (large p q, a covariance spanning many
            # orders): the Joseph form is a sum of positive semidefinite terms instead.
            P_new = _joseph(P_pred, inv_a, PMt, Li, self._R, u)
            repaired = 1.0
            if not fixedla.cholesky_ok(P_new):
                if not np.isfinite(P_new).all():
                    raise EstimatorDiverged(
                        f"akf: the state covariance P became non-finite at update {self._k + 1}"
                    )
                P_new = clip_psd(P_new, self._q_min, test_first=False)
                repaired = 2.0
        self._P = P_new

        self._k += 1
        b = self._b
        d = (1.0 - b) / (1.0 - b ** (self._k + 1))
        R = (1.0 - d) * self._R + d * (eps[:, None] * eps)  # eq. 18
        if self._eq32:
            R -= d * G  # eq. 17: the unbiased form
        Q = (1.0 - d) * self._Q + d * (Keps[:, None] * Keps + self._P - P_pred)  # eq. 17 (Q)
        if not (np.isfinite(Q).all() and np.isfinite(R).all() and np.isfinite(self._J).all()):
            raise EstimatorDiverged(
                f"akf: J or the noise estimates Q, R became non-finite at update {self._k}"
            )
        self._R = clip_psd(R, self._r_min)
        self._Q = clip_psd(Q, self._q_min, test_first=False)

        self._info = {"alpha": alpha, "innovation": stat, "skipped": 0.0}
        if repaired:
            self._info["repaired"] = repaired
        return self._J.copy()

    def info(self) -> dict[str, float]:
        """Diagnostics of the last update.

        Returns:
            alpha (adaptive factor), innovation (Delta epsilon_k, eq. 15), skipped (1.0 if the
            last move was in the dead zone), trace_P, trace_Q, trace_R.
        """
        return {
            **self._info,
            "trace_P": float(self._P.trace()),
            "trace_Q": float(self._Q.trace()),
            "trace_R": float(self._R.trace()),
        }


# --- config and registration ------------------------------------------------------------


class AkfEstimatorConfig(StrictModel):
    """Adaptive Kalman filter on vec_rows(J) (paper eqs. 8-18, docs/method.md §3).

    P_0 = p0 I, Q_0 = q0 I (pq x pq) and R_0 = r0 I (p x p). With features of order 1 and J
    entries O(10-100), p0 = 10 says "J_0 from probing is good to ~3 per entry", r0 = 1e-4 says
    "feature noise ~1e-2", q0 = 1e-2 lets J drift by ~0.1 per step; Q and R then adapt.
    """

    type: Literal["akf"] = "akf"
    p0: PositiveFloat = Field(
        10.0, le=1e12, description="Initial state covariance P_0 = p0 I (J units^2)."
    )
    q0: PositiveFloat = Field(
        1e-2, le=1e12, description="Initial process noise Q_0 = q0 I (J units^2)."
    )
    r0: PositiveFloat = Field(
        1e-4, le=1e12, description="Initial measurement noise R_0 = r0 I (feature^2)."
    )
    c0: float = Field(
        1.5,
        le=100.0,
        gt=0.0,
        description="IGG-III threshold c0 (eq. 14): alpha = 1 while |d_eps| <= c0.",
    )
    c1: float = Field(
        6.0,
        le=100.0,
        gt=0.0,
        description="IGG-III threshold c1 (eq. 14): alpha reaches 0 at |d_eps| = c1.",
    )
    alpha_floor: float = Field(
        1e-3,
        gt=0.0,
        le=1.0,
        description="Smallest adaptive factor alpha; eq. 14's alpha = 0 is clamped to it, since "
        "alpha divides P (eq. 13).",
    )
    forgetting: float = Field(
        0.95,
        gt=0.0,
        lt=1.0,
        description="Fading-memory factor b of d_k = (1 - b)/(1 - b^(k+1)) (eqs. 17-18); larger "
        "remembers longer (about 1/(1 - b) steps).",
    )
    r_update: Literal["eq33", "eq32"] = Field(
        "eq33",
        description="eq33: R = (1-d) R + d eps eps^T (biased, stays PSD; the paper's choice). "
        "eq32: subtracts C P C^T too (unbiased, may lose definiteness; then clipped).",
    )
    q_min: PositiveFloat = Field(
        1e-8, le=1e6, description="Eigenvalue floor applied to Q after each update (keeps it PSD)."
    )
    r_min: PositiveFloat = Field(
        1e-8, le=1e6, description="Eigenvalue floor applied to R after each update (keeps it PD)."
    )
    dead_zone: float = Field(1e-4, le=1.0, ge=0.0, description=DEAD_ZONE_DOC)

    @model_validator(mode="after")
    def _thresholds_ordered(self) -> AkfEstimatorConfig:
        if not self.c0 < self.c1:
            raise ValueError(
                f"c0 must be smaller than c1 (paper: c0 in [1, 1.5], c1 in [3, 8]); "
                f"got c0={self.c0}, c1={self.c1}"
            )
        return self


@ESTIMATORS.register(AkfEstimatorConfig)
def _build(cfg: AkfEstimatorConfig, ctx: BuildContext) -> AdaptiveKalmanJacobian:
    return AdaptiveKalmanJacobian(ctx.p, ctx.q, **cfg.model_dump(exclude={"type"}))
