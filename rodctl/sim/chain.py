"""The pymunk chain itself: N rigid segments, pivot joints and rotary springs, one clamped end.

Why a separate module from `rod.py`: the chain is the physics (a Hencky bar-chain discretisation
of the inextensible planar elastica) and is also what the validation tests build directly, with a
free end and a dead tip load for the cantilever; `RodSim` adds the gripper policy on top
(workspace, speed limits, settling, divergence).

Discretisation (docs/simulation.md):

* segment i (i = 0..N-1) is a rigid body of length l = L/N, centre at (i + 1/2) l along the rod;
* joint i between segments i-1 and i is a `PivotJoint` plus a `DampedRotarySpring` of stiffness
  k = EI / l (the midpoint rule on the bending energy  ∫ EI/2 θ'^2 ds);
* the clamp and the gripper hold the outer half-segment of their end, so their springs have
  stiffness 2 EI / l (a half Voronoi cell). With EI / l there the error is first order in 1/N
  (+3.4 % at N = 50 on the cantilever) instead of second order.

Quasi-static speed-up (legitimate because only the SETTLED shape is used, and the static
equilibrium of this chain does not depend on masses or inertias when no body force acts; with
gravity it depends on the masses ρA·l, which are the real ones, but never on the rotary inertia;
with table friction the stopping point of a sliding rod does depend on the dynamics, so there the
shapes are those of *a* slowly driven frictional rod, see docs/simulation.md):

* every segment gets a fictitious extra rotary inertia m·(g L)^2 (a radius of gyration g·L, like
  a very thick Rayleigh beam). Kinetic energy is then dominated by rotation, which turns the
  bending spectrum from ω ~ k^2 into ω ~ k: the ratio of the fastest to the slowest mode falls
  from ~N^2 to ~N/π, so an explicit step settles in ~N steps instead of ~N^2. It also lifts the
  explicit-spring stability limit from ~l^2 sqrt(ρA/EI) to ~l g L sqrt(ρA/EI);
* global velocity damping (`space.damping`) is set to critically damp the first bending mode, so
  every mode decays at least as fast as e^(-ω1 t). Chipmunk applies the spring impulse before it
  scales velocities by damping**dt, which softens every spring by that factor; each stiffness is
  divided by damping**dt to undo it. Without a tip force the settled shape would not even
  notice, with one it would.

The gripper is a kinematic body driven by velocity, never teleported (pitfall 3). Readouts use
`pymunk.batch` (one C call instead of a Python loop over bodies).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence

import numpy as np
import pymunk
import pymunk.batch as pbatch

_POS_ANGLE = pbatch.BodyFields.POSITION | pbatch.BodyFields.ANGLE
_VEL = pbatch.BodyFields.VELOCITY | pbatch.BodyFields.ANGULAR_VELOCITY


def segment_rotary_inertia(
    length: float, mass_per_length: float, segments: int, inertia_radius: float
) -> float:
    """Rotary inertia of one segment: its own m l^2/12 plus the fictitious m (g L)^2.

    Args:
        length: rod length L (m).
        mass_per_length: ρA (kg/m).
        segments: N.
        inertia_radius: g, the fictitious radius of gyration as a fraction of L.

    Returns:
        J (kg m^2).
    """
    seg = length / segments
    mass = mass_per_length * seg
    return mass * (seg * seg / 12.0 + (inertia_radius * length) ** 2)


def stable_dt_limit(
    length: float,
    bending_stiffness: float,
    mass_per_length: float,
    segments: int,
    inertia_radius: float,
) -> float:
    """The explicit-spring stability limit 2/ω_max of the zig-zag mode (s).

    In the zig-zag mode neighbouring segments turn by ±φ about fixed centres, each spring sees
    2φ and each segment two springs, so ω_max^2 = 4 k / J with k = EI/l (the clamp's 2k on one
    spring gives the same 4k for the end segment).
    """
    seg = length / segments
    j = segment_rotary_inertia(length, mass_per_length, segments, inertia_radius)
    return 2.0 / math.sqrt(4.0 * (bending_stiffness / seg) / j)


def first_mode_rate(
    length: float,
    bending_stiffness: float,
    mass_per_length: float,
    segments: int,
    inertia_radius: float,
    free_end: bool = False,
) -> float:
    """Angular frequency ω1 (rad/s) of the first bending mode of the straight chain.

    With rotation-dominated inertia (rotary inertia per length j = J/l) the small-angle dynamics
    is j θ_tt = EI θ_ss. Held at both ends (angles fixed, and the gripper's fixed position adds
    ∫θ ds = 0) the first mode is sin(2π s/L); with a free end it is sin(π s / 2L).
    """
    seg = length / segments
    j_per_length = segment_rotary_inertia(length, mass_per_length, segments, inertia_radius) / seg
    wavenumber = math.pi / (2.0 * length) if free_end else 2.0 * math.pi / length
    return wavenumber * math.sqrt(bending_stiffness / j_per_length)


def _drive(body: pymunk.Body, target: Sequence[float] | np.ndarray | None, dt: float) -> None:
    """Set a kinematic body's velocity so that it lands exactly on `target` [x, y, theta] at
    the end of a time step of `dt` (None: hold it still)."""
    if target is None:
        body.velocity = (0.0, 0.0)
        body.angular_velocity = 0.0
        return
    p = body.position
    inv = 1.0 / dt
    body.velocity = ((target[0] - p.x) * inv, (target[1] - p.y) * inv)
    body.angular_velocity = (target[2] - body.angle) * inv


#: Rate at which the solver closes every pivot joint's gap (clamp, interior, gripper) while the
#: rod lies on a table with friction, as a multiple of the rod's first bending-mode rate ω1
#: (27/s for the default rod; Chipmunk's default is 6.3/s). See `RodChain.set_table_friction`.
TABLE_GAP_RATE = 1.3
#: Largest speed (m/s) of that correction, so that a wide gap (0.2-0.3 mm at the gripper right
#: after a move) does not kick the rod. Measured: uncapped, 1.7 ω1 made an underdamped rod
#: (rod.damping 0.25-0.5) jump to another equilibrium branch (0.24 m away) at N = 50, and 2 ω1,
#: even capped, kept it from settling at N = 100; 1.3 ω1 with the cap settles at N = 25, 50, 100,
#: mu = 0.2-2, damping 0.25-1.
TABLE_GAP_MAX_SPEED = 2e-3


def _table_joints(space: pymunk.Space, bodies: list) -> list[pymunk.Constraint]:
    """pymunk's top-down friction: per segment a pivot (sliding) and a gear (turning) joint to
    the static body, with no position correction; their max forces are set from mu."""
    joints: list[pymunk.Constraint] = []
    for body in bodies:
        slide = pymunk.PivotJoint(space.static_body, body, (0, 0), (0, 0))
        spin = pymunk.GearJoint(space.static_body, body, 0.0, 1.0)
        for joint in (slide, spin):
            joint.max_bias = 0.0  # friction resists velocity only, no position pull-back
            joint.collide_bodies = False
        joints += [slide, spin]
    return joints


class RodChain:
    """A planar elastic rod as a pymunk chain, clamped at one end, gripped or free at the other.

    Deterministic: two chains built with the same arguments and driven the same way produce
    bit-identical states (rebuild, never deepcopy a `pymunk.Space`: the solver's warm-start
    impulses are not copied).

    Args:
        length: L (m).
        bending_stiffness: EI (N m^2).
        mass_per_length: ρA (kg/m).
        segments: N.
        clamp_pose: (3,) clamped end [x, y, theta], world; theta is the rod tangent there.
        dt: fixed time step (s).
        iterations: solver iterations per step.
        damping_rate: c (1/s); velocities decay as e^(-c t) between impulses. 0 = undamped.
        inertia_radius: g, fictitious radius of gyration of each segment as a fraction of L.
        gripped: True: the far end is held by a kinematic gripper, initially at the straight
            rod's end; False: the far end is free.
        tip_force: (2,) dead load (N, world frame) on the free end, reapplied every step. Only
            with `gripped=False`.
        gravity: (2,) acceleration (m/s², world frame) in the rod's plane, i.e. a vertical plane.
            pymunk adds it to every segment's velocity after the damping factor, so it is not
            softened by `damping_rate` the way the springs are (Munk2D `cpBodyUpdateVelocity`).
            Lumped at each segment's centre: the midpoint rule on the distributed load ρA·g,
            second order in 1/N like the springs.
        table_friction: Coulomb coefficient μ of a table under a horizontal rod (gravity normal
            to the plane); None: no table. pymunk's top-down friction idiom: per segment, a
            `PivotJoint` to the static body at the segment centre with max_force μ m g and a
            `GearJoint` with max torque μ m g l/4 (the Coulomb torque of a uniformly loaded
            segment spinning about its centre), both with max_bias 0 so they only resist motion
            and never pull the rod back. With μ > 0 the pivot joints close their gaps faster
            (see `set_table_friction`). μ = 0 builds the joints with zero force (a table without
            friction) and keeps the default gap correction: the same shapes as no table.
        table_gravity: g (m/s²) pressing the rod on the table (only with `table_friction`).
        movable_clamp: hold the clamped end by a kinematic body that `step` can drive (like the
            gripper) instead of pinning it to the static body. False builds exactly the chain
            of earlier versions (bit-identical runs).
        segment_inertia: rotary inertia of every segment (kg m²); None: from
            `segment_rotary_inertia`. A rebuilt chain passes its predecessor's, so that a
            stiffness change or a shorter held length keeps the same time-step limit.
    """

    def __init__(
        self,
        length: float,
        bending_stiffness: float,
        mass_per_length: float,
        segments: int,
        clamp_pose: Sequence[float] | np.ndarray,
        dt: float,
        iterations: int,
        damping_rate: float,
        inertia_radius: float,
        gripped: bool = True,
        tip_force: Sequence[float] | None = None,
        gravity: Sequence[float] = (0.0, 0.0),
        table_friction: float | None = None,
        table_gravity: float = 9.81,
        movable_clamp: bool = False,
        segment_inertia: float | None = None,
    ) -> None:
        if tip_force is not None and gripped:
            raise ValueError("a tip force needs a free end (gripped=False)")
        self.length = float(length)
        self.segments = int(segments)
        self.seg_length = self.length / self.segments
        self.dt = float(dt)
        self.clamp_pose = np.asarray(clamp_pose, dtype=float).copy()
        self.tip_force = None if tip_force is None else (float(tip_force[0]), float(tip_force[1]))
        self.steps = 0

        seg = self.seg_length
        mass = mass_per_length * seg
        inertia = segment_rotary_inertia(length, mass_per_length, segments, inertia_radius)
        if segment_inertia is not None:
            inertia = float(segment_inertia)
        self.segment_mass = mass
        self.segment_inertia = inertia
        self.bending_stiffness = float(bending_stiffness)
        self.mass_per_length = float(mass_per_length)

        space = pymunk.Space()
        space.iterations = int(iterations)
        self.gravity = (float(gravity[0]), float(gravity[1]))
        if self.gravity != (0.0, 0.0):
            space.gravity = self.gravity
        # Velocities are multiplied by damping**dt each step: damping = e^(-c) per second.
        space.damping = math.exp(-damping_rate)
        # Undo the spring softening by damping**dt: pymunk multiplies every velocity, the springs'
        # included, by damping**dt each step, which would soften the settled stiffness.
        soften = math.exp(-damping_rate * self.dt)  # = damping**dt, without the underflow
        k_in = bending_stiffness / seg / soften
        k_end = 2.0 * bending_stiffness / seg / soften

        bodies = self._add_segments(space, mass, inertia)
        constraints = self._joints(space, bodies, k_in, k_end, movable_clamp, gripped)
        self._joint_pivots = [c for c in constraints if isinstance(c, pymunk.PivotJoint)]
        self._default_error_bias = self._joint_pivots[0].error_bias
        self._default_max_bias = self._joint_pivots[0].max_bias
        self.table_friction = None if table_friction is None else float(table_friction)
        self.table_gravity = float(table_gravity)
        self.friction_joints: list[pymunk.Constraint] = []
        if self.table_friction is not None:
            self.friction_joints = _table_joints(space, bodies)
            self.set_table_friction(self.table_friction)
            constraints.extend(self.friction_joints)
        space.add(*constraints)
        self.space = space
        self.bodies = bodies
        self._pivots = [c for c in constraints if isinstance(c, pymunk.PivotJoint)]
        self._index_readout()

    def _add_segments(self, space: pymunk.Space, mass: float, inertia: float) -> list:
        """The N segments, straight along the clamp direction."""
        x0, y0, th0 = self.clamp_pose
        ux, uy = math.cos(th0), math.sin(th0)
        bodies = []
        for i in range(self.segments):
            body = pymunk.Body(mass, inertia)
            body.position = (
                x0 + (i + 0.5) * self.seg_length * ux,
                y0 + (i + 0.5) * self.seg_length * uy,
            )
            body.angle = th0
            bodies.append(body)
        space.add(*bodies)
        return bodies

    def _joints(
        self,
        space: pymunk.Space,
        bodies: list,
        k_in: float,
        k_end: float,
        movable_clamp: bool,
        gripped: bool,
    ) -> list[pymunk.Constraint]:
        """Pivots and bending springs: clamp, between segments, and the gripper."""
        n, seg = self.segments, self.seg_length
        x0, y0, th0 = self.clamp_pose
        ux, uy = math.cos(th0), math.sin(th0)
        half = seg / 2.0
        constraints: list[pymunk.Constraint] = []
        # Clamp: pivot at the clamp point + spring of 2EI/l; torque = (a.angle - b.angle - rest)k
        # with a = static body (angle 0), so rest = -theta_clamp keeps segment 0 at theta_clamp.
        self.clamp_body: pymunk.Body | None = None
        if movable_clamp:
            # Torque = (a.angle - b.angle - rest) k: the clamp body carries theta_clamp itself.
            clamp = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            clamp.position = (x0, y0)
            clamp.angle = th0
            space.add(clamp)
            constraints.append(pymunk.PivotJoint(clamp, bodies[0], (0, 0), (-half, 0)))
            constraints.append(pymunk.DampedRotarySpring(clamp, bodies[0], 0.0, k_end, 0))
            self.clamp_body = clamp
        else:
            constraints.append(
                pymunk.PivotJoint(space.static_body, bodies[0], (x0, y0), (-half, 0))
            )
            constraints.append(
                pymunk.DampedRotarySpring(space.static_body, bodies[0], -th0, k_end, 0)
            )
        for i in range(1, n):
            pivot = pymunk.PivotJoint(bodies[i - 1], bodies[i], (half, 0), (-half, 0))
            pivot.collide_bodies = False
            constraints.append(pivot)
            constraints.append(pymunk.DampedRotarySpring(bodies[i - 1], bodies[i], 0, k_in, 0))
        self.gripper: pymunk.Body | None = None
        if gripped:
            grip = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            grip.position = (x0 + n * seg * ux, y0 + n * seg * uy)
            grip.angle = th0
            space.add(grip)
            constraints.append(pymunk.PivotJoint(grip, bodies[-1], (0, 0), (half, 0)))
            constraints.append(pymunk.DampedRotarySpring(bodies[-1], grip, 0, k_end, 0))
            self.gripper = grip
        return constraints

    def _index_readout(self) -> None:
        """Batch readout: the buffer also holds the static body (a constraint is attached to
        it) and the gripper; find the segment rows by body id once."""
        n = self.segments
        self._buf = pbatch.Buffer()
        pbatch.get_space_bodies(self.space, pbatch.BodyFields.BODY_ID, self._buf)
        ids = np.frombuffer(self._buf.int_buf(), dtype=np.uintp).copy()
        row_of = {int(v): r for r, v in enumerate(ids)}
        self._rows = np.array([row_of[b.id] for b in self.bodies], dtype=np.intp)
        self._nrows = len(ids)
        first = int(self._rows[0])
        self._contiguous = bool(np.array_equal(self._rows, np.arange(first, first + n)))

    # ------------------------------------------------------------------ changing the rod
    def set_table_friction(self, mu: float) -> None:
        """Set the table's Coulomb coefficient (only on a chain built with `table_friction`).

        With μ > 0 the pivot joints also close their gaps faster (`TABLE_GAP_RATE` · ω1, at most
        `TABLE_GAP_MAX_SPEED`) than Chipmunk's default 10 % per 1/60 s. Why: at 20 solver
        iterations the chain's pivots open while the gripper drags it (a few mm summed along the
        chain during a move, on the weightless rod too) and the solver closes those gaps after
        the move. Without friction the default rate only sets how long the settle takes. On a
        table, friction holds the segments against that slow correction: the rod kept slipping
        at about the settle speed for a second or more while the gaps closed, and a control
        step took 2.3x the physics steps of the weightless rod (1.2x with the faster rate). The
        gaps are a solver error, not physics, so closing them faster changes no equilibrium (a
        table with μ = 1e-9 settles within 0.03 mm of the frictionless rod). μ = 0 keeps
        Chipmunk's defaults: a frictionless table is then the frictionless rod bit for bit.
        """
        if self.table_friction is None:
            raise ValueError("this chain has no table (built with table_friction=None)")
        if not (math.isfinite(mu) and mu >= 0):
            raise ValueError(f"table friction must be finite and >= 0, got {mu}")
        self.table_friction = float(mu)
        bias = self._default_error_bias
        if mu > 0:
            # Chipmunk closes 1 - error_bias**dt of the gap per step: error_bias is the fraction
            # left after one second. Past a rate of ~708/s it would underflow to 0 (the whole gap
            # in one step); the smallest normal float then closes a little less than asked.
            bias = max(math.exp(-TABLE_GAP_RATE * self.mode1_rate()), sys.float_info.min)
        max_bias = self._default_max_bias if mu == 0 else TABLE_GAP_MAX_SPEED
        for pivot in self._joint_pivots:
            pivot.error_bias = bias
            pivot.max_bias = max_bias
        normal = self.segment_mass * self.table_gravity
        for i in range(0, len(self.friction_joints), 2):
            self.friction_joints[i].max_force = mu * normal
            self.friction_joints[i + 1].max_force = mu * normal * self.seg_length / 4.0

    def set_bending_stiffness(self, bending_stiffness: float) -> None:
        """Change EI in place, keeping the time step stable and the damping critical.

        Every rotary spring is rescaled by the ratio r (the clamp's and the gripper's stay at
        twice the interior ones; the damping compensation is unchanged because the damping rate
        is). The segments' rotary inertia is scaled by r too: the bending frequencies go as
        sqrt(k/J), so they, the explicit-spring stability limit of `dt` and the critical damping
        of mode 1 all stay what they were. Rotary inertia does not enter any settled shape (it is
        already fictitious, see the module docstring), so only the clock of the settling changes.
        """
        if not (math.isfinite(bending_stiffness) and bending_stiffness > 0):
            raise ValueError(f"bending stiffness must be finite and > 0, got {bending_stiffness}")
        ratio = bending_stiffness / self.bending_stiffness
        for c in self.space.constraints:
            if isinstance(c, pymunk.DampedRotarySpring):
                c.stiffness = c.stiffness * ratio
        self.segment_inertia *= ratio
        for body in self.bodies:
            body.moment = self.segment_inertia
        self.bending_stiffness = float(bending_stiffness)

    def set_mass_per_length(self, mass_per_length: float) -> None:
        """Change ρA in place: every segment's mass and rotary inertia scale with it (so the
        settling speed-up is kept), and the table's friction forces follow the new weight."""
        if not (math.isfinite(mass_per_length) and mass_per_length > 0):
            raise ValueError(f"mass per length must be finite and > 0, got {mass_per_length}")
        ratio = mass_per_length / self.mass_per_length
        self.segment_mass *= ratio
        self.segment_inertia *= ratio
        for body in self.bodies:
            body.mass = self.segment_mass
            body.moment = self.segment_inertia
        self.mass_per_length = float(mass_per_length)
        if self.table_friction is not None:
            self.set_table_friction(self.table_friction)

    def mode1_rate(self) -> float:
        """ω1 (rad/s) of the gripper-held chain as it is now: `first_mode_rate` with the actual
        segment inertia and length (which `set_bending_stiffness` leaves unchanged and
        `set_mass_per_length` or a shorter held length change)."""
        j_per_length = self.segment_inertia / self.seg_length
        return 2.0 * math.pi / self.length * math.sqrt(self.bending_stiffness / j_per_length)

    # ------------------------------------------------------------------ readouts
    def _read(self, fields: pbatch.BodyFields) -> np.ndarray:
        self._buf.clear()
        pbatch.get_space_bodies(self.space, fields, self._buf)
        data = np.frombuffer(self._buf.float_buf(), dtype=np.float64).reshape(self._nrows, 3)
        if self._contiguous:
            r0 = self._rows[0]
            return data[r0 : r0 + self.segments].copy()
        return data[self._rows]

    def segment_states(self) -> np.ndarray:
        """(N, 3) segment centres and angles [x, y, angle], world frame."""
        return self._read(_POS_ANGLE)

    def segment_velocities(self) -> np.ndarray:
        """(N, 3) segment centre velocities and angular velocities [vx, vy, omega]."""
        return self._read(_VEL)

    def segment_ends(self) -> tuple[np.ndarray, np.ndarray]:
        """Start and end point of every segment, each (N, 2), world frame."""
        st = self.segment_states()
        half = self.seg_length / 2.0
        t = np.stack([np.cos(st[:, 2]), np.sin(st[:, 2])], axis=1) * half
        return st[:, :2] - t, st[:, :2] + t

    def joint_points(self) -> np.ndarray:
        """(N+1, 2) centreline at the joints, clamp end first.

        Interior joints are the mean of the two segment ends that meet there (they differ by
        the joint gap, micrometres); the two ends are the outer ends of the end segments.
        """
        start, end = self.segment_ends()
        pts = np.empty((self.segments + 1, 2))
        pts[0] = start[0]
        pts[1:-1] = 0.5 * (end[:-1] + start[1:])
        pts[-1] = end[-1]
        return pts

    def joint_gaps(self) -> np.ndarray:
        """(N+1,) or (N,) separation (m) of every pivot joint: clamp, interior, gripper."""
        start, end = self.segment_ends()
        gaps = [np.hypot(*(start[0] - self.current_clamp_pose()[:2]))]
        gaps.extend(np.hypot(*(end[:-1] - start[1:]).T))
        if self.gripper is not None:
            gaps.append(np.hypot(*(end[-1] - np.array(self.gripper.position))))
        return np.asarray(gaps, dtype=float)

    def max_speed(self) -> float:
        """Largest speed (m/s) of any segment end: |v_centre| + |omega| l/2."""
        vel = self.segment_velocities()
        ends = np.hypot(vel[:, 0], vel[:, 1]) + np.abs(vel[:, 2]) * (self.seg_length / 2)
        return float(np.max(ends))

    def kinetic_energy(self) -> float:
        """Kinetic energy (J) of the simulated chain, with the inflated rotary inertia."""
        vel = self.segment_velocities()
        lin = 0.5 * self.segment_mass * float(np.sum(vel[:, :2] ** 2))
        rot = 0.5 * self.segment_inertia * float(np.sum(vel[:, 2] ** 2))
        return lin + rot

    def current_clamp_pose(self) -> np.ndarray:
        """(3,) the clamped end's pose now (it moves only with `movable_clamp`)."""
        if self.clamp_body is None:
            return self.clamp_pose.copy()
        p = self.clamp_body.position
        return np.array([p.x, p.y, self.clamp_body.angle])

    def place(
        self, states: np.ndarray, gripper_pose: Sequence[float] | np.ndarray | None = None
    ) -> None:
        """Put a freshly built chain into a given shape, at rest (used to rebuild a chain).

        Args:
            states: (N, 3) segment centres and angles [x, y, angle], world frame, consistent
                with the clamp pose (joint gaps of micrometres are corrected by the solver).
            gripper_pose: (3,) pose of the kinematic gripper, if the chain has one.
        """
        if self.steps:
            raise RuntimeError("place() is for a chain that has not been stepped yet")
        states = np.asarray(states, dtype=float)
        if states.shape != (self.segments, 3):
            raise ValueError(f"states must be ({self.segments}, 3), got {states.shape}")
        for body, (x, y, a) in zip(self.bodies, states, strict=True):
            body.position = (float(x), float(y))
            body.angle = float(a)
            body.velocity = (0.0, 0.0)
            body.angular_velocity = 0.0
        if gripper_pose is not None and self.gripper is not None:
            self.gripper.position = (float(gripper_pose[0]), float(gripper_pose[1]))
            self.gripper.angle = float(gripper_pose[2])

    def gripper_pose(self) -> np.ndarray:
        """(3,) kinematic gripper pose [x, y, theta]; the free end's pose without a gripper."""
        if self.gripper is None:
            st = self.segment_states()[-1]
            half = self.seg_length / 2.0
            return np.array([st[0] + half * math.cos(st[2]), st[1] + half * math.sin(st[2]), st[2]])
        p = self.gripper.position
        return np.array([p.x, p.y, self.gripper.angle])

    # ------------------------------------------------------------------ stepping
    def step(
        self, target: np.ndarray | None = None, clamp_target: np.ndarray | None = None
    ) -> None:
        """Advance one time step; drive the gripper towards `target` [x, y, theta] by velocity.

        The gripper's velocity is set so that it lands exactly on `target` at the end of the
        step (kinematic bodies are integrated from their velocity). `target=None` holds it still.
        `clamp_target` drives a movable clamp the same way (None: it stays).
        """
        if self.clamp_body is not None:
            _drive(self.clamp_body, clamp_target, self.dt)
        elif clamp_target is not None:
            raise ValueError("this chain's clamp is fixed (built with movable_clamp=False)")
        if self.gripper is not None:
            _drive(self.gripper, target, self.dt)
        elif self.tip_force is not None:
            # A dead load: fixed world direction, applied at the free end (forces reset each step).
            tip = self.bodies[-1]
            tip.apply_force_at_world_point(
                self.tip_force, tip.local_to_world((self.seg_length / 2.0, 0.0))
            )
        self.space.step(self.dt)
        self.steps += 1

    def run(self, steps: int, target: np.ndarray | None = None) -> None:
        """`steps` steps holding the gripper at `target` (None: hold it where it is)."""
        for _ in range(steps):
            self.step(target)
