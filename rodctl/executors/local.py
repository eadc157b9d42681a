"""The default executor: this process for one worker, else a local 'spawn' process pool.

No service and nothing to install. The 'spawn' context because torch and fork do not mix; one
BLAS/torch thread per worker (`THREAD_ENV`, `init_worker`), so N workers use N cores.

Stopping: `cancel()` drops the queued tasks and sends SIGTERM to every pool process; their
handler (`init_worker`) sets the stop flag, the running episode ends at its next step as
`interrupted` and comes back, and tasks already handed to a worker return at once unstarted.
`shutdown()` then joins every process within the timeout and kills the ones that did not exit,
so no worker outlives the run, whichever process got the user's signal. A worker that dies
(killed, out of memory) breaks the pool: it is rebuilt and the tasks in flight are run again,
at most `MAX_RETRIES` more times each.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from typing import Any, Literal

from rodctl import signals
from rodctl.errors import UserError
from rodctl.executors.base import (
    CANCELLED,
    MAX_RETRIES,
    THREAD_ENV,
    Done,
    Executor,
    ExecutorConfig,
    ExecutorContext,
    init_worker,
    request_stop,
    stop_reason,
)
from rodctl.notices import share_with_workers
from rodctl.registry import EXECUTORS

#: Seconds a stopped pool's processes get to exit on their own before they are killed.
STOP_GRACE = 2.0


class _NotStarted:
    """Sentinel returned by `call_unless_stopped` (picklable, compared by type)."""


def _alive(proc: Any) -> bool:
    """True while the process exists (not yet exited, or exited but not yet reaped)."""
    if proc.exitcode is not None or proc.pid is None:
        return False
    try:
        os.kill(proc.pid, 0)
    except ProcessLookupError:
        return False
    return True


def call_unless_stopped(fn: Callable[[Any], Any], task: Any) -> Any:
    """Run fn(task) unless this process was asked to stop; then return `_NotStarted()`."""
    if stop_reason() is not None:
        return _NotStarted()
    return fn(task)


class LocalExecutor(Executor):
    """In-process (workers == 1) or a spawn `ProcessPoolExecutor` of `workers` processes."""

    name = "local"

    def __init__(self, workers: int, shutdown_timeout: float = 10.0) -> None:
        super().__init__(workers, shutdown_timeout)
        self.pool: ProcessPoolExecutor | None = None
        self._queue: list[tuple[Any, Callable[[Any], Any], Any, int]] = []
        self._futures: dict[Future, tuple[Any, Callable[[Any], Any], Any, int]] = {}
        self._saved_env: dict[str, str | None] = {}
        self._cancelled = False
        self._procs: list[Any] = []

    # --- lifecycle ----------------------------------------------------------------------------

    def start(self) -> None:
        if self.workers > 1:
            # Children inherit the environment at spawn: one BLAS thread per worker process.
            self._saved_env = {k: os.environ.get(k) for k in THREAD_ENV}
            os.environ.update({k: "1" for k in THREAD_ENV})
            share_with_workers()  # a notice said here is not said again by each worker
            self._new_pool()

    def _new_pool(self) -> None:
        self.pool = ProcessPoolExecutor(
            self.workers, mp_context=get_context("spawn"), initializer=init_worker
        )

    def shutdown(self, timeout: float) -> None:
        """Let the workers exit, killing any still alive after `timeout` seconds.

        After a stop the grace is short (`STOP_GRACE`): every task has already handed back
        its row with its logs closed, and a process importing or tearing down torch on a busy
        machine can take many seconds to exit on its own.
        """
        pool, self.pool = self.pool, None
        if pool is not None:
            # To join/kill them; a cancelled pool has forgotten its processes, `cancel` kept them.
            procs = list((pool._processes or {}).values()) or list(self._procs)  # noqa: SLF001
            pool.shutdown(wait=False, cancel_futures=True)
            grace = min(timeout, STOP_GRACE) if self._cancelled else timeout
            deadline = time.monotonic() + grace
            # The pool's own thread reaps the processes too, so poll rather than join.
            while any(_alive(p) for p in procs) and time.monotonic() < deadline:
                time.sleep(0.05)
            for p in procs:
                if _alive(p):
                    p.kill()
            end = time.monotonic() + 2.0  # SIGKILL is not instant; do not return before
            while any(_alive(p) for p in procs) and time.monotonic() < end:
                time.sleep(0.05)
        for k, v in self._saved_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        self._saved_env = {}

    # --- work ---------------------------------------------------------------------------------

    def submit(self, fn: Callable[[Any], Any], task: Any, key: Any) -> None:
        self._queue.append((key, fn, task, 1))

    def _dispatch(self) -> None:
        assert self.pool is not None
        queue, self._queue = self._queue, []
        with signals.held_from_children():  # `submit` starts the processes (see `init_worker`)
            for item in queue:
                key, fn, task, _attempt = item
                self._futures[self.pool.submit(call_unless_stopped, fn, task)] = item
        self._procs = list((self.pool._processes or {}).values())  # noqa: SLF001

    def cancel(self) -> None:
        if self._cancelled:
            return
        self._cancelled = True
        self._queue.clear()
        if self.pool is None:
            return
        processes = dict(self.pool._processes or {})  # noqa: SLF001
        self._procs = list(processes.values())  # `shutdown` below forgets them; ours joins them
        pids = list(processes.keys())
        # Drop the tasks no worker has taken yet. Through the pool, not `Future.cancel()`: a
        # future cancelled behind the pool's back stays in its pending items, and if a worker
        # then dies (a SIGTERM before its handler is in place) the pool's thread fails it with
        # `InvalidStateError: CANCELLED` and prints that traceback (CPython 3.11).
        self.pool.shutdown(wait=False, cancel_futures=True)
        for pid in pids:
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass

    def results(self, poll: float = 0.5) -> Iterator[Done]:
        if self.pool is None:
            yield from self._results_inline()
            return
        self._dispatch()
        stop_deadline: float | None = None
        while self._futures:
            if stop_reason() is not None and not self._cancelled:
                self.cancel()
            if self._cancelled and stop_deadline is None:
                stop_deadline = time.monotonic() + self.shutdown_timeout
            if stop_deadline is not None and time.monotonic() > stop_deadline:
                self._futures.clear()  # shutdown() kills what is left
                return
            done, _ = wait(list(self._futures), timeout=poll, return_when=FIRST_COMPLETED)
            # A cancelled future counts as done for `wait` only once the pool has noticed it.
            done = set(done) | {f for f in self._futures if f.cancelled()}
            broken = False
            for fut in done:
                key, fn, task, attempt = self._futures.pop(fut)
                if fut.cancelled():
                    yield Done(key, error=CANCELLED, attempts=attempt - 1)
                    continue
                exc = fut.exception()
                if isinstance(exc, BrokenProcessPool):
                    broken = True
                    if self._cancelled or self._signalled():
                        # Stopping: a worker that a signal ended mid-start-up is no fault.
                        yield Done(key, error=CANCELLED, attempts=attempt)
                    elif attempt > MAX_RETRIES:
                        yield Done(
                            key, error=f"worker lost {attempt} time(s): {exc}", attempts=attempt
                        )
                    else:
                        self._queue.append((key, fn, task, attempt + 1))
                    continue
                if exc is not None:
                    raise exc
                value = fut.result()
                if isinstance(value, _NotStarted):
                    # A worker got a stop signal on its own: the whole run stops.
                    request_stop("a worker was stopped")
                    yield Done(key, error=CANCELLED, attempts=attempt)
                    continue
                yield Done(key, value=value, attempts=attempt)
            if broken and self._signalled():
                # A worker killed by SIGINT/SIGTERM (before its handler was in place, or
                # the default action): the user or the system asked to stop, not a fault.
                request_stop("a worker was stopped")
                self._cancelled = True
            if broken and not self._cancelled:
                self._rebuild()

    def _signalled(self) -> bool:
        """Whether a pool process ended by SIGINT or SIGTERM."""
        codes = {p.exitcode for p in self._procs}
        return bool(codes & {-signal.SIGINT, -signal.SIGTERM})

    def _rebuild(self) -> None:
        """A worker died: every future of the old pool failed; run the survivors again."""
        for key, fn, task, attempt in self._futures.values():
            self._queue.append((key, fn, task, attempt + 1))
        self._futures.clear()
        old, self.pool = self.pool, None
        if old is not None:
            old.shutdown(wait=False, cancel_futures=True)
        self._new_pool()
        self._dispatch()

    def _results_inline(self) -> Iterator[Done]:
        """One worker: run the tasks here, one by one, between two stop checks."""
        while self._queue:
            key, fn, task, attempt = self._queue.pop(0)
            if stop_reason() is not None:
                self._queue.clear()
                yield Done(key, error=CANCELLED, attempts=0)
                return
            yield Done(key, value=fn(task), attempts=attempt)


class LocalExecutorConfig(ExecutorConfig):
    """This machine: in-process for one worker, else a local 'spawn' process pool."""

    type: Literal["local"] = "local"


@EXECUTORS.register(LocalExecutorConfig)
def _build(cfg: LocalExecutorConfig, ctx: ExecutorContext) -> LocalExecutor:
    """A `LocalExecutor` of `ctx.workers`; it has no address."""
    if ctx.address is not None:
        raise UserError("--address needs --executor ray (the local pool has no address)")
    return LocalExecutor(ctx.workers)
