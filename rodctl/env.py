"""`ShapeServoEnv`: the simulated rod, the gripper and the camera as a Gymnasium environment.

Why an environment: every consumer of an episode — `rodctl simulate`, each `compare` episode,
`replay --verify`, and a researcher's own RL or control code — needs the same thing: a fresh rod,
camera-noise stream and target from a seed, then "move the gripper by Δr, let the rod settle,
look at it". `gymnasium.Env` is the interface the field already knows, so the environment is
usable outside rodctl (`gymnasium.make("rodctl/ShapeServo-v0")`) and `check_env` holds it to the
contract (spaces, seeding, determinism).

One step (architecture: the data path):

    RodSim.apply(Δr) → settle → ground truth → Camera.render → CenterlineExtractor → observation

Observation (a `Dict` space):
    centerline: (N, 2) float64 pixels, clamp end first, as extracted from the camera image;
        zeros when the frame failed (then `extraction_ok` is 0).
    gripper: (3,) float64 gripper pose [x, y, theta] (world frame, m, rad): the robot's own
        proprioception. Dual-arm (`rod.arms: 2`): (6,), the gripper's pose then the x0 end's.
    applied: (3,) (dual-arm (6,)) float64 the pose increment the robot really made in the last
        step (after its per-axis speed limit and the workspace), zeros after `reset`. Within
        `rod.max_step` per axis except when the workspace clipped the move (the space allows
        the workspace's span).
    extraction_ok: 1 when the whole rod was seen and traced, else 0.
    target: (N, 2) float64 the target centerline in pixels (it moves only when the camera is
        bumped by a mid-run event: the same physical shape seen from the new pose).

Reward: minus the pixel error, the mean distance in pixels between the extracted centerline and
the target's (a failed frame costs the image diagonal). `terminated` on convergence (pixel error
below `run.pixel_tolerance`) or divergence, `truncated` at `run.max_steps`. `info` carries what a
real robot would not see: ground truth, projected truth, the settle result, the rod's health.
`render()` (render_mode "rgb_array") returns the camera frame. Mid-run events (`run.events`)
are applied before the move of their step; `info["events"]` has their log lines.

What the control loop (`rodctl.episode.run_episode`) needs comes through `reset`/`step`, so it
runs on `gymnasium.make(...)` and on wrapped environments: every `info` has `gripper` (the
simulator's gripper pose), `extraction_ok` (bool) and `image` (the camera frame the observation
was extracted from, the array `render()` returns, not a copy); the `info` of `reset` also has
`target` (the episode's `Target`). Beside them the loop reads three public members of the base
environment (`env.unwrapped`, as Gymnasium recommends for environment-specific attributes),
declared on the `ServoEnv` protocol: `config`, `task` (the `Task` a method starts from: it holds
the live camera model and the simulator's Jacobian, so it is no `info` value, which must pickle
for vector envs) and `stage_times()`.

The episode is a pure function of (config, seed): `reset(seed)` rebuilds the rod, the camera
and its noise stream, and the target, from named seed streams (`rodctl.runs.rng`).

Observations are float64 and shaped as above because the methods run on them (bit for bit,
`replay --verify`). For RL libraries, `rodctl.rl` wraps this environment as
`rodctl/ShapeServoRL-v0` and `rodctl/ShapeServoGoal-v0` (float32 vectors, actions in [-1, 1],
normalised observations, a success bonus, a goal-conditioned form for HER): docs/rl.md.
"""

from __future__ import annotations

import math
import operator
import time
from dataclasses import dataclass, replace
from typing import Any, Protocol, cast, runtime_checkable

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rodctl.config import ExperimentConfig, load_config, validate_config
from rodctl.config.rod import RodConfig
from rodctl.errors import UserError, pose_text
from rodctl.geometry import resample_polyline
from rodctl.runs import rng
from rodctl.sim import RodSim
from rodctl.targets import TARGET_TRIES, difficulty, target_candidates
from rodctl.vision import Camera, CenterlineExtractor

#: Gripper degrees of freedom: x, y, theta.
Q = 3


@runtime_checkable
class _AnalyticSim(Protocol):
    """An engine with d(centerline)/dr in closed form (the quasi-static one), exact where its
    chain is at an equilibrium (`_at_equilibrium`)."""

    def centerline_jacobian(self) -> np.ndarray: ...


def _is_analytic(sim: object) -> bool:
    """``isinstance(sim, _AnalyticSim)`` without the runtime-protocol check's cost (~4 µs, three
    times a control step): the protocol's one member is there."""
    return getattr(sim, "centerline_jacobian", None) is not None


def _at_equilibrium(sim: RodSim) -> bool:
    """The quasi-static chain's last solve converged (a pymunk chain has no such flag)."""
    return bool(getattr(sim.chain, "converged", False))


