"""`run_episode`: the only control loop, its stop rules and outcomes, and the sinks' lifecycle.

One episode, top to bottom:

    obs, info = env.reset(seed)     a fresh rod, camera-noise stream and target
    method.start(env.task)          fresh estimator and controller, target feature, probing plan
    u = method.act(obs)             record 0 (the initial observation) → sinks
    repeat:                         stop requested?  → interrupted
        obs, info = env.step(u)     move, settle, render, extract
        u = method.act(obs)         fold the observation in, choose the next move
        record k → sinks            the stop rule decides: converged / stalled / … / go on

The loop uses the env through `reset`/`step` and their `info` only, plus the base env's
`config`, `task` and `stage_times()` (the `ServoEnv` protocol, through `env.unwrapped`): it runs on
`gymnasium.make("rodctl/ShapeServo-v0", ...)` and on wrapped envs alike (a wrapper's
`truncated`, e.g. `TimeLimit`'s, ends the episode as `step_limit`).

`rodctl simulate`, every `rodctl compare` episode and `rodctl replay --verify` call it. The sinks
(MCAP, Rerun) are opened, written and closed here and nowhere else, always with the episode's
real status, whichever way it ends: `completed`, `failed` (diverged, lost the rod, an error) or
`interrupted`. A step is never cut in half: a stop request is honoured between steps, so every
record made is complete and in every sink.
"""

from __future__ import annotations

import math
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from rodctl import fixedla as fla
from rodctl import metrics
from rodctl.config import ExperimentConfig, dump_config
from rodctl.env import ServoEnv, StageTimes, Target, Task
from rodctl.errors import UserError, describe_os_error
from rodctl.logs.base import Sink
from rodctl.method import CONTROL, INITIAL, Method
from rodctl.numenv import numeric_environment
from rodctl.outcome import Outcome
from rodctl.records import RunHeader, RunSummary, StepRecord
from rodctl.registry import component_provenance, plugin_provenance


class Interrupted(Exception):
    """Raised between two steps when the user (Ctrl-C) or the system (SIGTERM) stops a run."""


class EpisodeFailed(Exception):
    """An exception ended the episode; `result` holds what was recorded until then."""

    def __init__(self, result: EpisodeResult) -> None:
        super().__init__(result.error)
        self.result = result


