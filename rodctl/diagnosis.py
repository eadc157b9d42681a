"""Why an episode failed: the `diagnosis` of a stalled or pinned episode, from its final state.

A stall is easily blamed on the wrong stage: on the benchmark's event-stiffness scenario every
autoencoder method, the oracle included, stalled on the same targets, and a direct search over
gripper poses reached the tolerance on some of them and not on others. So each stalled or
pinned episode of a compare run is examined, in its worker, right after it ended, with the
simulator's own model (what no real robot has), and gets one of:

- `workspace`: the episode ended pinned (every command clipped by the workspace), or the pose
  search below could not reach the tolerance and was clipped by the workspace on the way (in a
  dual-arm run, `rod.arms: 2`, either end's: the gripper's `rod.workspace`, the x0 end's
  `rod.clamp_arm.workspace`, or the reach between them).
- `estimator`: the method's own feature and law, told the true Jacobian (the `oracle`
  estimator, `ShapeServoEnv.true_jacobian`), converge from the same state within
  `ESTIMATOR_STEPS` steps: the Jacobian estimate was at fault.
- `unreachable`: a pose search with the true model cannot bring the rod within the pixel
  tolerance of the target: from this state, no nearby pose of the moved ends makes the target shape
  (after a mid-run event, or with a tolerance tighter than what the rod can show).
- `other`: the target is reachable and the true Jacobian does not help the method's law: the
  feature (its minimum is not the shape's) or the law itself.
- `inconclusive`: the pose search was still lowering the error (by more than `MIN_GAIN_PX` an
  iteration) when it ran out of iterations, so it says neither reachable nor not.

The pose search is Gauss-Newton on the clean pixel residual (the simulated centerline through
the camera model minus the target's pixels), its Jacobian by central differences of the
simulator (as `true_jacobian`, 2q settles an iteration), each move within the speed limit and
halved until the error falls; it stops at the tolerance or after `SEARCH_ITERATIONS`. It
searches over all q commanded values: the gripper's pose (q = 3), and in a dual-arm run the x0
end's too (q = 6), each end within its own speed limit (`rod.max_step`,
`rod.clamp_arm.max_step`) and workspace, as the robot moves them (`RodSim.apply`). Cost: at
most about `ESTIMATOR_STEPS` oracle steps plus `SEARCH_ITERATIONS` x (2q + 1) settles per
diagnosed episode (7 at q = 3, 13 at q = 6); converged episodes are never diagnosed. Mid-run
events do not fire during it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from rodctl.config import ExperimentConfig
from rodctl.env import ShapeServoEnv, pixel_error
from rodctl.geometry import resample_polyline

if TYPE_CHECKING:
    from rodctl.method import Method

#: The values of the `diagnosis` column (None for episodes that did not stall or get pinned).
DIAGNOSES = ("workspace", "estimator", "unreachable", "other", "inconclusive")

#: Steps the method's law gets with the true Jacobian from the failed episode's final state.
ESTIMATOR_STEPS = 30

#: Gauss-Newton iterations of the pose search.
SEARCH_ITERATIONS = 20

#: A search cut off at `SEARCH_ITERATIONS` is `inconclusive` only if its last iteration lowered
#: the error by more than this [px]; less is rounding in the settles (a dual-arm search crept by
#: < 1e-9 px an iteration on one machine and was `inconclusive`, `unreachable` on another).
MIN_GAIN_PX = 1e-3

#: Finite-difference step per axis [m, m, rad] of each moved end (as `ShapeServoEnv.true_jacobian`).
_FD = (1e-3, 1e-3, 5e-3)


def diagnose(
    env: ShapeServoEnv,
    cfg: ExperimentConfig,
    outcome: str,
    *,
    estimator_steps: int = ESTIMATOR_STEPS,
    search_iterations: int = SEARCH_ITERATIONS,
) -> str | None:
    """The diagnosis of an episode that ended `outcome` in `env` (left in its final state).

    Args:
        env: the episode's environment, as the episode left it (it is moved further here).
        cfg: the episode's experiment config (its feature and controller are reused).
        outcome: the episode's outcome; only "stalled" and "pinned" are diagnosed.

    Returns:
        One of `DIAGNOSES`, or None when the outcome is not diagnosed.
    """
    if outcome not in ("stalled", "pinned"):
        return None
    if outcome == "pinned":
        return "workspace"
    # No mid-run event fires while diagnosing: the state being examined is the episode's.
    env.cfg = env.cfg.model_copy(update={"run": env.cfg.run.model_copy(update={"events": []})})
    sim = env._episode()[0]
    snap = sim.snapshot()
    if true_jacobian_converges(env, cfg, estimator_steps):
        return "estimator"
    sim.restore(snap)
    best, clipped, capped = pose_search(env, search_iterations)
    if best < cfg.run.pixel_tolerance:
        return "other"
    if capped:
        return "inconclusive"  # still improving at the last iteration: not "cannot reach"
    return "workspace" if clipped else "unreachable"


#: The oracle methods of earlier diagnoses in this process with an autoencoder feature, by
#: their config without the episode's seed and target (`_oracle_method`).
_ORACLE_METHODS: dict[str, Any] = {}


def _oracle_method(cfg: ExperimentConfig) -> Any:
    """The method's feature and controller with the oracle estimator. An autoencoder's feature
    map loads and checks its checkpoint when built (2.6-4.5 ms of CPU, 3-5 % of a quasi-static
    diagnosis) and its forward pass keeps no state, so that method is built once per config and
    process, as `rodctl.bench.episodes` does for the episodes' own (`Method.start` gives each
    diagnosis a fresh estimator and controller: the same bits). It is never the episode's
    method: a feature map of its own, so the env's cached true Jacobian (keyed by the feature
    map) is not shared with the episode's, and pymunk pays the same settles as before."""
    from rodctl.estimation.oracle import OracleEstimatorConfig
    from rodctl.method import Method

    def build() -> Any:
        return Method(cfg.feature, OracleEstimatorConfig(), cfg.controller, experiment=cfg)

    if cfg.feature.type != "autoencoder":
        return build()  # cheap to build; a plug-in's feature may keep state
    key = cfg.model_dump_json(exclude={"seed": True, "run": {"target": True}})
    method = _ORACLE_METHODS.get(key)
    if method is None:
        method = build()
        if len(_ORACLE_METHODS) >= 16:
            del _ORACLE_METHODS[next(iter(_ORACLE_METHODS))]  # the oldest
        _ORACLE_METHODS[key] = method
    return method


