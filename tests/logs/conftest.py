"""Shared fixtures of the logging tests: a synthetic run written through the sinks."""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace

import pytest
import rerun as rr

from rodctl.config.logging import LoggingConfig
from rodctl.logs.mcap import McapSink
from rodctl.logs.rerun import RerunSink
from rodctl.logs.synthetic import SyntheticRun
from rodctl.records import RunHeader, RunSummary, StepRecord

#: The CLI that ships with rerun-sdk: next to this interpreter (venv) or on PATH.
_VENV_RERUN = Path(sys.executable).with_name("rerun")
RERUN = str(_VENV_RERUN) if _VENV_RERUN.exists() else (shutil.which("rerun") or "rerun")


@pytest.fixture(autouse=True)
def _rerun_strict():
    """Rerun drops malformed data with a mere warning unless strict mode is on."""
    rr.set_strict_mode(True)
    yield


def summary_of(records: Sequence[StepRecord], status: str = "completed") -> RunSummary:
    """A plausible summary of `records`."""
    last = records[-1]
    return RunSummary(
        status=status,
        outcome="converged",
        method="mfac-akf",
        steps=int(last.step),
        converged=True,
        steps_to_converge=int(last.step),
        final_T1=float(last.T1),
        final_pixel_error=float(last.pixel_error),
        wall_time_s=1.25,
        steps_per_s=24.0,
        extra={"run_id": "x", "note": "synthetic"},
    )


def write_run(
    sink_cls: type,
    path: Path,
    header: RunHeader,
    records: Sequence[StepRecord],
    summary: RunSummary | None,
    status: str = "completed",
    cfg: LoggingConfig | None = None,
) -> Path:
    """Feed a whole run to one sink, as the loop does, and close it."""
    sink = sink_cls(path, cfg or LoggingConfig())
    sink.open(header)
    try:
        for rec in records:
            sink.write(rec)
    finally:
        sink.close(summary, status)
    return path


@pytest.fixture(scope="session")
def rerun_exe() -> str:
    """The `rerun` command-line tool bundled with rerun-sdk."""
    return RERUN


def rrd_compare(a: Path, b: Path) -> int:
    """`rerun rrd compare --unordered a b`'s exit code: 0 when the recordings hold the same."""
    return subprocess.run(
        [RERUN, "rrd", "compare", "--unordered", str(a), str(b)],
        capture_output=True,
        text=True,
        timeout=60,
    ).returncode


@pytest.fixture(scope="session")
def helpers():
    """`write_run`, `summary_of` and `rrd_compare` (test modules cannot import conftest by
    name)."""

    return SimpleNamespace(write_run=write_run, summary_of=summary_of, rrd_compare=rrd_compare)


@pytest.fixture(scope="session")
def synthetic() -> tuple[RunHeader, list[StepRecord]]:
    """30 steps of a synthetic run, a camera frame on every 5th step."""
    run = SyntheticRun(seed=3, image_every=5)
    return run.header, run.records(30)


@pytest.fixture(scope="session")
def mcap_file(tmp_path_factory, synthetic) -> Path:
    header, records = synthetic
    path = tmp_path_factory.mktemp("mcap") / "run.mcap"
    return write_run(McapSink, path, header, records, summary_of(records))


@pytest.fixture(scope="session")
def rrd_file(tmp_path_factory, synthetic) -> Path:
    rr.set_strict_mode(True)
    header, records = synthetic
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    return write_run(RerunSink, path, header, records, summary_of(records))
