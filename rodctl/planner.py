"""A planner reference: the fewest speed-limited steps to a gripper pose whose shape is within
the pixel tolerance of a target, found by a search with the true model.

Why: `pose_steps` (the steps to the *target pose* at the speed limit) is beaten by methods that
meet the tolerance short of the target pose, and the oracle (the paper's law told the true
Jacobian) is not a ceiling either (docs/statistics.md). This module searches, with the simulator
the episodes run on, for the pose r that minimises the Chebyshev step count
k(r) = max_i ceil(|r_i − r_home,i| / max_step_i) among the poses whose settled shape is within
`run.pixel_tolerance` of the target, and checks that the straight path at the speed limit gets
there.

What it is, and what it is not: the fewest steps over the poses *this search finds*. The search
is local (a bounded least-squares fit from a few starts per step budget), so it is **not a proven
lower bound**: a pose it misses could need fewer steps, and a method may beat it. A bound would
need the global minimum of the pixel error over each box of poses, which the fold
(snap-through) points of the rod's shape map make non-Lipschitz; none is claimed.

The search, for a target (its pixels as the clean camera saw them), from the home pose h with the
per-axis speed limit m:

1. For a step budget k, the box B_k = {r : |r_i − h_i| <= k m_i} ∩ the workspace box. The
   smallest mean pixel error over B_k is sought by `scipy.optimize.least_squares` (trust-region
   reflective, with the bounds) on the residuals ρ_j = (‖x_j(r) − t_j‖² + ε²)^¼ of the 100
   centerline points, whose squares sum to 100 × the (smoothed) mean pixel error: the episode's
   success measure itself, not its root-mean-square. x_j(r) is the settled centerline through the
   camera model (no rendering), on the **quasi-static engine of the same rod** (docs/engines.md:
   the same chain, gravity included through ρA g), its Jacobian the engine's analytic
   d(centerline)/dr (implicit-function theorem) through the arc-length resampling and the
   camera's projection Jacobian; one continuation solve per evaluation, from the last state.
   Starts: the previous budget's best pose clipped into B_k, the target pose clipped into B_k,
   and the nominal path's pose after k steps, h + (k / k0)(r* − h).
2. k starts at k0 = `pose_steps` (B_k0 holds the target pose) and descends, jumping to one below
   the step count of the best pose found, until no start gets below the tolerance. If even B_k0
   does not (the target's pose does not make its pixels), the whole workspace is searched from the
   target pose, home, and the end pose of `rodctl.diagnosis.pose_search` run from home (the
   diagnosis's own Gauss-Newton): none within tolerance is **no plan** (`Plan.steps` None), as
   the diagnosis would call the target `unreachable` from the start.
3. Verification, on the config's own engine (pymunk or quasi-static) through the real render and
   centerline extraction of the clean camera (the camera the target was seen with: no pixel
   noise, blur or occluders): the episode's environment is reset and driven along the straight
   path r_home → r in k equal moves (each within the speed limit, so none saturates); the plan's
   step count is the first step whose extracted centerline is within the tolerance of the target's.
   Candidates are verified from the fewest steps up; the target pose itself is the last one, so
   a plan never needs more than `pose_steps` when the straight path to the target pose converges.
   Snap-throughs on the way (quasi-static engine) are counted.

Not handled (refused, `PlannerError`): mid-run events (the rod changes under the path; a plan on
the rod before the event says nothing about the episode), dual-arm runs (q = 6: no analytic
Jacobian) and table friction (the quasi-static engine refuses it; the shape depends on the path).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from rodctl.config import ExperimentConfig
from rodctl.diagnosis import pose_search, workspace_box
from rodctl.env import ShapeServoEnv, Target, pixel_error
from rodctl.errors import UserError
from rodctl.metrics import pose_steps
from rodctl.sim import RodSim
from rodctl.sim.quasistatic import QuasiStaticSim, resample_matrix

#: Smoothing of each point's distance in the objective (px): ρ_j² = sqrt(d_j² + ε²) ≈ d_j.
EPSILON_PX = 0.01

#: Residual evaluations allowed to one start's least-squares fit.
MAX_EVALUATIONS = 25

#: Iterations of diagnosis's pose search when the target pose's box does not reach the tolerance.
SEARCH_ITERATIONS = 20


class PlannerError(UserError):
    """A config the planner cannot plan for (events, dual-arm, table friction)."""


@dataclass
class Plan:
    """The planner's answer for one target.

    Attributes:
        steps: planner_steps, the fewest speed-limited steps found (verified); None: no pose
            within the tolerance was found (the target is unreachable from the start, as far as
            the search goes), or none whose straight path verified (`rejected` lists them).
        pose: (3,) the gripper pose the verified straight path was aimed at (None: no plan).
        move: (3,) the path's increment per step, (pose − home) / k for the k moves that reach
            `pose` at the speed limit (None: no plan); `steps` of them meet the tolerance.
        pixel_error: the extracted pixel error after `steps` moves of the verified path (px).
        pose_steps: steps to the target pose at the speed limit (`rodctl.metrics.pose_steps`).
        best_error: the smallest projected pixel error the search found (px), at any budget.
        snaps: snap-throughs on the verified path (quasi-static engine only; pymunk: 0).
        levels: (budget k, smallest projected pixel error found in B_k) per budget searched;
            k = -1: the whole workspace (searched when B_pose_steps did not reach the tolerance).
        evaluations: settled shapes the search evaluated.
        rejected: candidate poses whose straight path did not verify (budget k, extracted error).
        cpu_s: CPU time of the whole plan (search and verification).
    """

    steps: int | None
    pose: np.ndarray | None
    pixel_error: float
    pose_steps: int
    best_error: float
    snaps: int = 0
    move: np.ndarray | None = None
    levels: list[tuple[int, float]] = field(default_factory=list)
    evaluations: int = 0
    rejected: list[tuple[int, float]] = field(default_factory=list)
    cpu_s: float = 0.0


def check_plannable(cfg: ExperimentConfig) -> None:
    """Raise `PlannerError` (naming the field) for a config the planner does not handle."""
    if cfg.run.events:
        raise PlannerError(
            "planner: run.events is set; the planner plans on an event-free rod (a mid-run event "
            "changes the rod or camera under the path)"
        )
    if cfg.rod.arms != 1:
        raise PlannerError("planner: rod.arms is 2; the planner plans one gripper (q = 3)")
    if cfg.rod.table_friction:
        raise PlannerError(
            "planner: rod.table_friction is set; the quasi-static search model has no friction"
        )


def clean_config(cfg: ExperimentConfig) -> ExperimentConfig:
    """The config with the camera the target is seen with: no pixel noise, blur or occluders
    (as `ShapeServoEnv`'s target camera), and no logging."""
    render = cfg.camera.render.model_copy(
        update={"noise_std": 0.0, "blur_sigma": 0.0, "occlusions": [], "random_occlusions": 0}
    )
    camera = cfg.camera.model_copy(update={"render": render})
    return cfg.model_copy(update={"camera": camera})


def make_target(cfg: ExperimentConfig, pose: Any) -> Target:
    """The target a compare run made at gripper `pose` (its rod driven there, seen by the clean
    camera): the same pixels, since the target camera has no noise stream."""
    return ShapeServoEnv(cfg).make_target(np.asarray(pose, dtype=float))


class _Model:
    """The search model: the quasi-static engine of the same rod and the camera model, with the
    target's pixels; residuals and their Jacobian at a gripper pose."""

    def __init__(self, cfg: ExperimentConfig, camera: Any, target_pixels: np.ndarray) -> None:
        rod = cfg.rod.model_copy(update={"engine": "quasistatic"})
        self.sim = RodSim.at_home(rod)
        self.home_snap = self.sim.snapshot()
        self.camera = camera
        self.target = np.asarray(target_pixels, dtype=float)
        self.points = self.target.shape[0]
        self.w = resample_matrix(rod.segments, self.points)
        self.evaluations = 0
        self._at: np.ndarray | None = None
        self._jac: np.ndarray | None = None

    def go(self, pose: np.ndarray) -> np.ndarray:
        """Move the model's gripper to `pose` (continuation from the last state, in speed-limited
        increments, clipped by the workspace and reach) and return the pose reached."""
        pose = np.asarray(pose, dtype=float)
        if self._at is None or np.any(pose != self._at):
            res = self.sim.move_to(pose)
            if res.diverged:  # start again from home: a diverged chain stays diverged
                self.sim.restore(self.home_snap)
                self.sim.move_to(pose)
            self._at = pose.copy()
            self._jac = None
            self.evaluations += 1
        return self.sim.gripper_pose

    def pixels(self) -> np.ndarray:
        return self.camera.project(np.einsum("ij,jk->ik", self.w, self.sim.centerline()))

    def error(self, pose: np.ndarray) -> float:
        """Mean pixel error of the settled shape at `pose` (projected truth, no rendering)."""
        self.go(pose)
        if self.sim.diverged:
            return math.inf
        return pixel_error(self.pixels(), self.target)

    def residuals(self, pose: np.ndarray) -> np.ndarray:
        self.go(pose)
        d = self.pixels() - self.target
        if self.sim.diverged or not np.all(np.isfinite(d)):
            return np.full(self.points, 1e3)
        return (np.einsum("ij,ij->i", d, d) + EPSILON_PX**2) ** 0.25

    def jacobian(self, pose: np.ndarray) -> np.ndarray:
        """(points, 3) d ρ / d r: the engine's analytic d(centerline)/dr at an equilibrium, else
        central differences of the engine."""
        self.go(pose)
        if self._jac is not None:
            return self._jac
        joints = self.sim.centerline()
        points = np.einsum("ij,jk->ik", self.w, joints)
        d = self.camera.project(points) - self.target
        sim = self.sim
        if (
            isinstance(sim, QuasiStaticSim)
            and bool(getattr(sim.chain, "converged", False))
            and not sim.diverged
        ):
            dpoints = np.einsum("ij,jkq->ikq", self.w, sim.centerline_jacobian())
            dpix = np.einsum("ikl,ilq->ikq", self.camera.projection_jacobian(points), dpoints)
        else:
            snap = self.sim.snapshot()
            cols = []
            for axis, h in enumerate((1e-3, 1e-3, 5e-3)):
                vals = []
                for sign in (1.0, -1.0):
                    du = np.zeros(3)
                    du[axis] = sign * h
                    self.sim.apply(du)
                    vals.append(self.pixels())
                    self.sim.restore(snap)
                cols.append((vals[0] - vals[1]) / (2 * h))
            dpix = np.stack(cols, axis=2)
        if not np.all(np.isfinite(dpix)) or not np.all(np.isfinite(d)):
            self._jac = np.zeros((self.points, 3))
            return self._jac
        s = np.einsum("ij,ij->i", d, d) + EPSILON_PX**2
        # d (s^(1/4)) = (1/4) s^(-3/4) ds, ds = 2 d·dpix
        self._jac = 0.5 * s[:, None] ** -0.75 * np.einsum("ik,ikq->iq", d, dpix)
        return self._jac


def _fit(model: _Model, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, float]:
    """(pose reached, its mean pixel error): the bounded least-squares fit from `x0`."""
    x0 = np.clip(x0, lo, hi)
    span = np.maximum(hi - lo, 1e-12)
    fixed = span <= 1e-12
    if np.all(fixed):
        pose = model.go(x0)
        return pose, model.error(pose)
    try:
        sol = least_squares(
            model.residuals,
            x0,
            jac=model.jacobian,
            bounds=(lo - 1e-15 * fixed, hi + 1e-15 * fixed),
            method="trf",
            x_scale=span,
            max_nfev=MAX_EVALUATIONS,
            ftol=1e-6,
            xtol=1e-6,
            gtol=1e-10,
        )
        x = sol.x
    except ValueError:  # a start on a bound that scipy deems infeasible after rounding
        x = x0
    pose = model.go(x)
    return pose, model.error(x)


def plan(
    cfg: ExperimentConfig,
    target: Target,
    *,
    seed: int | None = None,
) -> Plan:
    """The planner reference for one target of an event-free, one-arm config.

    Args:
        cfg: the episode's experiment config (rod, camera, run.pixel_tolerance).
        target: the target (its pose and the pixels the clean camera saw).
        seed: the verification episode's seed (the clean camera has no noise, so it only names
            the episode).

    Returns:
        The `Plan` (steps None: no pose within tolerance was found).

    Raises:
        PlannerError: events, dual-arm or table friction.
    """
    t_cpu = time.process_time()
    check_plannable(cfg)
    clean = clean_config(cfg)
    tol = float(cfg.run.pixel_tolerance)
    env = ShapeServoEnv(clean)
    env.reset(seed=cfg.seed if seed is None else seed, options={"target": target})
    assert env.task is not None
    home = np.asarray(env.task.home_pose, dtype=float)
    m = np.asarray(env.task.max_step, dtype=float)
    t_pose = np.asarray(target.pose, dtype=float)[:3]
    k0 = pose_steps(home, t_pose, m)
    ws_lo, ws_hi = workspace_box(cfg, 3)
    model = _Model(cfg, env.camera, target.pixels)

    def box(k: float) -> tuple[np.ndarray, np.ndarray]:
        lo = np.maximum(ws_lo, home - k * m * (1 - 1e-9))
        hi = np.minimum(ws_hi, home + k * m * (1 - 1e-9))
        return lo, np.maximum(lo, hi)

    levels, found, best_err = _descend(model, box, home, t_pose, m, k0, tol)
    if not found:
        best_err = _search_workspace(env, model, box, home, t_pose, m, tol, found, best_err)
        levels.append((-1, best_err))
    result = Plan(None, None, math.nan, k0, best_err, levels=levels)
    candidates = sorted(found.items())
    if k0 >= 1 and not any(np.allclose(p, t_pose, atol=1e-12) for _, p in candidates):
        candidates.append((k0, t_pose))  # the straight path to the target pose itself
    for kk, pose in candidates:
        steps, err, snaps = _verify(env, target, home, pose, kk, tol, seed)
        if steps is not None:
            result.steps, result.pose, result.pixel_error, result.snaps = steps, pose, err, snaps
            result.move = (np.asarray(pose, dtype=float) - home) / max(kk, 1)
            break
        result.rejected.append((kk, err))
    result.evaluations = model.evaluations
    result.cpu_s = time.process_time() - t_cpu
    return result


_Box = Callable[[float], tuple[np.ndarray, np.ndarray]]


def _descend(
    model: _Model,
    box: _Box,
    home: np.ndarray,
    t_pose: np.ndarray,
    m: np.ndarray,
    k0: int,
    tol: float,
) -> tuple[list[tuple[int, float]], dict[int, np.ndarray], float]:
    """Budgets from `pose_steps` down: at each, the best fit within k speed-limited steps of
    home, from the previous best, the target pose and the point k steps along the straight path;
    stops at the first budget nothing meets the tolerance in. Returns (the best error per budget,
    {steps: pose} of the poses within tolerance (projected), the best error seen)."""
    levels: list[tuple[int, float]] = []
    found: dict[int, np.ndarray] = {}  # budget -> best pose (projected error < tol)
    best_pose, best_err = t_pose.copy(), model.error(t_pose)
    k = max(k0, 1)
    while k >= 1:
        lo, hi = box(k)
        starts = [best_pose, t_pose, home + (k / max(k0, 1)) * (t_pose - home)]
        level_pose, level_err = None, math.inf
        seen: list[np.ndarray] = []
        for x0 in starts:
            x0 = np.clip(x0, lo, hi)
            if any(np.allclose(x0, s, rtol=0, atol=1e-9) for s in seen):
                continue
            seen.append(x0)
            pose, err = _fit(model, x0, lo, hi)
            if err < level_err:
                level_pose, level_err = pose, err
        levels.append((k, level_err))
        if level_pose is None or level_err >= tol:
            break
        best_pose, best_err = level_pose, min(best_err, level_err)
        kk = pose_steps(home, level_pose, m)
        found[kk] = level_pose
        k = min(k, kk) - 1
    return levels, found, best_err


def _search_workspace(
    env: ShapeServoEnv,
    model: _Model,
    box: _Box,
    home: np.ndarray,
    t_pose: np.ndarray,
    m: np.ndarray,
    tol: float,
    found: dict[int, np.ndarray],
    best_err: float,
) -> float:
    """The target pose's box does not reach the tolerance: fits over the whole workspace, from
    the target pose, home and the end of the diagnosis's own search from the start (what would
    call the target `unreachable`); poses within tolerance go into `found`. The best error."""
    starts = [t_pose, home]
    sim = env.sim
    snap = sim.snapshot() if sim is not None else None
    searched, _, _ = pose_search(env, SEARCH_ITERATIONS)
    if sim is not None and snap is not None:
        starts.append(np.asarray(sim.gripper_pose, dtype=float))
        best_err = min(best_err, searched)
        sim.restore(snap)
    lo, hi = box(math.inf)
    for x0 in starts:
        pose, err = _fit(model, x0, lo, hi)
        best_err = min(best_err, err)
        if err < tol:
            found[pose_steps(home, pose, m)] = pose
    return best_err


def _verify(
    env: ShapeServoEnv,
    target: Target,
    home: np.ndarray,
    pose: np.ndarray,
    k: int,
    tol: float,
    seed: int | None,
) -> tuple[int | None, float, int]:
    """(first step within tolerance or None, the extracted error there or at the end, snaps):
    the episode's env driven from home along the straight path to `pose` in `k` equal moves,
    each seen through the real render and centerline extraction."""
    env.reset(seed=seed if seed is not None else env.cfg.seed, options={"target": target})
    u = (np.asarray(pose, dtype=float) - home) / max(k, 1)
    snaps, err = 0, math.inf
    for step in range(1, max(k, 1) + 1):
        _, _, _, _, info = env.step(u)
        snaps += int(bool(info.get("snap", False)))
        if info["diverged"]:
            return None, math.inf, snaps
        err = float(info["pixel_error"]) if info["extraction_ok"] else math.inf
        if err < tol:
            return step, err, snaps
    return None, err, snaps


def grid_min_error(
    cfg: ExperimentConfig, target: Target, k: int, n: int
) -> tuple[float, np.ndarray | None]:
    """(smallest projected pixel error, its pose) of bounded fits started from every pose of an
    n x n x n grid over the poses k speed-limited steps from home (the box B_k in the workspace):
    a check of `plan`, whose three starts per budget are local. The pixel tolerance is met only
    within millimetres of a pose, finer than any affordable grid, so each grid pose starts the
    same fit as `plan`'s rather than being scored alone. k < 1: the home pose alone."""
    check_plannable(cfg)
    env = ShapeServoEnv(clean_config(cfg))
    env.reset(options={"target": target})
    assert env.task is not None
    home = np.asarray(env.task.home_pose, dtype=float)
    m = np.asarray(env.task.max_step, dtype=float)
    model = _Model(cfg, env.camera, target.pixels)
    if k < 1:
        return model.error(home), home
    ws_lo, ws_hi = workspace_box(cfg, 3)
    lo = np.maximum(ws_lo, home - k * m * (1 - 1e-9))
    hi = np.maximum(lo, np.minimum(ws_hi, home + k * m * (1 - 1e-9)))
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi, strict=True)]
    best, best_pose = math.inf, None
    for x in axes[0]:
        for y in axes[1]:
            for t in axes[2]:
                model.sim.restore(model.home_snap)  # each start reached from home
                model._at = None
                pose, err = _fit(model, np.array([x, y, t]), lo, hi)
                if err < best and pose_steps(home, pose, m) <= k:
                    best, best_pose = err, pose.copy()
    return best, best_pose
