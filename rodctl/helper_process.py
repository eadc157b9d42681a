"""Helper processes that do one job of a command beside it (drawing the figures, writing run.rrd)
and never outlive it.

Why (issues #17, #24): importing matplotlib and drawing (~0.5 s of CPU each), and importing
rerun (~0.5 s) and writing the recording, were paid one after the other by `rodctl simulate`.
A helper started when the run starts imports its library on the second core while the command
imports its own and runs the episode, then receives the run as it goes; the command keeps what
the files and errors are (each job's module says how).

Lifetime: a helper never outlives the command. It is its own process group, so a Ctrl-C at the
terminal (or a signal to the command's group) reaches only the command, which decides how the
run ends; it dies with its parent (PR_SET_PDEATHSIG on Linux; elsewhere it exits when it reads
the end of its input, which the parent's death closes); and `stop()`, called in a `finally` by
every owner (`Helpers` stops all it started), kills it and reaps it.

Protocol: the parent sends pickles to the helper's stdin (`send`), each pickled when sent (what
changes afterwards is not sent), written by a thread so that a helper still importing never
blocks the command; `end()` closes the input after them. The helper reads them until the end of
its input (`messages`), writes one pickle, its reply, to its stdout and exits 0 (`reply`). A
traceback goes to its stderr. The helper's program imports only its job's module (`-P`: no
current folder on sys.path), with `rodctl` a bare package of the parent's folder: the package's
`__init__` imports gymnasium (0.2 s of CPU that would compete with the episode).

Failure: a helper that cannot start, fails, is killed or does not reply within the timeout makes
`result()` raise `HelperFailed` with the reason, naming the helper; it never raises anything else.
"""

from __future__ import annotations

import ctypes
import os
import pickle
import queue
import signal
import subprocess
import sys
import threading
import traceback
from collections.abc import Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import IO, Any, NoReturn

from rodctl import timeline
from rodctl.errors import describe_os_error

#: Seconds `result()` waits by default for a helper whose input has ended.
TIMEOUT_S = 60.0

#: The `rodctl` package folder the parent imported: the helper imports from the same one.
_PACKAGE = str(Path(__file__).resolve().parent)

#: The helper's program: argv = package folder, parent pid, the job's module (its `helper_main`).
_BOOT = (
    "import sys, types\n"
    "package = types.ModuleType('rodctl')\n"
    "package.__path__ = [sys.argv[1]]\n"
    "sys.modules['rodctl'] = package\n"
    "import importlib\n"
    "importlib.import_module(sys.argv[3]).helper_main()\n"
)

_END = object()


class HelperFailed(Exception):
    """The helper gave no reply; `str()` is the reason, naming the helper."""


class Helper:
    """The parent's handle on one helper process. `start()`, then `stop()` in a `finally`.

    Args:
        proc: the started process (None: it could not be started, `failure` says why).
        name: what the helper is called in messages ("figure process").
    """

    def __init__(self, proc: subprocess.Popen | None, name: str, failure: str | None = None):
        self.proc = proc
        self.name = name
        #: Why there will be no reply, known before `result()` (no process, data unpicklable).
        self.failure = failure
        self._queue: queue.SimpleQueue[Any] | None = None
        self._sender: threading.Thread | None = None
        self._ended = False
        self._broken = False  # the helper stopped reading: later messages are dropped

    @classmethod
    def start(cls, module: str, name: str) -> Helper:
        """Start the helper running `module.helper_main()` (it begins importing at once). Never
        raises: a helper that cannot be started is reported by `result()`."""
        cmd = [sys.executable, "-P", "-c", _BOOT, _PACKAGE, str(os.getpid()), module]
        own_group: dict[str, Any] = {"process_group": 0} if os.name == "posix" else {}
        try:
            proc = subprocess.Popen(
                cmd,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                **own_group,
            )
        except Exception as exc:  # noqa: BLE001 - no fork, no executable (embedded Python) ...
            why = describe_os_error(exc) if isinstance(exc, OSError) else repr(exc)
            return cls(None, name, f"could not start the {name}: {why}")
        return cls(proc, name)

    @property
    def usable(self) -> bool:
        """Whether messages still reach the helper (started, not failed, input not ended)."""
        return not (self.proc is None or self.failure or self._ended or self._broken)

    def send(self, message: Any, pending: Future | None = None) -> None:
        """Queue `message`, pickled now; then, if given, the result of `pending` (or the
        exception it raised) once it is done, as the next pickle. Returns at once and never
        raises (the parent's sinks call it, where an exception would fail the run's logs): a
        message that cannot be pickled makes `failure` say so and ends the exchange."""
        if not self.usable:
            return
        try:
            data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # noqa: BLE001 - e.g. a plug-in's unpicklable estimator info
            self.failure = f"the run could not be handed to the {self.name}: {exc!r}"
            self.end()
            return
        self._inbox().put((data, pending))

    def end(self) -> None:
        """No more messages: the helper's input closes once the queued ones are written."""
        if self._ended or self.proc is None:
            self._ended = True
            return
        self._inbox().put(_END)
        self._ended = True

    def result(self, timeout: float | None = None) -> Any:
        """The helper's reply (None if it sent none it could unpickle), waiting at most
        `timeout` s (default `TIMEOUT_S`) after ending its input. Raises `HelperFailed` (the
        helper is then stopped)."""
        timeout = TIMEOUT_S if timeout is None else timeout
        if self.failure is not None or self.proc is None:
            self.stop()
            raise HelperFailed(self.failure or f"no {self.name}")
        self.end()
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.stop()
            raise HelperFailed(f"the {self.name} did not finish within {timeout:g} s") from None
        finally:
            if self._sender is not None:
                self._sender.join(timeout=1.0)
        code = self.proc.returncode
        if code < 0:
            try:
                how = signal.Signals(-code).name
            except ValueError:
                how = f"signal {-code}"
            raise HelperFailed(f"the {self.name} was killed by {how}")
        if code != 0:
            lines = err.decode("utf-8", "replace").strip().splitlines()
            raise HelperFailed(
                f"the {self.name} failed: {lines[-1] if lines else f'exit code {code}'}"
            )
        try:
            return pickle.loads(out)
        except Exception:  # noqa: BLE001 - whatever it sent, it is no reply
            return None

    def stop(self) -> None:
        """Kill the helper if it still runs and reap it (idempotent; never raises)."""
        self._broken = True
        proc = self.proc
        if proc is None:
            return
        if proc.poll() is None:
            try:
                proc.kill()
            except OSError:
                pass
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:  # pragma: no cover - SIGKILL not delivered
            pass
        for pipe in (proc.stdin, proc.stdout, proc.stderr):
            if pipe is not None:
                try:
                    pipe.close()
                except OSError:
                    pass

    def __enter__(self) -> Helper:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def _inbox(self) -> queue.SimpleQueue[Any]:
        """The sender thread's queue, the thread started (and stdin taken over) on first use."""
        if self._queue is None:
            assert self.proc is not None and self.proc.stdin is not None  # started with PIPE
            stdin, self.proc.stdin = self.proc.stdin, None  # ours now; communicate() leaves it
            self._queue = queue.SimpleQueue()
            self._sender = threading.Thread(
                target=self._write_all,
                args=(stdin, self._queue),
                name=f"rodctl-{self.name.replace(' ', '-')}-send",
                daemon=True,
            )
            self._sender.start()
        return self._queue

    def _write_all(self, stdin: IO[bytes], inbox: queue.SimpleQueue[Any]) -> None:
        try:
            while (item := inbox.get()) is not _END:
                data, pending = item
                stdin.write(data)
                if pending is not None:
                    try:
                        value = pending.result()
                    except Exception as exc:  # noqa: BLE001 - the helper reports it in order
                        value = exc
                    stdin.write(_dumps_or_repr(value))
                stdin.flush()
        except (OSError, ValueError):  # the helper is gone: result() says why
            self._broken = True
        finally:
            try:
                stdin.close()
            except OSError:
                pass


