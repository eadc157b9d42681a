"""Terminal output: the progress bar of a run and the summary table (rich).

Progress goes to stderr so that stdout stays machine-readable (its last line is the run
directory); rich disables animation by itself when stderr is not a terminal.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table
from rich.text import Text

from rodctl.records import RunSummary, StepRecord, summary_text

stderr = Console(stderr=True)


class StepProgress:
    """The callback of `step_progress` (call it with each record); `done()` ends the bar before
    the block does, so that the summary can be printed under it while the command finishes."""

    def __init__(self, update: Callable[[StepRecord], None], done: Callable[[], None]) -> None:
        self._update, self.done = update, done

    def __call__(self, rec: StepRecord) -> None:
        self._update(rec)


@contextmanager
def step_progress(total: int, enabled: bool = True) -> Iterator[StepProgress]:
    """A progress bar over control steps showing T1 and the pixel error; yields the callback."""
    if not enabled:
        yield StepProgress(lambda _rec: None, lambda: None)
        return
    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("T1 {task.fields[t1]:.4f}  px err {task.fields[px]:.2f}"),
        TimeElapsedColumn(),
        console=stderr,
        transient=False,
    )
    task = progress.add_task("step", total=total, t1=float("nan"), px=float("nan"))
    started = stopped = False

    def on_step(rec: StepRecord) -> None:
        # The bar appears with the first step, so that a run failing before it (a bad target,
        # an unreadable checkpoint) prints its error without a bar of NaNs above it.
        nonlocal started
        if not started and not stopped:
            started = True
            progress.start()
        progress.update(
            task, completed=rec.step, t1=rec.T1, px=rec.pixel_error, description=rec.phase
        )

    def done() -> None:
        # Once only: off a terminal, every Progress.stop() prints an empty line.
        nonlocal stopped
        if started and not stopped:
            progress.stop()
        stopped = True

    try:
        yield StepProgress(on_step, done)
    finally:
        done()


class RateColumn(ProgressColumn):
    """Units of work per second since the bar started, e.g. "3.2 episodes/s".

    Work done in this process (the units a resumed run started with excluded, the `done_before`
    field of the task) over the time elapsed. Not rich's own speed, which divides by the time
    between the first and last update it sampled: two episodes that finish together, 3 ms
    apart after 1 s, made it "313 episodes/s".
    """

    def __init__(self, unit: str) -> None:
        super().__init__()
        self.unit = unit

    def render(self, task) -> Text:  # noqa: ANN001 - rich's Task
        done = task.completed - task.fields.get("done_before", 0)
        elapsed = task.finished_time if task.finished_time is not None else task.elapsed
        if not done or not elapsed:
            return Text("-")
        return Text(f"{done / elapsed:.2f} {self.unit}/s")


#: Seconds between two plain progress lines when stderr is not a terminal (`task_progress`).
LINE_EVERY_S = 5.0


def _clock(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


@contextmanager
def _progress_lines(label: str, total: int, unit: str, completed: int) -> Iterator[Callable]:
    """`task_progress` off a terminal: one plain line on stderr every `LINE_EVERY_S` seconds
    and when the work is done, e.g. "training: 120/300 epochs (40%), rms 2.31 px, 0:12 elapsed,
    ETA 0:18"."""
    start, last = time.monotonic(), -math.inf
    done = completed

    def advance(note: str = "", n: int = 1) -> None:
        nonlocal done, last
        done += n
        now = time.monotonic()
        if now - last < LINE_EVERY_S and done < total:
            return
        last = now
        elapsed = now - start
        rate = (done - completed) / elapsed if elapsed > 0 else 0.0
        eta = _clock((total - done) / rate) if rate > 0 else "?"
        share = f" ({100.0 * done / total:.0f}%)" if total else ""
        parts = [f"{label}: {done:,}/{total:,}{' ' + unit if unit else ''}{share}"]
        parts += [note] if note else []
        parts += [f"{_clock(elapsed)} elapsed", f"ETA {eta}"]
        print(", ".join(parts), file=sys.stderr, flush=True)

    yield advance


@contextmanager
def task_progress(
    label: str,
    total: int,
    enabled: bool = True,
    rate: str | None = None,
    completed: int = 0,
    *,
    lines_unit: str | None = None,
) -> Iterator[Callable[..., None]]:
    """A progress bar over `total` units of work (samples, epochs, episodes) on stderr.

    Yields ``advance(note="", n=1)``: move the bar by n and show a short note beside it.
    `rate` names the unit to show a rate of (e.g. "episodes"); `completed` starts the bar
    part-way (a resumed run). With `lines_unit` (e.g. "epochs"), when stderr is not a terminal
    (a log file, a pipe, a notebook) a plain line is printed every `LINE_EVERY_S` seconds
    instead of the bar, which rich would otherwise only draw at the end.
    """
    if enabled and lines_unit is not None and not stderr.is_terminal:
        with _progress_lines(label, total, lines_unit, completed) as advance:
            yield advance
        return
    progress = Progress(
        TextColumn(f"[bold]{label}"),
        BarColumn(),
        MofNCompleteColumn(),
        *([RateColumn(rate)] if rate else []),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.fields[note]}"),
        console=stderr,
        disable=not enabled,
    )
    with progress:
        task = progress.add_task(
            label, total=total, note="", completed=completed, done_before=completed
        )

        def advance(note: str = "", n: int = 1) -> None:
            progress.update(task, advance=n, note=note)

        yield advance


def summary_table(summary: RunSummary, title: str = "run summary") -> Table:
    """The summary as a two-column table."""
    table = Table(title=title, show_header=False)
    table.add_column("key", style="bold")
    table.add_column("value")
    for key, value in summary.to_json().items():
        table.add_row(key, summary_text(value))
    return table


def print_summary(summary: RunSummary) -> None:
    """Print the summary table to stderr."""
    stderr.print(summary_table(summary))
