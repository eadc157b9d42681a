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

    The run is read on a thread as it comes. Warming matplotlib up and drawing the figures once
    empty save time only while the helper waits: each is skipped once the input has ended (a
    helper that got its imports done after the episode goes straight to the drawing)."""
    out = helper_process.begin("figures")
    received: list[Any] = []
    ended = threading.Event()

    def read() -> None:
        received.extend(helper_process.messages())
        ended.set()

    threading.Thread(target=read, name="rodctl-figures-read", daemon=True).start()
    try:
        pngs = _draw(received, ended)
    except BaseException:  # noqa: BLE001 - the traceback to stderr, exit 1 (a reading thread
        helper_process.fail()  # would make the interpreter's shut-down abort)
    if pngs is None:
        helper_process.exit_now()  # the command needs no figures (or is gone)
    helper_process.reply(out, pngs, "figures")


def _draw(received: list[Any], ended: threading.Event) -> dict[str, bytes] | None:
    """The figures of the run `received` once `ended` is set (None: no run came)."""
    # The slow part (matplotlib), while the parent runs the episode; the command never imports it.
    from rodctl import plots  # noqa: PLC0415

    figures = plots.RunFigures()
    if not ended.is_set():
        plots.warm_up()
    figures.draw_empty(stop=ended.is_set)
    timeline.mark("figures", "ready")
    ended.wait()
    timeline.mark("figures", "input ended")
    header = next((value for kind, value in received if kind == "header"), None)
    records = [value for kind, value in received if kind == "record"]
    if header is None or not records:
        return None
    return figures.render(header, records)
