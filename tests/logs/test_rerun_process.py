"""run.rrd written by a helper process (`rodctl.logs.rerun_process`), as `rodctl simulate` does:
the same recording as `RerunSink` writes in this process, and a helper that dies costs the
recording only, with the reason (raised for a completed run, a warning otherwise)."""

from __future__ import annotations

import os
import signal

import pytest

from rodctl.config.logging import LoggingConfig
from rodctl.helper_process import Helpers
from rodctl.logs import rerun_process
from rodctl.logs.rerun import RerunSink
from rodctl.logs.rerun_process import RerunProcessSink


def _through(helpers: Helpers):
    """A sink class for `write_run`: each sink writes through a helper of `helpers`."""

    def make(path, cfg):
        return RerunProcessSink(helpers.take(rerun_process.MODULE, rerun_process.NAME), path, cfg)

    return make


def test_the_helper_writes_the_recording_rerun_sink_writes(tmp_path, synthetic, helpers):
    header, records = synthetic  # frames on every 5th step: chosen and encoded by this process
    summary = helpers.summary_of(records)
    cfg = LoggingConfig(flush_every_steps=7)
    here = helpers.write_run(RerunSink, tmp_path / "here.rrd", header, records, summary, cfg=cfg)
    with Helpers() as started:
        started.start(rerun_process.MODULE, rerun_process.NAME)
        there = helpers.write_run(
            _through(started), tmp_path / "there.rrd", header, records, summary, cfg=cfg
        )
        shorter = helpers.write_run(
            _through(started), tmp_path / "short.rrd", header, records[:-1], summary, cfg=cfg
        )

    assert helpers.rrd_compare(here, there) == 0
    assert helpers.rrd_compare(here, shorter) != 0  # the comparison can fail


@pytest.mark.parametrize("status", ["completed", "interrupted"])
def test_a_helper_that_dies_costs_the_recording_with_the_reason(tmp_path, synthetic, status):
    header, records = synthetic
    with Helpers() as started:
        sink = _through(started)(tmp_path / "run.rrd", LoggingConfig())
        sink.open(header)
        os.kill(sink.helper.proc.pid, signal.SIGKILL)
        sink.helper.proc.wait(timeout=30)
        reason = "the Rerun process was killed by SIGKILL"
        with pytest.warns(RuntimeWarning, match=reason):  # said at once, not only at close
            sink.write(records[0])
        for rec in records[1:]:
            sink.write(rec)  # the run goes on
        if status == "completed":
            with pytest.raises(RuntimeError, match=reason):
                sink.close(None, status)
        else:  # the exception that ended the run is the one to report: a warning only
            with pytest.warns(RuntimeWarning, match=reason):
                sink.close(None, status)
        sink.close(None, status)  # idempotent


def test_a_helper_that_cannot_start_fails_the_open_with_the_reason(
    tmp_path, synthetic, monkeypatch
):
    header, _ = synthetic
    monkeypatch.setattr("sys.executable", str(tmp_path / "no-python"))
    with Helpers() as started:
        sink = _through(started)(tmp_path / "run.rrd", LoggingConfig())
        with pytest.raises(RuntimeError, match="could not start the Rerun process: No such file"):
            sink.open(header)


def test_a_folder_that_cannot_take_the_file_is_an_os_error_naming_it(tmp_path, synthetic):
    header, _ = synthetic
    with Helpers() as started:
        sink = _through(started)(tmp_path / "missing" / "run.rrd", LoggingConfig())
        with pytest.raises(FileNotFoundError, match="missing"):
            sink.open(header)


def test_rerun_that_cannot_be_imported_fails_the_open_before_the_first_step(
    tmp_path, synthetic, monkeypatch
):
    """The helper's first act is importing rerun-sdk: when that fails the command is told at
    `open` (the run fails before its first step), not at `close`, after the episode."""
    header, _ = synthetic
    fake = tmp_path / "fake" / "rerun"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('injected: no rerun here')\n")
    path = os.pathsep.join(filter(None, [str(fake.parent), os.environ.get("PYTHONPATH")]))
    monkeypatch.setenv("PYTHONPATH", path)
    with Helpers() as started:
        sink = _through(started)(tmp_path / "run.rrd", LoggingConfig())
        sink.helper.proc.wait(timeout=60)  # it knows (and has ended) before the run opens
        with pytest.raises(RuntimeError, match="rerun-sdk cannot be imported: injected"):
            sink.open(header)
