"""`rodctl simulate`: one experiment into one run directory, safe against every way it can end.

Whatever happens — convergence, divergence, an exception inside the loop, Ctrl-C, SIGTERM — the
episode (`rodctl.episode.run_episode`) closes the sinks (MCAP and Rerun files finalised) with
its real status, summary.json is written from the records so far and meta.json records the
terminal status. Nothing already logged is lost.

The figures are drawn, and run.rrd is written, by helper processes (`rodctl.figure_worker`,
`rodctl.logs.rerun_process`) started with the run (`rodctl.logs.sinks.start_helpers`; the CLI
starts them before it imports this module), so that importing matplotlib and rerun overlaps
with the command's own imports and the episode instead of following them; the command still
writes the figures, and waits for both, before it returns.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rodctl import signals, timeline
from rodctl.config import ExperimentConfig
from rodctl.env import ShapeServoEnv
from rodctl.episode import EpisodeFailed, EpisodeResult, Outcome, run_episode
from rodctl.errors import RunFailed, UserError, describe_os_error
from rodctl.figure_worker import FiguresFailed, FigureWorker, save_figures
from rodctl.logs.base import Sink
from rodctl.logs.sinks import (
    FiguresSinkConfig,
    SinkContext,
    make_sink,
    selected_sinks,
    start_helpers,
)
from rodctl.method import Method
from rodctl.records import RunSummary, StepRecord
from rodctl.runs import RunDir, write_json_best_effort
from rodctl.training.auto import prepare_feature

#: Exit codes of `rodctl simulate` (docs/reliability.md).
EXIT_OK, EXIT_RUN_FAILED = 0, 1


@dataclass
class SimulateResult:
    """Where the run went and how it ended."""

    run: RunDir
    summary: RunSummary
    exit_code: int
    error: str | None = None


def make_sinks(cfg: ExperimentConfig, run_dir: Path, helpers: Any = None) -> list[Sink]:
    """The sinks the config asks for, writing into `run_dir` (`rodctl.logs.sinks`: MCAP and
    Rerun when switched on, then every `logging.sinks` entry, by its registered type);
    `helpers` (`start_helpers`): run.rrd written by a helper process."""
    ctx = SinkContext(run_dir=run_dir, logging=cfg.logging, experiment=cfg, helpers=helpers)
    return [make_sink(sink, ctx) for sink in selected_sinks(cfg.logging)]


class StopRequests:
    """Records SIGINT/SIGTERM instead of acting on them; the loop polls `reason()` each step.

    A handler that raised wherever the signal landed could cut a step in half or be swallowed
    by a library that turns exceptions into warnings; a flag is checked at one safe point.
    A signal the process was started ignoring (nohup, a background job) stays ignored.
    """

    def __init__(self) -> None:
        self._reason: str | None = None

    def reason(self) -> str | None:
        """The name of the first stop signal received, or None."""
        return self._reason

    def _handler(self, signum: int, _frame: object) -> None:
        self._reason = self._reason or signals.name(signum)

    @contextmanager
    def installed(self):
        """Catch SIGINT and SIGTERM for the duration (main thread only; no-op elsewhere)."""
        with signals.handled(self._handler):
            yield self


def simulate(
    cfg: ExperimentConfig,
    out: str | Path = "runs",
    *,
    argv: list[str] | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
    on_summary: Callable[[RunSummary], None] | None = None,
    live: Sink | Sequence[Sink] | None = None,
    helpers: Any = None,
) -> SimulateResult:
    """Run one experiment into a new run directory under `out`.

    The environment and method are built before the run directory exists, so a config that
    cannot run (a missing checkpoint, an impossible feature) is a `UserError` that leaves nothing
    behind. SIGINT/SIGTERM are recorded from then until meta.json is final: the episode stops at
    the next step boundary, and the closing of the logs is never cut short.
    The figure process (when `logging.figures`) is started first and never outlives the call.
    `on_summary` gets the episode's summary as soon as summary.json is written, before the
    figures are waited for (the run's status may still become `failed` if they cannot be
    written: see the result).
    `live`: more sinks, e.g. a started `rodctl.logs.live.LiveView` (its owner stops it) or a
    `RerunSink` streaming to a viewer.
    `helpers`: the helper processes started for this config (`start_helpers`; its owner stops
    them); None: started here, and stopped before returning.
    """
    stops = StopRequests()
    own = start_helpers(cfg.logging) if helpers is None else nullcontext()
    helpers = own if helpers is None else helpers
    figures: Any = None
    if cfg.logging.figures:  # the figure sink, through its registration
        figures = make_sink(FiguresSinkConfig(), SinkContext(None, cfg.logging, cfg, helpers))
    timeline.mark("main", "simulate")
    with own, stops.installed(), figures or nullcontext():
        env = ShapeServoEnv(cfg)
        prepare_feature(cfg)  # `feature.checkpoint: auto`: the quick encoder trained once
        method = Method.from_config(cfg)
        run = RunDir.create(out, cfg, command="simulate", argv=argv)
        _embed_encoder(cfg, run)
        timeline.mark("main", "episode start")
        result = _run(env, method, cfg, run, figures, live, on_step, stops, helpers)
        timeline.mark("main", "episode end")
        error = _episode_error(result, stops, run)
        summary = result.summary
        problems = [write_json_best_effort(run.path / "summary.json", summary.to_json())]
        shown: Exception | None = None  # a display error waits until meta.json is final
        if on_summary is not None:
            try:
                on_summary(summary)
            except Exception as exc:  # noqa: BLE001 - re-raised below
                shown = exc
        if figures and result.records and result.error is None:
            problems.append(_figures(figures, result, run.path / "figures"))
        status, error = _finish(run, result, problems, error)
        timeline.mark("main", "done")
    if shown is not None:
        raise shown
    code = EXIT_OK if status == "completed" else EXIT_RUN_FAILED
    return SimulateResult(run=run, summary=summary, exit_code=code, error=error)


def _run(
    env: ShapeServoEnv,
    method: Method,
    cfg: ExperimentConfig,
    run: RunDir,
    figures: Any,
    live: Sink | Sequence[Sink] | None,
    on_step: Callable[[StepRecord], None] | None,
    stops: StopRequests,
    helpers: Any,
) -> EpisodeResult:
    """The episode into `run`; a failed one's result, with its traceback in error.txt.

    Raises:
        UserError: bad input found before the first step; the run folder is removed (marked
            failed instead when it is not empty).
    """
    try:
        # The figure process first: it gets the records before the logs are closed.
        sinks = ([figures] if figures else []) + make_sinks(cfg, run.path, helpers)
        if live is not None:
            sinks += list(live) if isinstance(live, list | tuple) else [live]
        return run_episode(
            env,
            method,
            sinks=sinks,
            run_id=run.run_id,
            on_step=on_step,
            stop_requested=stops.reason,
        )
    except EpisodeFailed as exc:
        result = exc.result
        _best_effort(lambda: (run.path / "error.txt").write_text(result.traceback or ""))
        return result
    except UserError as exc:
        # Bad input found before the first step: nothing to keep, nothing left behind.
        if not run.discard_if_empty():
            run.finish("failed", error=str(exc))
        raise
    except Exception as exc:  # noqa: BLE001 - the episode could not start (a reset that failed)
        why = f"the episode could not start: {type(exc).__name__}: {exc}"
        _best_effort(lambda: (run.path / "error.txt").write_text(traceback.format_exc()))
        run.finish("failed", error=why)
        raise RunFailed(f"{why} (the traceback is in {run.path / 'error.txt'})") from exc


def _episode_error(result: EpisodeResult, stops: StopRequests, run: RunDir) -> str | None:
    """Why the episode did not complete (its error, its divergence, its stop signal), else None;
    a divergence's or a lost rod's reason goes into error.txt."""
    error = (
        result.error
        or result.reason
        or (
            f"interrupted by {stops.reason() or 'SIGINT'}"
            if result.outcome is Outcome.INTERRUPTED
            else None
        )
    )
    if result.reason and not result.error:  # diverged or lost: no traceback, the reason says it
        text = result.reason + "\n"
        _best_effort(lambda: (run.path / "error.txt").write_text(text))
    return error


def _finish(
    run: RunDir, result: EpisodeResult, problems: list[str | None], error: str | None
) -> tuple[str, str | None]:
    """meta.json made final; (the run's status, its error). What could not be written
    (`problems`: summary.json, the figures, meta.json itself) turns a completed run into a
    failed one."""
    lost = [p for p in problems if p]
    status = result.status
    if lost:
        # The run itself may have been fine; what it could not write makes it a failure.
        error = "; ".join(filter(None, [error, *lost]))
        status = "failed" if status == "completed" else status
    extra: dict[str, Any] = {"error": error} if error else {}
    if result.header is not None:
        extra["numeric_env"] = result.header.numeric_env
    meta_error = run.finish(status, outcome=result.summary.outcome, **extra)
    if meta_error:
        error = "; ".join(filter(None, [error, f"meta.json not updated: {meta_error}"]))
        status = "failed" if status == "completed" else status
    return status, error


def _embed_encoder(cfg: ExperimentConfig, run: RunDir) -> None:
    """Copy the encoder checkpoint into the run folder and record its hash (rodctl/portable.py),
    so that the folder verifies on another machine. On a full disk: as `RunDir.create` does."""
    from rodctl.errors import RunFailed
    from rodctl.portable import embed_checkpoint

    try:
        record = embed_checkpoint(cfg, run.path)
        if record is not None:
            run.meta["encoder"] = record
            run.write_meta()
    except OSError as exc:
        run.finish("failed", error=f"cannot copy the encoder checkpoint: {describe_os_error(exc)}")
        raise RunFailed(f"cannot start the run in {run.path}: {describe_os_error(exc)}") from None


def _figures(worker: FigureWorker, result: Any, folder: Path) -> str | None:
    """Write the figures the worker drew (it has the records already, as a sink); what could
    not be drawn or written, as a message."""
    worker.submit(result.header, result.records)  # nothing to do when the sink handed them over
    try:
        pngs = worker.result()
    except FiguresFailed as exc:
        return f"figures not written: {exc}"
    finally:
        timeline.mark("main", "figures received")
    return _best_effort(lambda: save_figures(pngs, folder))


def _best_effort(write: Callable[[], object]) -> str | None:
    """Run a write that may meet a full disk; its error message instead of an exception."""
    try:
        write()
        return None
    except OSError as exc:
        return describe_os_error(exc)
