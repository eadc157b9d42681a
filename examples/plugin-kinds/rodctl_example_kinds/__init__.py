"""One type of each of three more extension kinds, added to rodctl from outside it.

rodctl imports this module at start-up because `pyproject.toml` names it in the entry-point group
`rodctl.plugins`; nothing inside rodctl names these types:

- event `gripper_nudge` (`run.events`): the robot carrying the gripper is bumped and the gripper
  is driven by `delta` [dx, dy, dtheta] (m, m, rad), in increments within the rod's speed limit,
  before the step's move; the controller has to undo it.
- sink `csv` (`logging.sinks: [{type: csv}]`): one row per control step (step, simulated time,
  phase, gripper pose, command, T1, pixel error, the step's events) in `steps.csv` of the run
  folder, flushed row by row, so a run that is cut short keeps every step it took.
- executor `thread` (`--executor thread`): the tasks of compare and sweep on a pool of threads in
  this process (no process start-up; the episodes share the interpreter, so they overlap only
  where numpy and the physics release the GIL). Stopping is the same cooperative flag: the
  episodes of this process poll it between two steps.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from rodctl.config.base import Angle
from rodctl.errors import UserError
from rodctl.events import EventConfig, EventState
from rodctl.executors.base import (
    CANCELLED,
    Done,
    Executor,
    ExecutorConfig,
    ExecutorContext,
    stop_reason,
)
from rodctl.logs.sinks import SinkConfig, SinkContext
from rodctl.registry import EVENTS, EXECUTORS, SINKS

__all__ = [
    "CsvSink",
    "CsvSinkConfig",
    "GripperNudge",
    "ThreadExecutor",
    "ThreadExecutorConfig",
]

# --- event ---------------------------------------------------------------------------------------

#: One axis of a knock (m): bounded, as every config number is.
_Shift = Annotated[float, Field(ge=-0.2, le=0.2)]


class GripperNudge(EventConfig):
    """The gripper is knocked: driven by `delta` = [dx, dy, dtheta] (world frame) before the
    step's move, in increments within `rod.max_step`, the rod settling after each."""

    type: Literal["gripper_nudge"] = "gripper_nudge"
    delta: tuple[_Shift, _Shift, Angle] = Field(
        description="The knock [dx, dy, dtheta] (m, m, rad), world frame; |dx|, |dy| <= 0.2 m."
    )
    example: ClassVar[dict[str, Any] | None] = {
        "type": "gripper_nudge",
        "at_step": 1,
        "delta": (0.0, 0.02, 0.1),
    }

    def check(self, state: EventState, field: str) -> None:
        """A knock longer than the held rod is not a knock: refused before the run."""
        held = state.held * state.segment
        if float(np.hypot(*self.delta[:2])) >= held:
            raise UserError(
                f"{field}.delta: a nudge of {np.hypot(*self.delta[:2]):.4g} m is not shorter "
                f"than the held rod ({held:.4g} m at that step)"
            )


@EVENTS.register(GripperNudge)
def _apply_nudge(event: GripperNudge, sim: Any, camera: Any) -> str:
    """Drive the gripper by `delta` (`RodSim.move_to`, clipped to the workspace)."""
    old = np.asarray(sim.gripper_pose, dtype=float)
    result = sim.move_to(old + np.asarray(event.delta, dtype=float))
    new = np.asarray(sim.gripper_pose, dtype=float)
    clip = " (clipped by the workspace)" if result.clipped else ""
    state = "DIVERGED" if result.diverged else ("settled" if result.settled else "NOT settled")
    return (
        f"event gripper_nudge: gripper [{', '.join(f'{v:.4f}' for v in old)}] -> "
        f"[{', '.join(f'{v:.4f}' for v in new)}]{clip}; {state}"
    )


# --- sink ----------------------------------------------------------------------------------------

#: Columns of steps.csv (units: m, rad, feature units, px).
COLUMNS = (
    "step",
    "sim_time",
    "phase",
    "gripper_x",
    "gripper_y",
    "gripper_theta",
    "u_x",
    "u_y",
    "u_theta",
    "T1",
    "pixel_error",
    "events",
)


