"""run.rrd written by a helper process (`rodctl.helper_process`): the Rerun recording of
`rodctl simulate`, without rerun in the command.

Why (issue #24): importing rerun-sdk costs ~0.5 s of CPU and its first columns ~0.25 s more
(pyarrow imports pandas when there is one), paid by the command before the first step. The
helper starts with the run, imports rerun while the command imports its own libraries and runs
the episode, and writes the recording with the same `RerunSink` as in-process (so the file has
the same entities, blueprint and chunks: `rerun rrd compare` finds no difference).

The command's side (`RerunProcessSink`, a `Sink`) does what needs the run: it opens the file
first (so that a folder that cannot take it is an `OSError` naming it, at `open`, as in-process),
chooses the camera frames (`codec.FrameSchedule`) and has them PNG-encoded by the command's
shared encoder (`codec.FRAMES`: the MCAP's frames, encoded once for both), and streams the
header, each record (its frame as PNG bytes, not pixels) and the close to the helper. What the
recording meets (a full disk, a bad record) is known when the helper replies, at `close`: raised
for a completed run, a warning otherwise, as `RerunSink.close` does. A helper that cannot start,
fails, is killed or does not answer is the same kind of error ("the Rerun process …"), and
is said as soon as the command sees it: a helper that has ended already at `open` (rerun-sdk
that does not import: the helper's first act) fails the open, before the first step, as
`RerunSink.open` would; one that ends during the run is a warning at the next `write`, and
the error at `close` as above. Whatever
ends the run (an exception, SIGINT/SIGTERM at the command), the episode closes its sinks, so
the helper finishes the file with the run's real status and what was logged is kept; a command
killed outright takes its helper with it (the recording then ends where the helper had got to).

Protocol: `("open", path, options, header)`, then `("write", record, has_frame)` per step (with
`has_frame`, the PNG bytes as the next pickle), then `("close", summary, status)`. The reply:
`(error or None, [warning texts])`.
"""

from __future__ import annotations

import dataclasses
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rodctl import helper_process, timeline
from rodctl.helper_process import Helper, HelperFailed
from rodctl.logs import codec
from rodctl.logs.base import raise_or_warn
from rodctl.records import RunHeader, RunSummary, StepRecord

MODULE, NAME = "rodctl.logs.rerun_process", "Rerun process"

#: Seconds `close` waits for the helper to finish the file: beyond Rerun's own bounded waits
#: (`rodctl.logs.rerun.FLUSH_TIMEOUT_S`, twice) and an import still running.
CLOSE_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class RerunOptions:
    """What `RerunSink` reads of the logging config, as plain data: the helper imports neither
    pydantic nor the config models."""

    flush_every_steps: int
    image_rate_hz: float
    png_compression: int

    @classmethod
    def of(cls, cfg: Any) -> RerunOptions:
        """The options of a `LoggingConfig`."""
        return cls(int(cfg.flush_every_steps), float(cfg.image_rate_hz), int(cfg.png_compression))


