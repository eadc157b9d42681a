"""`RodSim`: the simulated rod as the experiment loop sees it.

One control step = move the gripper by a pose increment over `control_period` of simulated time
(velocity-driven, linear in time), then let the rod settle until no segment end moves faster than
`settle_speed_tol`, or `max_settle_time` runs out. The loop only ever looks at settled shapes,
which is why the chain underneath may use quasi-static tricks (inflated rotary inertia, critical
damping of the first mode; see `rodctl/sim/chain.py`).

Safety is explicit, never silent: commands are saturated per axis by `max_step`, target poses
outside the workspace (box limits, angle limits, or further than `max_reach · L` from the clamp)
are clipped or refused per `workspace.on_violation`, and a NaN or a pivot joint opening past
`gap_limit` marks the simulation as diverged — after which it refuses to move. Every one of those
outcomes is reported in the `ApplyResult`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rodctl.config.rod import RodConfig
from rodctl.errors import UserError
from rodctl.geometry import resample_polyline
from rodctl.sim.chain import RodChain, first_mode_rate, stable_dt_limit

#: Default home pose in the clamp frame: [x/L, y/L, theta]. Gently bent (chord 0.82 L), with a
#: nonzero lateral offset and end angle, so the equilibrium is a generic, unique one and not
#: the symmetric buckling bifurcation of a straight push.
DEFAULT_HOME_IN_CLAMP_FRAME = (0.8, 0.2, 0.5)

#: Steps between two speed checks while settling (a batch read costs about one step).
SETTLE_CHECK_EVERY = 5

#: Fraction of the stability limit used when `dt` is left to the simulator.
DT_SAFETY = 0.5
#: Largest global damping rate (1/s) pymunk can represent: it keeps e^-rate of the velocity per
#: second, a float that underflows near e^-745; 700 leaves a margin.
MAX_DAMPING_RATE = 700.0


@dataclass
class ApplyResult:
    """What one gripper move did.

    Attributes:
        settled: the rod came to rest within `max_settle_time`.
        clipped: the target pose was outside the workspace and was clipped (or refused).
        refused: the target pose was outside the workspace and the gripper did not move.
        diverged: NaN or a joint gap past `gap_limit`; the simulation is no longer trustworthy.
        u_applied: (3,) pose increment [dx, dy, dtheta] actually carried out.
        settle_time: simulated time (s) spent settling after the move.
        saturated: (3,) per-axis flags, True where `max_step` limited the command.
        sim_steps: physics steps taken (move + settle).
    """

    settled: bool
    clipped: bool
    refused: bool
    diverged: bool
    u_applied: np.ndarray
    settle_time: float
    saturated: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=bool))
    sim_steps: int = 0


@dataclass
class RodHealth:
    """Health figures of the chain right now.

    Attributes:
        max_joint_gap: largest pivot-joint separation (m), clamp and gripper joints included.
        has_nan: any NaN/inf in the segment states.
        kinetic_energy: kinetic energy (J) of the simulated chain (with the inflated rotary
            inertia, so it is a convergence figure, not the physical rod's energy).
        max_speed: largest segment-end speed (m/s).
    """

    max_joint_gap: float
    has_nan: bool
    kinetic_energy: float
    max_speed: float


class RodSim:
    """A clamped elastic rod held by a kinematic gripper moving in (x, y, theta).

    Building it is deterministic: the chain is built straight along the clamp direction and
    driven quasi-statically to the home pose (`move_to`), then settled. Two `RodSim`s built from
    the same config and fed the same commands give bit-identical centerlines.

    Args:
        cfg: the rod config.

    Raises:
        UserError: the home pose is outside the workspace, or the rod failed to reach it.
    """

    def __init__(self, cfg: RodConfig) -> None:
        self.cfg = cfg
        n = cfg.segments
        dt = cfg.dt
        if dt is None:
            dt = DT_SAFETY * stable_dt_limit(
                cfg.length, cfg.bending_stiffness, cfg.mass_per_length, n, cfg.inertia_radius
            )
        self.dt = float(dt)
        #: Estimated first bending-mode frequency (rad/s) of the gripper-held rod.
        self.omega1 = first_mode_rate(
            cfg.length, cfg.bending_stiffness, cfg.mass_per_length, n, cfg.inertia_radius
        )
        damping_rate = 2.0 * cfg.damping * self.omega1
        if damping_rate > MAX_DAMPING_RATE:
            # pymunk takes damping as the fraction of velocity kept per second, e^-rate: past
            # this it underflows to 0 and the rod could not move at all.
            raise UserError(
                f"rod: this rod's first bending mode ({self.omega1:.0f} rad/s) is too fast to "
                f"damp in pymunk (rate {damping_rate:.0f}/s > {MAX_DAMPING_RATE:.0f}/s). "
                "Increase rod.inertia_radius (it slows every mode without changing the settled "
                "shape), or lower rod.damping, or use a longer / softer rod"
            )
        self.chain = RodChain(
            length=cfg.length,
            bending_stiffness=cfg.bending_stiffness,
            mass_per_length=cfg.mass_per_length,
            segments=n,
            clamp_pose=cfg.clamp_pose,
            dt=self.dt,
            iterations=cfg.iterations,
            # Critical damping of mode 1: c = 2 ω1 (scaled by cfg.damping).
            damping_rate=damping_rate,
            inertia_radius=cfg.inertia_radius,
        )
        self._diverged = False

        if cfg.home_pose is not None:
            home = np.asarray(cfg.home_pose, dtype=float)
        else:
            cx, cy, cth = cfg.clamp_pose
            hx, hy, hth = DEFAULT_HOME_IN_CLAMP_FRAME
            c, s = math.cos(cth), math.sin(cth)
            x, y = hx * cfg.length, hy * cfg.length
            home = np.array([cx + c * x - s * y, cy + s * x + c * y, cth + hth])
            if self.clip_pose(home)[1]:
                raise UserError(
                    f"rod: the default home pose {list(np.round(home, 4))} is outside "
                    "rod.workspace for this clamp_pose; set rod.home_pose"
                )
        self._home = home
        result = self.move_to(home)
        if result.diverged or not result.settled:
            raise UserError(
                f"rod: the simulated rod did not settle at the home pose {list(np.round(home, 4))}"
                f" (diverged={result.diverged}); check rod.dt, rod.iterations, rod.segments"
            )

    # ------------------------------------------------------------------ state
    @property
    def _max_step(self) -> np.ndarray:
        return np.asarray(self.cfg.max_step, dtype=float)

    @property
    def _move_steps(self) -> int:
        """Physics steps per control period (the gripper's ramp)."""
        return max(1, round(self.cfg.control_period / self.dt))

    @property
    def home_pose(self) -> np.ndarray:
        """(3,) resolved home pose [x, y, theta], world frame."""
        return self._home.copy()

    @property
    def gripper_pose(self) -> np.ndarray:
        """(3,) gripper pose [x, y, theta]; theta = rod tangent there, clamp -> gripper."""
        return self.chain.gripper_pose()

    @property
    def sim_time(self) -> float:
        """Simulated time so far (s), the home move included."""
        return self.chain.steps * self.dt

    @property
    def diverged(self) -> bool:
        """True once a NaN or an over-wide joint was seen; the rod no longer moves."""
        return self._diverged

    def centerline(self, m: int | None = None) -> np.ndarray:
        """Ground-truth centreline, clamp end first, world metres.

        Args:
            m: None for the N+1 joint points; else the number of points, equally spaced in arc
                length along the polyline through the joints (both ends included), m >= 2.

        Returns:
            (N+1, 2) or (m, 2).
        """
        pts = self.chain.joint_points()
        if m is None:
            return pts
        return resample_polyline(pts, m)

    def health(self) -> RodHealth:
        """Largest joint gap, NaN flag, kinetic energy and largest speed right now."""
        states = self.chain.segment_states()
        vel = self.chain.segment_velocities()
        has_nan = not (np.all(np.isfinite(states)) and np.all(np.isfinite(vel)))
        gaps = self.chain.joint_gaps()
        return RodHealth(
            max_joint_gap=float(np.max(gaps)) if np.all(np.isfinite(gaps)) else math.inf,
            has_nan=has_nan,
            kinetic_energy=self.chain.kinetic_energy(),
            max_speed=self.chain.max_speed(),
        )

    # ------------------------------------------------------------------ workspace
    def clip_pose(self, pose: np.ndarray) -> tuple[np.ndarray, bool]:
        """The nearest allowed gripper pose, and whether `pose` had to change.

        Allowed: x, y, theta within the workspace limits and the clamp-to-gripper distance at
        most `max_reach · L`. Positions beyond the reach are pulled radially towards the clamp.

        Args:
            pose: (3,) [x, y, theta], world frame.

        Returns:
            ((3,) allowed pose, True if it differs from `pose`).
        """
        pose = np.asarray(pose, dtype=float)
        ws = self.cfg.workspace
        lo = np.array([ws.x_limits[0], ws.y_limits[0], ws.theta_limits[0]])
        hi = np.array([ws.x_limits[1], ws.y_limits[1], ws.theta_limits[1]])
        out = np.clip(pose, lo, hi)
        clamp = np.asarray(self.cfg.clamp_pose[:2], dtype=float)
        reach = ws.max_reach * self.cfg.length
        for _ in range(3):  # the reach cut and the box cut may need a second pass
            d = out[:2] - clamp
            dist = float(np.hypot(*d))
            if dist > reach:
                out[:2] = clamp + d * (reach / dist)
            out = np.clip(out, lo, hi)
        changed = bool(np.any(np.abs(out - pose) > 1e-12 * (1 + np.abs(pose))))
        return out, changed

    # ------------------------------------------------------------------ moving
    def apply(self, u: np.ndarray) -> ApplyResult:
        """One control step: move by `u` over `control_period`, then settle.

        The command is first saturated per axis by `max_step`, then the target pose is checked
        against the workspace (clipped or refused per `workspace.on_violation`).

        Args:
            u: (3,) pose increment [dx, dy, dtheta] (m, m, rad), world frame.

        Returns:
            What happened; `u_applied` is the increment actually carried out.
        """
        u = np.asarray(u, dtype=float).reshape(3)
        if not np.all(np.isfinite(u)):
            raise ValueError(f"RodSim.apply: non-finite command {u}")
        u_sat = np.clip(u, -self._max_step, self._max_step)
        saturated = u_sat != u
        result = self._move(self.gripper_pose + u_sat)
        result.saturated = saturated
        return result

    def move_to(self, pose: np.ndarray) -> ApplyResult:
        """Drive the gripper to an absolute pose in equal increments within `max_step`.

        Each increment is a full control step (move over `control_period`, then settle), so the
        rod follows a quasi-static path and stays on the equilibrium branch it started on.

        Args:
            pose: (3,) target [x, y, theta], world frame (clipped/refused like `apply`).

        Returns:
            The combined result: `u_applied` is the total displacement, `settle_time` the sum,
            `settled` that of the last increment.
        """
        start = self.gripper_pose
        target = np.asarray(pose, dtype=float).reshape(3)
        if not np.all(np.isfinite(target)):
            raise ValueError(f"RodSim.move_to: non-finite pose {target}")
        allowed, clipped = self.clip_pose(target)
        refuse = clipped and self.cfg.workspace.on_violation == "refuse"
        if self._diverged or refuse:
            return ApplyResult(
                settled=not self._diverged and self._is_slow(),
                clipped=clipped,
                refused=refuse,
                diverged=self._diverged,
                u_applied=np.zeros(3),
                settle_time=0.0,
            )
        delta = allowed - start
        n = max(1, math.ceil(float(np.max(np.abs(delta) / self._max_step)) - 1e-9))
        total = ApplyResult(True, clipped, False, False, np.zeros(3), 0.0)
        for k in range(1, n + 1):
            # The increments lie between the start and an allowed pose (the workspace is convex),
            # so they are not checked again.
            step = self._move(start + delta * (k / n), check=False)
            total.settled = step.settled
            total.settle_time += step.settle_time
            total.sim_steps += step.sim_steps
            if step.diverged:
                total.diverged = True
                break
        total.u_applied = self.gripper_pose - start
        return total

    def _move(self, target: np.ndarray, check: bool = True) -> ApplyResult:
        """Move to `target` over one control period and settle; `check`: apply the workspace."""
        start = self.gripper_pose
        allowed, clipped = self.clip_pose(target) if check else (target.copy(), False)
        refused = clipped and self.cfg.workspace.on_violation == "refuse"
        if self._diverged or refused:
            return ApplyResult(
                settled=not self._diverged and self._is_slow(),
                clipped=clipped,
                refused=refused,
                diverged=self._diverged,
                u_applied=np.zeros(3),
                settle_time=0.0,
            )
        # No wrapping of theta to (-pi, pi]: for a rod the gripper angle is not periodic (a
        # full turn winds the rod), so the workspace's theta_limits apply to it literally.
        chain = self.chain
        steps0 = chain.steps
        # Velocity-driven linear ramp of the gripper over the control period (pitfall 3).
        n = self._move_steps
        for k in range(1, n + 1):
            chain.step(start + (allowed - start) * (k / n))
        settled, diverged = self._settle(allowed)
        settle_steps = chain.steps - steps0 - n
        if not diverged:
            gaps = chain.joint_gaps()
            diverged = not bool(np.all(np.isfinite(gaps)) and np.max(gaps) <= self.cfg.gap_limit)
        if diverged:
            self._diverged = True
            settled = False
        return ApplyResult(
            settled=settled,
            clipped=clipped,
            refused=False,
            diverged=diverged,
            u_applied=self.gripper_pose - start,
            settle_time=settle_steps * self.dt,
            sim_steps=chain.steps - steps0,
        )

    def _settle(self, target: np.ndarray) -> tuple[bool, bool]:
        """Hold the gripper at `target` until two speed checks in a row are below tolerance.

        Returns:
            (settled, diverged): diverged when the speed is not finite.
        """
        chain = self.chain
        tol = self.cfg.settle_speed_tol
        budget = max(1, math.ceil(self.cfg.max_settle_time / self.dt - 1e-9))
        below = 0
        taken = 0
        while taken < budget:
            for _ in range(SETTLE_CHECK_EVERY):
                chain.step(target)
            taken += SETTLE_CHECK_EVERY
            speed = chain.max_speed()
            if not math.isfinite(speed):
                return False, True
            if speed < tol:
                below += 1
                if below >= 2:
                    return True, False
            else:
                below = 0
        return False, False

    def _is_slow(self) -> bool:
        speed = self.chain.max_speed()
        return math.isfinite(speed) and speed < self.cfg.settle_speed_tol
