"""Mid-run events: the object or the scene changes while the controller is running.

Why: with a weightless rod every rod is the same rod and nothing ever changes, so the paper's
claim that the adaptive Jacobian estimate *follows the model as it changes* cannot be tested.
These events make it change, at a given control step, through small public methods of `RodSim`
and `Camera` (the mechanics live there; this module is the config and the dispatch).

Each event is a pydantic model with `type` (the discriminator) and `at_step` (the control step,
probing included, before whose move it applies), and a method `apply(sim, camera) -> str` that
mutates the simulator and/or the camera and returns one human-readable log line. The
environment decides when to call it; see `apply_due` for the intended order.

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

`validate_events` checks what can be checked before the run (a slip longer than the rod, a
clamp pose out of reach of the target, a step past the step limit, removing an occluder that is
not there) and raises a `UserError` naming the field, e.g. `run.events[2].ds`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, NonNegativeFloat, NonNegativeInt, PositiveFloat, model_validator

from rodctl.config.base import Point2, Pose, StrictModel
from rodctl.errors import UserError

if TYPE_CHECKING:
    from rodctl.config.experiment import ExperimentConfig
    from rodctl.sim.rod import ApplyResult, RodSim
    from rodctl.vision.camera import Camera


def _settle_note(result: ApplyResult) -> str:
    if result.diverged:
        return "; the rod DIVERGED"
    state = "settled" if result.settled else "NOT settled"
    return f"; {state} after {result.settle_time:.2f} s sim"


#: Bounded values of event fields (every config number has an upper bound; docs/reliability.md).
_Step = Annotated[float, Field(gt=0.0, le=1.0)]
_Turn = Annotated[float, Field(gt=0.0, le=3.2)]
_Px = Annotated[float, Field(ge=-1e5, le=1e5)]


class _Event(StrictModel):
    at_step: NonNegativeInt = Field(
        le=1_000_000,
        description="Control step (probing included) before whose move the event applies.",
    )

    #: What the environment must refresh after this event (see the module docstring):
    #: "extractor" = rebuild the CenterlineExtractor from `camera`, `sim.clamp_pose` and
    #: `sim.held_length`; "target_pixels" = re-project the target's world centerline.
    refresh: ClassVar[frozenset[str]] = frozenset()


class _FactorOrValue(_Event):
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

    def apply(self, sim: RodSim, camera: Camera) -> str:
        old = sim.bending_stiffness
        new = self.new_value(old)
        result = sim.set_bending_stiffness(new)
        return f"event stiffness: EI {old:.4g} -> {new:.4g} N m^2{_settle_note(result)}"


class WeightChange(_FactorOrValue):
    """The rod's mass per length ρA changes (it picks up a load, water, a heavier sleeve).

    `value` is ρA in kg/m. Changes the shape under gravity and the friction on a table.
    """

    type: Literal["weight"] = "weight"

    def apply(self, sim: RodSim, camera: Camera) -> str:
        old = sim.mass_per_length
        new = self.new_value(old)
        result = sim.set_mass_per_length(new)
        return f"event weight: rho*A {old:.4g} -> {new:.4g} kg/m{_settle_note(result)}"


class ClampMove(_Event):
    """The clamped end is driven to a new pose, the gripper holding still (a bumped fixture).

    It moves in a straight line within `max_step` per control period, settling after each
    increment; if the gripper would end up beyond `rod.workspace.max_reach` of the held length,
    the clamp stops at that limit (logged).
    """

    type: Literal["clamp_move"] = "clamp_move"
    refresh: ClassVar[frozenset[str]] = frozenset({"extractor"})
    pose: Pose = Field(description="New clamp pose [x, y, theta] (world).")
    max_step: tuple[_Step, _Step, _Turn] | None = Field(
        None, description="Per-axis limit per control period (m, m, rad); None: rod.max_step."
    )

    def apply(self, sim: RodSim, camera: Camera) -> str:
        old = sim.clamp_pose
        result = sim.move_clamp(
            np.asarray(self.pose, dtype=float),
            None if self.max_step is None else np.asarray(self.max_step, dtype=float),
        )
        new = sim.clamp_pose
        clip = " (stopped at the reach limit)" if result.clipped else ""
        return f"event clamp_move: clamp {_fmt(old)} -> {_fmt(new)}{clip}{_settle_note(result)}"


class GraspSlip(_Event):
    """The grasp point slides along the rod by `ds`: the held length changes, the gripper stays.

    ds > 0: towards the clamp (held length shrinks); ds < 0: away from it (grows back, at most
    to rod.length). Rounded to whole segments (rod.length / rod.segments).
    """

    type: Literal["grasp_slip"] = "grasp_slip"
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

    def apply(self, sim: RodSim, camera: Camera) -> str:
        old = sim.held_length
        result = sim.slip_grasp(self.ds)
        clip = " (gripper clipped to the reach of the held length)" if result.clipped else ""
        return (
            f"event grasp_slip: held length {old:.4f} -> {sim.held_length:.4f} m{clip}"
            f"{_settle_note(result)}"
        )


class CameraBump(_Event):
    """The camera is knocked: its extrinsics change by the given increments (intrinsics stay)."""

    type: Literal["camera_bump"] = "camera_bump"
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

    def apply(self, sim: RodSim, camera: Camera) -> str:
        c = camera.cfg
        pose = self.new_pose(c.look_at, c.distance, c.tilt_deg, c.azimuth_deg)
        camera.set_pose(**pose)
        return (
            f"event camera_bump: look_at {_fmt(pose['look_at'])} m, distance "
            f"{pose['distance']:.4g} m, tilt {pose['tilt_deg']:.4g} deg, azimuth "
            f"{pose['azimuth_deg']:.4g} deg"
        )


class OccluderChange(_Event):
    """An occluder (a grey box in pixel coordinates) appears or disappears."""

    type: Literal["occluder"] = "occluder"
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

    def apply(self, sim: RodSim, camera: Camera) -> str:
        if self.action == "add":
            camera.add_occlusion(self.box)
            return f"event occluder: appears at {list(self.box)} px"
        camera.remove_occlusion(self.box)
        return f"event occluder: {list(self.box)} px disappears"


class NoiseChange(_Event):
    """The image gets noisier or cleaner (lighting, gain): pixel noise σ and optionally blur."""

    type: Literal["noise"] = "noise"
    noise_std: NonNegativeFloat = Field(le=100.0, description="New pixel noise σ (grey levels).")
    blur_sigma: NonNegativeFloat | None = Field(
        None, le=10.0, description="New blur σ (px); None: keep."
    )

    def apply(self, sim: RodSim, camera: Camera) -> str:
        camera.set_noise(self.noise_std, self.blur_sigma)
        blur = "" if self.blur_sigma is None else f", blur sigma {self.blur_sigma:.3g} px"
        return f"event noise: pixel noise sigma {self.noise_std:.3g}{blur}"


#: One mid-run event, chosen by `type` (a pydantic discriminated union). Use it in a config as
#: `events: list[Event] = Field(default_factory=list, description=...)`.
Event = Annotated[
    StiffnessChange
    | WeightChange
    | ClampMove
    | GraspSlip
    | CameraBump
    | OccluderChange
    | NoiseChange,
    Field(discriminator="type"),
]


def _fmt(pose: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.4f}" for v in np.asarray(pose, dtype=float)) + "]"


def due(events: list[Event], step: int) -> list[Event]:
    """The events that apply at control step `step`, in the order they were listed."""
    return [e for e in events if e.at_step == step]


def apply_due(events: list[Event], step: int, sim: RodSim, camera: Camera) -> list[str]:
    """Apply every event of `step` in list order; return their log lines (one each).

    Intended call: in the control loop, after the observation of step k-1 was used and before
    step k's move is applied (so the controller's next observation already sees the change).
    """
    return [event.apply(sim, camera) for event in due(events, step)]


def validate_events(events: list[Event], cfg: ExperimentConfig, field: str = "run.events") -> None:
    """Refuse, before the run, events that cannot apply. Raises `UserError` naming the field.

    Checks: `at_step` below `run.max_steps`; the held length after every grasp slip (in step
    order) stays within [2 segments, rod.length]; a moved clamp leaves the fixed target pose
    (if `run.target.pose` is set) within `max_reach` of the held length; the bumped camera still
    looks down at the plane (distance > 0, |tilt| < 90°); an occluder is removed only if present
    (in camera.render.occlusions or added by an earlier event).

    Args:
        events: the events, as in the config.
        cfg: the whole experiment config (rod, camera and run sections are read).
        field: dotted name of the list, for messages.
    """
    rod, cam = cfg.rod, cfg.camera
    seg = rod.length / rod.segments
    held = rod.segments
    clamp = np.asarray(rod.clamp_pose, dtype=float)
    target = cfg.run.target.pose
    look_at, distance = tuple(cam.look_at), cam.distance
    tilt, azimuth = cam.tilt_deg, cam.azimuth_deg
    boxes = [tuple(float(v) for v in b) for b in cam.render.occlusions]
    order = sorted(range(len(events)), key=lambda i: events[i].at_step)  # stable: list order
    for i in order:
        event = events[i]
        name = f"{field}[{i}]"
        if event.at_step >= cfg.run.max_steps:
            raise UserError(
                f"{name}.at_step: {event.at_step} is not below run.max_steps = "
                f"{cfg.run.max_steps}; the event would never happen"
            )
        if isinstance(event, GraspSlip):
            k = round(event.ds / seg)
            if k == 0:
                raise UserError(
                    f"{name}.ds: {event.ds} m is less than half a segment ({seg:.4g} m); "
                    "the slip is rounded to whole segments"
                )
            if held - k < 2:
                raise UserError(
                    f"{name}.ds: a slip of {event.ds} m is longer than the held rod "
                    f"({held * seg:.4g} m at that step; at least 2 segments must stay held)"
                )
            if held - k > rod.segments:
                raise UserError(
                    f"{name}.ds: a slip of {event.ds} m makes the held length "
                    f"{(held - k) * seg:.4g} m, longer than rod.length = {rod.length} m"
                )
            held -= k
        if isinstance(event, ClampMove):
            clamp = np.asarray(event.pose, dtype=float)
        if isinstance(event, (GraspSlip, ClampMove)) and target is not None:
            reach = rod.workspace.max_reach * held * seg
            dist = math.hypot(target[0] - clamp[0], target[1] - clamp[1])
            if dist > reach:
                if isinstance(event, ClampMove):
                    what, why = "pose", "the clamp pose is out of reach"
                else:
                    what, why = "ds", "the held rod is too short to reach the target"
                raise UserError(
                    f"{name}.{what}: after this event the target pose run.target.pose is "
                    f"{dist:.4g} m from the clamp, beyond max_reach * held length = {reach:.4g} m"
                    f" ({why})"
                )
        if isinstance(event, CameraBump):
            pose = event.new_pose(look_at, distance, tilt, azimuth)
            if pose["distance"] <= 0:
                raise UserError(
                    f"{name}.distance: the bumped camera distance {pose['distance']:.4g} m must be"
                    " > 0"
                )
            if not abs(pose["tilt_deg"]) < 90:
                raise UserError(
                    f"{name}.tilt_deg: the bumped tilt {pose['tilt_deg']:.4g} deg must be within "
                    "(-90, 90) to see the plane"
                )
            look_at, distance = pose["look_at"], pose["distance"]
            tilt, azimuth = pose["tilt_deg"], pose["azimuth_deg"]
        if isinstance(event, OccluderChange):
            box = tuple(float(v) for v in event.box)
            if event.action == "add":
                boxes.append(box)
            elif box in boxes:
                boxes.remove(box)
            else:
                raise UserError(
                    f"{name}.box: no occluder {list(box)} is present at step {event.at_step} "
                    "(neither in camera.render.occlusions nor added by an earlier event)"
                )
