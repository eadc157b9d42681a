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

from rodctl.config.rod import STANDARD_GRAVITY, RodConfig
from rodctl.errors import UserError, pose_text
from rodctl.geometry import resample_polyline
from rodctl.sim.chain import RodChain, first_mode_rate, stable_dt_limit

#: Default home pose in the clamp frame: [x/L, y/L, theta]. Gently bent (chord 0.82 L), with a
#: nonzero lateral offset and end angle, so the equilibrium is a generic, unique one and not
#: the symmetric buckling bifurcation of a straight push.
DEFAULT_HOME_IN_CLAMP_FRAME = (0.8, 0.2, 0.5)

#: Settled home states by rod configuration (`RodSim.at_home`).
_HOME_STATES: dict[str, dict] = {}

#: The reduction as a bare ufunc method (np.max adds a Python layer per call).
_MAX = np.maximum.reduce

#: Steps between two speed checks while settling (a batch read costs about one step).
SETTLE_CHECK_EVERY = 5

#: Fraction of the stability limit used when `dt` is left to the simulator.
DT_SAFETY = 0.5
#: Largest global damping rate (1/s) pymunk can represent: it keeps e^-rate of the velocity per
#: second, a float that underflows near e^-745; 700 leaves a margin.
MAX_DAMPING_RATE = 700.0


def home_pose(cfg: RodConfig) -> np.ndarray:
    """(3,) the gripper's home pose: `rod.home_pose`, or when it is null the default one
    (`DEFAULT_HOME_IN_CLAMP_FRAME` in the clamp frame, scaled by the rod length)."""
    if cfg.home_pose is not None:
        return np.asarray(cfg.home_pose, dtype=float)
    cx, cy, cth = cfg.clamp_pose
    hx, hy, hth = DEFAULT_HOME_IN_CLAMP_FRAME
    c, s = math.cos(cth), math.sin(cth)
    x, y = hx * cfg.length, hy * cfg.length
    return np.array([cx + c * x - s * y, cy + s * x + c * y, cth + hth])


def time_step(cfg: RodConfig) -> float:
    """The pymunk chain's time step (s): `rod.dt`, or when it is null `DT_SAFETY` times the
    chain's stability limit."""
    dt = cfg.dt
    if dt is None:
        dt = DT_SAFETY * stable_dt_limit(
            cfg.length, cfg.bending_stiffness, cfg.mass_per_length, cfg.segments, cfg.inertia_radius
        )
    return float(dt)


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
    #: Snap-throughs on the way (the quasi-static engine reports them; pymunk's always 0).
    snaps: int = 0


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


#: `rod.engine` -> the RodSim subclass that runs it; pymunk is RodSim itself. Engines register
#: themselves (`register_engine`) when `rodctl.sim` is imported, so this module imports none.
ENGINES: dict[str, type] = {}


def register_engine(name: str, sim_type: type) -> None:
    """Make `RodSim(cfg)` build `sim_type` when `cfg.engine == name`."""
    ENGINES[name] = sim_type


