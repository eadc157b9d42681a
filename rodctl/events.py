"""Mid-run events: the object or the scene changes while the controller is running.

Why: with a weightless rod every rod is the same rod and nothing ever changes, so the paper's
claim that the adaptive Jacobian estimate *follows the model as it changes* cannot be tested.
These events make it change, at a given control step, through small public methods of `RodSim`
and `Camera` (the mechanics live there; this module is the config and the registrations).

An event type is registered like a stage (`rodctl.registry.EVENTS`): a config model derived from
`EventConfig` (a `type` literal, the discriminator, and `at_step`, the control step, probing
included, before whose move it applies) and an apply function `apply(event, sim, camera) -> str`
that mutates the simulator and/or the camera and returns one human-readable log line::

    class Gust(EventConfig):
        # (a docstring: what happens, in the units of its fields)
        type: Literal["gust"] = "gust"
        dy: float = Field(ge=-0.1, le=0.1, description="Sideways push (m).")

    @EVENTS.register(Gust)
    def _apply(event: Gust, sim, camera) -> str:
        ...
        return f"event gust: {event.dy} m"

`run.events` is the union of every registered type, so a plug-in adds one without editing
rodctl, and an unknown `type` is refused by the config's validation. The environment decides when
to call `event.apply(sim, camera)`; see `apply_due` for the intended order.

What the environment must redo itself after an event (this module cannot see its objects):

* `camera_bump` and `clamp_move`: rebuild the centerline extractor (it calibrates the clamp's
  pixel from the camera and the clamp pose: `CenterlineExtractor(cfg.camera, camera,
  sim.clamp_pose, rod_length=sim.held_length)`); after `camera_bump` also re-project the
  target's world centerline through the bumped camera (the target stays the same physical
  shape). After `clamp_move`, render with `sim.clamp_pose`, not `cfg.rod.clamp_pose`.
* `grasp_slip`: rebuild the extractor too: its `rod_length` becomes `sim.held_length`
  (`sim.centerline()` is the held part only).
* `noise`, `occluder`, `stiffness`, `weight`: nothing (the camera reads its render settings every
  frame). Each model's `refresh` class attribute says this in code: {"extractor"},
  {"extractor", "target_pixels"} or empty.

`validate_events` checks what can be checked before the run: every `at_step` below the step
limit, then each event's own `check(state, field)` in step order on an `EventState` (what the
earlier events left: the held length, the clamp pose, the camera pose, the occluders), e.g. a
slip longer than the rod, a clamp pose out of reach of the target, removing an occluder that is
not there; it raises a `UserError` naming the field, e.g. `run.events[2].ds`. Both live in
`rodctl/config/events.py`, which the config's validation imports (config never imports this
module); they are re-exported here for plug-in authors.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import (
    Field,
    NonNegativeFloat,
    NonNegativeInt,
    PositiveFloat,
    ValidationError,
    model_validator,
)

from rodctl.config.base import Point2, Pose, StrictModel
from rodctl.config.camera import CameraConfig
from rodctl.config.events import EventState, validate_events
from rodctl.config.run import Event
from rodctl.errors import UserError
from rodctl.registry import EVENTS

if TYPE_CHECKING:
    from rodctl.sim.rod import ApplyResult, RodSim
    from rodctl.vision.camera import Camera

__all__ = [
    "CameraBump",
    "ClampMove",
    "Event",
    "EventConfig",
    "EventState",
    "GraspSlip",
    "NoiseChange",
    "OccluderChange",
    "StiffnessChange",
    "WeightChange",
    "apply_due",
    "due",
    "validate_events",
]


def _settle_note(result: ApplyResult) -> str:
    if result.diverged:
        return "; the rod DIVERGED"
    state = "settled" if result.settled else "NOT settled"
    return f"; {state} after {result.settle_time:.2f} s sim"


#: Bounded values of event fields (every config number has an upper bound; docs/reliability.md).
_Step = Annotated[float, Field(gt=0.0, le=1.0)]
_Turn = Annotated[float, Field(gt=0.0, le=3.2)]
_Px = Annotated[float, Field(ge=-1e5, le=1e5)]


class EventConfig(StrictModel):
    """Base of every event config model: `at_step`, `refresh`, `apply` and `check`."""

    at_step: NonNegativeInt = Field(
        le=1_000_000,
        description="Control step (probing included) before whose move the event applies.",
    )

    #: What the environment must refresh after this event (see the module docstring):
    #: "extractor" = rebuild the CenterlineExtractor from `camera`, `sim.clamp_pose` and
    #: `sim.held_length`; "target_pixels" = re-project the target's world centerline.
    refresh: ClassVar[frozenset[str]] = frozenset()

    #: One valid instance as a dict (with `type` and `at_step`): the meta-tests and
    #: `rodctl.testing.check_event` apply it to a small rod, so every registered type is run.
    example: ClassVar[dict[str, Any] | None] = None

    def apply(self, sim: RodSim, camera: Camera) -> str:
        """Apply the event through its registered apply function; its log line."""
        return EVENTS.build(self, sim, camera)

    def check(self, state: EventState, field: str) -> None:
        """Refuse (`UserError` naming `field`.<key>) what cannot apply after the events before
        it, and update `state` with what this event changes. The default checks nothing."""


class _FactorOrValue(EventConfig):
    factor: PositiveFloat | None = Field(
        None, le=1e3, description="Multiply the current value by this."
    )
    value: PositiveFloat | None = Field(None, le=1e6, description="Set this absolute value.")

    @model_validator(mode="after")
    def _one_of(self) -> _FactorOrValue:
        if (self.factor is None) == (self.value is None):
            raise ValueError("give exactly one of factor and value")
        return self

    def new_value(self, current: float) -> float:
        """The value after the event, from the current one."""
        if self.value is not None:
            return float(self.value)
        return current * float(self.factor or 1.0)


class StiffnessChange(_FactorOrValue):
    """The rod's bending stiffness EI changes (e.g. it warms up, or another rod is swapped in).

    `value` is EI in N m². Under gravity or on a table the settled shape changes; a weightless
    rod's shape does not depend on EI at all (only its end poses).
    """

    type: Literal["stiffness"] = "stiffness"
    example: ClassVar[dict[str, Any] | None] = {"type": "stiffness", "at_step": 1, "factor": 2.0}


@EVENTS.register(StiffnessChange)
def _apply_stiffness(event: StiffnessChange, sim: RodSim, camera: Camera) -> str:
    """EI changes and the rod settles (`RodSim.set_bending_stiffness`)."""
    old = sim.bending_stiffness
    new = event.new_value(old)
    result = sim.set_bending_stiffness(new)
    return f"event stiffness: EI {old:.4g} -> {new:.4g} N m^2{_settle_note(result)}"


class WeightChange(_FactorOrValue):
    """The rod's mass per length ρA changes (it picks up a load, water, a heavier sleeve).

    `value` is ρA in kg/m. Changes the shape under gravity and the friction on a table.
    """

    type: Literal["weight"] = "weight"
    example: ClassVar[dict[str, Any] | None] = {"type": "weight", "at_step": 1, "factor": 2.0}


@EVENTS.register(WeightChange)
def _apply_weight(event: WeightChange, sim: RodSim, camera: Camera) -> str:
    """ρA changes and the rod settles (`RodSim.set_mass_per_length`)."""
    old = sim.mass_per_length
    new = event.new_value(old)
    result = sim.set_mass_per_length(new)
    return f"event weight: rho*A {old:.4g} -> {new:.4g} kg/m{_settle_note(result)}"


def _check_reach(state: EventState, name: str, what: str, why: str) -> None:
    """A fixed target pose must stay within max_reach of the held length from the clamp."""
    dist = state.target_distance()
    if dist is None:
        return
    reach = state.max_reach * state.held * state.segment
    if dist > reach:
        raise UserError(
            f"{name}.{what}: after this event the target pose run.target.pose is "
            f"{dist:.4g} m from the clamp, beyond max_reach * held length = {reach:.4g} m"
            f" ({why})"
        )


class ClampMove(EventConfig):
    """The clamped end is driven to a new pose, the gripper holding still (a bumped fixture).

    It moves in a straight line within `max_step` per control period, settling after each
    increment; if the gripper would end up beyond `rod.workspace.max_reach` of the held length,
    the clamp stops at that limit (logged).
    """

    type: Literal["clamp_move"] = "clamp_move"
    example: ClassVar[dict[str, Any] | None] = {
        "type": "clamp_move",
        "at_step": 1,
        "pose": (0.0, 0.02, 0.1),
    }
    refresh: ClassVar[frozenset[str]] = frozenset({"extractor"})
    pose: Pose = Field(description="New clamp pose [x, y, theta] (world).")
    max_step: tuple[_Step, _Step, _Turn] | None = Field(
        None, description="Per-axis limit per control period (m, m, rad); None: rod.max_step."
    )

    def check(self, state: EventState, field: str) -> None:
        """The fixed target stays within reach of the moved clamp."""
        state.clamp = np.asarray(self.pose, dtype=float)
        _check_reach(state, field, "pose", "the clamp pose is out of reach")
        state.check_rod_in_front(f"{field}.pose")


@EVENTS.register(ClampMove)
def _apply_clamp_move(event: ClampMove, sim: RodSim, camera: Camera) -> str:
    """The clamp is driven to the new pose (`RodSim.move_clamp`)."""
    old = sim.clamp_pose
    result = sim.move_clamp(
        np.asarray(event.pose, dtype=float),
        None if event.max_step is None else np.asarray(event.max_step, dtype=float),
    )
    new = sim.clamp_pose
    clip = " (stopped at the reach limit)" if result.clipped else ""
    return f"event clamp_move: clamp {_fmt(old)} -> {_fmt(new)}{clip}{_settle_note(result)}"


class GraspSlip(EventConfig):
    """The grasp point slides along the rod by `ds`: the held length changes, the gripper stays.

    ds > 0: towards the clamp (held length shrinks); ds < 0: away from it (grows back, at most
    to rod.length). Rounded to whole segments (rod.length / rod.segments).
    """

    type: Literal["grasp_slip"] = "grasp_slip"
    example: ClassVar[dict[str, Any] | None] = {"type": "grasp_slip", "at_step": 1, "ds": 0.05}
    refresh: ClassVar[frozenset[str]] = frozenset({"extractor"})
    ds: float = Field(
        ge=-100.0,
        le=100.0,
        description="Slide of the grasp point along the rod (m), + towards clamp.",
    )

    @model_validator(mode="after")
    def _nonzero(self) -> GraspSlip:
        if self.ds == 0:
            raise ValueError("ds must be nonzero")
        return self

    def check(self, state: EventState, field: str) -> None:
        """At least 2 segments stay held, at most rod.length; the target stays within reach."""
        seg, held = state.segment, state.held
        k = round(self.ds / seg)
        if k == 0:
            raise UserError(
                f"{field}.ds: {self.ds} m is less than half a segment ({seg:.4g} m); "
                "the slip is rounded to whole segments"
            )
        if held - k < 2:
            raise UserError(
                f"{field}.ds: a slip of {self.ds} m is longer than the held rod "
                f"({held * seg:.4g} m at that step; at least 2 segments must stay held)"
            )
        if held - k > state.segments:
            raise UserError(
                f"{field}.ds: a slip of {self.ds} m makes the held length "
                f"{(held - k) * seg:.4g} m, longer than rod.length = {state.length} m"
            )
        state.held = held - k
        _check_reach(state, field, "ds", "the held rod is too short to reach the target")


@EVENTS.register(GraspSlip)
def _apply_grasp_slip(event: GraspSlip, sim: RodSim, camera: Camera) -> str:
    """The grasp point slides (`RodSim.slip_grasp`)."""
    old = sim.held_length
    result = sim.slip_grasp(event.ds)
    clip = " (gripper clipped to the reach of the held length)" if result.clipped else ""
    return (
        f"event grasp_slip: held length {old:.4f} -> {sim.held_length:.4f} m{clip}"
        f"{_settle_note(result)}"
    )


class CameraBump(EventConfig):
    """The camera is knocked: its extrinsics change by the given increments (intrinsics stay)."""

    type: Literal["camera_bump"] = "camera_bump"
    example: ClassVar[dict[str, Any] | None] = {
        "type": "camera_bump",
        "at_step": 1,
        "tilt_deg": 2.0,
    }
    refresh: ClassVar[frozenset[str]] = frozenset({"extractor", "target_pixels"})
    shift: Point2 = Field((0.0, 0.0), description="Added to camera.look_at (m).")
    distance: float = Field(0.0, ge=-100.0, le=100.0, description="Added to camera.distance (m).")
    tilt_deg: float = Field(
        0.0, ge=-90.0, le=90.0, description="Added to camera.tilt_deg (degrees)."
    )
    azimuth_deg: float = Field(
        0.0, ge=-360.0, le=360.0, description="Added to camera.azimuth_deg (degrees)."
    )

    def new_pose(self, look_at: Point2, distance: float, tilt: float, azimuth: float) -> dict:
        return {
            "look_at": (look_at[0] + self.shift[0], look_at[1] + self.shift[1]),
            "distance": distance + self.distance,
            "tilt_deg": tilt + self.tilt_deg,
            "azimuth_deg": azimuth + self.azimuth_deg,
        }

    def check(self, state: EventState, field: str) -> None:
        """The bumped pose is one `camera` may have (distance in (0, 100] m, tilt in [0, 80)
        deg, azimuth within +-360 deg: the camera is rebuilt from it) and has no point the rod
        can reach behind the camera."""
        before = {
            "distance": state.distance,
            "tilt_deg": state.tilt_deg,
            "azimuth_deg": state.azimuth_deg,
        }
        pose = self.new_pose(state.look_at, state.distance, state.tilt_deg, state.azimuth_deg)
        for key, was in before.items():
            try:
                CameraConfig.__pydantic_validator__.validate_assignment(
                    CameraConfig.model_construct(), key, pose[key]
                )
            except ValidationError as exc:
                why = exc.errors()[0]["msg"].replace("Input should be", "must be")
                raise UserError(
                    f"{field}.{key}: {getattr(self, key):g} takes camera.{key} from {was:g} "
                    f"to {pose[key]:.6g}, and camera.{key} {why}"
                ) from None
        state.look_at, state.distance = pose["look_at"], pose["distance"]
        state.tilt_deg, state.azimuth_deg = pose["tilt_deg"], pose["azimuth_deg"]
        state.check_rod_in_front(field)


@EVENTS.register(CameraBump)
def _apply_camera_bump(event: CameraBump, sim: RodSim, camera: Camera) -> str:
    """The camera's extrinsics change (`Camera.set_pose`)."""
    c = camera.cfg
    pose = event.new_pose(c.look_at, c.distance, c.tilt_deg, c.azimuth_deg)
    camera.set_pose(**pose)
    return (
        f"event camera_bump: look_at {_fmt(pose['look_at'])} m, distance "
        f"{pose['distance']:.4g} m, tilt {pose['tilt_deg']:.4g} deg, azimuth "
        f"{pose['azimuth_deg']:.4g} deg"
    )


