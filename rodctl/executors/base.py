"""What an executor is: it schedules task functions, hands back results as they finish, and stops.

`rodctl compare` and `rodctl sweep` describe their work as a list of plain-data tasks (dicts of
JSON-able values) and one module-level function to apply to each. An executor decides only
*where* they run — this process, a local spawn pool, Ray — and never looks inside a task: the
same task gives the same result whichever executor ran it, which is what makes a results table
independent of the executor (tested).

Stopping is cooperative. A process that runs tasks installs `stop_handlers()`: SIGINT and
SIGTERM then set a process-wide flag instead of raising, and an episode polls `stop_reason()`
between two steps (`run_episode(stop_requested=...)`), so it ends as `interrupted` with its
logs closed whole. The executor's `cancel()` makes that happen in every worker (a signal to a
pool process, `ray.cancel` on Ray), whichever process the user's signal reached first.

Executors are registered like stages (`rodctl.registry.EXECUTORS`): a config model derived from
`ExecutorConfig` (a `type` literal; the command line selects it by name, `--executor NAME`, and
builds it from its defaults) and a factory `factory(cfg, ctx: ExecutorContext) -> Executor`.
`local` is in rodctl/executors/local.py, `ray` in rodctl/executors/ray.py; a plug-in adds one
(a Dask or a batch-queue executor) the same way, without editing rodctl.
"""

from __future__ import annotations

import signal
import sys
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from rodctl import registry, signals
from rodctl.config.base import StrictModel
from rodctl.errors import UserError

#: How many times a task whose worker (or node) was lost is run again before it is recorded
#: as an error. Exceptions raised *inside* a task are never retried: they are the result.
MAX_RETRIES = 2

#: Environment variables that cap BLAS/OpenMP threads: one thread per worker process, so N
#: workers use N cores and not N x cores.
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

#: `Done.error` of a task dropped by `cancel()` (queued, or handed over after the stop flag).
CANCELLED = "cancelled"

_stop_reason: str | None = None


def stop_reason() -> str | None:
    """The name of the first stop signal this process received (e.g. "SIGTERM"), or None."""
    return _stop_reason


def request_stop(reason: str) -> None:
    """Ask every task of this process to stop at its next safe point."""
    global _stop_reason
    _stop_reason = _stop_reason or reason


def clear_stop() -> None:
    """Forget a stop request (a new run in the same process, e.g. a test)."""
    global _stop_reason
    _stop_reason = None


def _handler(signum: int, _frame: object) -> None:
    request_stop(signals.name(signum))