class CsvSinkConfig(SinkConfig):
    """steps.csv: one row per control step (step, sim_time s, phase, gripper pose m/rad, the
    command applied, T1, pixel error px, the step's events joined by ' | ')."""

    type: Literal["csv"] = "csv"
    name: str = Field(
        "steps.csv",
        pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]*\.csv$",
        max_length=64,
        description="File name inside the run folder (letters, digits, . _ -; ends in .csv).",
    )


class CsvSink:
    """Writes one CSV row per step; every row is flushed, the file closed at `close`."""

    def __init__(self, path: Any) -> None:
        self.path = path
        self._file: Any = None
        self._writer: Any = None

    def open(self, header: Any) -> None:
        self._file = open(self.path, "w", newline="", encoding="utf-8")  # noqa: SIM115
        self._writer = csv.writer(self._file)
        self._writer.writerow(COLUMNS)
        self._file.flush()

    def write(self, record: Any) -> None:
        g = np.asarray(record.gripper, dtype=float).ravel()
        u = np.asarray(record.u, dtype=float).ravel()
        self._writer.writerow(
            [
                int(record.step),
                repr(float(record.sim_time)),
                record.phase,
                *(repr(float(v)) for v in g[:3]),
                *(repr(float(v)) for v in u[:3]),
                repr(float(record.T1)),
                repr(float(record.pixel_error)),
                " | ".join(record.events),
            ]
        )
        self._file.flush()

    def close(self, summary: Any, status: str) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


@SINKS.register(CsvSinkConfig)
def _build_csv(cfg: CsvSinkConfig, ctx: SinkContext) -> CsvSink:
    """A `CsvSink` writing run_dir/<name>."""
    if ctx.run_dir is None:
        raise ValueError("the csv sink writes a file: it needs a run directory")
    return CsvSink(ctx.run_dir / cfg.name)


# --- executor ------------------------------------------------------------------------------------


class ThreadExecutorConfig(ExecutorConfig):
    """Threads of this process: no worker start-up; tasks overlap where numpy and the physics
    release the GIL."""

    type: Literal["thread"] = "thread"


def _unless_stopped(fn: Callable[[Any], Any], task: Any) -> Any:
    """fn(task), unless this process was asked to stop before the thread took it."""
    if stop_reason() is not None:
        return _NOT_STARTED
    return fn(task)


_NOT_STARTED = object()


class ThreadExecutor(Executor):
    """`workers` threads; `cancel()` drops the queued tasks (running ones see the stop flag,
    which is this process's own, and end at their next step). A thread cannot be killed:
    `shutdown` waits for the running tasks."""

    name = "thread"

    def __init__(self, workers: int, shutdown_timeout: float = 10.0) -> None:
        super().__init__(workers, shutdown_timeout)
        self.pool: ThreadPoolExecutor | None = None
        self._futures: dict[Future, Any] = {}

    def start(self) -> None:
        self.pool = ThreadPoolExecutor(self.workers, thread_name_prefix="rodctl-task")

    def submit(self, fn: Callable[[Any], Any], task: Any, key: Any) -> None:
        assert self.pool is not None, "start() first (use the executor as a context manager)"
        self._futures[self.pool.submit(_unless_stopped, fn, task)] = key

    def cancel(self) -> None:
        for fut in self._futures:
            fut.cancel()

    def results(self, poll: float = 0.5) -> Iterator[Done]:
        cancelled = False
        while self._futures:
            if stop_reason() is not None and not cancelled:
                self.cancel()
                cancelled = True
            done, _ = wait(list(self._futures), timeout=poll, return_when=FIRST_COMPLETED)
            for fut in done:
                key = self._futures.pop(fut)
                if fut.cancelled():
                    yield Done(key, error=CANCELLED, attempts=0)
                    continue
                exc = fut.exception()
                if exc is not None:
                    raise exc
                value = fut.result()
                if value is _NOT_STARTED:
                    yield Done(key, error=CANCELLED, attempts=0)
                    continue
                yield Done(key, value=value)

    def shutdown(self, timeout: float) -> None:
        pool, self.pool = self.pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


@EXECUTORS.register(ThreadExecutorConfig)
def _build_thread(cfg: ThreadExecutorConfig, ctx: ExecutorContext) -> ThreadExecutor:
    """A `ThreadExecutor` of `ctx.workers` threads; it has no address."""
    if ctx.address is not None:
        raise UserError("--address needs --executor ray (the thread executor has no address)")
    return ThreadExecutor(ctx.workers)