class RodSim:
    """A clamped elastic rod held by a kinematic gripper moving in (x, y, theta).

    With `rod.arms: 2` (dual-arm, docs/dual-arm.md) the clamp is a second gripper: `apply` takes
    (6,) commands (the gripper's increment, then the x0 end's), each end saturated by its own
    speed limit and clipped into its own workspace (`rod.clamp_arm`), and both ends move together.

    Building it is deterministic: the chain is built straight along the clamp direction and
    driven quasi-statically to the home pose (`move_to`), then settled. Two `RodSim`s built from
    the same config and fed the same commands give bit-identical centerlines.

    `RodSim(cfg)` with `cfg.engine == "quasistatic"` builds a `QuasiStaticSim`
    (`rodctl/sim/quasistatic.py`): the same policy layer (this class) on the chain's equilibrium
    solved directly instead of the pymunk dynamics.

    Args:
        cfg: the rod config.

    Raises:
        UserError: the home pose is outside the workspace, or the rod failed to reach it.
    """

    #: The chain class `_rebuild` builds (the quasi-static engine substitutes its own).
    _chain_type = RodChain

    def __new__(cls, cfg: RodConfig | None = None, *args: object, **kwargs: object) -> RodSim:
        if cls is RodSim:  # `rod.engine` picks the subclass (`register_engine`)
            cls = ENGINES.get(getattr(cfg, "engine", "pymunk"), cls)
        return super().__new__(cls)

    def __init__(self, cfg: RodConfig, *, drive_home: bool = True) -> None:
        self.cfg = cfg
        self._build_chain(cfg)
        self._diverged = False
        #: Segments between the clamp and the grasp (all N until a grasp slip).
        self._held = cfg.segments
        if not drive_home:  # `at_home` puts a stored home state in
            return

        home = home_pose(cfg)
        if cfg.home_pose is None:
            if self.clip_pose(home)[1]:
                raise UserError(
                    f"rod: the default home pose {pose_text(home)} is outside "
                    "rod.workspace for this clamp_pose; set rod.home_pose"
                )
        self._home = home
        result = self.move_to(home)
        if result.diverged or not result.settled:
            raise UserError(
                f"rod: the simulated rod did not settle at the home pose {pose_text(home)} ("
                + ("it diverged" if result.diverged else "still moving when the budget ran out")
                + "); check rod.dt, rod.iterations, rod.segments"
            )

    @classmethod
    def at_home(cls, cfg: RodConfig) -> RodSim:
        """A rod settled at its home pose, without driving it there again.

        The home state is computed once per rod configuration (per process, by the driven
        build above) and stored; every call, the first included, builds a fresh chain and puts
        that state in (`_home_state` / `_put_home_state`), so every episode starts from the
        same state whichever came first. For pymunk the restored state has the bodies' poses and
        velocities and no solver warm-start impulses (a pymunk space cannot copy them), so its
        next steps differ from those of the driven build by far less than the settle tolerance.
        """
        key = cfg.model_dump_json()
        state = _HOME_STATES.get(key)
        if state is None:
            state = RodSim(cfg)._home_state()
            if len(_HOME_STATES) >= 64:
                _HOME_STATES.pop(next(iter(_HOME_STATES)))
            _HOME_STATES[key] = state
        sim = RodSim(cfg, drive_home=False)
        sim._put_home_state(state)
        return sim

    def _home_state(self) -> dict:
        """What `at_home` stores: the settled chain's segment poses and velocities (the residual
        motion the settle left, below `settle_speed_tol`), the gripper, the clock."""
        return {
            "home": self._home.copy(),
            "states": self.chain.segment_states(),
            "velocities": self.chain.segment_velocities(),
            "gripper": self.chain.gripper_pose(),
            "steps": self.chain.steps,
        }

    def _put_home_state(self, state: dict) -> None:
        self._home = state["home"].copy()
        self.chain.place(state["states"], state["gripper"])
        for body, (vx, vy, omega) in zip(self.chain.bodies, state["velocities"], strict=True):
            body.velocity = (float(vx), float(vy))
            body.angular_velocity = float(omega)
        self.chain.steps = state["steps"]

    def _build_chain(self, cfg: RodConfig) -> None:
        """The pymunk chain, its time step and damping (the quasi-static engine overrides it)."""
        n = cfg.segments
        self.dt = time_step(cfg)
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
        self._damping_rate = damping_rate
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
            gravity=cfg.gravity,
            table_friction=cfg.table_friction,
            table_gravity=STANDARD_GRAVITY,
            # Dual-arm: the x0 end is a kinematic body the second arm drives.
            movable_clamp=cfg.arms == 2,
        )

    # ------------------------------------------------------------------ state
    @property
    def dual_arm(self) -> bool:
        """Both ends are moved (`rod.arms: 2`): commands and poses have q = 6."""
        return self.cfg.arms == 2

    @property
    def q(self) -> int:
        """Command dimension: 3 (the gripper) or 6 (the gripper, then the x0 end)."""
        return 6 if self.dual_arm else 3

    @property
    def end_poses(self) -> np.ndarray:
        """(q,) the moved ends' poses: the gripper's [x, y, theta], then (dual-arm) the x0
        end's."""
        if self.dual_arm:
            return np.concatenate([self.gripper_pose, self.clamp_pose])
        return self.gripper_pose

    @property
    def home_end_poses(self) -> np.ndarray:
        """(q,) `end_poses` at the start: the home pose, then (dual-arm) `rod.clamp_pose`."""
        if self.dual_arm:
            return np.concatenate([self._home, np.asarray(self.cfg.clamp_pose, dtype=float)])
        return self._home.copy()

    @property
    def max_steps(self) -> np.ndarray:
        """(q,) per-axis speed limits: `rod.max_step`, then (dual-arm) `rod.clamp_arm.max_step`."""
        if self.dual_arm:
            return np.concatenate([self._max_step, np.asarray(self.cfg.clamp_arm.max_step, float)])
        return self._max_step

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
    def clamp_pose(self) -> np.ndarray:
        """(3,) the clamped end's pose now [x, y, theta] (changes only with `move_clamp`)."""
        return self.chain.current_clamp_pose()

    @property
    def held_length(self) -> float:
        """Arc length (m) from the clamp to the grasp: L until a `slip_grasp`."""
        if self._held == self.cfg.segments:
            return float(self.cfg.length)  # exactly, not N * (L / N)
        return self._held * self.chain.seg_length

    @property
    def bending_stiffness(self) -> float:
        """EI (N m²) now (changed by `set_bending_stiffness`)."""
        return self.chain.bending_stiffness

    @property
    def mass_per_length(self) -> float:
        """ρA (kg/m) now (changed by `set_mass_per_length`)."""
        return self.chain.mass_per_length

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
    def snapshot(self) -> dict:
        """The simulator's dynamic state (every body's pose and velocity, the clock), for
        `restore`. The chain itself (its bodies and joints) must be the same at restore: no
        grasp slip or clamp move in between."""
        bodies = [*self.chain.bodies] + ([self.chain.gripper] if self.chain.gripper else [])
        if self.chain.clamp_body is not None:  # a moved clamp (dual-arm, clamp_move)
            bodies.append(self.chain.clamp_body)
        return {
            "bodies": bodies,
            "state": [
                (tuple(b.position), b.angle, tuple(b.velocity), b.angular_velocity) for b in bodies
            ],
            "steps": self.chain.steps,
            "diverged": self._diverged,
        }

    def restore(self, snap: dict) -> None:
        """Put the simulator back into a `snapshot` (the oracle's finite differences use it)."""
        if snap["bodies"][0] is not self.chain.bodies[0]:
            raise RuntimeError("restore: the chain was rebuilt since the snapshot")
        for body, (pos, angle, vel, omega) in zip(snap["bodies"], snap["state"], strict=True):
            body.position = pos
            body.angle = angle
            body.velocity = vel
            body.angular_velocity = omega
        self.chain.steps = snap["steps"]
        self._diverged = snap["diverged"]

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
        if pose.shape == (6,):
            return self._clip_both(pose)
        return self._clip_gripper(pose, self.chain.current_clamp_pose()[:2])

    def _clip_both(self, pose: np.ndarray) -> tuple[np.ndarray, bool]:
        """Dual-arm `clip_pose` of (6,) [gripper, x0 end]: the x0 end into its workspace box,
        then the gripper into its box and within reach of the x0 end's new position."""
        if not self.dual_arm:
            raise ValueError("a (6,) pose needs rod.arms: 2")
        ws = self.cfg.clamp_arm.workspace
        lo = np.array([ws.x_limits[0], ws.y_limits[0], ws.theta_limits[0]])
        hi = np.array([ws.x_limits[1], ws.y_limits[1], ws.theta_limits[1]])
        clamp = np.clip(pose[3:], lo, hi)
        grip, _ = self._clip_gripper(pose[:3], clamp[:2])
        out = np.concatenate([grip, clamp])
        changed = bool(np.any(np.abs(out - pose) > 1e-12 * (1 + np.abs(pose))))
        return out, changed

    def _reach(self) -> float:
        """Largest distance (m) between the ends: max_reach of the held length (dual-arm: the
        smaller of the two arms' max_reach)."""
        f = self.cfg.workspace.max_reach
        if self.dual_arm:
            f = min(f, self.cfg.clamp_arm.workspace.max_reach)
        return f * self.held_length

    def _clip_gripper(self, pose: np.ndarray, clamp: np.ndarray) -> tuple[np.ndarray, bool]:
        ws = self.cfg.workspace
        # Fast path (the usual case; the quasi-static engine's step costs about as much as this
        # check otherwise): a pose inside the box and the reach is returned unchanged, exactly
        # what the cuts below would return for it.
        x, y, t = pose.tolist()
        cx, cy = clamp[:2].tolist()  # where the x0 end will be
        reach = self._reach()
        if (
            ws.x_limits[0] <= x <= ws.x_limits[1]
            and ws.y_limits[0] <= y <= ws.y_limits[1]
            and ws.theta_limits[0] <= t <= ws.theta_limits[1]
            # |d| <= |dx| + |dy|: well inside the reach needs no hypot (np.hypot's own rounding
            # decides only near the reach, as before).
            and (
                abs(x - cx) + abs(y - cy) <= 0.999 * reach
                or float(np.hypot(x - cx, y - cy)) <= reach
            )
        ):
            return pose.copy(), False
        lo = np.array([ws.x_limits[0], ws.y_limits[0], ws.theta_limits[0]])
        hi = np.array([ws.x_limits[1], ws.y_limits[1], ws.theta_limits[1]])
        out = np.clip(pose, lo, hi)
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

        Dual-arm (`rod.arms: 2`): `u` is (6,), the gripper's increment then the x0 end's; each
        end is saturated by its own `max_step` and clipped into its own workspace, and both
        move together over the control period.
        """
        if self.dual_arm:
            return self._apply_both(u)
        u = np.asarray(u, dtype=float).reshape(3)
        # On Python floats (a few numpy calls cost more than the quasi-static step's algebra):
        # min(max(u, −m), m) is np.clip's value for a finite u and m > 0, bit for bit.
        ux, uy, ut = u.tolist()
        if not (math.isfinite(ux) and math.isfinite(uy) and math.isfinite(ut)):
            raise ValueError(f"RodSim.apply: non-finite command {u}")
        mx, my, mt = self.cfg.max_step
        sat = [min(max(ux, -mx), mx), min(max(uy, -my), my), min(max(ut, -mt), mt)]
        result = self._move(self.gripper_pose + sat)
        result.saturated = np.array([sat[0] != ux, sat[1] != uy, sat[2] != ut])
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
        if self.dual_arm and np.asarray(pose).size == 6:
            return self._move_to_both(np.asarray(pose, dtype=float).reshape(6))
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
        ramp = allowed - start
        for k in range(1, n):
            chain.step(start + ramp * (k / n))
        chain.step(start + ramp)  # k = n: ramp · 1.0 is ramp, bit for bit
        settled, diverged = self._settle(allowed)
        settle_steps = chain.steps - steps0 - n
        if not diverged:
            diverged = not self._max_gap() <= self.cfg.gap_limit  # NaN and inf: diverged
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

    # ------------------------------------------------------------------ dual-arm moves
    def _refuses(self, target: np.ndarray, allowed: np.ndarray) -> bool:
        """Whether a clipped (6,) move is refused: an end that had to be clipped whose arm's
        workspace says `refuse`."""
        changed = np.abs(allowed - target) > 1e-12 * (1 + np.abs(target))
        grip_ws, clamp_ws = self.cfg.workspace, self.cfg.clamp_arm.workspace
        return bool(
            (np.any(changed[:3]) and grip_ws.on_violation == "refuse")
            or (np.any(changed[3:]) and clamp_ws.on_violation == "refuse")
        )

    def _apply_both(self, u: np.ndarray) -> ApplyResult:
        """`apply` with both ends moved: u = (6,), the gripper's [dx, dy, dtheta], the x0 end's."""
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.shape != (6,):
            raise ValueError(f"RodSim.apply: a dual-arm command has 6 values, got {u.shape[0]}")
        if not np.all(np.isfinite(u)):
            raise ValueError(f"RodSim.apply: non-finite command {u}")
        limit = self.max_steps
        u_sat = np.clip(u, -limit, limit)
        saturated = u_sat != u
        result = self._move_both(self.end_poses + u_sat)
        result.saturated = saturated
        return result

    def _move_to_both(self, target: np.ndarray) -> ApplyResult:
        """`move_to` of both ends to (6,) poses, in equal increments within both speed limits
        (a straight line between allowed poses stays allowed: the boxes are convex and the ends'
        distance is convex along it)."""
        if not np.all(np.isfinite(target)):
            raise ValueError(f"RodSim.move_to: non-finite pose {target}")
        start = self.end_poses
        allowed, clipped = self.clip_pose(target)
        refuse = clipped and self._refuses(target, allowed)
        if self._diverged or refuse:
            return ApplyResult(
                settled=not self._diverged and self._is_slow(),
                clipped=clipped,
                refused=refuse,
                diverged=self._diverged,
                u_applied=np.zeros(6),
                settle_time=0.0,
                saturated=np.zeros(6, dtype=bool),
            )
        delta = allowed - start
        n = max(1, math.ceil(float(np.max(np.abs(delta) / self.max_steps)) - 1e-9))
        total = ApplyResult(True, clipped, False, False, np.zeros(6), 0.0, np.zeros(6, bool))
        for k in range(1, n + 1):
            step = self._move_both(start + delta * (k / n), check=False)
            total.settled = step.settled
            total.settle_time += step.settle_time
            total.sim_steps += step.sim_steps
            if step.diverged:
                total.diverged = True
                break
        total.u_applied = self.end_poses - start
        return total

    def _move_both(self, target: np.ndarray, check: bool = True) -> ApplyResult:
        """Both ends to (6,) `target` over one control period, then settle (`_move`'s twin)."""
        start = self.end_poses
        allowed, clipped = self.clip_pose(target) if check else (target.copy(), False)
        refused = clipped and self._refuses(target, allowed)
        if self._diverged or refused:
            return ApplyResult(
                settled=not self._diverged and self._is_slow(),
                clipped=clipped,
                refused=refused,
                diverged=self._diverged,
                u_applied=np.zeros(6),
                settle_time=0.0,
                saturated=np.zeros(6, dtype=bool),
            )
        chain = self.chain
        steps0 = chain.steps
        n = self._move_steps
        grip0, clamp0 = start[:3], start[3:]
        dgrip, dclamp = allowed[:3] - grip0, allowed[3:] - clamp0
        for k in range(1, n + 1):  # both ends on a velocity-driven linear ramp
            chain.step(grip0 + dgrip * (k / n), clamp0 + dclamp * (k / n))
        settled, diverged = self._settle(allowed[:3])
        settle_steps = chain.steps - steps0 - n
        diverged = diverged or self._gaps_too_wide()
        if diverged:
            self._diverged = True
            settled = False
        return ApplyResult(
            settled=settled,
            clipped=clipped,
            refused=False,
            diverged=diverged,
            u_applied=self.end_poses - start,
            settle_time=settle_steps * self.dt,
            saturated=np.zeros(6, dtype=bool),
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

    # ------------------------------------------------------------------ changing the rod
    # Mid-run events (rodctl/events.py) go through these. Each keeps the simulator's clock and
    # its stability: the time step, damping rate and control period never change.

    def set_bending_stiffness(self, bending_stiffness: float) -> ApplyResult:
        """Change EI mid-run, then let the rod settle into its new shape.

        Without a body force the settled shape does not depend on EI (only the end poses), so
        under the paper's weightless set-up this changes nothing but the settling; under gravity
        or on a table it changes the shape (tested).

        Returns:
            The settling, as an `ApplyResult` with a zero move.
        """
        self.chain.set_bending_stiffness(float(bending_stiffness))
        return self._hold()

    def set_mass_per_length(self, mass_per_length: float) -> ApplyResult:
        """Change ρA mid-run (e.g. the rod picks up weight), then settle."""
        self.chain.set_mass_per_length(float(mass_per_length))
        return self._hold()

    def set_table_friction(self, mu: float) -> ApplyResult:
        """Change the table's Coulomb coefficient (a rod built with `table_friction`), settle."""
        if self.chain.table_friction is None:
            raise ValueError("rod.table_friction is not set: this rod lies on no table")
        self.chain.set_table_friction(float(mu))
        return self._hold()

    def _hold(self) -> ApplyResult:
        """Settle with the gripper where it is (after a change of the rod itself)."""
        if self._diverged:
            return ApplyResult(False, False, False, True, np.zeros(3), 0.0)
        steps0 = self.chain.steps
        settled, diverged = self._settle(self.gripper_pose)
        diverged = diverged or self._gaps_too_wide()
        if diverged:
            self._diverged = True
            settled = False
        return ApplyResult(
            settled=settled,
            clipped=False,
            refused=False,
            diverged=diverged,
            u_applied=np.zeros(3),
            settle_time=(self.chain.steps - steps0) * self.dt,
            sim_steps=self.chain.steps - steps0,
        )

    def _max_gap(self) -> float:
        """The widest joint gap (m) after a move that `_settle` found not diverged (NaN when a
        gap is not finite)."""
        return float(_MAX(self.chain.joint_gaps()))

    def _gaps_too_wide(self) -> bool:
        gaps = self.chain.joint_gaps()
        return not bool(np.all(np.isfinite(gaps)) and np.max(gaps) <= self.cfg.gap_limit)

    def clamp_reach_limit(self, clamp_pose: np.ndarray) -> float:
        """Largest fraction f in [0, 1] of the straight move from the clamp now to `clamp_pose`
        that keeps the gripper within `max_reach` of the held length (the distance is convex
        along the move, so checking the end of each prefix is enough)."""
        start = self.clamp_pose[:2]
        end = np.asarray(clamp_pose, dtype=float)[:2]
        grip = self.gripper_pose[:2]
        reach = self._reach()
        d = end - start
        r0 = start - grip
        # |r0 + f d|² = reach²  ->  a f² + b f + c = 0
        a, b, c = float(d @ d), float(2 * r0 @ d), float(r0 @ r0 - reach**2)
        if c > 0:
            return 0.0  # already out of reach (cannot happen after a settled step)
        if a == 0.0 or a + b + c <= 0:
            return 1.0
        return float((-b + math.sqrt(b * b - 4 * a * c)) / (2 * a))

    def move_clamp(self, pose: np.ndarray, max_step: np.ndarray | None = None) -> ApplyResult:
        """Drive the clamped end to a new pose, the gripper holding still (a bumped fixture).

        The clamp moves in a straight line in equal increments within `max_step` per control
        period (default `rod.max_step`), velocity-driven like the gripper, settling after each.
        If the new clamp pose would put the gripper beyond `max_reach` of the held length, the
        clamp stops where the limit is reached (`clipped` is True).

        The first call rebuilds the chain with a kinematic clamp body in the current shape (the
        fixed clamp is pinned to the static body, which cannot move).

        Args:
            pose: (3,) new clamp pose [x, y, theta], world frame.
            max_step: (3,) per-axis limit per control period; None = `rod.max_step`.

        Returns:
            The combined result; `u_applied` is the clamp's displacement.
        """
        target = np.asarray(pose, dtype=float).reshape(3)
        if not np.all(np.isfinite(target)):
            raise ValueError(f"RodSim.move_clamp: non-finite pose {target}")
        limit = self._max_step if max_step is None else np.asarray(max_step, dtype=float)
        if self._diverged:
            return ApplyResult(False, False, True, True, np.zeros(3), 0.0)
        if self.chain.clamp_body is None:
            self._rebuild(self._held, movable_clamp=True)
        start = self.clamp_pose
        frac = self.clamp_reach_limit(target)
        clipped = frac < 1.0
        end = start + (target - start) * frac
        delta = end - start
        n = max(1, math.ceil(float(np.max(np.abs(delta) / limit)) - 1e-9))
        total = ApplyResult(True, clipped, False, False, np.zeros(3), 0.0)
        chain = self.chain
        grip = self.gripper_pose
        for k in range(1, n + 1):
            a = start + delta * ((k - 1) / n)
            b = start + delta * (k / n)
            steps0 = chain.steps
            m = self._move_steps
            for j in range(1, m + 1):
                chain.step(grip, a + (b - a) * (j / m))
            settled, diverged = self._settle(grip)
            diverged = diverged or self._gaps_too_wide()
            total.settled = settled
            total.sim_steps += chain.steps - steps0
            total.settle_time += (chain.steps - steps0 - m) * self.dt
            if diverged:
                self._diverged = True
                total.diverged = True
                total.settled = False
                break
        total.u_applied = self.clamp_pose - start
        return total

    def slip_grasp(self, ds: float) -> ApplyResult:
        """The grasp point slides by `ds` along the rod; the gripper ends where it was.

        ds > 0: towards the clamp, the held length shrinks by ds (the rest of the rod is pulled
        through the gripper); ds < 0: away from it, the held length grows by |ds| (at most back
        to the rod's full length L). ds is rounded to whole segments (L/N); the part beyond
        the grasp is not simulated: the gripper is rigid, so it carries no load into the held
        part, and `centerline()` is the held part only (clamp -> grasp), which is what the
        camera pipeline expects.

        How: the chain is rebuilt with the new number of segments in the current shape (extra
        segments continue straight along the gripper's tangent), the gripper is put on the new
        grasp point and driven back to its pose within `max_step` like any move. Without
        friction the settled shape does not depend on that path.

        Raises:
            ValueError: the held length would be < 2 segments or > L.
        """
        k = round(float(ds) / self.chain.seg_length)
        held = self._held - k
        if not 2 <= held <= self.cfg.segments:
            raise ValueError(
                f"grasp slip of {ds} m leaves a held length of {held * self.chain.seg_length:.4g}"
                f" m, outside [2 segments, rod.length = {self.cfg.length} m]"
            )
        if self._diverged:
            return ApplyResult(False, False, True, True, np.zeros(3), 0.0)
        pose = self.gripper_pose
        if k == 0:
            return self._hold()
        self._rebuild(held, movable_clamp=self.chain.clamp_body is not None)
        return self.move_to(pose)

    def _rebuild(self, held: int, movable_clamp: bool) -> None:
        """A new chain of `held` segments in the current shape, at rest, same clock and EI/ρA."""
        old = self.chain
        states = old.segment_states()
        grip = old.gripper_pose()
        seg = old.seg_length
        if held == old.segments:
            grip_pose = grip  # the same grasp: the gripper keeps its exact pose
        elif held < old.segments:
            # The new grasp is joint `held`: its position is where the two segments meet, its
            # tangent the mean of theirs (the continuum rod's tangent at that point).
            ends = old.joint_points()
            angle = 0.5 * (states[held - 1, 2] + states[held, 2])
            grip_pose = np.array([ends[held, 0], ends[held, 1], angle])
            states = states[:held]
        else:
            # Segments come back out of the gripper, straight along its tangent.
            extra = held - old.segments
            u = np.array([math.cos(grip[2]), math.sin(grip[2])])
            i = np.arange(extra) + 0.5
            more = np.column_stack(
                [grip[0] + i * seg * u[0], grip[1] + i * seg * u[1], np.full(extra, grip[2])]
            )
            states = np.vstack([states, more])
            grip_pose = np.array([*(grip[:2] + extra * seg * u), grip[2]])
        chain = self._chain_type(
            length=held * seg,
            bending_stiffness=old.bending_stiffness,
            mass_per_length=old.mass_per_length,
            segments=held,
            clamp_pose=old.current_clamp_pose(),
            dt=self.dt,
            iterations=self.cfg.iterations,
            damping_rate=self._damping_rate,
            inertia_radius=self.cfg.inertia_radius,
            gravity=old.gravity,
            table_friction=old.table_friction,
            table_gravity=old.table_gravity,
            movable_clamp=movable_clamp,
            segment_inertia=old.segment_inertia,
        )
        chain.place(states, grip_pose)
        chain.steps = old.steps  # one clock across rebuilds (sim_time)
        self.chain = chain
        self._held = held