@dataclass
class StopRule:
    """When an episode ends (docs/outputs.md: "A run stops on …"), from the records as they come.

    Args:
        cfg: the run section of the experiment config (tolerances, windows, limits).
    """

    cfg: Any
    _lost: int = 0
    _window: deque = field(default_factory=deque)
    _clipped: deque = field(default_factory=deque)

    @classmethod
    def from_config(cls, cfg: ExperimentConfig) -> StopRule:
        return cls(cfg.run)

    def reset(self) -> None:
        self._lost = 0
        # Pixel errors of the last stall_window + 1 good frames: progress over stall_window steps.
        self._window = deque(maxlen=self.cfg.stall_window + 1)
        self._clipped = deque(maxlen=self.cfg.stall_window)

    def converged(self, rec: StepRecord) -> bool:
        """Pixel error below `pixel_tolerance` (and T1 below `t1_tolerance` when set)."""
        tol = self.cfg.t1_tolerance
        return rec.pixel_error < self.cfg.pixel_tolerance and (tol is None or rec.T1 < tol)

    def check(self, rec: StepRecord, method: Method, diverged: bool = False) -> Outcome | None:
        """The outcome record `rec` ends the episode on, or None to go on.

        Args:
            rec: the step's record.
            method: the method (its own failure, whether it is open-loop or finished).
            diverged: the simulator reported a NaN or a joint gap in this step.
        """
        if method.failure:
            return Outcome(method.failure)
        if rec.phase != CONTROL:
            # Probing moves decide only divergence; their frames are for J_0.
            return Outcome.DIVERGED if diverged else None
        if diverged or not np.isfinite(rec.T1):
            return Outcome.DIVERGED
        self._lost = 0 if rec.extraction_ok else self._lost + 1
        if self._lost >= self.cfg.max_lost_frames:
            return Outcome.LOST_TRACKING
        if not rec.extraction_ok:
            return None  # a bridged or failed frame decides nothing
        if method.open_loop:
            return Outcome.COMPLETED if method.finished and rec.settled else None
        if self.converged(rec):
            return Outcome.CONVERGED
        self._window.append(rec.pixel_error)
        self._clipped.append(rec.clipped)
        if len(self._window) == self._window.maxlen and self._no_progress():
            if all(self._clipped):
                return Outcome.PINNED  # the law pushes against the workspace; J is not at fault
            if self._descent_vanished(rec):
                return Outcome.STALLED
        return None

    def _no_progress(self) -> bool:
        """The pixel error has not improved by `stall_improvement` over the window."""
        window = list(self._window)
        start, best = window[0], min(window[1:])
        return best > start * (1.0 - self.cfg.stall_improvement)

    def _descent_vanished(self, rec: StepRecord) -> bool:
        """The descent direction J^T e has vanished while e has not.

        With p = 6 > q = 3 any law descending ||e||^2 along J can rest where J^T e = 0 but
        e != 0 (docs/method.md): that is a stall, not a slow convergence.
        """
        # Fixed-order arithmetic (rodctl.fixedla): the same bits on every BLAS kernel.
        e = rec.s_target - rec.s
        denom = fla.norm(rec.J) * fla.norm(e)
        grad = fla.norm(fla.matvec(np.ascontiguousarray(rec.J.T), e)) / denom if denom > 0 else 0.0
        return bool(grad < self.cfg.stall_gradient)


@dataclass
class EpisodeResult:
    """What one episode produced.

    Attributes:
        outcome: how it ended.
        summary: the run summary (summary.json).
        header: what the sinks were opened with (None if the episode ended before).
        records: every step record, without camera images.
        error: the message of the exception that ended it (outcome ERROR), else None.
        traceback: that exception's traceback text, else None.
    """

    outcome: Outcome
    summary: RunSummary
    header: RunHeader | None
    records: list[StepRecord]
    error: str | None = None
    traceback: str | None = None
    #: why a diverged episode diverged (the quantity and the step: `divergence`) or why one
    #: lost the rod (`lost_tracking`), else None.
    reason: str | None = None

    @property
    def status(self) -> str:
        return self.outcome.status


def run_episode(
    env: gym.Env,
    method: Method,
    stop_rule: StopRule | None = None,
    sinks: Sequence[Sink] = (),
    *,
    seed: int | None = None,
    options: dict[str, Any] | None = None,
    run_id: str = "adhoc",
    on_step: Callable[[StepRecord], None] | None = None,
    stop_requested: Callable[[], str | None] | None = None,
) -> EpisodeResult:
    """Run one episode of `method` in `env` to its end; every record goes to every sink.

    Args:
        env: the environment: a `ShapeServoEnv`, as made or through `gymnasium.make` and any
            wrappers that keep the observation keys a method reads and the `info` keys of
            `ShapeServoEnv`; its base (`env.unwrapped`) is a `ServoEnv` whose config decides
            the run limits.
        method: the method under test.
        stop_rule: when to stop (default: from the env's run config).
        sinks: outputs; opened with the header, closed here with the episode's real status.
        seed, options: passed to `env.reset` (seed None: the config's seed).
        run_id: the run's id, written into the header.
        on_step: called with each record after the sinks have it (progress display).
        stop_requested: polled between steps; a non-empty reason (e.g. "SIGINT") ends the
            episode there with outcome `interrupted`.

    Returns:
        The result; its outcome says how the episode ended.

    Raises:
        UserError: the episode could not start (an unusable target, a checkpoint that does not
            fit); nothing was logged.
        EpisodeFailed: an exception ended it after it started; `.result` holds the records,
            and the sinks were closed with status `failed`.
    """
    base = _servo_env(env)
    wall0 = time.perf_counter()
    obs, info = env.reset(seed=base.config.seed if seed is None else seed, options=options)
    _check_observation(env, obs)
    # base.config after reset: `options` may have replaced it
    stop_rule = stop_rule or StopRule.from_config(base.config)
    stop_rule.reset()
    loop = _open(base, info, method, sinks, on_step, wall0, run_id)
    try:
        outcome = _steps(env, loop, stop_rule, obs, info, stop_requested)
    except (Interrupted, KeyboardInterrupt) as exc:
        outcome = Outcome.INTERRUPTED
        loop.note = f"interrupted by {exc or 'SIGINT'}"
    except Exception as exc:
        if isinstance(exc, UserError) and not loop.records:
            loop.close(None, "failed")
            raise
        result = loop.finish(Outcome.ERROR, error=exc)
        raise EpisodeFailed(result) from exc
    result = loop.finish(outcome)
    if result.error is not None:  # the logs could not be finalised
        raise EpisodeFailed(result)
    return result