def _dumps_or_repr(value: Any) -> bytes:
    try:
        return pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # noqa: BLE001 - an exception that does not pickle: its text
        return pickle.dumps(RuntimeError(repr(value)), protocol=pickle.HIGHEST_PROTOCOL)


class Helpers:
    """Helpers started before the run needs them (`start`), so that their imports overlap the
    command's; each is `take`n by the sink that uses it. A context manager: every helper it
    started or handed out is stopped at the end."""

    def __init__(self) -> None:
        self._waiting: dict[str, Helper] = {}
        self._all: list[Helper] = []

    def start(self, module: str, name: str) -> None:
        """Start the helper of `module` now (once)."""
        if module not in self._waiting:
            self._waiting[module] = helper = Helper.start(module, name)
            self._all.append(helper)
            timeline.mark("main", f"started {module}")

    def take(self, module: str, name: str) -> Helper:
        """The helper of `module` started earlier, or one started now; stopped with the rest."""
        helper = self._waiting.pop(module, None)
        if helper is None:
            helper = Helper.start(module, name)
            self._all.append(helper)
        return helper

    def stop(self) -> None:
        for helper in self._all:
            helper.stop()

    def __enter__(self) -> Helpers:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


# --- helper side ------------------------------------------------------------------------------


def _die_with_parent(parent: int) -> None:
    """Be killed when the parent dies (Linux), and exit now if it already has."""
    if sys.platform.startswith("linux"):
        try:
            PR_SET_PDEATHSIG = 1
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL))
        except (OSError, AttributeError):  # pragma: no cover - no prctl: stdin's end does it
            pass
    if os.getppid() != parent:
        os._exit(0)


def begin(role: str) -> IO[bytes]:
    """A helper's first call: die with the parent, keep stdout for the reply (anything printed
    goes to stderr); the reply stream, for `reply`."""
    out = sys.stdout.buffer
    sys.stdout = sys.stderr  # anything printed while working must not corrupt the reply
    _die_with_parent(int(sys.argv[2]))
    timeline.mark(role, "started")
    return out


def messages() -> Iterator[Any]:
    """The parent's messages in order, until the end of the input."""
    stream = sys.stdin.buffer
    while True:
        try:
            yield pickle.load(stream)
        except EOFError:
            return


def fail() -> NoReturn:
    """Exit 1 now, the exception being handled to stderr (`result()` reports its last line)."""
    traceback.print_exc()
    exit_now(1)


def exit_now(code: int = 0) -> NoReturn:
    """Exit at once (no interpreter shut-down, which a thread still reading the input would
    make abort, and which takes ~0.3 s with matplotlib loaded)."""
    sys.stderr.flush()
    os._exit(code)


def reply(out: IO[bytes], value: Any, role: str) -> NoReturn:
    """Send `value` and exit 0 at once: the interpreter's tear-down (~0.3 s with matplotlib
    loaded) would be waited for by the command."""
    out.write(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
    out.flush()
    timeline.mark(role, "replied")
    exit_now(0)
