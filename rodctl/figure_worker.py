"""A run's three figures drawn in a helper process, beside the run instead of after it.

Why (issue #17): importing matplotlib and drawing the figures took ~0.9 s at the end of every
`rodctl simulate`, after the episode. `FigureWorker.start()` starts the helper when the run
starts; it imports matplotlib and `rodctl.plots` on the second core while the episode runs and
then waits. As the first sink of the episode it receives the header and the step records when
the episode ends (before the MCAP and Rerun files are closed) and draws the PNGs while the
command closes its logs and writes summary.json; `result()` hands back the PNG bytes and the
command writes them (`save_figures`, here: the command never imports matplotlib), so where the
figures go, whether they are written at all and every error writing them can meet are those of
drawing in-process.

Failure: a helper that cannot start, fails, is killed or does not answer within the timeout makes
`result()` raise `FiguresFailed` with the reason; it never raises anything else.

Lifetime: the helper never outlives the command. It is its own process group, so a Ctrl-C at
the terminal (or a signal to the command's group) reaches only the command, which decides how
the run ends; it dies with its parent (PR_SET_PDEATHSIG on Linux; elsewhere it exits when it
reads the end of its input, which the parent's death closes); and `stop()`, called in a
`finally` by every user, kills it and reaps it.

Protocol: the parent writes one pickle `(header, records)` to the helper's stdin and closes it
(closing it without writing means "no figures": the helper exits); the helper writes one pickle
`{file name: PNG bytes}` to its stdout and exits 0. A traceback goes to its stderr.
"""

from __future__ import annotations

import ctypes
import os
import pickle
import signal
import subprocess
import sys
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rodctl.errors import describe_os_error
from rodctl.records import RunHeader, RunSummary, StepRecord

#: Seconds the command waits for the figures once it needs them (they take ~0.5 s; a helper
#: that has not answered by then is killed and the figures are reported as not written).
TIMEOUT_S = 60.0

#: The `rodctl` package folder the parent imported: the helper imports from the same one.
_PACKAGE = str(Path(__file__).resolve().parent)

#: The helper's program. It needs rodctl.records, rodctl.plots and this module, not the package's
#: `__init__` (which imports gymnasium to register the environment: 0.2 s of CPU that would
#: compete with the episode), so `rodctl` is a bare package of the parent's folder. `-P`: no
#: current folder on sys.path either.
_BOOT = (
    "import sys, types\n"
    "package = types.ModuleType('rodctl')\n"
    "package.__path__ = [sys.argv[1]]\n"
    "sys.modules['rodctl'] = package\n"
    "from rodctl.figure_worker import main\n"
    "main()\n"
)


class FiguresFailed(Exception):
    """The helper gave no figures; `str()` is the reason, for meta.json and the error line."""


