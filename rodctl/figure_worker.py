"""A run's three figures drawn in a helper process (`rodctl.helper_process`), beside the run
instead of after it.

Why (issue #17): importing matplotlib and drawing the figures took ~0.9 s at the end of every
`rodctl simulate`, after the episode. The helper starts when the run starts and imports
matplotlib and `rodctl.plots` on the second core while the command imports and runs the
episode. As the first sink of the episode it receives the header when the episode opens its
sinks and each step record as it is written (camera frames left out: no figure shows them), and
meanwhile begins the figures (`plots.RunFigures`), so that when the episode ends only the run's
data is left to draw; it draws the PNGs while the command closes
its logs and writes summary.json. `result()` hands back the PNG bytes and the command writes
them (`save_figures`, here: the command never imports matplotlib), so where the figures go,
whether they are written at all and every error writing them can meet are those of drawing
in-process.

Failure: a helper that cannot start, fails, is killed or does not answer within the timeout makes
`result()` raise `FiguresFailed` with the reason; it never raises anything else. Lifetime: that of
every helper (`rodctl.helper_process`): it never outlives the command.

Protocol: `("header", RunHeader)`, then one `("record", StepRecord)` per step; the end of the
input (with no record sent: "no figures", the helper exits). The reply: `{file name: PNG bytes}`.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rodctl import helper_process, timeline
from rodctl.helper_process import Helper, HelperFailed
from rodctl.records import RunHeader, RunSummary, StepRecord

#: Seconds the command waits for the figures once it needs them (they take ~0.5 s; a helper
#: that has not answered by then is killed and the figures are reported as not written).
TIMEOUT_S = 60.0

MODULE, NAME = "rodctl.figure_worker", "figure process"


class FiguresFailed(Exception):
    """The helper gave no figures; `str()` is the reason, for meta.json and the error line."""


class FigureWorker:
    """The parent's handle on the helper; also a sink (`rodctl.logs.base.Sink`) that streams
    the run to it. Use `start()` (or wrap a `Helper` already started), then `stop()` in a
    `finally`."""

    def __init__(self, helper: Helper) -> None:
        self.helper = helper
        self._opened = False  # the header went out: records follow as they come
        self._records = 0

    @classmethod
    def start(cls) -> FigureWorker:
        """Start the helper (it begins importing at once). Never raises: a helper that cannot
        be started is reported by `result()`."""
        return cls(Helper.start(MODULE, NAME))

    @property
    def failure(self) -> str | None:
        """Why there will be no figures, known before `result()` (no process, data unpicklable)."""
        return self.helper.failure

    # --- the sink: the episode streams the run to the helper ---------------------------------

    def open(self, header: RunHeader) -> None:
        if not self._opened:
            self._opened = True
            self.helper.send(("header", header))

    def write(self, record: StepRecord) -> None:
        if self._opened:
            self._records += 1
            self.helper.send(("record", _without_image(record)))

    def close(self, summary: RunSummary | None, status: str) -> None:
        self.helper.end()  # the helper draws what it has (nothing, when no step was written)

    # --- parent side --------------------------------------------------------------------------

    def submit(self, header: RunHeader, records: Sequence[StepRecord]) -> None:
        """Hand a whole run to the helper (once; nothing to do when the sink already streamed
        one). Returns at once and never raises."""
        if not self._opened:
            self.open(header)
            for record in records:
                self.write(record)
        self.helper.end()

    def result(self, timeout: float | None = None) -> dict[str, bytes]:
        """The PNG bytes by file name, waiting at most `timeout` s (default `TIMEOUT_S`) for
        the helper once the run is handed over. Raises `FiguresFailed` (the helper is then
        stopped)."""
        timeout = TIMEOUT_S if timeout is None else timeout
        if self.helper.failure is None and self.helper.proc is not None and not self._records:
            raise FiguresFailed(f"no run was handed to the {NAME}")
        try:
            pngs = self.helper.result(timeout)
        except HelperFailed as exc:
            raise FiguresFailed(str(exc)) from None
        if not (
            isinstance(pngs, dict)
            and pngs
            and all(isinstance(k, str) and isinstance(v, bytes) for k, v in pngs.items())
        ):
            raise FiguresFailed(f"the {NAME} sent no figures")
        return pngs

    def stop(self) -> None:
        """Kill the helper if it still runs and reap it (idempotent; never raises)."""
        self.helper.stop()

    def __enter__(self) -> FigureWorker:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def _without_image(record: StepRecord) -> StepRecord:
    """The record without its camera frame (~0.9 MB that no figure shows)."""
    if record.image is None:
        return record
    return dataclasses.replace(record, image=None)


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


def helper_main() -> None:
    """The helper: import, receive the run, draw, reply (see the module docstring).

    The run is read on a thread as it comes; the figures are made (not drawn) meanwhile."""
    out = helper_process.begin("figures")
    received: list[Any] = []
    ended = threading.Event()

    def read() -> None:
        received.extend(helper_process.messages())
        ended.set()

    reader = threading.Thread(target=read, name="rodctl-figures-read", daemon=True)
    reader.start()
    try:
        pngs = _draw(received, ended, reader)
    except BaseException:  # noqa: BLE001 - the traceback to stderr, exit 1 (a reading thread
        helper_process.fail()  # would make the interpreter's shut-down abort)
    if pngs is None:
        helper_process.exit_now()  # the command needs no figures (or is gone)
    helper_process.reply(out, pngs, "figures")


def _draw(
    received: list[Any], ended: threading.Event, reader: threading.Thread
) -> dict[str, bytes] | None:
    """The figures of the run `received` once `ended` is set (None: no run came)."""
    # The slow part (matplotlib), while the parent runs the episode; the command never imports it.
    from rodctl import plots  # noqa: PLC0415

    figures = plots.RunFigures()
    timeline.mark("figures", "ready")
    ended.wait()
    reader.join()  # it has returned: this process has one thread again (`_render`'s fork)
    timeline.mark("figures", "input ended")
    header = next((value for kind, value in received if kind == "header"), None)
    records = [value for kind, value in received if kind == "record"]
    if header is None or not records:
        return None
    return _render(figures, header, records)


#: The figure drawn by a forked child of the figure process while it draws the others
#: (`_render`): the slowest of the three (~half of the drawing).
FORKED = "commands.png"


def _cores() -> int:
    """The CPUs this process may run on (the machine's, not how busy they are)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _render(figures: Any, header: RunHeader, records: list[StepRecord]) -> dict[str, bytes]:
    """The PNGs of the run (`plots.RunFigures.render`), on two cores where there are two: the
    drawing is the end of `rodctl simulate`, after the episode, when the command and the Rerun
    process wait and their cores are idle, so a forked child draws `FORKED` while this process
    draws the others (the same bytes: each figure is its own). A child that fails costs time
    only: its figure is then drawn here. One core (or no fork): all three here, in turn."""
    if _cores() < 2 or not hasattr(os, "fork"):
        return figures.render(header, records)
    try:
        child = _fork_figure(figures, header, records)
    except OSError:
        return figures.render(header, records)
    from rodctl.plots import RUN_FIGURES  # noqa: PLC0415 - imported already (`_draw`)

    pngs = {n: figures.render_one(n, header, records) for n in RUN_FIGURES if n != FORKED}
    forked = _child_png(*child)
    timeline.mark("figures", "forked figure received")
    if forked is None:
        forked = figures.render_one(FORKED, header, records)
    return {n: forked if n == FORKED else pngs[n] for n in RUN_FIGURES}


def _fork_figure(figures: Any, header: RunHeader, records: list[StepRecord]) -> tuple[int, int]:
    """Fork a child that writes `FORKED`'s PNG bytes to a pipe and exits; (pid, read end)."""
    r, w = os.pipe()
    sys.stderr.flush()
    parent = os.getpid()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child (its coverage is not collected)
        code = 1
        try:
            os.close(r)
            helper_process.die_with_parent(parent)
            data = figures.render_one(FORKED, header, records)
            view = memoryview(data)
            while view:
                view = view[os.write(w, view) :]
            code = 0
        except BaseException:  # noqa: BLE001 - the parent draws it instead
            pass
        finally:
            os._exit(code)
    os.close(w)
    return pid, r


def _child_png(pid: int, fd: int) -> bytes | None:
    """The child's PNG bytes, None if it failed (reaped either way)."""
    chunks = []
    try:
        while data := os.read(fd, 1 << 16):
            chunks.append(data)
    except OSError:
        chunks = []
    finally:
        os.close(fd)
    _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0 or not chunks:
        return None
    return b"".join(chunks)
