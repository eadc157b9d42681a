"""`rodctl simulate`: one experiment into one run directory, safe against every way it can end.

Whatever happens — convergence, divergence, an exception inside the loop, Ctrl-C, SIGTERM — the
sinks are closed (MCAP and Rerun files finalised), summary.json is written from the records so
far and meta.json records the terminal status. Nothing already logged is lost.
"""

from __future__ import annotations

import signal
import threading
import time
import traceback
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from rodctl.config import ExperimentConfig
from rodctl.errors import UserError
from rodctl.experiment import Experiment, Interrupted
from rodctl.logs.base import Sink
from rodctl.records import RunSummary, StepRecord
from rodctl.runs import RunDir, write_json_atomic

#: Exit codes of `rodctl simulate` (architecture.md, CLI contract).
EXIT_OK, EXIT_RUN_FAILED = 0, 1


@dataclass
class SimulateResult:
    """Where the run went and how it ended."""

    run: RunDir
    summary: RunSummary
    exit_code: int
    error: str | None = None


def make_sinks(cfg: ExperimentConfig, run_dir: Path) -> list[Sink]:
    """The sinks the config asks for, writing into `run_dir`."""
    sinks: list[Sink] = []
    if cfg.logging.mcap:
        from rodctl.logs.mcap import McapSink

        sinks.append(McapSink(run_dir / "run.mcap", cfg.logging))
    if cfg.logging.rerun:
        from rodctl.logs.rerun import RerunSink

        sinks.append(RerunSink(run_dir / "run.rrd", cfg.logging))
    return sinks


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
        self._reason = self._reason or signal.Signals(signum).name

    @contextmanager
    def installed(self):
        """Catch SIGINT and SIGTERM for the duration (main thread only; no-op elsewhere)."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                previous[sig] = signal.signal(sig, self._handler)
        try:
            yield self
        finally:
            for sig, old in previous.items():
                signal.signal(sig, old)


def partial_summary(exp: Experiment, status: str, outcome: str, wall: float) -> RunSummary:
    """A summary of a run that did not reach its end, from the records made so far."""
    recs = exp.records
    last = recs[-1] if recs else None
    steps = last.step if last else 0
    return RunSummary(
        status=status,
        outcome=outcome,
        method=exp.method,
        steps=steps,
        converged=False,
        steps_to_converge=None,
        final_T1=float(last.T1) if last else float("nan"),
        final_pixel_error=float(last.pixel_error) if last else float("nan"),
        wall_time_s=round(wall, 4),
        steps_per_s=round(steps / wall, 3) if wall > 0 else 0.0,
        extra={"run_id": exp.run_id},
    )


def simulate(
    cfg: ExperimentConfig,
    out: str | Path = "runs",
    *,
    argv: list[str] | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
) -> SimulateResult:
    """Run one experiment into a new run directory under `out`.

    The stages are built before the run directory exists, so a config that cannot run (a
    missing checkpoint, an impossible feature) is a `UserError` that leaves nothing behind.
    SIGINT/SIGTERM are recorded from then until meta.json is final: the loop stops at the next
    step boundary, and the closing of the logs is never cut short.
    """
    stops = StopRequests()
    with stops.installed():
        exp = Experiment(cfg)
        run = RunDir.create(out, cfg, command="simulate", argv=argv)
        exp.run_id = run.run_id
        wall0 = time.perf_counter()
        summary: RunSummary | None = None
        error: str | None = None
        status = "failed"
        sinks: list[Sink] = []
        try:
            sinks = make_sinks(cfg, run.path)
            summary = exp.run(sinks, on_step=on_step, stop_requested=stops.reason)
            status = "completed" if summary.status == "completed" else "failed"
        except (Interrupted, KeyboardInterrupt) as exc:
            status, error = "interrupted", f"interrupted by {exc or 'SIGINT'}"
            wall = time.perf_counter() - wall0
            summary = partial_summary(exp, "interrupted", "interrupted", wall)
        except Exception as exc:
            if isinstance(exc, UserError) and not exp.records:
                # Bad input found before the first step: nothing to keep but the config.
                _close(sinks, None, "failed")
                run.finish("failed", error=str(exc))
                raise
            status = "failed"
            error = str(exc) if isinstance(exc, UserError) else f"{type(exc).__name__}: {exc}"
            (run.path / "error.txt").write_text(traceback.format_exc(), encoding="utf-8")
            summary = partial_summary(exp, "failed", "failed", time.perf_counter() - wall0)
        finally:
            _close(sinks, summary, status)
        write_json_atomic(run.path / "summary.json", summary.to_json())
        if cfg.logging.figures and exp.records:
            from rodctl.plots import write_figures

            write_figures(exp.header, exp.records, run.path / "figures")
        run.finish(status, outcome=summary.outcome, **({"error": error} if error else {}))
    code = EXIT_OK if status == "completed" else EXIT_RUN_FAILED
    return SimulateResult(run=run, summary=summary, exit_code=code, error=error)


def _close(sinks: list[Sink], summary: RunSummary | None, status: str) -> None:
    """Close every sink even if one fails; the first failure is re-raised afterwards."""
    first: BaseException | None = None
    for sink in sinks:
        try:
            sink.close(summary, status)
        except BaseException as exc:  # noqa: BLE001 - all sinks must get their chance to close
            first = first or exc
    if first is not None:
        raise first
