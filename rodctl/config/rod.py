"""Config of the simulated rod (pymunk chain) and the robot gripper that holds it.

Owned by `rodctl/sim/`. Defaults describe a 0.5 m elastic rod (EI = 5e-3 N m^2, rho*A =
0.0785 kg/m, the cable measured in shared/reference/research/simulation.md).

The integrator keys (`dt`, `iterations`, `damping`, `inertia_radius`) are tuned for the quasi-static
use the experiment makes of the rod: only the settled shape matters, and it does not depend on the
masses, so the simulator inflates rotary inertia and damps the first bending mode critically to
settle in few steps (see `rodctl/sim/chain.py`). The settled shape matches the elastica to ~0.02 %
of L at N = 50 (tests/sim/).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, NonNegativeFloat, PositiveFloat, model_validator

from rodctl.config.base import Angle, Coordinate, Pose, StrictModel, bounded


class WorkspaceConfig(StrictModel):
    """Where the gripper may go. A pose outside is clipped or refused (see `on_violation`)."""

    x_limits: tuple[Coordinate, Coordinate] = Field((0.05, 0.6), description="Gripper x range (m).")
    y_limits: tuple[Coordinate, Coordinate] = Field(
        (-0.35, 0.35), description="Gripper y range (m)."
    )
    theta_limits: tuple[Angle, Angle] = Field(
        (-2.0, 2.0), description="Gripper angle range (rad), world frame."
    )
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
        for name in ("x_limits", "y_limits", "theta_limits"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name} must be [low, high] with low < high, got [{lo}, {hi}]")
        return self


class RodConfig(StrictModel):
    """A planar elastic rod: one end clamped, the other held by a gripper moving in (x, y, θ)."""

    length: PositiveFloat = Field(0.5, le=100.0, description="Rod length L (m).")
    bending_stiffness: PositiveFloat = Field(
        5e-3, le=1e6, description="Bending stiffness EI (N m^2)."
    )
    mass_per_length: PositiveFloat = Field(
        0.0785, le=1e4, description="Mass per unit length rho*A (kg/m)."
    )
    segments: int = Field(50, le=1000, ge=2, description="Number of rigid segments in the chain.")
    clamp_pose: Pose = Field((0.0, 0.0, 0.0), description="Pose of the clamped end (world).")
    home_pose: Pose | None = Field(
        None,
        description=(
            "Gripper pose at the start of a run (world). None: a gently bent pose, "
            "[0.8 L, 0.2 L, 0.5 rad] from the clamp in the clamp's frame."
        ),
    )
    workspace: WorkspaceConfig = WorkspaceConfig()
    dt: PositiveFloat | None = Field(
        None,
        le=0.1,
        description=(
            "Simulation time step (s). None: half the explicit-spring stability limit "
            "2/omega_max of the zig-zag mode, which depends on L, EI, rho*A, N, inertia_radius."
        ),
    )
    iterations: int = Field(
        20, le=1000, ge=1, description="Constraint solver iterations per time step."
    )
    damping: NonNegativeFloat = Field(
        1.0,
        le=100.0,
        description=(
            "Global velocity damping as a fraction of critical damping of the first bending "
            "mode (1 = critical: fastest settling; 0 = undamped)."
        ),
    )
    inertia_radius: float = Field(
        0.3,
        ge=0.0,
        le=1.5,
        description=(
            "Fictitious radius of gyration added to every segment, as a fraction of L. Makes "
            "rotation dominate the dynamics so the rod settles in ~N steps; does not change any "
            "settled shape."
        ),
    )
    control_period: PositiveFloat = Field(
        0.1,
        le=10.0,
        description="Simulated time (s) over which one control step moves the gripper.",
    )
    max_step: tuple[
        bounded(0, 1.0, strict_lo=True),
        bounded(0, 1.0, strict_lo=True),
        bounded(0, 3.2, strict_lo=True),
    ] = Field(  # noqa: E501
        (0.01, 0.01, 0.05),
        description="Per-axis limit [dx, dy, dtheta] (m, m, rad) on one control step's move.",
    )
    settle_speed_tol: PositiveFloat = Field(
        2e-4,
        le=1e3,
        description=(
            "The rod counts as settled when no segment end moves faster than this (m/s) at two "
            "checks in a row. The residual shape error is about this speed / omega_1 (~10 um "
            "at the defaults, omega_1 ~ 21 rad/s)."
        ),
    )
    max_settle_time: PositiveFloat = Field(
        5.0, le=1000.0, description="Simulated time (s) allowed for settling after a move."
    )
    gap_limit: PositiveFloat = Field(
        1e-3,
        le=1.0,
        description=(
            "A pivot joint opening wider than this (m), or any NaN, marks the simulation as "
            "diverged."
        ),
    )

    @model_validator(mode="after")
    def _home_inside(self) -> RodConfig:
        if self.home_pose is not None:
            ws = self.workspace
            x, y, th = self.home_pose
            cx, cy, _ = self.clamp_pose
            inside = (
                ws.x_limits[0] <= x <= ws.x_limits[1]
                and ws.y_limits[0] <= y <= ws.y_limits[1]
                and ws.theta_limits[0] <= th <= ws.theta_limits[1]
                and ((x - cx) ** 2 + (y - cy) ** 2) ** 0.5 <= ws.max_reach * self.length
            )
            if not inside:
                raise ValueError(
                    f"home_pose {list(self.home_pose)} is outside rod.workspace or beyond "
                    f"max_reach * length = {ws.max_reach * self.length:.4g} m from the clamp"
                )
        return self
