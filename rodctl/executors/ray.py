"""Ray: the same tasks on a Ray started for the run (loopback only) or on an existing cluster.

Optional: `pip install 'rodctl[ray]'`; Ray is imported only when this executor starts (found
missing when it is made, before a run folder exists). Without `address`, a private local Ray
is started with `num_cpus=workers`, no dashboard, a small object store, every service bound to
127.0.0.1, no usage reporting, and it is shut down with the run.
With `address` (`--address HOST:PORT`, or `auto`), the run connects to that cluster as a
driver and only disconnects at the end; the cluster's nodes need rodctl (and any plug-in)
installed.

Faults: a task whose worker process or node dies is retried by Ray itself (`max_retries`,
bounded by `MAX_RETRIES`) and then comes back as `Done.error`; an exception inside the task
function is the function's own result. Stopping: `cancel()` is `ray.cancel` on every pending
task; Ray delivers it to a running task as a SIGINT in its worker, which the task's
`stop_handlers()` turn into the stop flag, so the episode ends whole as `interrupted`.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, Literal

from rodctl.errors import UserError
from rodctl.executors.base import (
    CANCELLED,
    MAX_RETRIES,
    THREAD_ENV,
    Done,
    Executor,
    ExecutorConfig,
    ExecutorContext,
    clear_stop,
    prepare_worker,
    request_stop,
    stop_handlers,
    stop_reason,
)
from rodctl.registry import ALLOW_OVERRIDE_ENV, EXECUTORS, override_allowed

#: Object store of a Ray started for the run: results are small rows, not arrays.
_OBJECT_STORE_BYTES = 128 * 2**20

_worker_ready = False


def run_task(fn: Callable[[Any], Any], task: Any) -> Any:
    """Body of the Ray task: set the worker up once, then fn(task) under the stop handlers.

    A Ray worker process is reused across tasks, so the stop flag of a previous (cancelled)
    task is cleared first.
    """
    global _worker_ready
    if not _worker_ready:
        prepare_worker()
        _worker_ready = True
    clear_stop()
    with stop_handlers():
        return fn(task)


_MISSING = "--executor ray needs Ray, which is an optional extra: pip install 'rodctl[ray]'"


def _import_ray(local: bool) -> Any:
    if local:
        # Ray otherwise advertises the machine's network address even for a one-node Ray;
        # with this its node address (and so every service) is the loopback one.
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        # A Ray started for one run sends nothing anywhere (Ray reports usage by default).
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    try:
        import ray
    except ImportError:
        raise UserError(_MISSING) from None
    if local:
        # Ray read the variable above when it was first imported; imported earlier (a notebook,
        # a test process) it did not see it, so set the constant it became (ray==2.60.0).
        from ray._private import ray_constants

        ray_constants.ENABLE_RAY_CLUSTER = False
    return ray


class RayExecutor(Executor):
    """Tasks as Ray tasks (one CPU each) on a local Ray started for the run, or on `address`."""

    name = "ray"

    def __init__(
        self, workers: int, address: str | None = None, shutdown_timeout: float = 10.0
    ) -> None:
        # Found missing here, when the command line is read, not at start(): by then the run's
        # folder exists, and bad input must leave none.
        if importlib.util.find_spec("ray") is None:
            raise UserError(_MISSING)
        super().__init__(workers, shutdown_timeout)
        self.address = address
        self.ray: Any = None
        self._remote: Any = None
        self._owns_ray = False
        self._temp_dir: str | None = None  # the session folder of a Ray started for the run
        self._pending: dict[Any, tuple[Any, Any]] = {}  # ObjectRef -> (key, attempts)
        self._queue: list[tuple[Callable[[Any], Any], Any, Any]] = []
        self._cancelled = False

    def start(self) -> None:
        ray = _import_ray(local=self.address is None)
        self.ray = ray
        env = {k: "1" for k in THREAD_ENV}
        if override_allowed():
            env[ALLOW_OVERRIDE_ENV] = "1"  # a cluster's workers do not have our environment
        if ray.is_initialized():
            pass  # a Ray the caller started (a notebook, a test): use it, leave it running
        else:
            self._owns_ray = True  # ours to shut down (or to disconnect from), even half-started
            try:
                self._init(ray, env)
            except SystemExit as exc:
                # ray.init's own SIGTERM handler exits the process; a run stopped while Ray
                # starts is an interrupted run like any other, with nothing left running.
                request_stop(signal.Signals(exc.code).name if exc.code in (2, 15) else "exit")
                self.shutdown(self.shutdown_timeout)
                raise KeyboardInterrupt(stop_reason()) from None
        self._remote = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(
            run_task
        )

    def _init(self, ray: Any, env: dict[str, str]) -> None:
        if self.address is None:
            # Ray's session folder (logs, sockets, spilled objects) goes into a temporary
            # folder of the run's own, removed at shutdown, not into <tmp>/ray/session_*.
            self._temp_dir = tempfile.mkdtemp(prefix="rodctl-ray-")
            ray.init(
                _temp_dir=self._temp_dir,
                num_cpus=self.workers,
                include_dashboard=False,
                _node_ip_address="127.0.0.1",
                object_store_memory=_OBJECT_STORE_BYTES,
                log_to_driver=False,
                configure_logging=True,
                logging_level="warning",
                runtime_env={"env_vars": env},
            )
            return
        try:
            ray.init(
                address=self.address,
                log_to_driver=False,
                logging_level="warning",
                runtime_env={"env_vars": env},
            )
        except (ConnectionError, ValueError, RuntimeError) as exc:
            self._owns_ray = False
            raise UserError(f"--address {self.address}: cannot connect to Ray: {exc}") from None

    def submit(self, fn: Callable[[Any], Any], task: Any, key: Any) -> None:
        if self._remote is None:
            raise RuntimeError("RayExecutor.submit before start()")
        if self._cancelled:
            return
        self._pending[self._remote.remote(fn, task)] = (key, 1)

    def cancel(self) -> None:
        if self._cancelled or self.ray is None:
            return
        self._cancelled = True
        for ref in list(self._pending):
            try:
                self.ray.cancel(ref, force=False)
            except Exception:  # noqa: BLE001 - already finished or gone: nothing to cancel
                pass

    def results(self, poll: float = 0.5) -> Iterator[Done]:
        ray = self.ray
        exceptions = ray.exceptions
        stop_deadline: float | None = None
        while self._pending:
            if stop_reason() is not None and not self._cancelled:
                self.cancel()
            if self._cancelled and stop_deadline is None:
                stop_deadline = time.monotonic() + self.shutdown_timeout
            if stop_deadline is not None and time.monotonic() > stop_deadline:
                for ref in list(self._pending):
                    try:
                        ray.cancel(ref, force=True)
                    except Exception:  # noqa: BLE001
                        pass
                self._pending.clear()
                return
            ready, _ = ray.wait(list(self._pending), num_returns=1, timeout=poll)
            for ref in ready:
                key, attempts = self._pending.pop(ref)
                try:
                    value = ray.get(ref)
                except exceptions.TaskCancelledError:
                    yield Done(key, error=CANCELLED, attempts=attempts)
                    continue
                except exceptions.RayTaskError as exc:
                    cause = exc.cause if getattr(exc, "cause", None) is not None else exc
                    if isinstance(cause, KeyboardInterrupt):
                        yield Done(key, error=CANCELLED, attempts=attempts)
                        continue
                    raise cause from None
                except exceptions.RayError as exc:
                    # Worker or node lost, after Ray's own bounded retries.
                    yield Done(
                        key,
                        error=f"worker lost {MAX_RETRIES + 1} time(s): {type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else ''}",
                        attempts=MAX_RETRIES + 1,
                    )
                    continue
                yield Done(key, value=value, attempts=attempts)

    def shutdown(self, timeout: float) -> None:
        if self.ray is None:
            return
        if self._pending:
            self.cancel()
            for ref in list(self._pending):
                try:
                    self.ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001
                    pass
            self._pending.clear()
        if self._owns_ray:
            # Not only once initialised: a signal while ray.init runs leaves a node that is
            # started but not connected (is_initialized() False), and ray.shutdown stops it.
            # ray.shutdown has no timeout of its own; never let it hang the command.
            t = threading.Thread(target=self.ray.shutdown, daemon=True)
            t.start()
            t.join(timeout)
        self._owns_ray = False
        if self._temp_dir is not None:
            shutil.rmtree(self._temp_dir, ignore_errors=True)
            self._temp_dir = None


class RayExecutorConfig(ExecutorConfig):
    """Ray: a local Ray started for the run (loopback only), or the cluster at `--address`
    (`pip install 'rodctl[ray]'`)."""

    type: Literal["ray"] = "ray"


@EXECUTORS.register(RayExecutorConfig)
def _build(cfg: RayExecutorConfig, ctx: ExecutorContext) -> RayExecutor:
    """A `RayExecutor` of `ctx.workers` on `ctx.address` (None: a Ray of its own)."""
    return RayExecutor(ctx.workers, address=ctx.address)