def _rows_of(encode: Any) -> Any:
    """The `encode_rows` of the feature map whose bound `encode` this is ((B, N, 2) -> (B, p),
    the same bits as `encode` shape by shape: `AutoencoderFeatureMap`), else None. Only when
    one class defines both (a subclass that overrides `encode` alone gets the plain loop)."""
    owner = getattr(encode, "__self__", None)
    if owner is None or getattr(encode, "__name__", None) != "encode":
        return None
    defining: dict[str, type] = {}
    for cls in type(owner).__mro__:
        for name in ("encode", "encode_rows"):
            if name in cls.__dict__:
                defining.setdefault(name, cls)
    if defining.get("encode_rows") is None or defining.get("encode") is not defining["encode_rows"]:
        return None
    if getattr(encode, "__func__", None) is not defining["encode"].__dict__["encode"]:
        return None  # an encode set on the instance, not the class's
    return owner.encode_rows


#: [matrix, its `_two_point_rows`] of the last resampling matrix looked at.
_TWO_POINT: list[Any] = [None, None]


def _two_point_rows(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(f, a, b) when row r of `w` is a_r at column f_r, b_r at f_r + 1 and zero elsewhere
    (linear interpolation between neighbouring joints: `resample_matrix`), else None.
    Remembered for the last read-only matrix (`resample_matrix`'s are cached and read-only)."""
    if _TWO_POINT[0] is w and not w.flags.writeable:
        return _TWO_POINT[1]
    rows = np.arange(w.shape[0])
    first = np.minimum(np.argmax(w != 0.0, axis=1), w.shape[1] - 2)
    a, b = w[rows, first], w[rows, first + 1]
    rebuilt = np.zeros_like(w)
    rebuilt[rows, first], rebuilt[rows, first + 1] = a, b
    found = (first, a.copy(), b.copy()) if np.array_equal(rebuilt, w) else None
    _TWO_POINT[:] = [w, found]
    return found


def _interpolate(two: tuple[np.ndarray, np.ndarray, np.ndarray], x: np.ndarray) -> np.ndarray:
    """einsum("ij,j...->i...", w, x) for the two-point rows (f, a, b) of `w` and a finite x,
    with the same bits, as a x[f] + b x[f + 1] + 0.0.

    The einsum sums a x[f], b x[f + 1] and exact zeros (zero weights times finite values) in
    some order: adding a zero to a nonzero value is exact, so a nonzero sum is the one rounding
    of a x[f] + b x[f + 1] whatever the order; a zero sum comes out +0.0 (einsum accumulates
    from +0.0), which is what the final + 0.0 makes of a -0.0. tests/test_env_sums.py checks
    both against einsum, signed zeros included."""
    f, a, b = two
    shape = (-1,) + (1,) * (x.ndim - 1)
    return (a.reshape(shape) * x[f] + b.reshape(shape) * x[f + 1]) + 0.0


def _chain_2x2(pj: np.ndarray, dpoints: np.ndarray) -> np.ndarray:
    """einsum("ikl,ilq->ikq", pj, dpoints) for (N, 2, 2) and (N, 2, q), with the same bits: each
    entry is a sum of two products, so (as in `_interpolate`) one rounding, + 0.0 for a zero."""
    return (pj[:, :, 0, None] * dpoints[:, None, 0] + pj[:, :, 1, None] * dpoints[:, None, 1]) + 0.0


def pixel_error(extracted: np.ndarray, target: np.ndarray) -> float:
    """Mean distance (px) between corresponding points of two (N, 2) clamp-first centerlines.

    Each distance is sqrt(dx^2 + dy^2), the one rounding of the sum that `np.linalg.norm(d,
    axis=1)` makes too (the same bits, without its generic-case overhead). The mean is
    np.mean's own pairwise sum and one division, without its Python layer."""
    d = np.subtract(extracted, target)
    sq = d * d
    dist = np.sqrt(sq[:, 0] + sq[:, 1])
    return float(np.add.reduce(dist)) / dist.shape[0]


@dataclass
class Frame:
    """One look at the rod: ground truth, the camera frame and what was extracted from it.

    Attributes:
        centerline: (M, 2) simulator joints, world metres, clamp first.
        projected_truth: (N, 2) ground truth through the camera model, pixels.
        image: (H, W, 3) uint8 RGB camera frame.
        extracted: (N, 2) pixels from the image; all NaN when the frame failed.
        ok: the whole rod was seen and traced.
        note: why `ok` is False ("" otherwise).
    """

    centerline: np.ndarray
    projected_truth: np.ndarray
    image: np.ndarray
    extracted: np.ndarray
    ok: bool
    note: str


@dataclass
class Target:
    """A reachable target: the gripper pose that produces it and what the camera saw there.

    Attributes:
        pose: (3,) gripper pose, world frame, as the rod settled there.
        centerline: (M, 2) ground truth, world metres.
        pixels: (N, 2) the extracted target centerline, pixels.
        difficulty: normalised distance from the home pose (`rodctl.targets`).
    """

    pose: np.ndarray
    centerline: np.ndarray
    pixels: np.ndarray
    difficulty: float


@dataclass(frozen=True)
class Task:
    """What a method is told at the start of an episode: the set-up, not the rod's internals.

    Attributes:
        target_pixels: (N, 2) the target centerline as the camera extracted it.
        home_pose: (q,) gripper pose at the start, world frame (r is measured from it); q = 6
            dual-arm (`rod.arms: 2`): the gripper's, then the x0 end's.
        clamp_pose: (3,) pose of the clamped end, world frame (dual-arm: where it starts).
        max_step: (q,) the robot's per-axis speed limit per step [m, m, rad] (per end).
        probe_size: (q,) size of the probing moves the run allows.
        camera: the calibrated camera model (project / unproject / projection_jacobian).
        points: N, the centerline points.
        true_jacobian: the simulator's Jacobian of a feature at the current shape
            (`ShapeServoEnv.true_jacobian`): only the `oracle` reference method uses it, and
            it is labelled as not realisable on a real robot.
    """

    target_pixels: np.ndarray
    home_pose: np.ndarray
    clamp_pose: np.ndarray
    max_step: np.ndarray
    probe_size: np.ndarray
    camera: Any
    points: int
    true_jacobian: Any = None


@dataclass
class StageTimes:
    """Wall time per stage, summed over an episode (seconds)."""

    sim: float = 0.0
    vision: float = 0.0
    feature: float = 0.0
    control: float = 0.0
    logging: float = 0.0

    def per_step_ms(self, steps: int) -> dict[str, float]:
        n = max(steps, 1)
        return {k: round(1e3 * v / n, 4) for k, v in self.__dict__.items()}


@runtime_checkable
class ServoEnv(Protocol):
    """What the control loop reads of a base environment besides `reset`/`step` and their `info`
    (`ShapeServoEnv` is one; `run_episode` reaches it through `env.unwrapped`)."""

    @property
    def config(self) -> ExperimentConfig:
        """The experiment config the environment runs (its rod, camera and run sections)."""
        ...

    #: The number of commanded pose values: 3 (one gripper) or 6 (dual-arm, `rod.arms: 2`).
    q: int

    @property
    def task(self) -> Task | None:
        """What a method is told at the start of the episode (None before the first reset)."""
        ...

    def stage_times(self) -> StageTimes:
        """Wall time spent in the simulator and in vision since the last `reset` (a copy)."""
        ...


def _home_sim(rod: Any) -> RodSim:
    """A fresh rod at home: its settled home state, computed once per rod config and restored
    for every episode, the first included (`RodSim.at_home`), with either engine. For pymunk the
    restored state has no solver warm start, so its steps differ from those of a rod driven home
    within the settle tolerance (docs/engines.md, "Reset without re-driving")."""
    return RodSim.at_home(rod)


#: The largest episode seed `reset` takes: the config's `seed` bound, so that a run's seed is
#: one a config file and the command line can give too.
MAX_EPISODE_SEED = 2**63 - 1


def _episode_seed(seed: Any) -> int:
    """`reset`'s seed as a Python int (numpy integers too), in [0, MAX_EPISODE_SEED]."""
    try:
        value = operator.index(seed) if not isinstance(seed, bool) else None
    except TypeError:
        value = None
    if value is None or not 0 <= value <= MAX_EPISODE_SEED:
        raise ValueError(f"reset: seed {seed!r} must be an integer in [0, 2**63 - 1]")
    return value


def _given_target(options: dict[str, Any]) -> Target | None:
    """`reset`'s `target` option (a `Target` from `make_target`) or None; an unknown option or
    a target of another type is a ValueError."""
    unknown = set(options) - {"target_pose", "start_pose", "target"}
    if unknown:
        raise ValueError(f"reset: unknown options {sorted(unknown)}")
    given = options.get("target")
    if given is not None and not isinstance(given, Target):
        raise ValueError("reset: options['target'] must be a Target (from make_target)")
    return given


def _as_config(config: ExperimentConfig | dict | str | None) -> ExperimentConfig:
    if config is None:
        return ExperimentConfig()
    if isinstance(config, ExperimentConfig):
        return config
    if isinstance(config, dict):
        return validate_config(config, "ShapeServoEnv config")
    return load_config(config)


class ShapeServoEnv(gym.Env):
    """Deform a planar elastic rod, seen through a fixed camera, by moving its gripper.

    Args:
        config: an `ExperimentConfig`, a mapping or the path of a YAML config (None: defaults).
            Only the rod, camera and run sections matter here; the method is not the env's.
        render_mode: None or "rgb_array" (the camera frame).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(
        self,
        config: ExperimentConfig | dict | str | None = None,
        render_mode: str | None = None,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self._configure(_as_config(config))
        self._seeded = False
        self.sim: RodSim | None = None
        self.frame: Frame | None = None
        self.target: Target | None = None
        self.task: Task | None = None
        self.steps = 0
        self.times = StageTimes()
        self._resets = 0  # episodes started: part of the true Jacobian's cache key
        self._true_jacobian_cache: tuple | None = None

    def _configure(self, cfg: ExperimentConfig) -> None:
        self.cfg = cfg
        self.clamp_pose = np.asarray(cfg.rod.clamp_pose, dtype=float)
        self.max_step = np.asarray(cfg.rod.max_step, dtype=float)
        #: Both ends moved (rod.arms: 2): actions and poses are q = 6, the gripper's then the x0
        #: end's.
        self.dual_arm = cfg.rod.arms == 2
        self.q = 6 if self.dual_arm else Q
        n = cfg.camera.points
        size = np.array([cfg.camera.width, cfg.camera.height], dtype=float)
        big = float(np.hypot(*size))
        ws = cfg.rod.workspace
        margin = 1e-6  # poses on a workspace limit, give or take rounding
        lo = np.array([ws.x_limits[0], ws.y_limits[0], ws.theta_limits[0]]) - margin
        hi = np.array([ws.x_limits[1], ws.y_limits[1], ws.theta_limits[1]]) + margin
        if self.dual_arm:
            arm = cfg.rod.clamp_arm
            cws = arm.workspace
            self.max_step = np.concatenate([self.max_step, np.asarray(arm.max_step, float)])
            lo = np.concatenate([lo, [cws.x_limits[0] - margin, cws.y_limits[0] - margin]])
            lo = np.append(lo, cws.theta_limits[0] - margin)
            hi = np.concatenate([hi, [cws.x_limits[1] + margin, cws.y_limits[1] + margin]])
            hi = np.append(hi, cws.theta_limits[1] + margin)
        self.action_space = spaces.Box(-self.max_step, self.max_step, dtype=np.float64)
        # Extracted points lie in the image; the bounds leave room for sub-pixel fits. One
        # bound for both axes, so that the space prints as one line.
        pixels = spaces.Box(-size.max(), 2 * size.max(), (n, 2), dtype=np.float64)
        self.observation_space = spaces.Dict(
            {
                "centerline": pixels,
                "gripper": spaces.Box(lo, hi, dtype=np.float64),
                # A free move is within max_step per axis; a move clipped at the reach limit
                # is pulled towards the clamp and can exceed one axis's limit (by ~1 % in
                # random walks), more after a clamp move or a grasp slip. What always holds:
                # both poses are in the workspace.
                "applied": spaces.Box(lo - hi, hi - lo, dtype=np.float64),
                "extraction_ok": spaces.Discrete(2),
                "target": pixels,
            }
        )
        self._lost_frame_cost = big

    @property
    def config(self) -> ExperimentConfig:
        """The experiment config this environment runs (replaced by `reset(options=config)`)."""
        return self.cfg

    def stage_times(self) -> StageTimes:
        """Wall time spent in the simulator (`sim`) and in rendering and extraction (`vision`)
        since the last `reset`, target making included; a copy."""
        return replace(self.times)

    # --- Gymnasium API -------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode: a fresh rod at home, camera-noise stream and target.

        Args:
            seed: the episode seed. None: the config's `seed` on the first reset, then a seed
                drawn from the environment's own generator (Gymnasium's convention).
            options: optional `config` (replaces the config: `ExperimentConfig`, mapping or
                path), `target_pose` ([x, y, theta], else `run.target` decides), `target` (a
                `Target` from `make_target`, reused without driving the rod there again) and
                `start_pose` (the gripper pose the episode starts from, else the home pose).

        Raises:
            UserError: a target or start pose that is out of reach or unusable.
            ValueError: an unknown option, a pose that is not 3 (dual-arm: or 6) finite
                numbers, or a seed outside [0, 2**63 - 1].
        """
        options = dict(options or {})
        if "config" in options:
            self._configure(_as_config(options.pop("config")))
        # Every option checked before anything changes: a refused reset leaves the env as it was.
        given = _given_target(options)
        pose = options.get("target_pose")
        pose = None if pose is None else self._pose_option("target_pose", pose)
        rod = self._start_rod(options.get("start_pose"))
        if seed is None:
            seed = self.cfg.seed if not self._seeded else int(self.np_random.integers(2**31))
        else:
            seed = _episode_seed(seed)
        super().reset(seed=seed)
        self._seeded = True
        self.episode_seed = seed
        self._rod_cfg = rod
        self.times = StageTimes()
        self._new_camera(seed)
        # A target made earlier (`make_target`) is reused as is: the clean camera that sees it
        # has no noise stream, so it is the same target this episode would make.
        self.target = given or self._make_target(pose, seed)
        self.sim = _home_sim(rod)
        self.home_pose = self.sim.home_end_poses
        self.steps = 0
        self._resets += 1
        self.frame = self._look()
        if not self.frame.ok:
            raise UserError(
                f"initial frame: the rod's centerline could not be extracted ({self.frame.note})"
            )
        self.task = self._task(rod, self.target)
        return self._observation(np.zeros(self.q)), {
            **self._info(None),
            "target": self.target,
        }

    def _start_rod(self, start_pose: Any) -> RodConfig:
        """The episode's rod config: the config's, or with `start_pose` as the home pose (and,
        dual-arm with 6 values, the x0 end's clamp pose), validated as the config's own start
        poses are: each end in its arm's workspace, the gripper within reach of the x0 end (a bad
        one is a UserError naming it)."""
        rod = self.cfg.rod
        if start_pose is None:
            return rod
        start = self._pose_option("start_pose", start_pose)
        update: dict[str, Any] = {"home_pose": start[:3]}
        if self.dual_arm and len(start) == 6:  # both ends' start poses
            update["clamp_pose"] = start[3:]
        return validate_config(
            {**rod.model_dump(), **update}, f"reset: start_pose {list(start)}", model=type(rod)
        )

    def _pose_option(self, name: str, value: Any) -> tuple[float, ...]:
        """`reset`'s `start_pose` or `target_pose` as floats: 3 values (the gripper's) or,
        dual-arm, 6 (both ends'), all finite; anything else is a ValueError naming it."""
        takes = "3 values (the gripper's [x, y, theta])"
        takes += " or 6 (both ends')" if self.dual_arm else ""
        try:
            pose = tuple(float(v) for v in np.asarray(value, dtype=float).reshape(-1))
            shape = np.shape(value)
        except (TypeError, ValueError):
            raise ValueError(
                f"reset: {name} {value!r} is not a list of numbers; it takes {takes}"
            ) from None
        if len(shape) != 1 or len(pose) not in (3, self.q):
            raise ValueError(f"reset: {name} {value!r} has shape {shape}; it takes {takes}")
        if not all(np.isfinite(pose)):
            raise ValueError(f"reset: {name} {list(pose)} is not finite")
        return pose

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """Move the gripper by `action` = [dx, dy, dtheta] (dual-arm: then the x0 end's), let
        the rod settle, look at it.

        The robot saturates each axis at `rod.max_step` and the workspace clips or refuses
        poses out of reach; `info["saturated"]`, `info["clipped"]` say so, and the
        observation's `applied` is the move really made.
        """
        if self.sim is None:
            raise RuntimeError("call reset() before step()")
        u = np.asarray(action, dtype=float)
        if u.shape != (self.q,):  # numpy's own message was a reshape error, or none for (3, 1)
            axes = "[dx, dy, dtheta]" if self.q == Q else "[dx, dy, dtheta] of each end"
            raise ValueError(f"step: the action must have shape ({self.q},), {axes}; got {u.shape}")
        if not np.isfinite(u).all():  # refused before anything changes, like the sim does
            raise ValueError(f"step: the action {u.tolist()} is not finite (a NaN or inf)")
        events = self._apply_events(self.steps + 1)
        t = time.perf_counter()
        res = self.sim.apply(u)
        self.times.sim += time.perf_counter() - t
        self.steps += 1
        self.frame = self._look()
        info = self._info(res)
        take = getattr(self.sim, "take_snap_notes", None)
        if take is not None:  # the quasi-static engine reports its snap-throughs
            notes = take()
            info["snap"] = bool(notes)
            events = [*events, *notes]
        info["events"] = events
        err = info["pixel_error"]
        # A frame where the rod was not wholly seen (bridged, lost: `extraction_ok` 0) costs the
        # image diagonal whatever its bridged points' error, as the goal form's compute_reward
        reward = -err if self.frame.ok and math.isfinite(err) else -self._lost_frame_cost
        diverged = bool(res.diverged)
        converged = self.frame.ok and err < self.cfg.run.pixel_tolerance
        terminated = diverged or bool(converged)
        truncated = not terminated and self.steps >= self.cfg.run.max_steps
        return self._observation(res.u_applied), float(reward), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """The last camera frame, (H, W, 3) uint8 RGB (render_mode "rgb_array")."""
        if self.render_mode != "rgb_array" or self.frame is None:
            return None
        return self.frame.image

    def _episode(self) -> tuple[RodSim, Frame, Target]:
        """The current episode's simulator, last frame and target (`reset` sets them)."""
        if self.sim is None or self.frame is None or self.target is None:
            raise RuntimeError("call reset() first")
        return self.sim, self.frame, self.target

    def true_jacobian(
        self, encode: Any, steps: tuple[float, float, float] = (1e-3, 1e-3, 5e-3)
    ) -> np.ndarray:
        """The Jacobian d s / d r of a feature at the rod's current shape, by central finite
        differences of the simulator: each axis moved by ± its step, the rod settled, its
        ground truth projected by the camera (no rendering noise), encoded, and the simulator
        put back (`RodSim.snapshot` / `restore`). Six settles a call.

        This is what no method on a real robot can know: the `oracle` reference uses it to
        show what the paper's law does when told the true Jacobian (a reference, not a ceiling).

        Args:
            encode: the feature map, (N, 2) pixels -> (p,).
            steps: the finite-difference step per axis [m, m, rad].

        Returns:
            (p, 3) Jacobian in feature units per [m, m, rad].
        """
        # One evaluation per state and feature map: the oracle's J and the step's Jacobian
        # error (`jacobian_error_reference`) share it, and pymunk pays its settles once.
        key = (*self._state_key(), tuple(steps))
        cached = self._true_jacobian_cache
        if cached is not None and cached[0] == key and cached[1] == encode:
            return cached[2].copy()
        J = self._true_jacobian(encode, steps)
        self._true_jacobian_cache = (key, encode, J.copy())
        return J

    def jacobian_error_reference(self, encode: Any) -> np.ndarray | None:
        """The true Jacobian a step's estimate is scored against (`run.jacobian_error`), or
        None where the run does not compute it.

        "auto": only where it costs no settle: the quasi-static engine at a converged
        equilibrium with one arm (analytic; a dual-arm J is central differences), or a
        `true_jacobian` already evaluated at this state for this feature (the oracle's).
        "always": pymunk's six-settle finite differences otherwise too; their restore keeps no
        solver warm start, so they perturb the rest of the run within the settle tolerance, as
        the oracle's do. "never": None.
        """
        mode = self.cfg.run.jacobian_error
        if mode == "never" or self.sim is None:
            return None
        if mode == "auto":
            cheap = (  # analytic: the quasi-static engine at an equilibrium, one arm
                not self.dual_arm and _is_analytic(self.sim) and _at_equilibrium(self.sim)
            )
            if not cheap:  # only the J an oracle already evaluated at this very state
                cached = self._true_jacobian_cache
                if not (cached and cached[1] == encode and cached[0][:-1] == self._state_key()):
                    return None
        return self.true_jacobian(encode)

    def _state_key(self) -> tuple:
        """What identifies the state a true Jacobian was evaluated at: the episode, the step,
        the rod and its exact shape and gripper pose (a snapshot restored and moved again, as
        the diagnosis does, reaches other states at the same step counts)."""
        sim = self._episode()[0]
        shape = sim.centerline().tobytes() + sim.gripper_pose.tobytes()
        return (self._resets, self.steps, id(sim), sim.chain.steps, shape)

    def _true_jacobian(self, encode: Any, steps: tuple[float, ...]) -> np.ndarray:
        n = self.cfg.camera.points
        sim = self._episode()[0]
        if self.dual_arm:  # the x0 end's columns by the same central differences
            steps = (*steps, *steps)
        elif _is_analytic(sim) and _at_equilibrium(sim):
            # Exact only at an equilibrium; after a solve that did not converge, differences.
            return self._analytic_jacobian(encode, steps)
        snap = sim.snapshot()
        cols = []
        for axis, h in enumerate(steps):
            values = []
            for sign in (1.0, -1.0):
                du = np.zeros(self.q)
                du[axis] = sign * h
                sim.apply(du)
                pixels = self.camera.project(resample_polyline(sim.centerline(), n))
                values.append(np.asarray(encode(pixels), dtype=float))
                sim.restore(snap)
            cols.append((values[0] - values[1]) / (2.0 * h))
        return np.stack(cols, axis=1)

    def _analytic_jacobian(self, encode: Any, steps: tuple[float, ...]) -> np.ndarray:
        """`true_jacobian` on the quasi-static engine: d(centerline)/dr exactly, by the
        implicit-function theorem on the equilibrium's KKT system (`rodctl/sim/quasistatic.py`),
        through the arc-length resampling (a fixed linear map for an inextensible chain) and the
        camera's projection Jacobian; the feature map by central differences along each
        column's pixel direction (pixels ± h dpix/dr, h the axis' step): no settles."""
        from rodctl.sim.quasistatic import resample_matrix

        n = self.cfg.camera.points
        sim = self._episode()[0]
        w = resample_matrix(sim.chain.segments, n)  # cached: do not modify
        # `_true_jacobian` calls it on such an engine only (`_is_analytic`): a cast, not the
        # runtime-protocol isinstance (~10 us a step)
        joints, djoints = sim.centerline(), cast(_AnalyticSim, sim).centerline_jacobian()
        two = _two_point_rows(w)
        if two is not None and np.isfinite(joints).all() and np.isfinite(djoints).all():
            points, dpoints = _interpolate(two, joints), _interpolate(two, djoints)
        else:  # no BLAS either way: kernel-independent
            points = np.einsum("ij,jk->ik", w, joints)
            dpoints = np.einsum("ij,jkq->ikq", w, djoints)
        dpix = _chain_2x2(self.camera.projection_jacobian(points), dpoints)
        pixels = self.camera.project(points)
        h = np.asarray(steps, dtype=float)
        move = (dpix * h).transpose(2, 0, 1)  # (q, N, 2): h_a dpix[:, :, a] (a view)
        shifted = np.empty((2 * len(steps), *pixels.shape))  # pixels + and - each move
        np.add(pixels, move, out=shifted[0::2])
        np.subtract(pixels, move, out=shifted[1::2])
        rows = _rows_of(encode)
        if rows is not None:  # all the shapes in one pass, the same bits as one by one
            values = np.asarray(rows(shifted), dtype=float)
        else:
            values = np.stack([np.asarray(encode(x), dtype=float) for x in shifted])
        return np.ascontiguousarray(((values[0::2] - values[1::2]) / (2.0 * h)[:, None]).T)

    def make_target(
        self,
        pose: Any = None,
        *,
        seed: int | None = None,
        band: tuple[float, float] | None = None,
        generator: np.random.Generator | None = None,
    ) -> Target:
        """Check that a gripper pose gives a usable target, without starting an episode.

        Drives a fresh rod to `pose` (None: sample one as `run.target` says), lets it settle and
        extracts what the camera sees, with the camera of episode `seed` (default: the config's).
        `band` (low, high) and `generator`: sample in that normalised offset band, from that
        generator, instead of `run.target`'s band and the seed's 'targets' stream (a study's
        target set, `rodctl.bench.target_set`).

        Raises:
            UserError: the pose is out of reach, the rod does not settle there, or the camera
                cannot extract it.
        """
        seed = self.cfg.seed if seed is None else int(seed)
        self._rod_cfg = self.cfg.rod
        self._new_camera(seed)
        return self._make_target(pose, seed, band, generator)

    # --- internals -----------------------------------------------------------------------------

    def _task(self, rod: Any, target: Target) -> Task:
        """What the method is told of the episode that `reset` has just set up on `rod`."""
        return Task(
            target_pixels=target.pixels,
            home_pose=self.home_pose,
            clamp_pose=np.asarray(rod.clamp_pose, dtype=float),  # dual-arm: start_pose may move it
            max_step=self.max_step,
            probe_size=np.tile(np.asarray(self.cfg.run.probe_size, dtype=float), self.q // Q),
            camera=self.camera,
            points=self.cfg.camera.points,
            true_jacobian=self.true_jacobian,
        )

    def _new_camera(self, seed: int) -> None:
        """A camera with a fresh noise stream for episode `seed`, and its extractor; and the
        clean camera the target is seen with."""
        cfg = self.cfg
        self.camera = Camera(cfg.camera, rng(seed, "camera"))
        self.extractor = CenterlineExtractor(
            cfg.camera, self.camera, self.clamp_pose, rod_length=cfg.rod.length
        )
        self._clean_camera(cfg.camera)

    def _clean_camera(self, camera_cfg: Any) -> None:
        """The camera the target is seen with: the target is what the rod looks like in the
        target pose, not one noisy frame of it (one noise artefact in the target frame would
        bias every method's goal, or make the target unusable). Same camera pose and scene, no
        pixel noise, blur or occluders."""
        render = camera_cfg.render.model_copy(
            update={"noise_std": 0.0, "blur_sigma": 0.0, "occlusions": [], "random_occlusions": 0}
        )
        clean = camera_cfg.model_copy(update={"render": render})
        self._target_camera = Camera(clean)
        self._target_extractor = CenterlineExtractor(
            clean, self._target_camera, self.clamp_pose, rod_length=self.cfg.rod.length
        )

    def _apply_events(self, step: int) -> list[str]:
        """Apply the mid-run events due before step `step`'s move; one log line each.

        What an event changes that the environment derives (rodctl/events.py): the extractor
        calibrates the clamp pixel and the rod length, so it is rebuilt after a clamp move, a
        grasp slip or a camera bump; after a bump the target — the same physical shape — is
        seen again through the moved camera, so its pixels change (the observation's `target`).
        """
        if not self.cfg.run.events:
            return []
        from rodctl.events import due

        sim = self._episode()[0]
        lines = []
        for event in due(list(self.cfg.run.events), step):
            lines.append(event.apply(sim, self.camera))
            if "extractor" in event.refresh:
                self.extractor = CenterlineExtractor(
                    self.camera.cfg,
                    self.camera,
                    sim.clamp_pose,
                    rod_length=sim.held_length,
                )
            if "target_pixels" in event.refresh:
                self._clean_camera(self.camera.cfg)
                t = self._episode()[2]
                clamp = t.pose[3:] if self.dual_arm else self.clamp_pose
                frame = self._see(t.centerline, t.pose[:3], clamp, clean=True)
                if frame.ok:
                    self.target = Target(t.pose, t.centerline, frame.extracted, t.difficulty)
                else:
                    lines.append(f"the target cannot be seen by the moved camera ({frame.note})")
        return lines

    def _look(self, sim: RodSim | None = None, *, clean: bool = False) -> Frame:
        """Render the rod as the camera sees it (`clean`: without nuisances) and extract it."""
        sim = sim or self.sim
        if sim is None:
            raise RuntimeError("call reset() first")
        return self._see(sim.centerline(), sim.gripper_pose, sim.clamp_pose, clean=clean)

    def _see(
        self, truth: np.ndarray, gripper: np.ndarray, clamp: np.ndarray, *, clean: bool
    ) -> Frame:
        """Render a rod centerline with the gripper and clamp, and extract it."""
        camera = self._target_camera if clean else self.camera
        extractor = self._target_extractor if clean else self.extractor
        t = time.perf_counter()
        if self.dual_arm:  # the extractor starts at the x0 end's pixel: where that end is now
            extractor = CenterlineExtractor(
                camera.cfg, camera, clamp, rod_length=extractor.rod_length
            )
        image = camera.render(truth, gripper, clamp)
        ext = extractor.extract(image, gripper)
        projected = camera.project(resample_polyline(truth, self.cfg.camera.points))
        self.times.vision += time.perf_counter() - t
        return Frame(truth, projected, image, ext.points, ext.ok, ext.note)

    def _observation(self, applied: np.ndarray) -> dict[str, Any]:
        sim, f, target = self._episode()
        pts = f.extracted if f.ok else np.zeros_like(f.extracted)
        return {
            "centerline": np.array(pts, dtype=np.float64),
            "gripper": np.asarray(sim.end_poses, dtype=np.float64),
            "applied": np.array(applied, dtype=np.float64),
            "extraction_ok": int(f.ok),
            "target": np.array(target.pixels, dtype=np.float64),
        }

    def _info(self, res: Any) -> dict[str, Any]:
        """What the simulator knows and a real robot would not, plus the settle result."""
        sim, f, target = self._episode()
        health = sim.health()
        return {
            "step": self.steps,
            "sim_time": float(sim.sim_time),
            "pixel_error": pixel_error(f.extracted, target.pixels),
            "extracted": f.extracted,
            "extraction_note": f.note,
            "ground_truth": f.centerline,
            "projected_truth": f.projected_truth,
            "settled": True if res is None else bool(res.settled),
            "saturated": (
                np.zeros(self.q, bool) if res is None else np.asarray(res.saturated, bool)
            ),
            "clipped": False if res is None else bool(res.clipped or res.refused),
            "diverged": False if res is None else bool(res.diverged),
            "max_joint_gap": float(health.max_joint_gap),
            "kinetic_energy": float(health.kinetic_energy),
            "gripper": np.array(sim.gripper_pose, dtype=float),
            "extraction_ok": bool(f.ok),
            "image": f.image,
            # dual-arm: the x0 end's pose (the second gripper); absent with one arm
            **({"clamp": np.array(sim.clamp_pose, dtype=float)} if self.dual_arm else {}),
        }

    def _make_target(
        self,
        pose: Any,
        seed: int,
        band: tuple[float, float] | None = None,
        generator: np.random.Generator | None = None,
    ) -> Target:
        """Drive a fresh rod to the target gripper pose (given or sampled: `make_target`) and
        look at it."""
        cfg = self.cfg
        given = pose if pose is not None else cfg.run.target.pose
        sim = _home_sim(self._rod_cfg)
        home = sim.home_end_poses
        tcfg = cfg.run.target
        if given is not None:
            pose, clipped = sim.clip_pose(np.asarray(given, dtype=float))
            if clipped:
                raise UserError(
                    f"run.target.pose {list(given)} is outside the workspace or out of reach "
                    f"(nearest allowed pose: {pose_text(pose)})"
                )
            candidates: Any = [pose]
        else:
            lo, hi = band if band is not None else (tcfg.min_offset, tcfg.max_offset)
            candidates = target_candidates(
                rng(seed, "targets") if generator is None else generator,
                home,
                cfg.rod.length,
                lambda p: not sim.clip_pose(p)[1],
                lo,
                hi,
            )
        for pose in candidates:
            res = sim.move_to(pose)
            frame = self._look(sim, clean=True)
            if res.diverged or not res.settled or not frame.ok:
                why = frame.note or ("diverged" if res.diverged else "did not settle")
                if given is not None:
                    raise UserError(f"run.target.pose {list(given)}: unusable target ({why})")
                sim = _home_sim(self._rod_cfg)
                continue
            return Target(
                pose=sim.end_poses,
                centerline=frame.centerline,
                pixels=frame.extracted,
                difficulty=difficulty(sim.end_poses, home, cfg.rod.length),
            )
        raise UserError(
            f"run.target: {TARGET_TRIES} sampled targets in a row were unusable; check the config"
        )