def true_jacobian_converges(env: ShapeServoEnv, cfg: ExperimentConfig, steps: int) -> bool:
    """The method's feature and controller with the oracle estimator, from the env's current
    state (the last frame), reach the pixel tolerance within `steps` moves."""
    method = _oracle_method(cfg)
    assert env.task is not None  # the episode's reset set it
    try:
        return _oracle_run(method, env, cfg, steps)
    finally:
        method.release()  # a cached method must not keep this env alive


def _oracle_run(method: Method, env: ShapeServoEnv, cfg: ExperimentConfig, steps: int) -> bool:
    """`true_jacobian_converges`' moves, with `method` (the oracle's) on `env`."""
    assert env.task is not None
    method.start(env.task)
    obs: dict[str, Any] = env._observation(np.zeros(env.q))
    if not obs["extraction_ok"]:
        return False
    tol, t1 = cfg.run.pixel_tolerance, cfg.run.t1_tolerance
    u = method.act(obs)
    for _ in range(steps):
        if not np.all(np.isfinite(u)):
            return False
        obs, _, _, _, info = env.step(u)
        if info["diverged"]:
            return False
        u = method.act(obs)
        if obs["extraction_ok"] and info["pixel_error"] < tol and (t1 is None or method.T1 < t1):
            return True
    return False