def _open(
    base: ServoEnv,
    info: dict[str, Any],
    method: Method,
    sinks: Sequence[Sink],
    on_step: Callable[[StepRecord], None] | None,
    wall0: float,
    run_id: str,
) -> _Loop:
    """The episode's bookkeeping after `reset`: the method started on the env's task, the sinks
    opened with the header (closed again if one fails to open; a `UserError` passes)."""
    cfg = base.config
    task = base.task
    if task is None:
        raise TypeError(f"run_episode: {type(base).__name__}.reset() left its `task` unset")
    method.start(task)
    loop = _Loop(base, cfg, task, info, method, sinks, on_step, wall0)
    try:
        loop.open(run_id)  # closes what it opened if one sink fails to open
    except Exception as exc:
        if isinstance(exc, UserError):
            raise
        raise EpisodeFailed(loop.finish(Outcome.ERROR, error=exc, close=False)) from exc
    return loop


def _steps(
    env: gym.Env,
    loop: _Loop,
    stop_rule: StopRule,
    obs: dict[str, Any],
    info: dict[str, Any],
    stop_requested: Callable[[], str | None] | None,
) -> Outcome:
    """The steps of a started episode, record 0 (the initial observation) first, until the stop
    rule, the step limit or a wrapper's `truncated` ends it; the outcome.

    Raises:
        Interrupted: `stop_requested` gave a reason between two steps.
    """
    method, q, max_steps = loop.method, loop.env.q, loop.cfg.run.max_steps
    u = method.act(obs)
    loop.emit(loop.record(info, u=np.zeros(q), u_raw=np.zeros(q), phase=INITIAL))
    outcome: Outcome | None = None
    k = 0
    while outcome is None and k < max_steps:
        reason = stop_requested() if stop_requested is not None else None
        if reason:
            raise Interrupted(reason)
        k += 1
        phase = method.phase
        if not np.all(np.isfinite(u)):
            # A NaN estimate or feature: the method has broken down; do not move the robot.
            rec = loop.record(loop.info, u=np.zeros(q), u_raw=u, phase=phase, moved=False)
            loop.emit(rec)
            loop.reason = divergence(rec, False)
            return Outcome.DIVERGED
        obs, _, _, truncated, info = env.step(u)
        u_raw = u
        u = method.act(obs)
        rec = loop.record(info, u=obs["applied"], u_raw=u_raw, phase=phase)
        loop.emit(rec)
        outcome = stop_rule.check(rec, method, diverged=info["diverged"])
        if outcome is Outcome.DIVERGED:
            loop.reason = divergence(rec, info["diverged"])
        elif outcome is Outcome.LOST_TRACKING:
            loop.reason = lost_tracking(rec, loop.cfg.run.max_lost_frames)
        elif outcome is None and truncated:
            outcome = Outcome.STEP_LIMIT  # a time limit: run.max_steps or a wrapper's
    return outcome or Outcome.STEP_LIMIT


