"""A disk that fills: at the start, in the middle of a run, while finalising. The promise: exit 1
within seconds, one line saying what and where, meta.json and summary.json saying `failed` with
the reason whenever the disk lets them be written, and what was logged before kept."""

from __future__ import annotations

import errno
import json
import subprocess
import sys
import time

import pytest
from faults.filesystems import fill
from paths import REPO
from typer.testing import CliRunner

import rodctl.simulate as simulate_module
from rodctl.cli import app
from rodctl.replay import read_run

SCRIPTED = str(REPO / "configs/scripted.yaml")
QUICK = ["--set", "logging.figures=false", "--set", "logging.rerun=false"]


class _FullAfter:
    """A sink wrapper whose writes fail with ENOSPC after `n` records, like a filling disk."""

    def __init__(self, sink, n):
        self.sink, self.n = sink, n

    def open(self, header):
        self.sink.open(header)

    def write(self, record):
        if record.step >= self.n:
            raise OSError(errno.ENOSPC, "No space left on device", "run.mcap")
        self.sink.write(record)

    def close(self, summary, status):
        self.sink.close(summary, status)


@pytest.mark.slow
def test_injected_enospc_mid_run_fails_cleanly_and_keeps_the_steps_before(tmp_path, monkeypatch):
    real = simulate_module.make_sinks
    monkeypatch.setattr(
        simulate_module,
        "make_sinks",
        lambda cfg, path, *helpers: [_FullAfter(s, 6) for s in real(cfg, path, *helpers)],
    )
    res = CliRunner().invoke(app, ["simulate", SCRIPTED, "-q", "-o", str(tmp_path), *QUICK])
    assert res.exit_code == 1, res.output
    assert "No space left on device" in res.output and "Traceback" not in res.output
    (run_dir,) = tmp_path.iterdir()
    meta = json.loads((run_dir / "meta.json").read_text())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert meta["status"] == "failed" and "No space left" in meta["error"]
    assert summary["status"] == "failed" and summary["outcome"] == "error"
    run = read_run(run_dir)
    assert [r.step for r in run.records] == list(range(6)) and run.status == "failed"


def _simulate(out, *extra, timeout=120):
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "rodctl", "simulate", SCRIPTED, "-q", "-o", str(out), *extra],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return proc, time.monotonic() - t0


@pytest.mark.slow
def test_a_disk_already_full_at_start_leaves_nothing_half_written(small_disk):
    disk = small_disk("1m")
    fill(disk)
    proc, _ = _simulate(disk / "runs")
    assert proc.returncode == 1, proc.stderr
    assert "No space left on device" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    runs = disk / "runs"
    assert not runs.exists() or not any(runs.iterdir())


@pytest.mark.slow
def test_a_disk_that_fills_mid_run_ends_within_seconds_with_failed_status(small_disk):
    disk = small_disk("600k")
    # The scripted path with a frame every step fills 600 kB with both logs well before its end.
    proc, wall = _simulate(disk, "--set", "logging.image_rate_hz=50")
    assert proc.returncode == 1, (proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    assert wall < 90
    (run_dir,) = [p for p in disk.iterdir() if p.is_dir()]
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "failed", meta
    assert "No space left on device" in meta.get("error", ""), meta


@pytest.mark.slow
def test_replay_into_a_read_only_folder_says_so(tmp_path, small_disk):
    res = CliRunner().invoke(
        app, ["simulate", SCRIPTED, "-q", "-o", str(tmp_path), "--set", "run.max_steps=5", *QUICK]
    )
    run_dir = res.output.strip().splitlines()[-1]
    ro = small_disk("1m", "ro", read_only=True)
    res = CliRunner().invoke(app, ["replay", run_dir, "-o", str(ro / "out")])
    assert res.exit_code == 1, res.output
    assert "Read-only file system" in res.output and "Traceback" not in res.output


class _FailsToOpen:
    def open(self, header):
        raise OSError(errno.ENOSPC, "No space left on device", "run.mcap")

    def write(self, record):
        raise AssertionError("never opened")

    def close(self, summary, status):
        raise AssertionError("never opened")


@pytest.mark.slow
def test_a_log_that_cannot_be_opened_fails_the_run_cleanly(tmp_path, monkeypatch):
    monkeypatch.setattr(simulate_module, "make_sinks", lambda cfg, path, *_: [_FailsToOpen()])
    res = CliRunner().invoke(app, ["simulate", SCRIPTED, "-q", "-o", str(tmp_path), *QUICK])
    assert res.exit_code == 1 and "No space left on device" in res.output, res.output
    (run_dir,) = tmp_path.iterdir()
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "failed" and "No space left" in meta["error"]
