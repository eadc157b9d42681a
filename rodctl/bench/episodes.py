"""The worker of every study: one `EpisodeTask` run to its results row.

Each episode runs in whatever process its executor chose, one BLAS/torch thread each, from its
task alone: the method's whole config, the target and its seed. Its row holds the columns of
results.csv that the episode decides (outcome, steps, errors, smoothness, ...); the study adds
the rest. An episode that raises is an `error` row, never the end of the study.
"""

from __future__ import annotations

import traceback
from pathlib import Path
from typing import Any, cast

import numpy as np

from rodctl.bench.tasks import EpisodeTask
from rodctl.config import ExperimentConfig, dump_config
from rodctl.config.base import Pose
from rodctl.config.run import EndPoses
from rodctl.env import ShapeServoEnv, Target
from rodctl.episode import EpisodeFailed, EpisodeResult, run_episode
from rodctl.executors.base import stop_reason
from rodctl.method import Method
from rodctl.outcome import Outcome
from rodctl.runs import write_json_atomic

#: The per-episode comparison metrics of `rodctl.metrics`, copied from the summary into a row.
METRIC_COLUMNS = (
    "pose_steps",
    "excess_steps",
    "smoothness_translation",
    "smoothness_rotation",
    "near_origin_steps",
    "event_peak_error",
    "event_steps_to_converge",
    "finished_before_event",
)


#: Methods with an autoencoder feature built for earlier episodes of this process, by their
#: config without the episode's seed and target (`_method`).
_METHODS: dict[str, Method] = {}


def _method(cfg: ExperimentConfig) -> Method:
    """The episode's method. An autoencoder's feature map loads and checks its checkpoint when
    it is built (~2 ms of CPU, as much as a tenth of a quasi-static episode), and its numpy
    forward pass keeps no state, so a method of that feature is built once per config and
    process and reused: `Method.start` gives every episode a fresh estimator, controller and
    probing plan, so it runs as a method built for it would (bit-identical results, tested).
    Other features are built per episode as before (cheap; a plug-in's may keep state)."""
    if cfg.feature.type != "autoencoder":
        return Method.from_config(cfg)
    # Everything but what the worker sets per episode (the seed, the target).
    key = cfg.model_dump_json(exclude={"seed": True, "run": {"target": True}})
    method = _METHODS.get(key)
    if method is None:
        method = Method.from_config(cfg)
        if len(_METHODS) >= 16:
            del _METHODS[next(iter(_METHODS))]  # the oldest
        _METHODS[key] = method
    return method


def run_episode_task(task: EpisodeTask) -> dict[str, Any]:
    """Worker: one method on one target; returns its results row (and records if asked)."""
    cfg = ExperimentConfig.model_validate(task.config)
    # The episode's own config says everything (seed, target), so its log replays alone.
    cfg.seed = task.seed
    # Checked as it is assigned (`validate_assignment`): 3 values, or 6 with rod.arms: 2.
    cfg.run.target.pose = cast("Pose | EndPoses", tuple(task.pose))
    row: dict[str, Any] = task.row_tags()
    log_dir = Path(task.log_dir) if task.log_dir else None
    env = result = None
    try:
        env, result = _run(task, cfg, log_dir)
    except Exception as exc:  # noqa: BLE001 - one bad episode must not end the benchmark
        failed = exc.result if isinstance(exc, EpisodeFailed) else None
        row.update(
            outcome="error", error=failed.error if failed else f"{type(exc).__name__}: {exc}"
        )
        if log_dir is not None:
            text = failed.traceback if failed else traceback.format_exc()
            (log_dir / "error.txt").write_text(text or "", encoding="utf-8")
    if result is not None and env is not None:
        if task.diagnose:
            _diagnose(env, cfg, result, row)
        # A diverged or lost episode's reason (`EpisodeResult.reason`) is its row's error.
        row.update(_result_columns(result, row.get("error", "") or result.reason or ""))
        if log_dir is not None:
            write_json_atomic(log_dir / "summary.json", result.summary.to_json())
        if task.want_records:
            row["_records"] = (result.header, result.records)
    return row


def _target_options(task: EpisodeTask) -> dict[str, Any] | None:
    """The shared target as the clean camera saw it, when this episode's rod and camera made
    it: the same Target the episode would make by driving a rod there again (issue #17)."""
    view = task.target_view
    if view is None:
        return None
    target = Target(
        pose=np.asarray(task.pose, dtype=float),
        centerline=np.asarray(view["centerline"], dtype=float),
        pixels=np.asarray(view["pixels"], dtype=float),
        difficulty=float(task.target_difficulty or 0.0),
    )
    return {"target": target}


def _run(
    task: EpisodeTask, cfg: ExperimentConfig, log_dir: Path | None
) -> tuple[ShapeServoEnv, EpisodeResult]:
    """The episode and its env, logged to `log_dir` (its config and its sinks' files) when
    asked."""
    sinks: list[Any] = []
    if log_dir is not None:
        from rodctl.simulate import make_sinks  # noqa: PLC0415 - the sinks' libraries, when asked

        log_dir.mkdir(parents=True, exist_ok=True)
        (log_dir / "config.yaml").write_text(dump_config(cfg), encoding="utf-8")
        sinks = make_sinks(cfg, log_dir)
    env = ShapeServoEnv(cfg)
    method = _method(cfg)
    try:
        return env, run_episode(
            env,
            method,
            sinks=sinks,
            run_id=task.name,
            options=_target_options(task),
            # SIGINT/SIGTERM of this process (or Ray's cancel) end it whole, between two steps.
            stop_requested=stop_reason,
        )
    finally:
        method.release()  # a cached method must not keep this episode's env alive


def _diagnose(
    env: ShapeServoEnv, cfg: ExperimentConfig, result: EpisodeResult, row: dict[str, Any]
) -> None:
    """Why a stalled or pinned episode failed, from its final state, with the simulator's model
    (`rodctl.diagnosis`), into the summary's extras; a diagnosis that fails says so in `row`."""
    summary = result.summary
    if summary.outcome not in ("stalled", "pinned"):
        return
    from rodctl.diagnosis import diagnose  # noqa: PLC0415 - the pose search's scipy, when needed

    try:
        summary.extra["diagnosis"] = diagnose(env, cfg, summary.outcome)
    except Exception as exc:  # noqa: BLE001 - the episode's own result stands
        row["error"] = f"diagnosis failed: {type(exc).__name__}: {exc}"


def _result_columns(result: EpisodeResult, error: str) -> dict[str, Any]:
    """The row's columns from the episode's summary (`error`: what the row already says)."""
    summary = result.summary
    extra = summary.extra
    return dict(
        outcome=summary.outcome,
        converged=summary.outcome == "converged",
        steps=summary.steps,
        steps_to_converge=summary.steps_to_converge,
        final_pixel_error=summary.final_pixel_error,
        final_T1=summary.final_T1,
        path_length=extra.get("path_length"),
        rotation_length=extra.get("rotation_length"),
        smoothness=extra.get("smoothness"),
        saturated_steps=extra.get("saturated_steps"),
        clipped_steps=extra.get("clipped_steps"),
        probe_steps=extra.get("probe_steps"),
        **{k: extra.get(k) for k in METRIC_COLUMNS},
        jacobian_error_median=extra.get("jacobian_error_median"),
        jacobian_error_final=extra.get("jacobian_error_final"),
        diagnosis=extra.get("diagnosis"),
        wall_time_s=summary.wall_time_s,
        error=f"interrupted by {stop_reason() or 'SIGINT'}"
        if summary.outcome == Outcome.INTERRUPTED
        else error,
    )
