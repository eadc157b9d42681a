"""The events' check before the run: what each event leaves for the next (`EventState`) and
`validate_events`, which the experiment config's validation runs on `run.events`.

Pure data like the rest of `rodctl.config`: an event's `check(state, field)` (its config model,
in rodctl/events.py or a plug-in) reads and updates the state; nothing here touches a simulator
or a camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rodctl.config.camera import MIN_DEPTH_M, nearest_depth
from rodctl.errors import UserError

__all__ = ["EventState", "validate_events"]


@dataclass
class EventState:
    """What the events before the one being checked left, as `validate_events` follows them in
    step order (built from the experiment config; an event's `check` reads and updates it).

    Attributes:
        segment: rod.length / rod.segments (m).
        segments: rod.segments.
        length: rod.length (m).
        held: segments held between clamp and gripper (grasp slips change it).
        max_reach: rod.workspace.max_reach (a fraction of the held length).
        clamp: (3,) the clamp pose (world).
        target: the fixed target gripper pose (`run.target.pose`), or None (sampled).
        look_at, distance, tilt_deg, azimuth_deg: the camera pose.
        boxes: the occluders present ([u0, v0, u1, v1] px each).
        max_steps: run.max_steps.
        arm_box: with rod.arms: 2, the x0 end's workspace (x0, x1, y0, y1) (m); else None.
    """

    segment: float
    segments: int
    length: float
    held: int
    max_reach: float
    clamp: np.ndarray
    target: Any
    look_at: tuple[float, float]
    distance: float
    tilt_deg: float
    azimuth_deg: float
    boxes: list[tuple[float, ...]] = field(default_factory=list)
    max_steps: int = 0
    arm_box: tuple[float, float, float, float] | None = None

    @classmethod
    def from_config(cls, cfg: Any) -> EventState:
        """The state before any event, from an experiment config (rod, camera, run)."""
        rod, cam = cfg.rod, cfg.camera
        return cls(
            segment=rod.length / rod.segments,
            segments=rod.segments,
            length=rod.length,
            held=rod.segments,
            max_reach=rod.workspace.max_reach,
            clamp=np.asarray(rod.clamp_pose, dtype=float),
            target=cfg.run.target.pose,
            look_at=tuple(cam.look_at),
            distance=cam.distance,
            tilt_deg=cam.tilt_deg,
            azimuth_deg=cam.azimuth_deg,
            boxes=[tuple(float(v) for v in b) for b in cam.render.occlusions],
            max_steps=cfg.run.max_steps,
            arm_box=(*rod.clamp_arm.workspace.x_limits, *rod.clamp_arm.workspace.y_limits)
            if rod.arms == 2
            else None,
        )

    def rod_depth(self) -> float:
        """The smallest depth (m) in front of the camera of a point the rod can reach: every
        point of it lies within rod.length of the x0 end, which is the clamp (one arm) or
        anywhere in its arm's workspace (two)."""
        if self.arm_box is None:
            centres = [(float(self.clamp[0]), float(self.clamp[1]))]
        else:
            x0, x1, y0, y1 = self.arm_box
            centres = [(x0, y0), (x0, y1), (x1, y0), (x1, y1)]
        return nearest_depth(
            self.look_at, self.distance, self.tilt_deg, self.azimuth_deg, centres, self.length
        )

    def check_rod_in_front(self, where: str) -> None:
        """Refuse (naming `where`) a camera pose that has part of the rod's reach behind it."""
        depth = self.rod_depth()
        if depth < MIN_DEPTH_M:
            where_ = f"{-depth:.3g} m behind it" if depth < 0 else f"only {depth:.3g} m in front"
            raise UserError(
                f"{where}: the camera (distance {self.distance:.4g} m from look_at "
                f"{list(self.look_at)}, tilt {self.tilt_deg:.4g} deg, azimuth "
                f"{self.azimuth_deg:.4g} deg) would have points the rod can reach (within "
                f"rod.length = {self.length:g} m of the x0 end) {where_}; every such point "
                f"must be at least {MIN_DEPTH_M:g} m in front for the camera to draw it: move "
                "the camera further away or tilt it less"
            )

    def target_distance(self) -> float | None:
        """Distance (m) from the clamp to the fixed target pose; None without one."""
        if self.target is None:
            return None
        return math.hypot(self.target[0] - self.clamp[0], self.target[1] - self.clamp[1])


def validate_events(events: list[Any], cfg: Any, field: str = "run.events") -> None:
    """Refuse, before the run, events that cannot apply. Raises `UserError` naming the field.

    Checks `at_step` below `run.max_steps` for every event, then each event's own `check` in
    step order (list order within a step) on the `EventState` the earlier events left: for the
    built-in types, the held length after every grasp slip stays within [2 segments,
    rod.length]; a moved clamp leaves the fixed target pose (if `run.target.pose` is set) within
    `max_reach` of the held length; the bumped camera still looks down at the plane (distance >
    0, |tilt| < 90°); an occluder is removed only if present.

    Args:
        events: the events, as in the config.
        cfg: the whole experiment config (rod, camera and run sections are read).
        field: dotted name of the list, for messages.
    """
    state = EventState.from_config(cfg)
    order = sorted(range(len(events)), key=lambda i: events[i].at_step)  # stable: list order
    for i in order:
        event = events[i]
        name = f"{field}[{i}]"
        if event.at_step >= state.max_steps:
            raise UserError(
                f"{name}.at_step: {event.at_step} is not below run.max_steps = "
                f"{state.max_steps}; the event would never happen"
            )
        check = getattr(event, "check", None)
        if check is not None:
            check(state, name)