class OccluderChange(EventConfig):
    """An occluder (a grey box in pixel coordinates) appears or disappears."""

    type: Literal["occluder"] = "occluder"
    example: ClassVar[dict[str, Any] | None] = {
        "type": "occluder",
        "at_step": 1,
        "action": "add",
        "box": (0, 0, 10, 10),
    }
    action: Literal["add", "remove"] = Field(description="add: appears; remove: disappears.")
    box: tuple[_Px, _Px, _Px, _Px] = Field(
        description="[u0, v0, u1, v1] (px), as camera.render.occlusions."
    )

    @model_validator(mode="after")
    def _ordered(self) -> OccluderChange:
        u0, v0, u1, v1 = self.box
        if not (u0 < u1 and v0 < v1):
            raise ValueError(f"box must be [u0, v0, u1, v1] with u0 < u1, v0 < v1, got {self.box}")
        return self

    def check(self, state: EventState, field: str) -> None:
        """An occluder is removed only if present (configured or added by an earlier event)."""
        box = tuple(float(v) for v in self.box)
        if self.action == "add":
            state.boxes.append(box)
        elif box in state.boxes:
            state.boxes.remove(box)
        else:
            raise UserError(
                f"{field}.box: no occluder {list(box)} is present at step {self.at_step} "
                "(neither in camera.render.occlusions nor added by an earlier event)"
            )


