"""Config of the simulated rod (pymunk chain) and the robot gripper that holds it.

Owned by `rodctl/sim/`. Defaults describe a 0.5 m elastic rod (EI = 5e-3 N m^2, rho*A =
0.0785 kg/m, a typical power cable).

The integrator keys (`dt`, `iterations`, `damping`, `inertia_radius`) are tuned for the quasi-static
use the experiment makes of the rod: only the settled shape matters, and it does not depend on the
rotary inertia (nor on the masses, without gravity), so the simulator inflates rotary inertia and
damps the first bending mode critically to settle in few steps (see `rodctl/sim/chain.py`). The
settled shape matches the elastica to ~0.02 % of L at N = 50 (tests/sim/), and with `gravity` the
heavy elastica to ~0.05 % of L up to q L^3/EI = 100.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    NonNegativeFloat,
    PositiveFloat,
    ValidationError,
    model_serializer,
    model_validator,
)

from rodctl.config.base import Angle, Coordinate, Point2, Pose, StrictModel

#: Tuple items of a per-axis step limit, in (0, hi]: metres (x, y) and radians (theta).
_StepMetres = Annotated[float, Field(gt=0, le=1.0)]
_StepRadians = Annotated[float, Field(gt=0, le=3.2)]

#: Standard gravity (m/s²): the weight pressing a rod on the table (`table_friction`).
STANDARD_GRAVITY = 9.80665

#: Material presets: outer diameter (m), wall thickness (m, None = solid), Young's modulus (Pa),
#: density (kg/m³). Sources and ranges are in docs/simulation.md ("Materials"); the power cable
#: is an effective (composite) modulus chosen so that it is the default rod.
MATERIALS: dict[str, dict[str, float | None]] = {
    "spring_steel_wire": {"diameter": 1.0e-3, "wall": None, "modulus": 200e9, "density": 7850.0},
    "nitinol_wire": {"diameter": 1.0e-3, "wall": None, "modulus": 75e9, "density": 6450.0},
    "pvc_tube": {"diameter": 8.0e-3, "wall": 1.5e-3, "modulus": 20e6, "density": 1250.0},
    "silicone_tube": {"diameter": 8.0e-3, "wall": 1.5e-3, "modulus": 3e6, "density": 1150.0},
    "rubber_cord": {"diameter": 6.0e-3, "wall": None, "modulus": 2e6, "density": 950.0},
    "power_cable": {"diameter": 10.0e-3, "wall": None, "modulus": 10.19e6, "density": 1000.0},
}


class MaterialConfig(StrictModel):
    """A round rod or tube of one material: EI and ρA follow from its section.

    `name` picks a preset whose diameter, wall, modulus and density are the defaults; any of
    them may be given to override the preset (e.g. a thicker PVC tube). `name: custom` needs all
    of diameter, modulus and density.
    """

    name: Literal[
        "spring_steel_wire",
        "nitinol_wire",
        "pvc_tube",
        "silicone_tube",
        "rubber_cord",
        "power_cable",
        "custom",
    ] = Field(description="A preset (see the materials table in docs/simulation.md) or 'custom'.")
    diameter: PositiveFloat | None = Field(None, le=1.0, description="Outer diameter (m).")
    wall: PositiveFloat | None = Field(
        None,
        le=0.5,
        description="Tube wall thickness (m); None: the preset's (solid for a wire/cord).",
    )
    modulus: PositiveFloat | None = Field(None, le=1e13, description="Young's modulus E (Pa).")
    density: PositiveFloat | None = Field(None, le=1e5, description="Density (kg/m³).")

    @model_validator(mode="after")
    def _complete(self) -> MaterialConfig:
        self.section()  # raises a ValueError naming what is missing or inconsistent
        return self

    def section(self) -> tuple[float, float | None, float, float]:
        """(diameter, wall or None, modulus, density) resolved against the preset, checked."""
        preset = MATERIALS.get(self.name, {})
        vals: dict[str, Any] = {}
        for key in ("diameter", "wall", "modulus", "density"):
            own = getattr(self, key)
            vals[key] = own if own is not None else preset.get(key)
        for key in ("diameter", "modulus", "density"):
            if vals[key] is None:
                raise ValueError(f"material '{self.name}' needs {key}")
        d, wall = float(vals["diameter"]), vals["wall"]
        if wall is not None and not 2 * wall < d:
            raise ValueError(f"wall {wall} m must be less than half the diameter {d} m")
        return (
            d,
            (None if wall is None else float(wall)),
            float(vals["modulus"]),
            float(vals["density"]),
        )

    def stiffness_and_mass(self) -> tuple[float, float]:
        """(EI in N m², ρA in kg/m) of the round section: I = π(d⁴ − dᵢ⁴)/64, A = π(d² − dᵢ²)/4."""
        d, wall, modulus, density = self.section()
        inner = 0.0 if wall is None else d - 2.0 * wall
        second_moment = math.pi * (d**4 - inner**4) / 64.0
        area = math.pi * (d**2 - inner**2) / 4.0
        return modulus * second_moment, density * area


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

    def contains(self, pose: Any) -> bool:
        """Whether the pose [x, y, theta] lies in the box (limits included; reach not checked)."""
        x, y, th = (float(v) for v in pose)
        return (
            self.x_limits[0] <= x <= self.x_limits[1]
            and self.y_limits[0] <= y <= self.y_limits[1]
            and self.theta_limits[0] <= th <= self.theta_limits[1]
        )


#: The x0 end's workspace by default (dual-arm): a box around the clamp, not the gripper's.
_CLAMP_WORKSPACE = {"x_limits": (-0.2, 0.25), "y_limits": (-0.35, 0.35)}


class ClampArmConfig(StrictModel):
    """The second arm of a dual-arm set-up (`rod.arms: 2`): it holds the x0 end (the clamp) and
    moves it in (x, y, theta) like the gripper, with its own speed limit and workspace."""

    @model_validator(mode="before")
    @classmethod
    def _own_defaults(cls, data: Any) -> Any:
        """A workspace given in part keeps the x0 end's defaults for the rest (not the
        gripper's, whose x range [0.05, 0.6] m excludes the default clamp pose)."""
        if isinstance(data, dict) and isinstance(data.get("workspace"), dict):
            data = {**data, "workspace": {**_CLAMP_WORKSPACE, **data["workspace"]}}
        return data

    max_step: tuple[_StepMetres, _StepMetres, _StepRadians] = Field(
        (0.01, 0.01, 0.05),
        description="Per-axis limit [dx, dy, dtheta] (m, m, rad) on one step of the x0 end.",
    )
    workspace: WorkspaceConfig = Field(
        WorkspaceConfig(**_CLAMP_WORKSPACE),
        description=(
            "Where the x0 end may go (its max_reach and on_violation as for the gripper; the "
            "ends' distance is held within the smaller of the two max_reach)."
        ),
    )