def workspace_box(cfg: ExperimentConfig, q: int) -> tuple[np.ndarray, np.ndarray]:
    """(q,) lower and upper limits of each commanded axis: the gripper's `rod.workspace` box,
    then (q = 6) the x0 end's `rod.clamp_arm.workspace` box."""
    boxes = [cfg.rod.workspace] + ([cfg.rod.clamp_arm.workspace] if q == 6 else [])
    lo = [v for w in boxes for v in (w.x_limits[0], w.y_limits[0], w.theta_limits[0])]
    hi = [v for w in boxes for v in (w.x_limits[1], w.y_limits[1], w.theta_limits[1])]
    return np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)


def _bounded_step(
    jac: np.ndarray, r: np.ndarray, pose: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, bool]:
    """The Gauss-Newton step min ||jac du + r|| with the axes held that sit on a workspace limit
    and would push past it, and whether any was held (the workspace stopped the search there).

    Without it a step that mostly asks for a held axis is scaled down to that axis's speed limit
    and then clipped, so the free axes creep (a dual-arm search with the x0 end at its box's
    edge improved by 0.01 px an iteration, never stopping, 'inconclusive')."""
    q = pose.shape[0]
    free = np.ones(q, dtype=bool)
    blocked = False
    step = np.zeros(q)
    for _ in range(q):
        step = np.zeros(q)
        if not free.any():
            break
        step[free] = -np.linalg.lstsq(jac[:, free], r, rcond=None)[0]
        held = free & (((pose <= lo + 1e-9) & (step < 0)) | ((pose >= hi - 1e-9) & (step > 0)))
        if not held.any():
            break
        free &= ~held
        blocked = True
    return step, blocked


def pose_search(env: ShapeServoEnv, iterations: int) -> tuple[float, bool, bool]:
    """(best clean pixel error reached, whether the workspace clipped a move, whether it ran out
    of iterations while still improving): Gauss-Newton over the poses of the moved ends (the
    gripper's; dual-arm: the x0 end's too, q = 6) on the simulated rod, from its current state,
    towards the target. Each move is within every axis's speed limit (`env.max_step`: the
    gripper's, then the x0 end's), and "clipped" counts either end's workspace."""
    sim, _, episode_target = env._episode()
    camera = env.camera
    n = env.cfg.camera.points
    q = env.q
    target = np.asarray(episode_target.pixels, dtype=float)
    max_step = np.asarray(env.max_step, dtype=float)  # (q,)
    fd = np.tile(_FD, q // 3)
    lo, hi = workspace_box(env.cfg, q)
    tol = env.cfg.run.pixel_tolerance

    def residual() -> np.ndarray:
        return camera.project(resample_polyline(sim.centerline(), n)) - target

    r = residual()
    best, clipped = pixel_error(r + target, target), False
    improved, gain = False, 0.0
    for _ in range(iterations):
        if best < tol:
            break
        snap = sim.snapshot()
        cols = []
        for axis, h in enumerate(fd):
            values = []
            for sign in (1.0, -1.0):
                du = np.zeros(q)
                du[axis] = sign * h
                sim.apply(du)
                values.append(residual().ravel())
                sim.restore(snap)
            cols.append((values[0] - values[1]) / (2.0 * h))
        jac = np.stack(cols, axis=1)
        step, blocked = _bounded_step(jac, r.ravel(), sim.end_poses, lo, hi)
        clipped = clipped or blocked
        step /= max(1.0, float(np.max(np.abs(step) / max_step)))  # within the speed limit
        improved = False
        for _ in range(4):  # halve the move until the error falls
            res = sim.apply(step)
            r_new = residual()
            err = pixel_error(r_new + target, target)
            if err < best and not res.diverged:
                clipped = clipped or bool(res.clipped or res.refused)
                r, best, improved, gain = r_new, err, True, best - err
                break
            clipped = clipped or bool(res.clipped or res.refused)
            sim.restore(snap)
            step = step / 2.0
        if not improved:
            break  # a local minimum of the pixel error (or the workspace edge)
    # Cut off while still improving, by more than rounding in the settles (MIN_GAIN_PX).
    return best, clipped, improved and gain > MIN_GAIN_PX and best >= tol