@EVENTS.register(OccluderChange)
def _apply_occluder(event: OccluderChange, sim: RodSim, camera: Camera) -> str:
    """The box is added to or removed from the camera's occlusions."""
    if event.action == "add":
        camera.add_occlusion(event.box)
        return f"event occluder: appears at {list(event.box)} px"
    camera.remove_occlusion(event.box)
    return f"event occluder: {list(event.box)} px disappears"


class NoiseChange(EventConfig):
    """The image gets noisier or cleaner (lighting, gain): pixel noise σ and optionally blur."""

    type: Literal["noise"] = "noise"
    example: ClassVar[dict[str, Any] | None] = {"type": "noise", "at_step": 1, "noise_std": 3.0}
    noise_std: NonNegativeFloat = Field(le=100.0, description="New pixel noise σ (grey levels).")
    blur_sigma: NonNegativeFloat | None = Field(
        None, le=10.0, description="New blur σ (px); None: keep."
    )


@EVENTS.register(NoiseChange)
def _apply_noise(event: NoiseChange, sim: RodSim, camera: Camera) -> str:
    """The camera's render noise changes (`Camera.set_noise`)."""
    camera.set_noise(event.noise_std, event.blur_sigma)
    blur = "" if event.blur_sigma is None else f", blur sigma {event.blur_sigma:.3g} px"
    return f"event noise: pixel noise sigma {event.noise_std:.3g}{blur}"


def _fmt(pose: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.4f}" for v in np.asarray(pose, dtype=float)) + "]"


def due(events: list[Any], step: int) -> list[Any]:
    """The events that apply at control step `step`, in the order they were listed."""
    return [e for e in events if e.at_step == step]


def apply_due(events: list[Any], step: int, sim: RodSim, camera: Camera) -> list[str]:
    """Apply every event of `step` in list order; return their log lines (one each).

    Intended call: in the control loop, after the observation of step k-1 was used and before
    step k's move is applied (so the controller's next observation already sees the change).
    """
    return [event.apply(sim, camera) for event in due(events, step)]