class FigureWorker:
    """The parent's handle on the helper; also a sink (`rodctl.logs.base.Sink`) that hands the
    run over when the episode closes its sinks. Use `start()`, then `stop()` in a `finally`."""

    def __init__(self, proc: subprocess.Popen | None, failure: str | None = None) -> None:
        self.proc = proc
        #: Why there will be no figures, known before `result()` (no process, data unpicklable).
        self.failure = failure
        self._header: RunHeader | None = None
        self._records: list[StepRecord] = []
        self._sender: threading.Thread | None = None

    @classmethod
    def start(cls) -> FigureWorker:
        """Start the helper (it begins importing at once). Never raises: a helper that cannot
        be started is reported by `result()`."""
        cmd = [sys.executable, "-P", "-c", _BOOT, _PACKAGE, str(os.getpid())]
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
            return cls(None, f"could not start the figure process: {why}")
        return cls(proc)

    # --- the sink: the episode hands the run over as it closes -------------------------------

    def open(self, header: RunHeader) -> None:
        self._header, self._records = header, []

    def write(self, record: StepRecord) -> None:
        self._records.append(record)

    def close(self, summary: RunSummary | None, status: str) -> None:
        if self._header is not None and self._records:
            self.submit(self._header, self._records)

    # --- parent side --------------------------------------------------------------------------

    def submit(self, header: RunHeader, records: Sequence[StepRecord]) -> None:
        """Hand the run to the helper (once; later calls do nothing). Returns at once and never
        raises (it runs as a sink, where an exception would fail the run's logs): a thread
        writes the data, so a helper still importing never blocks the command."""
        if self._sender is not None or self.proc is None or self.failure is not None:
            return
        try:
            data = pickle.dumps((header, list(records)), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # noqa: BLE001 - e.g. a plug-in's unpicklable estimator info
            self.failure = f"the run could not be handed to the figure process: {exc!r}"
            return
        stdin, self.proc.stdin = self.proc.stdin, None  # ours now; communicate() leaves it
        assert stdin is not None  # started with stdin=PIPE

        def send() -> None:
            try:
                stdin.write(data)
            except (OSError, ValueError):  # the helper is gone; result() says why
                pass
            finally:
                try:
                    stdin.close()
                except OSError:
                    pass

        self._sender = threading.Thread(target=send, name="figure-worker-send", daemon=True)
        self._sender.start()

    def result(self, timeout: float | None = None) -> dict[str, bytes]:
        """The PNG bytes by file name, waiting at most `timeout` s (default `TIMEOUT_S`) for
        the helper after `submit`. Raises `FiguresFailed` (the helper is then stopped)."""
        timeout = TIMEOUT_S if timeout is None else timeout
        if self.failure is not None or self.proc is None:
            raise FiguresFailed(self.failure or "no figure process")
        if self._sender is None:
            raise FiguresFailed("no run was handed to the figure process")
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.stop()
            raise FiguresFailed(f"the figure process did not finish within {timeout:g} s") from None
        finally:
            self._sender.join(timeout=1.0)
        code = self.proc.returncode
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            raise FiguresFailed(f"the figure process was killed by {name}")
        if code != 0:
            lines = err.decode("utf-8", "replace").strip().splitlines()
            raise FiguresFailed(
                f"the figure process failed: {lines[-1] if lines else f'exit code {code}'}"
            )
        try:
            pngs = pickle.loads(out)
        except Exception:  # noqa: BLE001 - whatever it sent, it is not figures
            pngs = None
        if not (
            isinstance(pngs, dict)
            and pngs
            and all(isinstance(k, str) and isinstance(v, bytes) for k, v in pngs.items())
        ):
            raise FiguresFailed("the figure process sent no figures")
        return pngs

    def stop(self) -> None:
        """Kill the helper if it still runs and reap it (idempotent; never raises)."""
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

    def __enter__(self) -> FigureWorker:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def save_figures(pngs: Mapping[str, bytes], out_dir: str | Path) -> list[Path]:
    """Write PNG bytes by file name (`rodctl.plots.render_figures`) under `out_dir`, creating it
    (an `OSError` is the caller's: a full disk, a read-only folder)."""
    paths = []
    for name, data in pngs.items():
        path = Path(out_dir) / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        paths.append(path)
    return paths


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


def main() -> None:
    """The helper: import, wait for the run, draw, reply (see the module docstring)."""
    reply = sys.stdout.buffer
    sys.stdout = sys.stderr  # anything printed while drawing must not corrupt the reply
    _die_with_parent(int(sys.argv[2]))
    # The slow part (matplotlib), while the parent runs the episode; the command never imports it.
    from rodctl import plots  # noqa: PLC0415

    plots.warm_up()
    data = sys.stdin.buffer.read()
    if not data:
        return  # the command needs no figures (or is gone)
    header, records = pickle.loads(data)
    pngs = plots.render_figures(header, records)
    reply.write(pickle.dumps(pngs, protocol=pickle.HIGHEST_PROTOCOL))
    reply.flush()
    sys.stderr.flush()
    # Done: skip the interpreter's tear-down of matplotlib (~0.3 s the command would wait for).
    os._exit(0)