class RerunProcessSink:
    """Writes run.rrd through a helper process (module docstring); a `Sink`.

    Args:
        helper: a started `Helper` of this module (`Helpers.take`); stopped by its owner.
        path: the .rrd file to write.
        cfg: the logging config (flush interval, frame rate, PNG level of frames).
    """

    def __init__(self, helper: Helper, path: str | Path, cfg: Any) -> None:
        self.helper = helper
        self.path = Path(path)
        self.options = RerunOptions.of(cfg)
        self._frames = codec.FrameSchedule(self.options.image_rate_hz)
        self._opened = self._closed = False
        self._warned = False  # the helper's end was reported during the run

    def open(self, header: RunHeader) -> None:
        if self._opened:
            raise RuntimeError("RerunProcessSink.open called twice")
        # Rerun reports a file it cannot create with no path or reason: open it here, so a
        # read-only or full disk is an OSError that names both (as `RerunSink.open`).
        open(self.path, "ab").close()
        # It could not start, or it has ended already (rerun-sdk does not import, say): the run
        # cannot have its file, and says so now, before its first step (as `RerunSink.open`).
        if (why := self.helper.ended()) is not None:
            raise RuntimeError(why)
        self._opened = True
        self.helper.send(("open", str(self.path), self.options, header))

    def write(self, record: StepRecord) -> None:
        if not self._opened or self._closed:
            raise RuntimeError("RerunProcessSink.write called before open (or after close)")
        if not self._warned and (why := self.helper.ended()) is not None:
            # Said at once, not only at close (where it is raised for a completed run, as any
            # error of the recording's).
            self._warned = True
            warnings.warn(f"{self.path}: {why}; run.rrd will be incomplete", RuntimeWarning, 2)
        frame = None
        if record.image is not None and self._frames.due(record):
            frame = codec.FRAMES.submit(record.image, self.options.png_compression)
            self._frames.take(record)
        bare = record if record.image is None else dataclasses.replace(record, image=None)
        size = 0 if record.image is None else int(record.image.nbytes)  # the PNG is less
        self.helper.send(("write", bare, frame is not None), pending=frame, pending_bytes=size)

    def close(self, summary: RunSummary | None, status: str) -> None:
        """Have the helper finish the file and wait for it; its errors as `RerunSink.close`
        raises or warns them. Idempotent."""
        if self._closed or not self._opened:
            self._closed = True
            return
        self._closed = True
        self.helper.send(("close", summary, status))
        timeline.mark("main", "rerun close sent")
        try:
            reply = self.helper.result(CLOSE_TIMEOUT_S)
        except HelperFailed as exc:
            raise_or_warn([RuntimeError(str(exc))], status, f"{self.path}: the Rerun recording")
            return
        finally:
            timeline.mark("main", "rerun closed")
        if not (isinstance(reply, tuple) and len(reply) == 2):
            error: BaseException | None = RuntimeError(f"the {NAME} sent no reply")
            notes: list[str] = []
        else:
            error, notes = reply
        for note in notes:
            warnings.warn(note, RuntimeWarning, stacklevel=2)
        if error is not None:
            raise_or_warn([error], status, f"{self.path}: closing the Rerun recording failed")


# --- helper side ------------------------------------------------------------------------------


def helper_main() -> None:
    """The helper: import rerun, then write what the command sends (see the module docstring)."""
    out = helper_process.begin("rerun")
    try:
        from rodctl.logs.rerun import RerunSink  # noqa: PLC0415 (the slow part: while the run starts)
    except ImportError as exc:  # the command sees this process end, and says why at once
        print(f"rerun-sdk cannot be imported: {exc}", file=sys.stderr)
        helper_process.exit_now(1)

    _without_pandas()
    timeline.mark("rerun", "ready")
    sink: RerunSink | None = None
    error: BaseException | None = None
    notes: list[str] = []
    stream = helper_process.messages()
    for message in stream:
        kind = message[0]
        try:
            if kind == "open":
                _, path, options, header = message
                sink = RerunSink(path, options)
                sink.open(header)
            elif kind == "write":
                _, record, has_frame = message
                png = next(stream) if has_frame else None
                if isinstance(png, BaseException):
                    raise png
                if sink is not None and error is None:
                    sink.write_step(record, None if png is None else _done(png))
            elif kind == "close" and sink is not None:
                _, summary, status = message
                # After an error the file is still finished, as a failed run's.
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    sink.close(summary, status if error is None else "failed")
                notes += [str(w.message) for w in caught]
        except Exception as exc:  # noqa: BLE001 - the first error goes to the command
            error = error or exc
    timeline.mark("rerun", "closed")
    helper_process.reply(out, (_picklable(error), notes), "rerun")


def _done(value: bytes) -> Any:
    """A future that is done already: what `RerunSink.write_step` takes."""
    from concurrent.futures import Future  # noqa: PLC0415 (helper side only)

    future: Future[bytes] = Future()
    future.set_result(value)
    return future


def _picklable(error: BaseException | None) -> BaseException | None:
    import pickle  # noqa: PLC0415 (helper side only)

    if error is None:
        return None
    try:
        pickle.dumps(error)
        return error
    except Exception:  # noqa: BLE001 - its text, then
        return RuntimeError(repr(error))


def _without_pandas() -> None:
    """Tell pyarrow that there is no pandas in this process. Why: pyarrow imports pandas (when
    installed, ~0.25 s of CPU) the first time it converts a numpy array, to check whether the
    array is a pandas object; Rerun converts every column it logs that way, and this process
    logs nothing else. Importing pandas from here on fails (as where it is not installed, which
    pyarrow handles), so no pandas object can exist here."""
    if "pandas" not in sys.modules:
        sys.meta_path.insert(0, _NoPandas())


class _NoPandas:
    """An import finder that refuses pandas (`_without_pandas`)."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> None:
        if name.partition(".")[0] == "pandas":
            raise ModuleNotFoundError("the Rerun process does without pandas", name=name)
        return None