class RodConfig(StrictModel):
    """A planar elastic rod: one end clamped, the other held by a gripper moving in (x, y, θ)."""

    length: PositiveFloat = Field(0.5, le=100.0, description="Rod length L (m).")
    bending_stiffness: PositiveFloat = Field(
        5e-3,
        le=1e6,
        description="Bending stiffness EI (N m^2). Computed from `material` if that is set.",
    )
    mass_per_length: PositiveFloat = Field(
        0.0785,
        le=1e4,
        description="Mass per unit length rho*A (kg/m). Computed from `material` if that is set.",
    )
    material: MaterialConfig | None = Field(
        None,
        description=(
            "A real rod's material and section (a preset name, fields override it); sets EI and "
            "rho*A. Giving EI or rho*A as well is allowed only if they agree with it."
        ),
    )
    gravity: Point2 = Field(
        (0.0, 0.0),
        description=(
            "Gravity in the rod's plane [gx, gy] (m/s^2, world frame): a rod in a vertical plane, "
            "e.g. [0, -9.81]. [0, 0]: weightless (the paper's set-up)."
        ),
    )
    table_friction: NonNegativeFloat | None = Field(
        None,
        le=10.0,
        description=(
            "Coulomb friction coefficient of a table under a horizontal rod (its weight, at "
            "standard gravity, presses it on the table). None: no table. Exclusive with gravity."
        ),
    )
    engine: Literal["pymunk", "quasistatic"] = Field(
        "pymunk",
        description=(
            "pymunk: the chain's dynamics run until it settles (the paper's set-up). quasistatic: "
            "the same chain's settled equilibrium solved directly by Newton's method "
            "(docs/engines.md); dt, iterations, damping, inertia_radius, settle_speed_tol and "
            "max_settle_time only concern the dynamics and are not used by it."
        ),
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
    arms: Literal[1, 2] = Field(
        1,
        description=(
            "1: the x0 end is clamped, the gripper moves (q = 3). 2: dual-arm, the x0 end is "
            "held by a second arm (`clamp_arm`) that moves too: a command is [dx, dy, dtheta] of "
            "the gripper, then of the x0 end (q = 6); docs/dual-arm.md."
        ),
    )
    clamp_arm: ClampArmConfig = Field(
        ClampArmConfig(),
        description="The second arm's speed limit and workspace (only with arms: 2).",
    )
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
    max_step: tuple[_StepMetres, _StepMetres, _StepRadians] = Field(  # noqa: E501
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

    @model_serializer(mode="wrap")
    def _omit_off_physics(self, handler: Any) -> Any:
        """Leave `material`, `gravity`, `table_friction`, `engine` out of a dump while off.

        Why: the resolved config is logged in every run (MCAP metadata, header, attachment), and
        a weightless rod without a table must keep producing byte-identical logs to the versions
        before these keys existed. The keys are still in the schema (`rodctl config schema`).
        """
        data = handler(self)
        if isinstance(data, dict):
            if self.material is None:
                data.pop("material", None)
            if tuple(self.gravity) == (0.0, 0.0):
                data.pop("gravity", None)
            if self.table_friction is None:
                data.pop("table_friction", None)
            if self.engine == "pymunk":
                data.pop("engine", None)
            if self.arms == 1:  # one arm: the dump of the versions before dual-arm
                data.pop("arms", None)
                data.pop("clamp_arm", None)
        return data

    @model_validator(mode="before")
    @classmethod
    def _material_sets_section(cls, data: Any) -> Any:
        """Fill EI and rho*A from `material`; explicit values must agree (a resolved config
        carries both, and must load again)."""
        if not isinstance(data, dict) or data.get("material") is None:
            return data
        material = data["material"]
        if not isinstance(material, MaterialConfig):
            try:
                material = MaterialConfig.model_validate(material)
            except ValidationError:
                return data  # the field's own validation reports it, at rod.material.<key>
        ei, rho_a = material.stiffness_and_mass()
        out = dict(data)
        for key, value in (("bending_stiffness", ei), ("mass_per_length", rho_a)):
            given = out.get(key)
            if given is not None and not _close(given, value):
                raise ValueError(
                    f"{key} = {given} disagrees with material '{material.name}' ({value:.6g}); "
                    f"give one or the other"
                )
            out[key] = value
        out["material"] = material
        return out

    @model_validator(mode="after")
    def _one_plane(self) -> RodConfig:
        if self.table_friction is not None and tuple(self.gravity) != (0.0, 0.0):
            raise ValueError(
                "table_friction (a horizontal rod on a table) and an in-plane gravity (a rod in a "
                "vertical plane) exclude each other; set one of them"
            )
        return self

    @model_validator(mode="after")
    def _engine_supports(self) -> RodConfig:
        if self.engine == "quasistatic" and self.table_friction is not None:
            raise ValueError(
                "table_friction is not supported with engine: quasistatic. On a table the "
                "settled shape depends on the path the rod slid along; the quasi-static "
                "engine's incremental minimisation agrees with the pymunk table driven slowly, "
                "but the pymunk table as configured (its control_period) settles 0.3-0.6 % of "
                "L away from that, beyond the 0.2 % agreement asked for (docs/engines.md, "
                "Friction), so it is refused rather than giving other shapes. Use engine: "
                "pymunk for a rod on a table"
            )
        return self

    @model_validator(mode="after")
    def _clamp_arm_needs_two(self) -> RodConfig:
        if self.arms == 1 and "clamp_arm" in self.model_fields_set:
            raise ValueError("clamp_arm is the second arm's: it needs arms: 2")
        if self.arms == 2 and not self.clamp_arm.workspace.contains(self.clamp_pose):
            raise ValueError(
                f"rod.clamp_pose {list(self.clamp_pose)} (the x0 end's start with arms: 2) is "
                f"outside rod.clamp_arm.workspace ({_box_text(self.clamp_arm.workspace)})"
            )
        return self

    def _reach_m(self) -> float:
        """Largest distance (m) between the ends at the start: max_reach of the rod length
        (dual-arm: the smaller of the two arms' max_reach, as `RodSim` clips)."""
        reach = self.workspace.max_reach
        if self.arms == 2:
            reach = min(reach, self.clamp_arm.workspace.max_reach)
        return reach * self.length

    @model_validator(mode="after")
    def _home_inside(self) -> RodConfig:
        if self.home_pose is not None:
            x, y, _ = self.home_pose
            cx, cy, _ = self.clamp_pose
            inside = (
                self.workspace.contains(self.home_pose)
                and ((x - cx) ** 2 + (y - cy) ** 2) ** 0.5 <= self._reach_m()
            )
            if not inside:
                raise ValueError(
                    f"home_pose {list(self.home_pose)} is outside rod.workspace or beyond "
                    f"max_reach * length = {self._reach_m():.4g} m from the clamp"
                    + (" (the smaller of the two arms' max_reach)" if self.arms == 2 else "")
                )
        return self


def _box_text(ws: WorkspaceConfig) -> str:
    return (
        f"x in {list(ws.x_limits)} m, y in {list(ws.y_limits)} m, "
        f"theta in {list(ws.theta_limits)} rad"
    )


def _close(given: Any, value: float) -> bool:
    try:
        return abs(float(given) - value) <= 1e-9 * abs(value)
    except (TypeError, ValueError):
        return False
