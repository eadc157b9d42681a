"""`rodctl compare`: the paper's comparison (Chen, section VI) turned into a reproducible benchmark.

The paper claims that its framework (autoencoder + AKF + MFAC) converges fastest, Ma et al. 2022
second and Aghajanzadeh et al. 2022 slowest but smoothest, and shows only curves of one run. Here
every method runs the same K reachable targets from the same start, under the same speed limits,
step budget, probing budget and success criterion (the mean pixel distance to the target's
extracted 100-point centerline, the one measure every feature can be judged by), and the outcome
of every episode is written down: converged, stalled, step limit or diverged.

Fairness is structural: `CompareConfig` lets a method choose only its feature, estimator and
controller; everything else comes from one shared `base` experiment. Each target has its own
seed (camera noise), shared by all methods, so two methods on one target differ only by method.

Episodes are independent, so an executor (`rodctl.executors`: this process, a spawn pool, Ray)
runs them, one BLAS/torch thread each; results depend neither on the number of workers nor on
the executor. Each row is appended to results.jsonl the moment its episode finishes, so a run
stopped by SIGINT/SIGTERM (or killed) keeps them and `--resume` finishes it.
Outputs, in one new folder: results.csv / results.json (one row per episode), summary.md (the
table also printed to the terminal, and the paired comparison with the reference), targets.yaml
(the target poses, reusable as a `targets.file`), figures/ (the paper's three figures side by
side for one target, success rate and steps against target difficulty), statistics.json and
report.html (`rodctl.report`) and, if asked, every episode's logs under episodes/.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from pydantic import ValidationError

from rodctl import journal
from rodctl.config import ExperimentConfig, dump_config
from rodctl.config.compare import (
    CompareConfig,
    CompareTargetsConfig,
    MethodConfig,
    check_pose_lengths,
    pose_kind,
)
from rodctl.config.loading import (
    ConfigError,
    config_source,
    format_validation_error,
    load_config,
)
from rodctl.episode import Outcome
from rodctl.errors import RunFailed, UserError, describe_os_error
from rodctl.executors.base import (
    Executor,
    clear_stop,
    make_executor,
    request_stop,
    stop_handlers,
    stop_reason,
)
from rodctl.executors.local import CANCELLED
from rodctl.registry import component_provenance
from rodctl.report import markdown_table
from rodctl.runs import RunDir, jsonable, seed_sequence, write_json_atomic

#: Episode outcomes, in the order the summary lists them ("error": the episode raised); a
#: comparison's episodes are closed-loop (never "completed") and none counts as "interrupted".
OUTCOMES = tuple(o.value for o in Outcome if o not in (Outcome.COMPLETED, Outcome.INTERRUPTED))

#: Columns of results.csv, in order.
CSV_COLUMNS = (
    "scenario",
    "seed",
    "method",
    "target",
    "band",
    "difficulty",
    "target_x",
    "target_y",
    "target_theta",
    "outcome",
    "converged",
    "steps",
    "steps_to_converge",
    "final_pixel_error",
    "final_T1",
    "path_length",
    "rotation_length",
    "smoothness",
    "saturated_steps",
    "clipped_steps",
    "probe_steps",
    "pose_steps",
    "excess_steps",
    "smoothness_translation",
    "smoothness_rotation",
    "near_origin_steps",
    "event_peak_error",
    "event_steps_to_converge",
    "finished_before_event",
    "jacobian_error_median",
    "jacobian_error_final",
    "diagnosis",
    "wall_time_s",
    "error",
)

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

#: Candidate poses tried per sampled target before giving up (a candidate can fail to settle).
_TARGET_TRIES = 20


# --- config -----------------------------------------------------------------------------------


def load_compare_config(path: str | Path, overrides: Sequence[str] | None = None) -> CompareConfig:
    """Load a compare config: YAML -> `--set` overrides -> validation, every method checked.

    Each method is validated as the full `ExperimentConfig` it will run (base + its three
    stages), so a method that cannot run (e.g. an offline Jacobian on a feature that does not
    observe its nodes) fails here, named by its dotted path.

    Raises:
        ConfigError: (a `UserError`) naming the file and the offending dotted key.
    """
    cfg = load_config(path, overrides, model=CompareConfig)
    source = config_source(path, overrides)
    for name in cfg.methods:
        method_config(cfg, name, source=source)
    return cfg


class MethodsSpec(Protocol):
    """What `method_config` reads of a compare, sweep or suite config."""

    @property
    def base(self) -> ExperimentConfig: ...

    @property
    def methods(self) -> Mapping[str, MethodConfig] | None: ...


class TargetSpec(Protocol):
    """What target making reads of a compare config (a sweep gives one per seed)."""

    @property
    def seed(self) -> int: ...

    @property
    def base(self) -> ExperimentConfig: ...

    @property
    def targets(self) -> CompareTargetsConfig: ...


def method_config(
    cfg: MethodsSpec, name: str, *, source: str = "compare config"
) -> ExperimentConfig:
    """The `ExperimentConfig` of one method: the shared base with the method's three stages.

    Raises:
        ConfigError: the combination does not validate (names `methods.<name>`).
    """
    assert cfg.methods is not None, "method_config needs a config with methods"
    method = cfg.methods[name]
    data = cfg.base.model_dump(mode="json")
    data.update(
        name=name,
        feature=method.feature.model_dump(mode="json"),
        estimator=method.estimator.model_dump(mode="json"),
        controller=method.controller.model_dump(mode="json"),
    )
    try:
        return ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, data, f"{source}: methods.{name}")) from None


# --- targets ----------------------------------------------------------------------------------


@dataclass
class CompareTarget:
    """One shared target: the gripper pose that makes it and how hard it is.

    Attributes:
        index: position in the target set (targets are numbered easy to hard when sampled).
        pose: (3,) gripper pose [x, y, theta], world frame, as the rod settled there (rod.arms:
            2: (6,), the gripper's pose then the x0 end's).
        difficulty: normalised distance of `pose` from the home pose (`rodctl.targets`).
        seed: the experiment seed of every episode on this target (camera noise).
        view: what the clean camera saw there, {"centerline": (M, 2) m, "pixels": (N, 2) px}:
            every method's episode reuses it instead of driving a rod to the target again
            (the same rod and camera made it; `_settle_target`). None: each episode makes it.
    """

    index: int
    pose: np.ndarray
    difficulty: float
    seed: int
    view: dict[str, Any] | None = None

    def band(self, edges: Sequence[float]) -> str:
        """The difficulty band's name: easy / medium / hard for two edges, else band0..bandN."""
        i = int(np.searchsorted(np.asarray(edges, dtype=float), self.difficulty, side="right"))
        names = ("easy", "medium", "hard") if len(edges) == 2 else None
        return names[i] if names else f"band{i}"