@contextmanager
def stop_handlers() -> Iterator[None]:
    """SIGINT and SIGTERM set the stop flag for the duration (main thread only, else no-op).

    A flag polled at one safe point cannot cut a step, or the writing of a log, in half. A
    signal the process was started ignoring (nohup) stays ignored.
    """
    with signals.handled(_handler):
        yield


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM ends a long command like Ctrl-C does (KeyboardInterrupt), so it is caught and
    recorded as `interrupted` instead of killing the process with meta.json left `running`."""

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt(signals.name(signum))

    with signals.handled(handler, (signal.SIGTERM,)):
        yield


def prepare_worker() -> None:
    """What every worker process (local pool or Ray) needs before its first task: plug-ins
    registered as in the parent, and one torch thread if a plug-in already imported torch.
    torch itself is not imported (1.2 s a worker, and most tasks never use it): the executors
    start workers with `THREAD_ENV` set to 1, which torch reads when a task imports it."""
    registry._IN_WORKER = True  # the parent has warned of any allowed override
    registry.load_plugins()
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def init_worker() -> None:
    """Start of every local pool process: `prepare_worker` (a config naming a plug-in type
    must validate there too), and cooperative stop handlers. The pool starts its processes
    with SIGINT blocked (`signals.held_from_children`): a Ctrl-C during their imports waits
    until the handler is in place, and is taken here."""
    prepare_worker()
    signals.install(_handler, over_ignored=True)
    signals.release()


@dataclass
class Done:
    """One finished task.

    Attributes:
        key: the key it was submitted with.
        value: what the task function returned (None if `error`).
        error: set when the task could not be run to its end by the infrastructure (its worker
            or node was lost `MAX_RETRIES` + 1 times, or it was cancelled); an exception inside
            the task function is the function's business, not this.
        attempts: how many times it was started.
    """

    key: Any
    value: Any = None
    error: str | None = None
    attempts: int = 1


class Executor(ABC):
    """Runs `fn(task)` for submitted tasks somewhere; yields `Done` as each finishes.

    Use as a context manager: `__enter__` starts the workers, `__exit__` shuts them down within
    `shutdown_timeout` seconds whatever happened (no process is left behind).
    """

    name = "executor"

    def __init__(self, workers: int, shutdown_timeout: float = 10.0) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = workers
        self.shutdown_timeout = shutdown_timeout

    def __enter__(self) -> Executor:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown(self.shutdown_timeout)

    @abstractmethod
    def start(self) -> None:
        """Start the workers (a pool, a Ray connection)."""

    @abstractmethod
    def submit(self, fn: Callable[[Any], Any], task: Any, key: Any) -> None:
        """Queue `fn(task)`; its result comes back from `results()` with `key`."""

    @abstractmethod
    def results(self, poll: float = 0.5) -> Iterator[Done]:
        """Yield every submitted task's `Done` as it finishes, until none is pending.

        Returns every `poll` seconds at the latest to check `stop_reason()`: when a stop was
        requested, it calls `cancel()` once and goes on yielding what the workers hand back
        (episodes cut short come back as `interrupted`).
        """

    @abstractmethod
    def cancel(self) -> None:
        """Drop queued tasks and ask running ones to stop at their next safe point."""

    @abstractmethod
    def shutdown(self, timeout: float) -> None:
        """Stop every worker within `timeout` seconds (killing those that do not stop)."""

    def map(
        self,
        fn: Callable[[Any], Any],
        tasks: Sequence[Any],
        on_done: Callable[[Done], None] | None = None,
    ) -> list[Done]:
        """Every task through `fn`, the `Done`s in task order (`on_done` sees them as they come)."""
        for i, task in enumerate(tasks):
            self.submit(fn, task, i)
        out: list[Done | None] = [None] * len(tasks)
        for done in self.results():
            out[done.key] = done
            if on_done is not None:
                on_done(done)
        return [d if d is not None else Done(i, error="not run") for i, d in enumerate(out)]


class ExecutorConfig(StrictModel):
    """Base of every executor config model (its `type` is the `--executor` name)."""


@dataclass(frozen=True)
class ExecutorContext:
    """What an executor factory is given besides its config: the command line's choices.

    Attributes:
        workers: how many tasks run at once (`--workers`).
        address: where to connect (`--address`), or None; a factory of an executor without
            addresses refuses one with a `UserError`.
    """

    workers: int
    address: str | None = None


def make_executor(kind: str, workers: int, address: str | None = None) -> Executor:
    """The executor named on the command line (`--executor NAME`, `--address`), built by its
    registered factory (`rodctl.registry.EXECUTORS`, plug-ins included).

    Raises:
        UserError: an unknown kind, `--address` for an executor without one, or Ray not
            installed.
    """
    registry.load_plugins()
    if kind not in registry.EXECUTORS:
        raise UserError(
            f"--executor {kind!r}: expected one of "
            f"{', '.join(repr(n) for n in registry.EXECUTORS.names())} "
            "(`rodctl plugins` lists them with their sources)"
        )
    cfg = registry.EXECUTORS.get(kind).config()
    return registry.EXECUTORS.build(cfg, ExecutorContext(workers=workers, address=address))


class SharedExecutor(Executor):
    """An executor that another owner started, lent to one study: `__enter__`/`__exit__` do not
    start or stop its workers, everything else is the owner's executor's.

    A suite runs each scenario as its own study on the one pool it started for all of them
    (`rodctl.bench.suite`), instead of a new pool (spawn processes that import rodctl again, a
    Ray started again) per scenario. Episodes depend on nothing but their task, so results are
    the same either way.
    """

    def __init__(self, owner: Executor) -> None:
        super().__init__(owner.workers, owner.shutdown_timeout)
        self.owner = owner
        self.name = owner.name

    def start(self) -> None:
        """Nothing: the owner started the workers."""

    def shutdown(self, timeout: float) -> None:
        """Nothing: the owner stops the workers."""

    def submit(self, fn: Callable[[Any], Any], task: Any, key: Any) -> None:
        self.owner.submit(fn, task, key)

    def results(self, poll: float = 0.5) -> Iterator[Done]:
        return self.owner.results(poll)

    def cancel(self) -> None:
        self.owner.cancel()
