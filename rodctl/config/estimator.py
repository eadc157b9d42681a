"""Config of the deformation-Jacobian estimator: one union member per method, keyed by `type`.

Owned by `rodctl/estimation/`.

Scales the defaults assume (say so when you change them): features are autoencoder latents of
order 1, the gripper pose is in metres and radians, one control step moves at most about
[0.01 m, 0.01 m, 0.05 rad], so a feature changes by ~0.1-1 per step and Jacobian entries are
O(10-100). Every online method starts from a least-squares fit to q + 1 probing moves
(method-notes section 1, "how J_0 starts"); their size is `run.probe_size`.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, PositiveFloat, model_validator

from rodctl.config.base import StrictModel

_DEAD_ZONE_DOC = (
    "Skip the update when ||dr|| (Euclidean, metres and radians mixed) is below this: a tiny "
    "move carries no information about J and would amplify feature noise."
)


class AkfEstimatorConfig(StrictModel):
    """Adaptive Kalman filter on vec_rows(J) (paper eqs. 25-33, method-notes section 1).

    P_0 = p0 I, Q_0 = q0 I (pq x pq) and R_0 = r0 I (p x p). With features of order 1 and J
    entries O(10-100), p0 = 10 says "J_0 from probing is good to ~3 per entry", r0 = 1e-4 says
    "feature noise ~1e-2", q0 = 1e-2 lets J drift by ~0.1 per step; Q and R then adapt.
    """

    type: Literal["akf"] = "akf"
    p0: PositiveFloat = Field(10.0, description="Initial state covariance P_0 = p0 I (J units^2).")
    q0: PositiveFloat = Field(1e-2, description="Initial process noise Q_0 = q0 I (J units^2).")
    r0: PositiveFloat = Field(1e-4, description="Initial measurement noise R_0 = r0 I (feature^2).")
    c0: float = Field(
        1.5, gt=0.0, description="IGG-III threshold c0 (eq. 29): alpha = 1 while |d_eps| <= c0."
    )
    c1: float = Field(
        6.0, gt=0.0, description="IGG-III threshold c1 (eq. 29): alpha reaches 0 at |d_eps| = c1."
    )
    alpha_floor: float = Field(
        1e-3,
        gt=0.0,
        le=1.0,
        description="Smallest adaptive factor alpha; eq. 29's alpha = 0 is clamped to it, since "
        "alpha divides P (eq. 28).",
    )
    forgetting: float = Field(
        0.95,
        gt=0.0,
        lt=1.0,
        description="Fading-memory factor b of d_k = (1 - b)/(1 - b^(k+1)) (eqs. 32-33); larger "
        "remembers longer (about 1/(1 - b) steps).",
    )
    r_update: Literal["eq33", "eq32"] = Field(
        "eq33",
        description="eq33: R = (1-d) R + d eps eps^T (biased, stays PSD; the paper's choice). "
        "eq32: subtracts C P C^T too (unbiased, may lose definiteness; then clipped).",
    )
    q_min: PositiveFloat = Field(
        1e-8, description="Eigenvalue floor applied to Q after each update (keeps it PSD)."
    )
    r_min: PositiveFloat = Field(
        1e-8, description="Eigenvalue floor applied to R after each update (keeps it PD)."
    )
    dead_zone: float = Field(1e-4, ge=0.0, description=_DEAD_ZONE_DOC)

    @model_validator(mode="after")
    def _thresholds_ordered(self) -> AkfEstimatorConfig:
        if not self.c0 < self.c1:
            raise ValueError(
                f"c0 must be smaller than c1 (paper: c0 in [1, 1.5], c1 in [3, 8]); "
                f"got c0={self.c0}, c1={self.c1}"
            )
        return self


class BroydenEstimatorConfig(StrictModel):
    """Rank-1 Broyden update J += gamma (ds - J dr) dr^T / (dr^T dr) (method-notes section 4).

    Part of our re-implementation of the Ma et al. 2022 baseline from its published description.
    """

    type: Literal["broyden"] = "broyden"
    gamma: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description="Step size gamma in (0, 1]; 1 makes each update satisfy the secant exactly.",
    )
    dead_zone: float = Field(1e-4, ge=0.0, description=_DEAD_ZONE_DOC)


class WindowedLsEstimatorConfig(StrictModel):
    """Least squares over the last `window` (dr, ds) pairs (method-notes section 4).

    The alternative online estimator of the Ma et al. 2022 baseline (our re-implementation).
    """

    type: Literal["windowed_ls"] = "windowed_ls"
    window: int = Field(10, ge=1, description="Number of most recent informative pairs fitted.")
    ridge: float = Field(
        1e-6,
        ge=0.0,
        description="Weight mu of mu ||J - J_prev||^2 in the fit (m^2): a pseudo-move of "
        "sqrt(mu) per axis that keeps the fit defined when the window's moves are collinear.",
    )
    dead_zone: float = Field(1e-4, ge=0.0, description=_DEAD_ZONE_DOC)


class OfflineEstimatorConfig(StrictModel):
    """A fixed Jacobian from the rest shape's as-similar-as-possible (ASAP) model.

    The Aghajanzadeh et al. 2022 baseline (our re-implementation, method-notes section 4). No
    probing: the loop builds J once from `rodctl.estimation.asap.asap_jacobian` (composed with
    the camera's projection Jacobian) and passes it to `reset`. The servoed nodes must be the
    points the feature observes.
    """

    type: Literal["offline"] = "offline"
    nodes: int = Field(
        40, ge=6, description="Nodes the rest shape is resampled to for the ASAP model."
    )
    servoed: list[Annotated[float, Field(gt=0.0, lt=1.0)]] = Field(
        [0.25, 0.5, 0.75],
        min_length=1,
        description="Servoed points as fractions of arc length from the clamp (0) to the "
        "gripper (1); 2 features each (x, y).",
    )


EstimatorConfig = Annotated[
    AkfEstimatorConfig
    | BroydenEstimatorConfig
    | WindowedLsEstimatorConfig
    | OfflineEstimatorConfig,
    Field(discriminator="type"),
]