def _target_seeds(seed: int, k: int) -> list[int]:
    """(k,) per-target experiment seeds from the 'compare' stream."""
    state = seed_sequence(seed, "compare").generate_state(k, dtype=np.uint32)
    return [int(v) for v in state]


def read_target_file(path: str | Path, arms: int = 1) -> list[list[float]]:
    """Gripper poses from a YAML/JSON file: a list of [x, y, theta], or {targets: [...]}.

    `arms`: the rod's `rod.arms`; with 2 every pose holds 6 values, both ends' poses (the
    gripper's, then the x0 end's), and 3-value poses are refused (`check_pose_lengths`).

    Raises:
        ConfigError: missing file, not YAML, or not a non-empty list of 3-number (rod.arms: 2:
            6-number) poses.
    """
    from rodctl.config.loading import parse_yaml, read_yaml_text

    path = Path(path)
    # The rules of config files: size, nesting, duplicate keys and alias bombs refused.
    data = parse_yaml(read_yaml_text(path, f"targets.file {path}"), f"targets.file {path}")
    if isinstance(data, dict) and "targets" in data:
        data = data["targets"]
    kind = pose_kind(arms)
    if not isinstance(data, list) or not data:
        raise ConfigError(f"targets.file {path}: expected a non-empty list of {kind}")
    from rodctl.config.compare import MAX_TARGETS

    if len(data) > MAX_TARGETS:
        raise ConfigError(
            f"targets.file {path}: {len(data)} poses, more than the {MAX_TARGETS} a compare takes"
        )
    poses = []
    for i, item in enumerate(data):
        ok = isinstance(item, list | tuple) and len(item) in (3, 6)
        ok = ok and all(isinstance(v, int | float) and math.isfinite(v) for v in item)
        if not ok:
            want = "[x, y, theta] (three" if arms == 1 else "6 values (six"
            raise ConfigError(
                f"targets.file {path}: item {i} is {item!r}; expected {want} finite numbers: "
                "metres, metres, radians" + (")" if arms == 1 else " for each end)")
            )
        poses.append([float(v) for v in item])
    check_pose_lengths(poses, arms, f"targets.file {path}", ConfigError)
    return poses


def _check_config(cfg: TargetSpec) -> ExperimentConfig:
    """The base with cheap stages: target checks need the rod and camera, not a method."""
    data = cfg.base.model_dump(mode="json")
    data.update(feature={"type": "nodes"}, estimator={"type": "akf"}, controller={"type": "mfac"})
    return ExperimentConfig.model_validate(data)


def _settle_target(task: dict[str, Any]) -> dict[str, Any]:
    """Worker: find a usable target (given pose, or sampled in its band) and settle it.

    A target is usable when the rod settles there and the camera extracts its centerline
    (`Experiment.make_target`). Returns {"pose", "difficulty"} or {"error"}.
    """
    from rodctl.env import ShapeServoEnv
    from rodctl.sim import RodSim
    from rodctl.targets import sample_target_pose

    cfg = ExperimentConfig.model_validate(task["config"])
    if task.get("pose") is not None:
        candidates: Iterable[np.ndarray] = [np.asarray(task["pose"], dtype=float)]
    else:
        gen = np.random.Generator(np.random.PCG64(task["seed_seq"]))
        sim = RodSim(cfg.rod)
        lo, hi = task["band"]
        home = sim.home_end_poses  # the gripper's (dual-arm: both ends', sampled in 6-D)

        def sample() -> Iterable[np.ndarray]:
            for _ in range(_TARGET_TRIES):
                yield sample_target_pose(
                    gen, home, cfg.rod.length, lambda p: not sim.clip_pose(p)[1], lo, hi
                )

        candidates = sample()
    why = "no candidate"
    for pose in candidates:
        try:
            target = ShapeServoEnv(cfg).make_target([float(v) for v in pose])
        except UserError as exc:
            why = str(exc)
            continue
        return {
            "pose": [float(v) for v in target.pose],
            "difficulty": float(target.difficulty),
            "view": {"centerline": target.centerline, "pixels": target.pixels},
        }
    return {"error": why}


def given_target_poses(cfg: TargetSpec, config_dir: Path) -> list[list[float]] | None:
    """The target poses from `targets.file` (relative to `config_dir`) or `targets.poses`."""
    tc = cfg.targets
    if tc.file is not None:
        path = Path(tc.file)
        return read_target_file(
            path if path.is_absolute() else config_dir / path, cfg.base.rod.arms
        )
    if tc.poses is not None:
        # A compare config checks this when it loads; a sweep's (same targets) here.
        check_pose_lengths(tc.poses, cfg.base.rod.arms, "targets.poses", ConfigError)
        return [list(p) for p in tc.poses]
    return None