#: `dump_config` of the last few configs, keyed by their JSON (`_config_yaml`).
_CONFIG_YAML: dict[str, str] = {}


def _config_yaml(cfg: ExperimentConfig) -> str:
    """`dump_config(cfg)` for the run header, remembered for the last few configs: a study runs
    many episodes of one config, and the YAML costs ~4 ms of CPU an episode (about a twentieth
    of a quasi-static one). The key is the config's JSON (~0.05 ms), which holds every value
    exactly, so an equal key gives the same YAML."""
    key = cfg.model_dump_json()
    text = _CONFIG_YAML.get(key)
    if text is None:
        text = dump_config(cfg)
        if len(_CONFIG_YAML) >= 8:
            del _CONFIG_YAML[next(iter(_CONFIG_YAML))]  # the oldest
        _CONFIG_YAML[key] = text
    return text


def _servo_env(env: gym.Env) -> ServoEnv:
    """The base environment of `env` (Gymnasium's `env.unwrapped`), checked to be a `ServoEnv`."""
    base = getattr(env, "unwrapped", env)
    if not isinstance(base, ServoEnv):
        raise TypeError(
            f"run_episode: the base environment {type(base).__name__} is not a ServoEnv "
            "(it needs `config`, `task` and `stage_times()`, as rodctl.env.ShapeServoEnv has)"
        )
    return base


#: The observation keys a method reads (`Method.act`; `target` too when present).
OBSERVATION_KEYS = ("centerline", "extraction_ok", "gripper", "applied")


def _check_observation(env: gym.Env, obs: Any) -> None:
    """Refuse, before anything is logged, an env whose wrappers changed the observation so
    that a method cannot read it (flattened, filtered, stacked)."""
    missing = [k for k in OBSERVATION_KEYS if k not in obs] if isinstance(obs, dict) else None
    line: Any = obs.get("centerline") if isinstance(obs, dict) else None
    if missing is None or missing or np.ndim(line) != 2:
        what = (
            f"a {type(obs).__name__}, not a dict" if missing is None
            else f"without {', '.join(missing)}" if missing
            else f"with a centerline of shape {np.shape(line)}, not (N, 2)"
        )  # fmt: skip
        raise TypeError(
            f"run_episode: {type(env).__name__}'s observation is {what}; a method reads "
            f"{', '.join(OBSERVATION_KEYS)} (and target) as ShapeServoEnv gives them, so a "
            "wrapper that flattens, filters or stacks the observation cannot be run by one"
        )


def _numbers(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{float(x):.6g}" for x in np.ravel(v)) + "]"


def lost_tracking(rec: StepRecord, max_lost_frames: int) -> str:
    """Why an episode lost the rod at `rec`'s step, in words: during probing too few frames
    were good to fit J_0; in control, `max_lost_frames` frames in a row found no rod."""
    where = f"lost the rod at step {rec.step}"
    if rec.phase != CONTROL:
        return (
            f"{where}: too few probing frames showed the rod to fit the initial Jacobian J_0 "
            "(the extractor found no rod in one or more of them: an occluder, the rod out of "
            "view, or noise past what it tolerates)"
        )
    return (
        f"{where}: the extractor found no rod in {max_lost_frames} frames in a row "
        "(run.max_lost_frames): an occluder, the rod out of view, or noise past what it "
        "tolerates"
    )


