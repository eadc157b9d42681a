"""The one skeleton every study runs on: `rodctl compare` and `rodctl sweep` are `Study`s.

A study plans its episode tasks (making its shared targets on the way) and reports on the rows;
`run_study` does the rest the same way for each: the run folder (new, or the `--resume` one with
its config checked unchanged), the executor (this process, a spawn pool or Ray), the journal
(every row appended to results.jsonl the moment its episode finishes; a resumed run keeps the
finished ones), the progress bars, and the stop: SIGINT/SIGTERM end the run between episodes,
the finished rows are reported as partial and `RunInterrupted` says how many there are.
meta.json ends `completed`, `interrupted` or `failed` (with why) whatever happens.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, TypeVar

from pydantic import BaseModel

from rodctl.bench.episodes import run_episode_task
from rodctl.bench.journal import ResultsLog, finished_rows, start_run
from rodctl.bench.tasks import EpisodeTask, row_key
from rodctl.display import task_progress
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
from rodctl.outcome import Outcome
from rodctl.runs import RunDir


class RunInterrupted(Exception):
    """SIGINT/SIGTERM stopped a run; its folder holds every finished episode, marked partial."""

    def __init__(
        self, folder: Path, reason: str, done: int, total: int, unit: str = "episodes"
    ) -> None:
        # total 0: stopped while planning, before the episodes were counted
        count = f"{done} of {total} {unit} finished" if total else f"before the {unit} started"
        super().__init__(f"interrupted by {reason}: {count}")
        self.folder = folder
        self.reason = reason
        self.done = done


class Study(Protocol):
    """What `run_study` needs of a compare or a sweep."""

    #: The command, as meta.json and `--resume` name it ("compare", "sweep").
    command: str
    #: When the run began (`time.perf_counter()`); `run_study` moves it back by a resumed run's
    #: earlier invocations (meta.json's `wall_s`), so its wall times count them too.
    wall0: float

    @property
    def config(self) -> Any:
        """The study's validated config (its `name` names the run folder)."""
        ...

    @property
    def hashed(self) -> dict[str, Any]:
        """What `--resume` requires unchanged (the config without `workers`, given targets)."""
        ...

    def plan(self, pool: Executor, folder: Path, progress: bool) -> list[EpisodeTask]:
        """The episode tasks, in the order they run (the shared targets made on `pool`)."""
        ...

    def report(
        self, folder: Path, rows: list[dict[str, Any]], total: int, pool: Executor, progress: bool
    ) -> None:
        """Write the outputs of the finished `rows` (of `total` episodes; fewer: partial)."""
        ...


_C = TypeVar("_C", bound=BaseModel)


def with_workers(cfg: _C, workers: int | None) -> _C:
    """`cfg` as the run uses it: `--workers` (`workers`, when given) replaces the config's, so
    that the folder's config.yaml says what ran, not what the file said."""
    return cfg if workers is None else cfg.model_copy(update={"workers": workers})


def make_pool(
    kind: str, workers: int | None, configured: int | None, address: str | None
) -> Executor:
    """The executor of a study: `workers` (the command line's), else the config's, else one per
    CPU core; `kind` "local" or "ray" (`address`: an existing Ray cluster).

    Raises:
        UserError: fewer than one worker, or an executor that cannot start.
    """
    n_workers = workers or configured or os.cpu_count() or 1
    if n_workers < 1:
        raise UserError(f"--workers must be >= 1, got {n_workers}")
    return make_executor(kind, n_workers, address)


def run_study(
    study: Study,
    out: str,
    pool: Executor,
    *,
    progress: bool,
    resume: str | None = None,
    on_start: Callable[[Path], None] | None = None,
    executor: str | None = None,
) -> Path:
    """Run `study` on `pool` into a new folder under `out` (or the `resume` folder); return it.

    `on_start`: called with the run's folder as soon as it exists. `executor`: the `--executor`
    kind `pool` was made from (its factory is recorded in meta.json as the run's `executor`).

    Raises:
        UserError: a `resume` folder of another command or config; whatever the study raises.
        RunInterrupted: SIGINT/SIGTERM stopped the run; the finished rows are reported.
        RunFailed: an OS error (a full or read-only disk), in one line.
    """
    run = _begin(study, out, resume, executor, on_start)
    log = ResultsLog(run.path / "results.jsonl")
    status, reason, rows, total = "failed", None, [], 0
    late: str | None = None
    failure: str | None = None
    bad_input = False
    try:
        # Handlers before the executor starts (a signal during start-up counts) and again
        # after it: ray.init replaces SIGTERM's handler.
        with stop_handlers(), pool, stop_handlers():
            tasks = study.plan(pool, run.path, progress)
            total = len(tasks)
            kept = finished_rows(log, tasks)
            todo = [t for t in tasks if t.key not in kept]
            new = stream_episodes(pool, todo, log, progress=progress, done_before=len(kept))
            reason = stop_reason()
        rows = _in_task_order(tasks, kept, new)
        reason, late = _report(study, run.path, rows, total, pool, progress, reason)
        status = "interrupted" if reason else "completed"
        if reason:
            raise RunInterrupted(run.path, reason, len(rows), total)
        return run.path
    except KeyboardInterrupt as exc:
        status, reason = "interrupted", str(exc) or "SIGINT"
        raise RunInterrupted(run.path, reason, len(rows), total) from None
    except Exception as exc:
        failure, bad_input = failure_reason(exc, run.path), isinstance(exc, UserError)
        if isinstance(exc, OSError):  # a full or read-only disk: one line, exit 1
            raise RunFailed(failure) from None
        raise
    finally:
        run.meta["wall_s"] = time.perf_counter() - study.wall0  # the report's time included
        with stop_handlers():  # a stop while meta.json is made final is late, not lost
            _finish(run, log, status, reason, failure, len(rows), total, late)
        if bad_input and resume is None and not rows:
            # Bad input found once the folder existed (an unreachable target): nothing ran,
            # so nothing is left, as for bad input found before (docs/reliability.md).
            run.discard_if_empty()