def make_targets(
    cfg: TargetSpec,
    given: list[list[float]] | None,
    run_tasks: Callable[[list[dict], Callable[[dict], Any]], list[Any]],
) -> list[CompareTarget]:
    """The shared targets, checked reachable, numbered easy to hard when sampled.

    Sampled targets spread evenly over [min_offset, max_offset]: target i is drawn (uniform
    direction, `rodctl.targets.sample_target_pose`) in the i-th of K equal sub-bands, from its
    own child of the 'targets' seed stream, so the set does not depend on the worker count.

    Raises:
        UserError: a given target pose is unusable, or a sampled band has no usable pose.
    """
    tc = cfg.targets
    base = _check_config(cfg).model_dump(mode="json")
    tasks: list[dict[str, Any]]
    if given is not None:
        tasks = [{"config": base, "pose": p} for p in given]
    else:
        k = tc.count
        edges = np.linspace(tc.min_offset, tc.max_offset, k + 1)
        children = seed_sequence(cfg.seed, "targets").spawn(k)
        tasks = [
            {"config": base, "seed_seq": children[i], "band": (edges[i], edges[i + 1])}
            for i in range(k)
        ]
    results = run_tasks(tasks, _settle_target)
    seeds = _target_seeds(cfg.seed, len(tasks))
    targets = []
    for i, res in enumerate(results):
        if "error" in res:
            what = f"target {i} {given[i]}" if given is not None else f"sampled target {i}"
            raise UserError(f"{what} is unusable: {res['error']}")
        targets.append(
            CompareTarget(i, np.asarray(res["pose"]), res["difficulty"], seeds[i], res.get("view"))
        )
    return targets


# --- episodes ---------------------------------------------------------------------------------


def _episode(task: dict[str, Any]) -> dict[str, Any]:
    """Worker: one method on one target; returns its results row (and records if asked)."""
    from rodctl.env import ShapeServoEnv
    from rodctl.episode import EpisodeFailed, run_episode
    from rodctl.method import Method

    cfg = ExperimentConfig.model_validate(task["config"])
    # The episode's own config says everything (seed, target), so its log replays alone.
    cfg.seed = task["seed"]
    cfg.run.target.pose = tuple(task["pose"])
    # The shared target as the clean camera saw it, when this episode's rod and camera made it:
    # the same Target the episode would make by driving a rod there again (issue #17).
    view = task.get("target_view")
    options = None
    if view is not None:
        from rodctl.env import Target

        target = Target(
            pose=np.asarray(task["pose"], dtype=float),
            centerline=np.asarray(view["centerline"], dtype=float),
            pixels=np.asarray(view["pixels"], dtype=float),
            difficulty=float(task["target_difficulty"]),
        )
        options = {"target": target}
    run_id = task.get("run_id") or f"{task['method']}_t{task['target']:03d}"
    row: dict[str, Any] = _task_tags(task)
    log_dir = Path(task["log_dir"]) if task.get("log_dir") else None
    result = None
    try:
        sinks: list[Any] = []
        if log_dir is not None:
            from rodctl.simulate import make_sinks

            log_dir.mkdir(parents=True, exist_ok=True)
            (log_dir / "config.yaml").write_text(dump_config(cfg), encoding="utf-8")
            sinks = make_sinks(cfg, log_dir)
        env = ShapeServoEnv(cfg)
        result = run_episode(
            env,
            Method.from_config(cfg),
            sinks=sinks,
            run_id=run_id,
            options=options,
            # SIGINT/SIGTERM of this process (or Ray's cancel) end it whole, between two steps.
            stop_requested=stop_reason,
        )
    except Exception as exc:  # noqa: BLE001 - one bad episode must not end the benchmark
        failed = exc.result if isinstance(exc, EpisodeFailed) else None
        row.update(
            outcome="error", error=failed.error if failed else f"{type(exc).__name__}: {exc}"
        )
        if log_dir is not None:
            text = failed.traceback if failed else traceback.format_exc()
            (log_dir / "error.txt").write_text(text or "", encoding="utf-8")
    if result is not None:
        summary = result.summary
        extra = summary.extra
        if task.get("diagnose") and summary.outcome in ("stalled", "pinned"):
            # Why it failed, from its final state, with the simulator's model (rodctl.diagnosis).
            from rodctl.diagnosis import diagnose

            try:
                extra["diagnosis"] = diagnose(env, cfg, summary.outcome)
            except Exception as exc:  # noqa: BLE001 - the episode's own result stands
                row["error"] = f"diagnosis failed: {type(exc).__name__}: {exc}"
        row.update(
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
            else row.get("error", ""),
        )
        if log_dir is not None:
            write_json_atomic(log_dir / "summary.json", summary.to_json())
        if task.get("want_records"):
            row["_records"] = (result.header, result.records)
    return row


# --- running episodes: executor, results written as they finish, resume, stop -----------------


