"""Config of the experiment loop: target, probing, step budget and stopping criteria.

Owned by `rodctl/episode.py` (stop rules) and `rodctl/env.py` (targets).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    BeforeValidator,
    ConfigDict,
    Field,
    PositiveFloat,
    PositiveInt,
    WithJsonSchema,
    model_validator,
)

from rodctl.config.base import Angle, Coordinate, Pose, StageConfig, StageSlot, StrictModel
from rodctl.outcome import EXPECTABLE, Outcome
from rodctl.registry import depends_on_stages

#: Tuple items of a probing move, in (0, hi]: metres (x, y) and radians (theta).
_ProbeMetres = Annotated[float, Field(gt=0, le=0.1)]
_ProbeRadians = Annotated[float, Field(gt=0, le=1.0)]

#: One mid-run event, chosen by `type` among every type registered in `rodctl.registry.EVENTS`
#: (the built-ins are in rodctl/events.py; a plug-in adds more). An unknown `type` is refused.
Event = Annotated[StageConfig, StageSlot("event")]


def _expectable(value: object) -> object:
    """Refuse what no config can expect, with the list of what it can (before the enum)."""
    if isinstance(value, str) and value not in EXPECTABLE:
        names = [repr(o.value) for o in EXPECTABLE]
        raise ValueError(f"Input should be {', '.join(names[:-1])} or {names[-1]}")
    return value


#: An outcome a config may declare (`run.expect`): one of `rodctl.outcome.EXPECTABLE`.
ExpectedOutcome = Annotated[
    Outcome,
    BeforeValidator(_expectable),
    WithJsonSchema({"enum": [o.value for o in EXPECTABLE], "type": "string"}),
]


#: Both ends' poses (rod.arms: 2): the gripper's [x, y, theta], then the x0 end's.
EndPoses = tuple[Coordinate, Coordinate, Angle, Coordinate, Coordinate, Angle]


class TargetConfig(StrictModel):
    """Where the target shape comes from. Targets are reachable by construction: the rod is driven
    to a gripper pose, allowed to settle, and the camera's view of it becomes the target."""

    pose: Pose | EndPoses | None = Field(
        None,
        description=(
            "Gripper pose that produces the target shape (world). None: sample one. Dual-arm "
            "(rod.arms: 2): 6 values, the gripper's pose then the x0 end's (3: the x0 end stays)."
        ),
    )
    min_offset: float = Field(
        0.3,
        le=100.0,
        ge=0.0,
        description="Sampled targets: least normalised distance from home (docs/configs.md).",
    )
    max_offset: float = Field(
        1.0, le=100.0, gt=0.0, description="Sampled targets: largest normalised distance from home."
    )

    @model_validator(mode="after")
    def _ordered(self) -> TargetConfig:
        if self.min_offset > self.max_offset:
            raise ValueError(
                f"min_offset ({self.min_offset}) must not exceed max_offset ({self.max_offset})"
            )
        return self


@depends_on_stages
class RunConfig(StrictModel):
    """How long a run lasts and when it stops."""

    # The events' union is built from the registry when the schema is first needed (after the
    # built-in types and plug-ins have registered), and rebuilt when a type is added.
    model_config = ConfigDict(defer_build=True)

    max_steps: PositiveInt = Field(
        200, le=1_000_000, description="Step limit, probing steps included."
    )
    target: TargetConfig = TargetConfig()
    probe_size: tuple[_ProbeMetres, _ProbeMetres, _ProbeRadians] = Field(  # noqa: E501
        (0.005, 0.005, 0.03),
        description="Size of the q + 1 probing moves that initialise J: [dx m, dy m, dtheta rad].",
    )
    pixel_tolerance: PositiveFloat = Field(
        1.0,
        le=1e4,
        description="Converged when the mean distance (px) to the target centerline is below this…",
    )
    t1_tolerance: PositiveFloat | None = Field(
        None,
        le=1e9,
        description="…and T1 = ||s* - s|| is below this (feature units; None: pixel error only, "
        "the common criterion when features of different methods are compared).",
    )
    stall_window: PositiveInt = Field(
        15,
        le=100_000,
        description="Stalled when the pixel error has not improved for this many steps…",
    )
    stall_improvement: float = Field(
        0.02,
        ge=0.0,
        lt=1.0,
        description="…by at least this fraction of its value at the window's start…",
    )
    stall_gradient: PositiveFloat = Field(
        0.05,
        le=1.0,
        description="…while ||J^T e|| / (||J|| ||e||) is below this (no descent direction left).",
    )
    max_lost_frames: PositiveInt = Field(
        3, le=100_000, description="Consecutive failed centerline extractions that end the run."
    )
    events: list[Event] = Field(
        default_factory=list,
        description="Mid-run events: at a control step (probing included), before its move, the "
        "rod, the clamp, the grasp or the camera changes (rodctl/events.py, docs/simulation.md).",
    )
    jacobian_error: Literal["auto", "always", "never"] = Field(
        "auto",
        description="Score each step's Jacobian estimate against the simulator's true Jacobian "
        "(||J_est - J||_F / ||J||_F, docs/engines.md): auto = where it costs no settle (the "
        "quasi-static engine, or the oracle's own J); always = with pymunk too, by six extra "
        "settles a step that perturb the run within the settle tolerance; never.",
    )
    expect: ExpectedOutcome | None = Field(
        None,
        title="Expect",  # WithJsonSchema drops the title pydantic would give the field
        description="Outcome this config is expected to reach (checked by the config test suite).",
    )