def _begin(
    study: Study,
    out: str,
    resume: str | None,
    executor: str | None,
    on_start: Callable[[Path], None] | None,
) -> RunDir:
    """The run's folder, made (or the `resume` one reopened, its earlier invocations' wall
    time added to the study's), and `on_start` told of it."""
    run = start_run(out, study.config, study.command, study.hashed, resume, executor)
    if resume is not None:  # what the earlier invocations took (0 before it was recorded)
        study.wall0 -= float(run.meta.get("wall_s") or 0.0)
    if on_start is not None:
        on_start(run.path)
    return run


def _report(
    study: Study,
    folder: Path,
    rows: list[dict[str, Any]],
    total: int,
    pool: Executor,
    progress: bool,
    reason: str | None,
) -> tuple[str | None, str | None]:
    """Write the study's report; (the stop that leaves the run interrupted, a late stop).

    A stop after the last episode, or during the report (seconds: it is let finish), leaves a
    whole run completed; late, it still ends a suite before its next scenario (`_finish`)."""
    late = None
    if total and len(rows) == total:
        late, reason = reason, None
    with stop_handlers():  # a stop meanwhile is taken as late by `_finish`
        study.report(folder, rows, total, pool, progress)
    return reason, late


def _in_task_order(
    tasks: list[EpisodeTask],
    kept: dict[tuple, dict[str, Any]],
    new: list[dict[str, Any] | None],
) -> list[dict[str, Any]]:
    """The finished rows (kept from an earlier run, or new), in the order of the tasks."""
    got = {row_key(r): r for r in new if r is not None and r["outcome"] != Outcome.INTERRUPTED}
    found = [kept.get(t.key) or got.get(t.key) for t in tasks]
    return [r for r in found if r is not None]


def _finish(
    run: RunDir,
    log: ResultsLog,
    status: str,
    reason: str | None,
    failure: str | None,
    finished: int,
    total: int,
    late: str | None = None,
) -> None:
    """The journal compacted and meta.json's end: status, why, how many episodes finished.
    `late`: a stop that came after the last episode (the run is whole): it stays requested, so
    that a suite running this study stops before its next scenario."""
    log.compact()
    extra = {"episodes": {"finished": finished, "total": total}}
    why = f"interrupted by {reason}" if reason else failure
    run.finish(status, **({"error": why} if why else {}), **extra)
    if status == "completed":  # a stop while finishing (under stop_handlers) is late too
        late = late or stop_reason()
    clear_stop()
    if late is not None:
        request_stop(late)


def failure_reason(exc: BaseException, folder: Path) -> str:
    """One line saying why a compare or sweep failed, for the terminal and meta.json: an OS
    error with its path (the run folder when the library writing did not say which file)."""
    if isinstance(exc, OSError):
        if exc.filename is None:
            return f"{exc.strerror or exc}: while writing in {folder}"
        return describe_os_error(exc)
    return str(exc) if isinstance(exc, UserError) else f"{type(exc).__name__}: {exc}"


def run_tasks(
    executor: Executor, tasks: list[Any], fn: Callable[[Any], Any], label: str, progress: bool
) -> list[Any]:
    """fn(task) for every task on the executor, results in task order.

    Raises:
        KeyboardInterrupt: a stop was requested before every task finished.
        UserError: a task could not be run (its worker was lost every time).
    """
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
    tasks: list[EpisodeTask],
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
    rows: list[dict[str, Any] | None] = [None] * len(tasks)
    for i, task in enumerate(tasks):
        executor.submit(run_episode_task, task, i)
    total = len(tasks) + done_before
    with task_progress(label, total, progress, rate="episodes", completed=done_before) as advance:
        for done in executor.results():
            task = tasks[done.key]
            if done.error == CANCELLED:
                continue
            if done.error is not None:
                row = {**task.row_tags(), "outcome": "error", "error": done.error}
            else:
                row = done.value
            if row["outcome"] == Outcome.INTERRUPTED:
                # The row says "interrupted by SIGTERM"; the stop reason is the signal alone.
                why = str(row.get("error") or "").removeprefix("interrupted by ")
                request_stop(why or "a worker was stopped")
            row = log.append(row)  # an episode's first final row stays its record
            rows[done.key] = row
            advance(f"{row.get('method', '')}: {row['outcome']}")
    return rows