class ResultsLog:
    """results.jsonl: one JSON line per finished episode, appended and fsync'ed at once.

    The crash-safe record of a run: whatever stops it (SIGKILL, power loss), every episode that
    finished is on disk, and `--resume` reads them back. A line cut by a crash is ignored.
    One final row per episode key (`rodctl.journal`): a final row for a key that already has
    one is not written again, and `read` dedupes (the last final row per key wins).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._final: dict[tuple, dict[str, Any]] | None = None
        self._tail_checked = False

    def append(self, row: dict[str, Any]) -> dict[str, Any]:
        """Write `row`; returns the journal's row for its episode (an earlier final row of the
        same key, which stays the record, with `row`'s in-memory `_` fields)."""
        if self._final is None:
            self._final = {_row_key(r): r for r in self.read() if journal.is_final(r)}
        clean = {k: v for k, v in row.items() if not k.startswith("_")}
        key = _row_key(row)
        if journal.is_final(row) and key in self._final:
            return {**self._final[key], **{k: v for k, v in row.items() if k.startswith("_")}}
        line = json.dumps(jsonable(clean))
        with self.path.open("a", encoding="utf-8") as fh:
            if not self._tail_checked and fh.tell() > 0 and not self._ends_with_newline():
                fh.write("\n")  # after a line a crash cut: this row must not be glued to it
            self._tail_checked = True
            fh.write(line + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        if journal.is_final(row):
            self._final[key] = json.loads(line)
        return row

    def _ends_with_newline(self) -> bool:
        with self.path.open("rb") as fh:
            fh.seek(-1, os.SEEK_END)
            return fh.read(1) == b"\n"

    def _read_all(self) -> list[dict[str, Any]]:
        if not self.path.is_file():
            return []
        rows = []
        for line in self.path.read_text(encoding="utf-8").splitlines():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return rows

    def read(self) -> list[dict[str, Any]]:
        """Every whole row written so far (a torn last line is skipped), one per episode key."""
        return journal.dedupe(self._read_all(), _row_key)

    def compact(self) -> None:
        """Drop the rows later ones superseded (an interrupted episode run again to its end)."""
        try:
            journal.compact(self.path, self._read_all(), _row_key)
        except OSError:
            pass  # left as it is: every reader dedupes the same way


class RunInterrupted(Exception):
    """SIGINT/SIGTERM stopped a run; its folder holds every finished episode, marked partial."""

    def __init__(
        self, folder: Path, reason: str, done: int, total: int, unit: str = "episodes"
    ) -> None:
        super().__init__(f"interrupted by {reason}: {done} of {total} {unit} finished")
        self.folder = folder
        self.reason = reason
        self.done = done


def config_hash(data: Any) -> str:
    """sha256 of a resolved config (canonical JSON): what `--resume` requires unchanged."""
    text = json.dumps(jsonable(data), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _dotted_diff(old: Any, new: Any, prefix: str = "") -> list[str]:
    """The dotted keys whose values differ between two plain-data configs."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new), key=str):
            out += _dotted_diff(old.get(k), new.get(k), f"{prefix}{k}.")
        return out
    return [] if old == new else [prefix.rstrip(".") or "(whole config)"]


def open_resumed_run(folder: str | Path, command: str, hashed: dict[str, Any]) -> RunDir:
    """Reopen `folder` (a run of `command`) to finish it; its config must hash the same.

    Raises:
        UserError: not a run folder of that command, or the config changed (names the keys).
    """
    path = Path(folder)
    meta_path = path / "meta.json"
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise UserError(f"--resume {path}: not a run folder ({meta_path}: {exc})") from None
    if meta.get("command") != command:
        raise UserError(
            f"--resume {path}: a run of `rodctl {meta.get('command')}`, not `rodctl {command}`"
        )
    old = meta.get("resume", {}).get("hashed")
    if old is None:
        raise UserError(f"--resume {path}: meta.json has no config hash to check against")
    if config_hash(old) != config_hash(hashed):
        changed = [
            c.removeprefix("config.") if c != "targets" else "the targets file's poses"
            for c in _dotted_diff(jsonable(old), jsonable(hashed))
        ]
        raise UserError(
            f"--resume {path}: the config changed since that run (resume needs the same "
            f"config; workers and executor may differ): {', '.join(changed[:10])}"
            + (f" and {len(changed) - 10} more" if len(changed) > 10 else "")
        )
    journal.lock_run_folder(path, command)  # held until run.finish; refused if in use
    run = RunDir(path=path, meta=meta)
    run.meta.update(status="running", ended_at=None)
    run.meta.pop("error", None)
    run.meta.setdefault("resumed", []).append({"argv": list(sys.argv)})
    run.write_meta()
    return run


def start_run(
    out: str,
    cfg: Any,
    command: str,
    hashed: dict[str, Any],
    resume: str | None,
    executor: str | None = None,
) -> RunDir:
    """A new run folder (config hash in meta.json; `executor`: the `--executor` kind, its
    factory recorded as the run's `executor`), or the `--resume` one reopened."""
    if resume is not None:
        return open_resumed_run(resume, command, hashed)
    run = RunDir.create(out, cfg, command=command)
    journal.lock_run_folder(run.path, command)  # held until run.finish
    run.meta["resume"] = {"config_hash": config_hash(hashed), "hashed": jsonable(hashed)}
    if executor is not None:
        run.meta.update(component_provenance(None, executor))
    run.write_meta()
    return run


def run_tasks(
    executor: Executor, tasks: list[dict], fn: Callable[[dict], Any], label: str, progress: bool
) -> list[Any]:
    """fn(task) for every task on the executor, results in task order.

    Raises:
        KeyboardInterrupt: a stop was requested before every task finished.
        UserError: a task could not be run (its worker was lost every time).
    """
    from rodctl.display import task_progress

    with task_progress(label, len(tasks), progress) as advance:
        done = executor.map(fn, tasks, on_done=lambda _d: advance())
    if stop_reason() is not None:
        raise KeyboardInterrupt(stop_reason())
    for d in done:
        if d.error is not None:
            raise UserError(f"{label} task {d.key}: {d.error}")
    return [d.value for d in done]


def stream_episodes(
    executor: Executor,
    tasks: list[dict[str, Any]],
    log: ResultsLog,
    *,
    progress: bool,
    done_before: int = 0,
    label: str = "episodes",
) -> list[dict[str, Any] | None]:
    """Run the episode tasks; every row is appended to `log` the moment it arrives.

    Returns the rows in task order, None for the tasks a stop left unrun. An episode that comes
    back `interrupted` (its worker got SIGINT/SIGTERM) stops the whole run, as a signal to the
    parent does. A task whose worker was lost every time is an `error` row.
    """
    from rodctl.display import task_progress

    rows: list[dict[str, Any] | None] = [None] * len(tasks)

    def describe(row: dict[str, Any]) -> str:
        return f"{row.get('method', '')}: {row['outcome']}"

    for i, task in enumerate(tasks):
        executor.submit(_episode, task, i)
    total = len(tasks) + done_before
    with task_progress(label, total, progress, rate="episodes", completed=done_before) as advance:
        for done in executor.results():
            task = tasks[done.key]
            if done.error == CANCELLED:
                continue
            if done.error is not None:
                row = {**_task_tags(task), "outcome": "error", "error": done.error}
            else:
                row = done.value
            if row["outcome"] == Outcome.INTERRUPTED:
                # The row says "interrupted by SIGTERM"; the stop reason is the signal alone.
                why = str(row.get("error") or "").removeprefix("interrupted by ")
                request_stop(why or "a worker was stopped")
            row = log.append(row)  # an episode's first final row stays its record
            rows[done.key] = row
            advance(describe(row))
    return rows


def _task_tags(task: dict[str, Any]) -> dict[str, Any]:
    """The identifying columns of a task's row (method, target, and a sweep's tags), and a
    compare's target columns."""
    tags = {"method": task["method"], "target": task["target"], **task.get("tags", {})}
    return {**tags, **task.get("columns", {})}


# --- statistics -------------------------------------------------------------------------------


def _quantiles(values: Sequence[float]) -> tuple[float | None, float | None, float | None]:
    """(q25, median, q75) of the values, or Nones when there are none."""
    if not values:
        return None, None, None
    q = np.percentile(np.asarray(values, dtype=float), [25, 50, 75])
    return float(q[0]), float(q[1]), float(q[2])


def summarize(rows: Sequence[dict[str, Any]], methods: Sequence[str], bands: Sequence[str]) -> dict:
    """Per-method statistics over the episodes.

    Steps to converge are taken over converged episodes only; `paired_*` restricts them to the
    targets every method converged on, the fair basis for "who converges fastest". Smoothness
    (summed ||u_k - u_{k-1}||) and path length are over converged episodes too, since a run that
    wanders until the step limit accumulates both without bound.
    """
    by_target: dict[int, set[str]] = {}
    for r in rows:
        if r["outcome"] == "converged":
            by_target.setdefault(r["target"], set()).add(r["method"])
    common = {t for t, ms in by_target.items() if set(methods) <= ms}
    out: dict[str, Any] = {"common_targets": len(common), "methods": {}}
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        conv = [r for r in mine if r["outcome"] == "converged"]
        q25, med, q75 = _quantiles([r["steps_to_converge"] for r in conv])
        p25, pmed, p75 = _quantiles([r["steps_to_converge"] for r in conv if r["target"] in common])
        stats: dict[str, Any] = {
            "episodes": len(mine),
            "converged": len(conv),
            "success_rate": len(conv) / len(mine) if mine else None,
            "outcomes": {o: sum(r["outcome"] == o for r in mine) for o in OUTCOMES},
            "steps_median": med,
            "steps_q25": q25,
            "steps_q75": q75,
            "paired_steps_median": pmed,
            "paired_steps_q25": p25,
            "paired_steps_q75": p75,
            "smoothness_median": _quantiles([r["smoothness"] for r in conv])[1],
            "path_length_median": _quantiles([r["path_length"] for r in conv])[1],
            "final_pixel_error_median": _quantiles(
                [r["final_pixel_error"] for r in mine if r.get("final_pixel_error") is not None]
            )[1],
            "bands": {},
        }
        for b in bands:
            rb = [r for r in mine if r["band"] == b]
            cb = [r for r in rb if r["outcome"] == "converged"]
            stats["bands"][b] = {
                "episodes": len(rb),
                "success_rate": len(cb) / len(rb) if rb else None,
                "steps_median": _quantiles([r["steps_to_converge"] for r in cb])[1],
            }
        out["methods"][m] = stats
    return out


def _fmt(v: Any, spec: str = ".0f") -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def summary_rows(summary: dict, bands: Sequence[str]) -> tuple[list[str], list[list[str]]]:
    """The summary table as a header and string rows (shared by the terminal and summary.md).

    Band cells read "success % / median steps"; the last column counts stalled / pinned /
    step-limit / failed (diverged, lost the rod, raised) episodes.
    """
    header = [
        "method",
        "success",
        "steps [IQR]",
        "paired steps",
        "smooth.",
        "path m",
        "final px",
        *bands,
        "stall/pin/limit/fail",
    ]
    lines = []
    for m, s in summary["methods"].items():
        rate = s["success_rate"]
        o = s["outcomes"]
        lines.append(
            [
                m,
                f"{s['converged']}/{s['episodes']} ({_fmt(None if rate is None else 100 * rate)}%)",
                f"{_fmt(s['steps_median'])} [{_fmt(s['steps_q25'])}-{_fmt(s['steps_q75'])}]",
                f"{_fmt(s['paired_steps_median'])} [{_fmt(s['paired_steps_q25'])}-"
                f"{_fmt(s['paired_steps_q75'])}]",
                _fmt(s["smoothness_median"], ".3f"),
                _fmt(s["path_length_median"], ".3f"),
                _fmt(s["final_pixel_error_median"], ".2f"),
                *[
                    f"{_fmt(None if bs['success_rate'] is None else 100 * bs['success_rate'])}% / "
                    f"{_fmt(bs['steps_median'])}"
                    for bs in (s["bands"][b] for b in bands)
                ],
                f"{o['stalled']}/{o.get('pinned', 0)}/{o['step_limit']}/"
                f"{o['diverged'] + o['lost_tracking'] + o['error']}",
            ]
        )
    return header, lines


# --- figures ----------------------------------------------------------------------------------


def success_figure(rows: Sequence[dict], methods: Sequence[str], path: Path, bins: int = 5) -> Path:
    """Success rate and median steps to converge against target difficulty, one line per method.

    Methods differ by colour, line style and marker (`rodctl.plots.style`), and each method's
    points are shifted sideways by a small, fixed amount, so two methods with the same value
    (every method at 100 %) stay visible side by side instead of hiding each other."""
    from rodctl.plots import DPI

    fig = success_axes(rows, methods, bins)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    return path


def success_axes(rows: Sequence[dict], methods: Sequence[str], bins: int = 5) -> Any:
    """The matplotlib Figure of `success_figure`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from rodctl.plots import style

    d = np.array([r["difficulty"] for r in rows], dtype=float)
    edges = np.linspace(d.min(), d.max() + 1e-9, bins + 1)
    mid = 0.5 * (edges[:-1] + edges[1:])
    span = float(d.max() - d.min()) or 0.1
    fig = Figure(figsize=(6.4, 5.6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for i, m in enumerate(methods):
        rate, steps = [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            rb = [r for r in rows if r["method"] == m and lo <= r["difficulty"] < hi]
            cb = [r["steps_to_converge"] for r in rb if r["outcome"] == "converged"]
            rate.append(100 * len(cb) / len(rb) if rb else np.nan)
            steps.append(np.median(cb) if cb else np.nan)
        x = mid + (i - (len(methods) - 1) / 2) * 0.012 * span
        st = style(i) | {"markersize": 6}
        ax1.plot(x, rate, label=m, **st)
        ax2.plot(x, steps, label=m, **st)
    ax1.set_ylabel("success rate (%)")
    ax1.set_ylim(-5, 105)
    ax2.set_ylabel("median steps to converge")
    ax2.set_xlabel("target difficulty (normalised offset from home)")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    ax1.legend(fontsize=8)
    fig.suptitle("Success and speed against target difficulty")
    FigureCanvasAgg(fig)
    return fig


# --- the command ------------------------------------------------------------------------------


def _preflight(cfg: CompareConfig) -> dict[str, ExperimentConfig]:
    """Every method's config, each built once here so a missing checkpoint, or one trained for
    another rod or camera, fails before work (and `checkpoint: auto` trains here, once)."""
    from rodctl.features import make_feature_map
    from rodctl.training import prepare_feature

    configs = {name: method_config(cfg, name) for name in cfg.methods}
    for ecfg in configs.values():
        prepare_feature(ecfg)
        make_feature_map(ecfg.feature, points=ecfg.camera.points, experiment=ecfg)
    return configs


def run_compare(
    config_path: str,
    overrides: list[str],
    out: str,
    *,
    progress: bool,
    workers: int | None,
    executor: str = "local",
    address: str | None = None,
    resume: str | None = None,
    on_start: Callable[[Path], None] | None = None,
) -> Path:
    """Run the benchmark of `config_path` into a new folder under `out`; return that folder.

    Args:
        config_path: the compare config (YAML).
        overrides: `--set a.b=v` overrides, applied to the compare config (e.g.
            `methods.ours.controller.weights=[...]`, `targets.count=10`, `base.run.max_steps=100`).
        out: parent folder of the output folder.
        progress: show progress bars and print the summary table (stderr).
        workers: worker processes (Ray: CPUs of a Ray started for the run); None: the config's
            `workers`, else one per CPU core.
        executor: "local" (this process or a spawn pool) or "ray".
        address: an existing Ray cluster to run on (executor "ray").
        resume: an earlier run folder of the same config: its finished episodes are kept and
            only the others run, into that folder.
        on_start: called with the run's folder as soon as it exists (a suite records it, so
            that `--resume` continues this folder even after the process was killed).

    Returns:
        The output folder (holding results.jsonl/csv/json, summary.md, targets.yaml, figures/).

    Raises:
        UserError: bad config, target file or target; a method that cannot be built; a
            `resume` folder whose config differs.
        RunInterrupted: SIGINT/SIGTERM stopped the run; every finished episode is written
            (results marked partial) and meta.json says `interrupted`.
    """
    wall0 = time.perf_counter()
    cfg = load_compare_config(config_path, overrides)
    configs = _preflight(cfg)
    given = given_target_poses(cfg, Path(config_path).resolve().parent)
    n_workers = workers or cfg.workers or os.cpu_count() or 1
    if n_workers < 1:
        raise UserError(f"--workers must be >= 1, got {n_workers}")
    pool = make_executor(executor, n_workers, address)
    hashed = {"config": cfg.model_dump(mode="json", exclude={"workers"}), "targets": given}
    run = start_run(out, cfg, "compare", hashed, resume, executor)
    if on_start is not None:
        on_start(run.path)
    log = ResultsLog(run.path / "results.jsonl")
    status, reason, rows, total = "failed", None, [], 0
    failure: str | None = None
    try:
        # Handlers before the executor starts (a signal during start-up counts) and again
        # after it: ray.init replaces SIGTERM's handler.
        with stop_handlers(), pool, stop_handlers():
            targets = make_targets(
                cfg, given, lambda tasks, fn: run_tasks(pool, tasks, fn, "targets", progress)
            )
            write_targets(targets, run.path / "targets.yaml")
            fig_target = _figure_target(cfg, targets)
            tasks = _episode_tasks(cfg, configs, targets, fig_target, run.path)
            total = len(tasks)
            kept = finished_rows(log, tasks, rerun=lambda t: t["want_records"])
            todo = [t for t in tasks if _row_key(t) not in kept]
            new = stream_episodes(pool, todo, log, progress=progress, done_before=len(kept))
            reason = stop_reason()
        got = {_row_key(r): r for r in new if r is not None and r["outcome"] != "interrupted"}
        found = [kept.get(_row_key(t)) or got.get(_row_key(t)) for t in tasks]
        rows = [r for r in found if r is not None]
        partial = len(rows) < total
        _report(cfg, run.path, targets, rows, fig_target, wall0, pool, progress, partial)
        status = "interrupted" if reason else "completed"
        if reason:
            raise RunInterrupted(run.path, reason, len(rows), total)
        return run.path
    except KeyboardInterrupt as exc:
        status, reason = "interrupted", str(exc) or "SIGINT"
        raise RunInterrupted(run.path, reason, len(rows), total) from None
    except Exception as exc:
        failure = failure_reason(exc, run.path)
        if isinstance(exc, OSError):  # a full or read-only disk: one line, exit 1
            raise RunFailed(failure) from None
        raise
    finally:
        log.compact()
        extra = {"episodes": {"finished": len(rows), "total": total}}
        why = f"interrupted by {reason}" if reason else failure
        run.finish(status, **({"error": why} if why else {}), **extra)
        clear_stop()


def failure_reason(exc: BaseException, folder: Path) -> str:
    """One line saying why a compare or sweep failed, for the terminal and meta.json: an OS
    error with its path (the run folder when the library writing did not say which file)."""
    if isinstance(exc, OSError):
        if exc.filename is None:
            return f"{exc.strerror or exc}: while writing in {folder}"
        return describe_os_error(exc)
    return str(exc) if isinstance(exc, UserError) else f"{type(exc).__name__}: {exc}"


def _row_key(item: dict[str, Any]) -> tuple:
    """What identifies an episode (a task or its row) across runs: method, target and, in a
    sweep, its point and seed (a task carries them in `tags`, a row as columns)."""
    tags = item.get("tags", item)
    sweep = (tags["point"], tags["seed"]) if "point" in tags else (None, None)
    return (item["method"], item["target"], *sweep)


def finished_rows(
    log: ResultsLog, tasks: Sequence[dict[str, Any]], rerun: Callable[[dict], bool]
) -> dict[tuple, dict[str, Any]]:
    """The rows of `log` (an earlier, interrupted run) that `--resume` keeps, by episode key.

    An episode counts as finished whatever its outcome except `interrupted`. Tasks for which
    `rerun` is true run again anyway (the figure target: its records are not in the log).
    """
    wanted = {_row_key(t) for t in tasks if not rerun(t)}
    out = {}
    for row in log.read():
        key = _row_key(row)
        if key in wanted and row.get("outcome") != "interrupted":
            out[key] = row
    return out


def _episode_tasks(
    cfg: CompareConfig,
    configs: dict[str, ExperimentConfig],
    targets: Sequence[CompareTarget],
    fig_target: int,
    folder: Path,
) -> list[dict[str, Any]]:
    """One task per (target, method), target-major: partial progress covers every method."""
    tasks = []
    for t in targets:
        for name, ecfg in configs.items():
            log_dir = folder / "episodes" / name / f"t{t.index:03d}" if cfg.keep_logs else None
            tasks.append(
                {
                    "config": ecfg.model_dump(mode="json"),
                    "method": name,
                    "target": t.index,
                    "pose": [float(v) for v in t.pose],
                    # Every method shares the base's rod and camera: the target made once.
                    "target_view": t.view,
                    "target_difficulty": t.difficulty,
                    "seed": t.seed,
                    "want_records": t.index == fig_target,
                    "log_dir": str(log_dir) if log_dir else None,
                    # A stalled or pinned episode is examined for why (rodctl.diagnosis).
                    "diagnose": True,
                    # results.jsonl carries every column of results.csv (`_report` sets the same)
                    "columns": {
                        "scenario": cfg.scenario,
                        "seed": cfg.seed,
                        "band": t.band(cfg.targets.bands),
                        "difficulty": round(t.difficulty, 6),
                        "target_x": float(t.pose[0]),
                        "target_y": float(t.pose[1]),
                        "target_theta": float(t.pose[2]),
                        "converged": False,
                    },
                }
            )
    return tasks


def _report(
    cfg: CompareConfig,
    folder: Path,
    targets: Sequence[CompareTarget],
    rows: list[dict[str, Any]],
    fig_target: int,
    wall0: float,
    pool: Executor,
    progress: bool,
    partial: bool = False,
) -> None:
    """results.csv/json, summary.md, figures, and the table on the terminal.

    `partial`: the run was stopped; the tables hold the episodes that finished and say so.
    """
    bands = _band_names(cfg)
    records = {r["method"]: r.pop("_records") for r in rows if "_records" in r}
    by_index = {t.index: t for t in targets}
    for r in rows:
        t = by_index[r["target"]]
        r.update(
            scenario=cfg.scenario,
            seed=cfg.seed,
            band=t.band(cfg.targets.bands),
            difficulty=round(t.difficulty, 6),
            target_x=float(t.pose[0]),
            target_y=float(t.pose[1]),
            target_theta=float(t.pose[2]),
            converged=r["outcome"] == "converged",
        )
    summary = summarize(rows, list(cfg.methods), bands)
    wall = time.perf_counter() - wall0
    n_workers = pool.workers
    write_results(
        folder,
        cfg,
        targets,
        rows,
        summary,
        wall,
        n_workers,
        partial=partial,
        executor=pool.name,
        figure_target=fig_target,
    )
    header, lines = summary_rows(summary, bands)
    write_summary_md(
        folder / "summary.md", cfg, header, lines, summary, wall, n_workers, fig_target
    )
    if partial:
        md = folder / "summary.md"
        expected = len(targets) * len(cfg.methods)
        note = (
            f"**PARTIAL**: the run was interrupted; {len(rows)} of {expected} episodes finished "
            "and are counted here. `rodctl compare CONFIG --resume FOLDER` finishes it.\n\n"
        )
        md.write_text(note + md.read_text(encoding="utf-8"), encoding="utf-8")
    if rows:
        _write_figures(folder / "figures", records, rows, list(cfg.methods))
    from rodctl.comparisons import write_compare_report

    write_compare_report(folder, cfg, rows)
    if progress:
        title = f"{cfg.name}: {len(targets)} targets, {wall:.0f} s"
        _print_table(summary, title + (" (PARTIAL)" if partial else ""))


def _band_names(cfg: CompareConfig) -> list[str]:
    n = len(cfg.targets.bands) + 1
    return ["easy", "medium", "hard"] if n == 3 else [f"band{i}" for i in range(n)]


def _figure_target(cfg: CompareConfig, targets: Sequence[CompareTarget]) -> int:
    """The target drawn side by side: the configured one, else the one of median difficulty."""
    if cfg.figure_target is not None:
        if cfg.figure_target >= len(targets):
            raise UserError(
                f"figure_target={cfg.figure_target}, but there are only {len(targets)} targets"
            )
        return cfg.figure_target
    order = sorted(targets, key=lambda t: t.difficulty)
    return order[(len(order) - 1) // 2].index


def write_targets(targets: Sequence[CompareTarget], path: Path) -> None:
    """targets.yaml: the poses (reusable as `targets.file`) with their difficulty as comments."""
    arms = len(targets[0].pose) // 3 if targets else 1
    lines = [f"# rodctl compare targets: {pose_kind(arms)} (world, m, rad)", "targets:"]
    for t in targets:
        pose = ", ".join(repr(float(v)) for v in t.pose)
        lines.append(f"  - [{pose}]  # {t.index}: difficulty {t.difficulty:.3f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_results(
    folder: Path,
    cfg: CompareConfig,
    targets: Sequence[CompareTarget],
    rows: Sequence[dict],
    summary: dict,
    wall: float,
    workers: int,
    *,
    partial: bool = False,
    executor: str = "local",
    figure_target: int | None = None,
) -> None:
    """results.csv (one row per episode) and results.json (rows, summary, targets, config).

    `partial`: an interrupted run; results.json says so (`"partial": true`).
    `figure_target`: the target the side-by-side figures show (their captions name it).
    """
    with (folder / "results.csv").open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_COLUMNS})
    data = {
        "name": cfg.name,
        "seed": cfg.seed,
        "wall_time_s": round(wall, 2),
        "workers": workers,
        "executor": executor,
        "partial": partial,
        "figure_target": figure_target,
        "targets": [
            {
                "index": t.index,
                "pose": [float(v) for v in t.pose],
                "difficulty": t.difficulty,
                "seed": t.seed,
            }
            for t in targets
        ],
        "summary": summary,
        "episodes": [{k: r.get(k) for k in CSV_COLUMNS} for r in rows],
        "config": cfg.model_dump(mode="json"),
    }
    write_json_atomic(folder / "results.json", data)


def write_summary_md(
    path: Path,
    cfg: CompareConfig,
    header: Sequence[str],
    lines: Sequence[Sequence[str]],
    summary: dict,
    wall: float,
    workers: int,
    fig_target: int,
) -> None:
    """summary.md: the table, what each method is, and how the benchmark was run."""
    run = cfg.base.run
    text = [
        f"# rodctl compare: {cfg.name}",
        "",
        f"{summary['methods'][next(iter(cfg.methods))]['episodes']} targets per method, seed "
        f"{cfg.seed}; step budget {run.max_steps} (probing included), success = mean pixel "
        f"error < {run.pixel_tolerance} px on the {cfg.base.camera.points}-point centerline; "
        f"speed limit {list(cfg.base.rod.max_step)} per step. Wall time {wall:.0f} s on "
        f"{workers} worker(s).",
        "",
        "Steps: steps to converge over converged episodes, median [IQR]; *paired*: only the "
        f"{summary['common_targets']} targets every method converged on. Smoothness: summed "
        "||u_k - u_{k-1}|| and path: summed ||(dx, dy)||, medians over converged episodes. "
        f"Band columns (difficulty edges {cfg.targets.bands}): success % / median steps. Last "
        "column: stalled / pinned / step limit / failed (diverged, lost the rod, error) episodes.",
        "",
        markdown_table(header, lines),
        "",
        "## Methods",
        "",
    ]
    for name, m in cfg.methods.items():
        text.append(
            f"- **{name}** ({m.feature.type} / {m.estimator.type} / {m.controller.type}): "
            f"{m.description}"
        )
    text += ["", f"Figures: figures/ (side-by-side figures for target {fig_target})."]
    path.write_text("\n".join(text) + "\n", encoding="utf-8")


def _write_figures(folder: Path, records: dict, rows: Sequence[dict], methods: list[str]) -> None:
    from rodctl.plots import write_comparison_figures

    ordered = {m: records[m] for m in methods if m in records}
    if ordered:
        write_comparison_figures(ordered, folder)
    success_figure(rows, methods, folder / "success_vs_difficulty.png")


def terminal_table(summary: dict, title: str) -> Any:
    """The summary as a rich table that fits 80 columns (the full table is in summary.md).

    Columns: success rate; median [IQR] steps to converge; paired median (targets every
    method converged on); median smoothness; median final pixel error; stalled / pinned /
    step-limit / failed episodes.
    """
    from rich import box
    from rich.table import Table

    table = Table(title=title, box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True)
    justifications: tuple[tuple[str, Literal["left", "right"]], ...] = (
        ("method", "left"),
        ("success", "right"),
        ("steps [IQR]", "right"),
        ("paired", "right"),
        ("smooth", "right"),
        ("px", "right"),
        ("st/pin/lim/fail", "right"),
    )
    for name, justify in justifications:
        table.add_column(name, justify=justify, no_wrap=True, min_width=len(name))
    for m, st in summary["methods"].items():
        rate = st["success_rate"]
        o = st["outcomes"]
        fails = o["diverged"] + o["lost_tracking"] + o["error"]
        table.add_row(
            m,
            f"{_fmt(None if rate is None else 100 * rate)}%",
            f"{_fmt(st['steps_median'])} [{_fmt(st['steps_q25'])}-{_fmt(st['steps_q75'])}]",
            _fmt(st["paired_steps_median"]),
            _fmt(st["smoothness_median"], ".3f"),
            _fmt(st["final_pixel_error_median"], ".2f"),
            f"{o['stalled']}/{o.get('pinned', 0)}/{o['step_limit']}/{fails}",
        )
    return table


def _print_table(summary: dict, title: str) -> None:
    from rodctl.display import stderr

    stderr.print(terminal_table(summary, title))
