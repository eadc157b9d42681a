"""Config of the simulated rod (pymunk chain) and the robot gripper that holds it.

Owned by `rodctl/sim/`. Defaults describe a 0.5 m elastic rod (EI = 5e-3 N m^2, rho*A =
0.0785 kg/m, the cable measured in shared/reference/research/simulation.md).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, PositiveFloat, model_validator

from rodctl.config.base import Pose, StrictModel


class WorkspaceConfig(StrictModel):
    """Where the gripper may go. A pose outside is clipped or refused (see `on_violation`)."""

    x_limits: tuple[float, float] = Field((-1.0, 1.0), description="Gripper x range (m).")
    y_limits: tuple[float, float] = Field((-1.0, 1.0), description="Gripper y range (m).")
    max_reach: float = Field(
        0.98,
        gt=0.0,
        le=1.0,
        description="Largest clamp-to-gripper distance as a fraction of the rod length.",
    )
    on_violation: Literal["clip", "refuse"] = Field(
        "clip", description="clip: move to the nearest allowed pose; refuse: do not move."
    )

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceConfig:
        for name in ("x_limits", "y_limits"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name} must be [low, high] with low < high, got [{lo}, {hi}]")
        return self


class RodConfig(StrictModel):
    """A planar elastic rod: one end clamped, the other held by a gripper moving in (x, y, theta)."""

    length: PositiveFloat = Field(0.5, description="Rod length L (m).")
    bending_stiffness: PositiveFloat = Field(5e-3, description="Bending stiffness EI (N m^2).")
    mass_per_length: PositiveFloat = Field(0.0785, description="Mass per unit length rho*A (kg/m).")
    segments: int = Field(50, ge=2, description="Number of rigid segments in the chain.")
    clamp_pose: Pose = Field((0.0, 0.0, 0.0), description="Pose of the clamped end (world).")
    home_pose: Pose | None = Field(
        None,
        description="Gripper pose at the start of a run (world). None: a default bent pose.",
    )
    workspace: WorkspaceConfig = WorkspaceConfig()
