"""Config of the controller: one union member per law, keyed by `type`.

Owned by `rodctl/control/`.

Every law returns a pose increment u = [dx (m), dy (m), dtheta (rad)] per control step; the loop
saturates it per axis (the robot's speed limit, about [0.01, 0.01, 0.05]) afterwards. Defaults
assume features of order 1 and Jacobian entries O(10-100) (autoencoder latents); see each field.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, PositiveFloat, field_validator

from rodctl.config.base import Pose, StrictModel

#: Default MFAC weights (omega_1..omega_7), see `MfacControllerConfig`.
DEFAULT_MFAC_WEIGHTS = (0.55, 1e-4, 0.2, 0.05, 1e-4, 0.0998, 0.1)


class MfacControllerConfig(StrictModel):
    """MFAC velocity law with seven performance weights (paper eq. 24, method-notes section 2).

    Weights omega_1..omega_7 weigh: error, feature amplitude, feature rate, feature acceleration,
    distance from home, speed, acceleration. They must be positive and sum to 1.

    Default (0.55, 1e-4, 0.2, 0.05, 1e-4, 0.0998, 0.1): one step removes about
    omega_1 / (omega_1 + ... + omega_4) ~ 0.69 of the linearised error (fast), omega_3 and
    omega_7 smooth it. omega_2 and omega_5 are tiny because at rest omega_1 J^T e =
    omega_2 J^T s + omega_5 r (method-notes section 2): they leave a steady-state error of order
    (omega_2/omega_1) ||s|| ~ 2e-4 for order-1 features. omega_6 and omega_7 act in command
    units (m^2) against J^T J ~ 1e2-1e4 in feature units, so at ~0.1 they damp only directions
    J barely observes (singular values below ~1), which is where a noisy estimate would
    otherwise ask for large moves.
    """

    type: Literal["mfac"] = "mfac"
    weights: tuple[float, float, float, float, float, float, float] = Field(
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


class PinvControllerConfig(StrictModel):
    """u = lambda J^+ sat(s* - s), the Ma et al. 2022 law (our re-implementation).

    method-notes writes -lambda J^+ sat(s - s*): the same thing, since sat is odd.
    """

    type: Literal["pinv"] = "pinv"
    gain: float = Field(
        0.5, gt=0.0, le=1.0, description="lambda: the fraction of the linearised error removed."
    )
    error_limit: PositiveFloat = Field(
        0.5, description="sat(): each feature error component is clipped to +-this (feature units)."
    )
    rcond: float = Field(
        1e-4,
        gt=0.0,
        lt=1.0,
        description="Singular values below rcond * the largest are dropped in J^+ (numpy pinv).",
    )


class QpControllerConfig(StrictModel):
    """min 1/2 ||J u - lambda e||^2 + 1/2 u^T R u s.t. |u_i| <= max_step_i (our re-implementation).

    The Aghajanzadeh et al. 2022 "optimal deformation control" step as reconstructed from the
    group's published descriptions (method-notes section 4); the bounds are the loop's
    per-axis speed limits. R = diag(r_weights) in feature^2 per command^2: small against
    J^T J (~1e2-1e4 for latents, ~1e6 for pixel node features), so it only regularises
    directions J barely observes.
    """

    type: Literal["qp"] = "qp"
    gain: float = Field(
        0.3, gt=0.0, le=1.0, description="lambda: the fraction of the error one step aims at."
    )
    r_weights: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (1.0, 1.0, 1.0), description="Diagonal of R: penalty on [dx, dy, dtheta] (feature^2/u^2)."
    )


class ScriptedControllerConfig(StrictModel):
    """Drive the gripper through absolute world poses, ignoring the feature and J.

    Each step moves towards the current waypoint by at most the loop's `max_step` per axis and
    advances to the next waypoint once within `tolerance` on every axis; the run ends when the
    last one is reached and the rod has settled.
    """

    type: Literal["scripted"] = "scripted"
    waypoints: list[Pose] = Field(
        ...,
        min_length=1,
        description="Absolute gripper poses [[x, y, theta], ...] (world frame, m, rad), in order.",
    )
    tolerance: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (1e-4, 1e-4, 1e-3),
        description="A waypoint is reached when every axis is within this [m, m, rad].",
    )


ControllerConfig = Annotated[
    MfacControllerConfig | PinvControllerConfig | QpControllerConfig | ScriptedControllerConfig,
    Field(discriminator="type"),
]
