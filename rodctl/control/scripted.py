"""A scripted gripper path: absolute world poses visited in order, the feature ignored.

Used to drive the simulated rod along known paths (data collection, target generation,
validation against ground truth), through the same loop as the servo laws.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
import numpy.typing as npt
from pydantic import Field

from rodctl.config.base import Angle, Coordinate, Pose, StrictModel
from rodctl.registry import CONTROLLERS, BuildContext


class ScriptedController:
    """Moves towards each waypoint by at most `max_step` per axis; `done` after the last.

    The controller receives r relative to the run's home pose (the Controller protocol), and
    the waypoints are absolute world poses, so it adds `home_pose` back.
    """

    #: It ignores the feature and J: no probing, no convergence, the run ends with the path.
    open_loop = True

    def __init__(
        self,
        waypoints: npt.ArrayLike,
        *,
        home_pose: npt.ArrayLike,
        max_step: npt.ArrayLike,
        tolerance: npt.ArrayLike = (1e-4, 1e-4, 1e-3),
    ) -> None:
        """Args:
        waypoints: (n, 3) absolute gripper poses [x, y, theta], world frame.
        home_pose: (3,) gripper pose at the start of the run, world frame.
        max_step: (3,) per-axis bound on one increment.
        tolerance: (3,) per-axis distance at which a waypoint counts as reached.
        """
        self._home = np.asarray(home_pose, dtype=float)
        q = self._home.shape[0]  # 3, or 6 when both ends are moved
        self._wp = np.atleast_2d(np.asarray(waypoints, dtype=float))
        if self._wp.ndim != 2 or self._wp.shape[1] != q or self._wp.shape[0] < 1:
            raise ValueError(f"waypoints must be (n >= 1, {q}), got {self._wp.shape}")
        self._max = np.asarray(max_step, dtype=float)
        tol = np.asarray(tolerance, dtype=float)
        self._tol = np.tile(tol, q // tol.shape[0]) if q % tol.shape[0] == 0 else tol
        if not np.all(self._max > 0.0):
            raise ValueError(f"max_step must be positive, got {self._max.tolist()}")
        self.reset()

    @property
    def done(self) -> bool:
        """True once the last waypoint has been reached."""
        return self._index >= len(self._wp)

    @property
    def index(self) -> int:
        """Index of the waypoint being approached (len(waypoints) when done)."""
        return self._index

    def reset(self) -> None:
        """Start again from the first waypoint."""
        self._index = 0

    def command(
        self, s: np.ndarray, s_target: np.ndarray, J: np.ndarray, r: np.ndarray
    ) -> np.ndarray:
        """Increment (3,) towards the current waypoint from r (3,) (relative to home).

        s, s_target and J are ignored. Returns zeros once `done`.
        """
        pose = self._home + np.asarray(r, dtype=float)
        while not self.done and np.all(np.abs(self._wp[self._index] - pose) <= self._tol):
            self._index += 1
        if self.done:
            return np.zeros_like(pose)
        return np.clip(self._wp[self._index] - pose, -self._max, self._max)


# --- config and registration ------------------------------------------------------------


#: Both ends' poses [x1, y1, theta1, x2, y2, theta2] (q = 6).
DualPose = tuple[Coordinate, Coordinate, Angle, Coordinate, Coordinate, Angle]

#: A per-axis tolerance [m or rad].
Tol = Annotated[float, Field(gt=0.0, le=10.0)]


class ScriptedControllerConfig(StrictModel):
    """Drive the gripper through absolute world poses, ignoring the feature and J.

    Each step moves towards the current waypoint by at most the loop's `max_step` per axis and
    advances to the next waypoint once within `tolerance` on every axis; the run ends when the
    last one is reached and the rod has settled.
    """

    type: Literal["scripted"] = "scripted"
    waypoints: list[Pose] | list[DualPose] = Field(
        ...,
        min_length=1,
        description="Absolute gripper poses [[x, y, theta], ...] (world frame, m, rad), in order; "
        "6 values each (both ends, in the command's order) when both ends are moved (q = 6).",
    )
    tolerance: tuple[Tol, Tol, Tol] = Field(
        (1e-4, 1e-4, 1e-3),
        description="A waypoint is reached when every axis is within this [m, m, rad].",
    )


@CONTROLLERS.register(ScriptedControllerConfig)
def _build(cfg: ScriptedControllerConfig, ctx: BuildContext) -> ScriptedController:
    assert ctx.home_pose is not None and ctx.max_step is not None, "built for a task"
    return ScriptedController(
        cfg.waypoints, home_pose=ctx.home_pose, max_step=ctx.max_step, tolerance=cfg.tolerance
    )