def divergence(rec: StepRecord, simulator: bool) -> str:
    """What diverged at `rec`'s step, in words: the first non-finite quantity, or the simulator's
    own verdict (a NaN in the rod or a joint gap past `rod.gap_limit`)."""
    where = f"diverged at step {rec.step}"
    if not np.all(np.isfinite(rec.u_raw)):
        return (
            f"{where}: the controller's command u = {_numbers(rec.u_raw)} is not finite (a NaN "
            "or infinite feature, Jacobian estimate or gain); the robot was not moved"
        )
    if simulator or not np.all(np.isfinite(rec.gripper)) or not np.all(np.isfinite(rec.centerline)):
        if not np.all(np.isfinite(rec.gripper)):
            return f"{where}: the gripper pose {_numbers(rec.gripper)} is not finite"
        if not np.all(np.isfinite(rec.centerline)):
            return f"{where}: the rod's state (its centerline) holds NaN or infinite values"
        return (
            f"{where}: the rod simulation broke down: its largest joint gap is "
            f"{float(rec.max_joint_gap):.3g} m, past rod.gap_limit (or a NaN in the solver)"
        )
    for name in ("T1", "s", "J"):
        value = np.asarray(getattr(rec, name), dtype=float)
        if not np.all(np.isfinite(value)):
            return f"{where}: the {name} of the method is not finite ({_numbers(value)[:80]})"
    return f"{where}: the method reported that it diverged"


def _final_pose(rec: StepRecord) -> np.ndarray:
    """The moved ends' poses after `rec`'s step: the gripper's, then (dual-arm) the x0 end's."""
    if rec.clamp is None:
        return np.asarray(rec.gripper)
    return np.concatenate([rec.gripper, rec.clamp])


def _jacobian_error_summary(recs: Sequence[StepRecord]) -> dict[str, float | None]:
    """The episode's Jacobian errors in brief: the median over the steps that have one, and the
    last step's (None where there is none)."""
    errors = [float(r.jacobian_error) for r in recs]
    finite = sorted(e for e in errors if math.isfinite(e))
    last = errors[-1] if errors and math.isfinite(errors[-1]) else None
    # np.median's value (the middle one, or the mean of the two middle ones: their sum halved),
    # without it: its first call imports numpy.ma (~10 ms, a fifth of a quasi-static episode)
    k = len(finite) // 2
    median = (
        (finite[k] if len(finite) % 2 else (finite[k - 1] + finite[k]) / 2.0) if finite else None
    )
    return {"jacobian_error_median": median, "jacobian_error_final": last}


