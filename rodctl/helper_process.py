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
blocks the command; `end()` closes the input after them. What waits for the thread is bounded
(`QUEUE_BYTES`): when it is full, `send` waits up to `QUEUE_WAIT_S` for the helper to read,
then gives the helper up (`failure` says so; later messages are dropped and `result()` raises),
so that a helper that stops reading costs the command a bounded wait and memory, not a copy of
every record of the run. The helper reads them until the end of
its input (`messages`), writes one pickle, its reply, to its stdout and exits 0 (`reply`). A
traceback goes to its stderr. The helper's program imports only its job's module (`-P`: no
current folder on sys.path), with `rodctl` a bare package of the parent's folder: the package's
`__init__` imports gymnasium (0.2 s of CPU that would compete with the episode).

Failure: a helper that cannot start, fails, is killed or does not reply within the timeout makes
`result()` raise `HelperFailed` with the reason, naming the helper; it never raises anything else.
`ended()` tells, without waiting, whether a helper has already ended before its reply (an import
that failed, a kill), so that its owner can say so at once instead of at the end.

Forked helpers (issue #24): `rodctl simulate` starts its helpers from the entry point
(`rodctl._entry`), before its own imports, by `fork_helper` instead of a new interpreter: the
child has the interpreter and numpy already (~0.1 s of CPU each, and as much of latency). It is
safe there: no Python thread exists yet, and OpenBLAS (numpy's BLAS) stops its own threads
before a fork and starts them again when next used (its `pthread_atfork` handler), so that the
child has one thread and the parent the same BLAS as without the fork. The child is made to
look like a spawned helper (its own process group, stdin/stdout/stderr the three pipes, every
other file descriptor closed), runs the job's `helper_main()` and leaves by `os._exit`, never
returning into the parent's code. Anywhere else (a library use of `rodctl.simulate`, the tests,
not Linux) the helpers are spawned as before.
"""

from __future__ import annotations

import collections
import ctypes
import os
import pickle
import selectors
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import IO, Any, NoReturn

from rodctl import timeline
from rodctl.errors import describe_os_error

#: Seconds `result()` waits by default for a helper whose input has ended.
TIMEOUT_S = 60.0

#: Bytes of pickles a helper's input may hold back (its sender thread's queue): ~70 of the
#: largest records (a 640x480 frame's PNG), thousands of the usual ones.
QUEUE_BYTES = 64 << 20
#: Seconds `send` waits for room when the queue is full before it gives the helper up.
QUEUE_WAIT_S = 10.0

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

    def __init__(
        self, proc: subprocess.Popen | _Forked | None, name: str, failure: str | None = None
    ):
        self.proc = proc
        self.name = name
        #: Why there will be no reply, known before `result()` (no process, data unpicklable).
        self.failure = failure
        self._queue: _Inbox | None = None
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

    @classmethod
    def fork(cls, module: str, name: str) -> Helper:
        """Start the helper as a fork of this process (`fork_helper`; only where the module
        docstring says it is safe). Never raises: a helper that cannot be forked is reported by
        `result()`."""
        try:
            return cls(fork_helper(module), name)
        except OSError as exc:
            return cls(None, name, f"could not start the {name}: {describe_os_error(exc)}")

    def ended(self) -> str | None:
        """Why the helper ended before its reply was asked for (it failed, was killed), or None
        while it runs. Does not wait; once it says why, `failure` does too."""
        if self.failure is not None:
            return self.failure
        if self.proc is None or self._ended or self.proc.poll() is None:
            return None
        err = b""
        if self.proc.stderr is not None:
            try:
                err = self.proc.stderr.read()  # it has exited: the pipe ends
            except (OSError, ValueError):
                pass
        self.failure = _ended_why(self.name, self.proc.returncode, err)
        self._broken = True
        return self.failure

    @property
    def usable(self) -> bool:
        """Whether messages still reach the helper (started, not failed, input not ended)."""
        return not (self.proc is None or self.failure or self._ended or self._broken)

    def send(self, message: Any, pending: Future | None = None, pending_bytes: int = 0) -> None:
        """Queue `message`, pickled now; then, if given, the result of `pending` (or the
        exception it raised) once it is done, as the next pickle (`pending_bytes`: about how
        large, for the queue's bound). Returns at once unless the queue is full (the module
        docstring) and never raises (the parent's sinks call it, where an exception would fail
        the run's logs): a message that cannot be pickled makes `failure` say so and ends the
        exchange."""
        if not self.usable:
            return
        try:
            data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # noqa: BLE001 - e.g. a plug-in's unpicklable estimator info
            self.failure = f"the run could not be handed to the {self.name}: {exc!r}"
            self.end()
            return
        size = len(data) + (pending_bytes if pending is not None else 0)
        if not self._inbox().put((data, pending, size), size, QUEUE_WAIT_S):
            self.failure = (
                f"the {self.name} stopped reading its input ({QUEUE_BYTES >> 20} MB of the run "
                f"waited for it {QUEUE_WAIT_S:g} s): given up"
            )
            self._broken = True

    def end(self) -> None:
        """No more messages: the helper's input closes once the queued ones are written."""
        if self._ended or self.proc is None:
            self._ended = True
            return
        self._inbox().put(_END, 0, None)
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
        if code != 0:
            raise HelperFailed(_ended_why(self.name, code, err))
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

    def _inbox(self) -> _Inbox:
        """The sender thread's queue, the thread started (and stdin taken over) on first use."""
        if self._queue is None:
            assert self.proc is not None and self.proc.stdin is not None  # started with PIPE
            stdin, self.proc.stdin = self.proc.stdin, None  # ours now; communicate() leaves it
            self._queue = _Inbox(QUEUE_BYTES)
            self._sender = threading.Thread(
                target=self._write_all,
                args=(stdin, self._queue),
                name=f"rodctl-{self.name.replace(' ', '-')}-send",
                daemon=True,
            )
            self._sender.start()
        return self._queue

    def _write_all(self, stdin: IO[bytes], inbox: _Inbox) -> None:
        try:
            while (item := inbox.get()) is not _END:
                data, pending, size = item
                stdin.write(data)
                if pending is not None:
                    try:
                        value = pending.result()
                    except Exception as exc:  # noqa: BLE001 - the helper reports it in order
                        value = exc
                    stdin.write(_dumps_or_repr(value))
                stdin.flush()
                inbox.done(size)
        except (OSError, ValueError):  # the helper is gone: result() says why
            self._broken = True
        finally:
            try:
                stdin.close()
            except OSError:
                pass


def _ended_why(name: str, code: int | None, err: bytes) -> str:
    """Why a helper that exited with `code` (negative: killed by that signal) gave no reply,
    from the last line of its stderr `err`."""
    if code is not None and code < 0:
        try:
            how = signal.Signals(-code).name
        except ValueError:
            how = f"signal {-code}"
        return f"the {name} was killed by {how}"
    lines = err.decode("utf-8", "replace").strip().splitlines()
    return f"the {name} failed: {lines[-1] if lines else f'exit code {code}'}"


class _Inbox:
    """A FIFO of messages for the sender thread, holding at most `limit` bytes of them (one
    message larger than that still passes, alone)."""

    def __init__(self, limit: int) -> None:
        self._items: collections.deque[Any] = collections.deque()
        self._bytes = 0
        self._limit = limit
        self._cond = threading.Condition()

    def put(self, item: Any, size: int, timeout: float | None) -> bool:
        """Queue `item` of `size` bytes, waiting up to `timeout` s for room (None: no limit and
        no wait, for the end mark). False: no room came in time, nothing queued."""
        with self._cond:
            if timeout is not None:
                room = self._cond.wait_for(
                    lambda: self._bytes == 0 or self._bytes + size <= self._limit, timeout
                )
                if not room:
                    return False
            self._items.append(item)
            self._bytes += size
            self._cond.notify_all()
            return True

    def get(self) -> Any:
        with self._cond:
            self._cond.wait_for(lambda: bool(self._items))
            return self._items.popleft()

    def done(self, size: int) -> None:
        """`size` bytes of a message taken by `get` have been written: room for more."""
        with self._cond:
            self._bytes -= size
            self._cond.notify_all()


def _dumps_or_repr(value: Any) -> bytes:
    try:
        return pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # noqa: BLE001 - an exception that does not pickle: its text
        return pickle.dumps(RuntimeError(repr(value)), protocol=pickle.HIGHEST_PROTOCOL)


class _Forked:
    """What `Helper` uses of a `subprocess.Popen`, for a helper forked from this process."""

    def __init__(self, pid: int, stdin: IO[bytes], stdout: IO[bytes], stderr: IO[bytes]) -> None:
        self.pid = pid
        self.stdin: IO[bytes] | None = stdin
        self.stdout: IO[bytes] | None = stdout
        self.stderr: IO[bytes] | None = stderr
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere: its status is lost
                pid, status = self.pid, 255 << 8
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        delay = 0.0005
        while self.poll() is None:  # no pidfd in every kernel: short naps, growing to 20 ms
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                raise subprocess.TimeoutExpired(f"helper {self.pid}", timeout or 0.0)
            time.sleep(delay if left is None else min(delay, left))
            delay = min(delay * 2, 0.02)
        return self.poll() or 0

    def kill(self) -> None:
        if self.poll() is None:  # not reaped yet: the pid is still this child's
            os.kill(self.pid, signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> tuple[bytes, bytes]:
        """Everything the helper writes to stdout and stderr until both end, then its exit (as
        `Popen.communicate` with stdin taken over: `subprocess.TimeoutExpired` after
        `timeout` s)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        chunks: dict[int, list[bytes]] = {}
        with selectors.DefaultSelector() as sel:
            for stream in (self.stdout, self.stderr):
                if stream is not None:
                    chunks[stream.fileno()] = []
                    sel.register(stream.fileno(), selectors.EVENT_READ)
            while sel.get_map():
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise subprocess.TimeoutExpired(f"helper {self.pid}", timeout or 0.0)
                for key, _ in sel.select(left):
                    data = os.read(key.fd, 1 << 16)
                    if data:
                        chunks[key.fd].append(data)
                    else:
                        sel.unregister(key.fd)
        left = None if deadline is None else max(0.0, deadline - time.monotonic())
        self.wait(left)
        out = b"".join(chunks.get(self.stdout.fileno(), [])) if self.stdout else b""
        err = b"".join(chunks.get(self.stderr.fileno(), [])) if self.stderr else b""
        return out, err


def fork_helper(module: str) -> _Forked:
    """Fork a helper that runs `module.helper_main()` (module docstring, "Forked helpers"):
    call only while this process has no other thread. Raises `OSError` (no fork, no pipes)."""
    parent = os.getpid()
    pipes = [os.pipe() for _ in range(3)]  # stdin, stdout, stderr; not inheritable
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()  # nothing buffered here may be written twice, by the child too
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child (its coverage is not collected)
        _forked_child(module, parent, pipes)
    (in_r, in_w), (out_r, out_w), (err_r, err_w) = pipes
    for fd in (in_r, out_w, err_w):
        os.close(fd)
    return _Forked(pid, os.fdopen(in_w, "wb"), os.fdopen(out_r, "rb"), os.fdopen(err_r, "rb"))


def _forked_child(module: str, parent: int, pipes: list[tuple[int, int]]) -> NoReturn:
    """The forked helper: made to look like a spawned one, then its job; never returns."""
    global _PARENT
    code = 1
    try:
        os.setpgid(0, 0)  # its own group: the terminal's Ctrl-C reaches only the command
        signal.signal(signal.SIGINT, signal.default_int_handler)  # not `_entry.quiet_start`'s
        (in_r, _), (_, out_w), (_, err_w) = pipes
        for fd, target in ((in_r, 0), (out_w, 1), (err_w, 2)):
            os.dup2(fd, target)
        os.closerange(3, _max_fd())  # the parent's ends (and the other helper's) closed here
        # The streams on the three pipes (the parent's may be None: started with one closed),
        # kept alive here as sys.__stdout__ keeps a spawned helper's (`begin` replaces stdout).
        _STDIO[:] = [
            open(fd, mode, encoding="utf-8", closefd=False)  # noqa: SIM115 - for good
            for fd, mode in ((0, "r"), (1, "w"), (2, "w"))
        ]
        sys.stdin, sys.stdout, sys.stderr = _STDIO
        _PARENT = parent
        _bare_package()
        import importlib  # noqa: PLC0415 (the child only)

        importlib.import_module(module).helper_main()
        code = 0
    except BaseException:  # noqa: BLE001 - to stderr, then out: never back into the parent's code
        try:
            traceback.print_exc()
            sys.stderr.flush()
        except BaseException:  # noqa: BLE001, S110 - nothing left to report it with
            pass
    finally:
        os._exit(code)


def _bare_package() -> None:
    """Make `rodctl` a bare package of the same folder in a forked helper, as in a spawned one.
    Why: the fork happens while `rodctl/__init__` runs, so the package stays "being imported"
    in the child for good, and any other thread that imports from it (the figure process's
    reader, unpickling a record) would wait forever for the import lock of the main thread."""
    import types  # noqa: PLC0415 (the child only)

    old = sys.modules["rodctl"]
    package = types.ModuleType("rodctl", old.__doc__)
    package.__path__ = list(old.__path__)
    for key, value in vars(old).items():  # the submodules imported before the fork
        if isinstance(value, types.ModuleType) and value.__name__.startswith("rodctl."):
            setattr(package, key, value)
    sys.modules["rodctl"] = package


def _max_fd() -> int:
    try:
        return min(int(os.sysconf("SC_OPEN_MAX")), 1 << 20)
    except (OSError, ValueError):  # pragma: no cover
        return 1024


#: The parent's pid in a forked helper (a spawned one has it as argv[2]).
_PARENT: int | None = None
#: A forked helper's stdin, stdout and stderr streams (`_forked_child`).
_STDIO: list[Any] = []

#: Helpers forked by the entry point before the command's own imports (`start_early`), by
#: module, until `Helpers.start` takes them (or `stop_early` stops those the run does not need).
_EARLY: dict[str, Helper] = {}


def start_early(jobs: list[tuple[str, str]]) -> None:
    """Fork the helpers of `jobs` (module, name) now, for the run's `Helpers.start` to take:
    the entry point's (`rodctl._entry`), before the command's imports and any thread (with
    another Python thread running, none: `Helpers.start` spawns them later)."""
    if threading.active_count() > 1:
        return
    for module, name in jobs:
        if module not in _EARLY:
            _EARLY[module] = Helper.fork(module, name)
            timeline.mark("main", f"started {module}")


def stop_early() -> None:
    """Stop the helpers forked early that no run took (the config switched their job off)."""
    while _EARLY:
        _EARLY.popitem()[1].stop()


class Helpers:
    """Helpers started before the run needs them (`start`), so that their imports overlap the
    command's; each is `take`n by the sink that uses it. A context manager: every helper it
    started or handed out is stopped at the end. `start` takes a helper the entry point forked
    for this module already (`start_early`), if there is one."""

    def __init__(self) -> None:
        self._waiting: dict[str, Helper] = {}
        self._all: list[Helper] = []

    def start(self, module: str, name: str) -> None:
        """Start the helper of `module` now (once)."""
        if module not in self._waiting:
            early = _EARLY.pop(module, None)
            self._waiting[module] = helper = early or Helper.start(module, name)
            self._all.append(helper)
            if early is None:
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


def die_with_parent(parent: int) -> None:
    """Be killed when the process `parent` dies (Linux), and exit now if it already has: a
    helper at its start, and a child a helper forks itself (PR_SET_PDEATHSIG is not inherited
    across a fork)."""
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
    die_with_parent(_PARENT if _PARENT is not None else int(sys.argv[2]))
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