class _Loop:
    """The bookkeeping of one episode: records, image rate, timing, sinks, the summary."""

    def __init__(
        self,
        env: ServoEnv,
        cfg: ExperimentConfig,
        task: Task,
        info: dict[str, Any],
        method: Method,
        sinks: Sequence[Sink],
        on_step: Callable[[StepRecord], None] | None,
        wall0: float,
    ) -> None:
        self.env, self.method, self.sinks, self.on_step = env, method, list(sinks), on_step
        self.cfg = cfg
        #: the episode's set-up: what the method was told, and the target (`info` of `reset`)
        self.task = task
        self.target: Target = info["target"]
        #: the `info` of the last reset or step (the state the current records describe)
        self.info = info
        self.wall0 = wall0
        self.records: list[StepRecord] = []
        self.header: RunHeader | None = None
        self.logging = 0.0
        self.note: str | None = None
        self.reason: str | None = None
        self.setup_time = 0.0

    def open(self, run_id: str) -> None:
        method, cfg, task, target = self.method, self.cfg, self.task, self.target
        self.header = RunHeader(
            run_id=run_id,
            method=method.label,
            config_yaml=_config_yaml(cfg),
            image_size=(cfg.camera.width, cfg.camera.height),
            clamp_pose=task.clamp_pose,
            home_pose=task.home_pose,
            target_centerline=target.centerline,
            target_pixels=target.pixels,
            target_feature=method.s_target,
            target_pose=target.pose,
            rod_length=cfg.rod.length,
            numeric_env=numeric_environment(),
            provenance={
                "plugins": plugin_provenance(),
                "stages": dict(getattr(method, "stages", {})),
                **component_provenance(cfg),  # the run's mid-run events and sinks
            },
        )
        self.setup_time = time.perf_counter() - self.wall0
        opened: list[Sink] = []
        try:
            for sink in self.sinks:
                sink.open(self.header)
                opened.append(sink)
        except BaseException:
            self.sinks = opened
            self.close(None, "failed")
            raise

    def record(
        self,
        info: dict[str, Any],
        *,
        u: np.ndarray,
        u_raw: np.ndarray,
        phase: str,
        moved: bool = True,
    ) -> StepRecord:
        """The record of the current step from the env's info and the method's state."""
        m = self.method
        assert m.s is not None, "recorded after the method's first act()"
        self.info = info
        k = len(self.records)
        J = np.array(m.J, dtype=float)
        return StepRecord(
            step=k,
            sim_time=info["sim_time"],
            phase=phase,
            gripper=info["gripper"],
            centerline=info["ground_truth"],
            extracted=info["extracted"],
            projected_truth=info["projected_truth"],
            u=np.array(u, dtype=float),
            u_raw=np.array(u_raw, dtype=float),
            s=m.s,
            s_target=m.s_target,
            T1=m.T1,
            J=J,
            J_singular_values=fla.singular_values(J),
            pixel_error=info["pixel_error"],
            settled=info["settled"] if moved else True,
            saturated=info["saturated"] if moved else np.zeros(self.env.q, dtype=bool),
            clipped=info["clipped"] if moved else False,
            max_joint_gap=info["max_joint_gap"],
            kinetic_energy=info["kinetic_energy"],
            extraction_ok=info["extraction_ok"],
            extraction_note=info["extraction_note"],
            estimator_info=m.estimator_info(),
            events=list(info.get("events", [])) if moved else [],
            jacobian_error=self._jacobian_error(J),
            clamp=info.get("clamp"),
        )

    def _jacobian_error(self, J: np.ndarray) -> float:
        """||Ĵ - J||_F / ||J||_F of the method's estimate Ĵ against the simulator's true
        Jacobian J of the method's own feature at this step's shape
        (`ShapeServoEnv.jacobian_error_reference`, as `run.jacobian_error` asks); NaN where the
        method has no estimate (before probing fits J_0, an open-loop path) or the run does not
        compute J (docs/engines.md)."""
        m = self.method
        reference = getattr(self.env, "jacobian_error_reference", None)
        if reference is None or m.open_loop or not np.any(J) or not np.all(np.isfinite(J)):
            return float("nan")
        true = reference(m.feature.encode)
        if true is None or true.shape != J.shape:
            return float("nan")
        scale = fla.norm(true)
        return fla.norm(J - true) / scale if scale > 0 else float("nan")

    def emit(self, rec: StepRecord) -> None:
        # Every record carries its frame; the sinks pick frames by simulated time
        # (logging.image_rate_hz), so the rate holds in the log's own clock.
        rec.image = self.info["image"]
        t = time.perf_counter()
        for sink in self.sinks:
            sink.write(rec)
        self.logging += time.perf_counter() - t
        rec.image = None
        self.records.append(rec)
        if self.on_step is not None:
            self.on_step(rec)

    def close(self, summary: RunSummary | None, status: str) -> None:
        """Close every sink even if one fails; the first failure is re-raised afterwards."""
        first: BaseException | None = None
        for sink in self.sinks:
            try:
                sink.close(summary, status)
            except BaseException as exc:  # noqa: BLE001 - all sinks must get their chance
                first = first or exc
        if first is not None:
            raise first

    def finish(
        self, outcome: Outcome, error: BaseException | None = None, *, close: bool = True
    ) -> EpisodeResult:
        """Summarise, close the sinks with the real status (unless `close` is False: they were
        never all opened), and return the result."""
        summary = self.summary(outcome)
        if close and self.header is not None:
            try:
                self.close(summary, outcome.status)
            except Exception as exc:  # noqa: BLE001 - e.g. a full disk while finalising
                if error is None:  # the logs could not be finalised: the run failed
                    outcome, error = Outcome.ERROR, exc
                    summary = self.summary(outcome)
        message = tb = None
        if error is not None:
            message = str(error)
            if isinstance(error, OSError):
                message = f"{type(error).__name__}: {describe_os_error(error)}"
            elif not isinstance(error, UserError):
                message = f"{type(error).__name__}: {error}"
            tb = "".join(traceback.format_exception(error))
        failed = (Outcome.DIVERGED, Outcome.LOST_TRACKING)
        reason = self.reason if outcome in failed else None
        return EpisodeResult(outcome, summary, self.header, self.records, message, tb, reason)

    def _benchmark_metrics(self, outcome: Outcome) -> dict[str, Any]:
        """The comparison metrics of `rodctl.metrics` for this episode."""
        task, cfg, recs = self.task, self.cfg, self.records
        pose_steps = metrics.pose_steps(task.home_pose, self.target.pose, task.max_step)
        trans, rot = metrics.smoothness(recs, task.max_step)
        converged = outcome is Outcome.CONVERGED
        peak, reconverge = metrics.after_event(recs, converged)
        return {
            "pose_steps": pose_steps,
            "excess_steps": recs[-1].step - pose_steps if converged else None,
            "smoothness_translation": trans,
            "smoothness_rotation": rot,
            "near_origin_steps": (
                metrics.near_origin_steps(recs, cfg.run.pixel_tolerance) if converged else None
            ),
            "event_peak_error": peak,
            "event_steps_to_converge": reconverge,
            "finished_before_event": metrics.finished_before_event(recs, bool(cfg.run.events)),
        }

    def summary(self, outcome: Outcome) -> RunSummary:
        method, recs, target = self.method, self.records, self.target
        wall = time.perf_counter() - self.wall0
        steps = recs[-1].step if recs else 0
        last = recs[-1] if recs else None
        env_times = self.env.stage_times()
        times = StageTimes(
            sim=env_times.sim,
            vision=env_times.vision,
            feature=method.times.feature,
            control=method.times.control,
            logging=self.logging,
        )
        extra: dict[str, Any] = {"run_id": self.header.run_id if self.header else ""}
        if outcome not in (Outcome.INTERRUPTED, Outcome.ERROR) and last is not None:
            us = np.array([r.u for r in recs[1:]]).reshape(-1, self.env.q)
            extra.update(
                setup_time_s=round(self.setup_time, 4),
                probe_steps=sum(r.phase == "probe" for r in recs),
                target_pose=[float(v) for v in target.pose],
                target_difficulty=round(target.difficulty, 6),
                home_pose=[float(v) for v in self.task.home_pose],
                # Like home_pose and target_pose: 6 values dual-arm (the x0 end's after).
                final_gripper=[float(v) for v in _final_pose(last)],
                final_J_singular_values=[float(v) for v in last.J_singular_values],
                path_length=float(np.sum(np.linalg.norm(us[:, :2], axis=1))),
                rotation_length=float(np.sum(np.abs(us[:, 2]))),
                smoothness=float(np.sum(np.linalg.norm(np.diff(us, axis=0), axis=1))),
                **self._benchmark_metrics(outcome),
                saturated_steps=int(sum(bool(np.any(r.saturated)) for r in recs)),
                clipped_steps=int(sum(r.clipped for r in recs)),
                unsettled_steps=int(sum(not r.settled for r in recs)),
                lost_frames=int(sum(not r.extraction_ok for r in recs)),
                **_jacobian_error_summary(recs),
                time_per_step_ms=times.per_step_ms(len(recs)),
            )
        run_time = wall - self.setup_time
        return RunSummary(
            status=outcome.status,
            outcome=outcome.value,
            method=method.label,
            steps=steps,
            converged=outcome is Outcome.CONVERGED,
            steps_to_converge=steps if outcome is Outcome.CONVERGED else None,
            final_T1=float(last.T1) if last else float("nan"),
            final_pixel_error=float(last.pixel_error) if last else float("nan"),
            wall_time_s=round(wall, 4),
            steps_per_s=round(steps / run_time, 3) if run_time > 0 else 0.0,
            extra=extra,
        )
