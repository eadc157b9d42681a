"""`rodctl.replay`: a run's other outputs rebuilt from its MCAP alone."""

from __future__ import annotations

import subprocess
from dataclasses import replace
from types import SimpleNamespace

import pytest
from rich.console import Console
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.display import summary_table
from rodctl.errors import UserError
from rodctl.logs.mcap import McapSink
from rodctl.logs.rerun import RerunSink
from rodctl.replay import format_summary, read_run, rebuild, summary_object, summary_rows


@pytest.fixture
def run_dir(tmp_path, synthetic, helpers):
    header, records = synthetic
    d = tmp_path / header.run_id  # a run folder is named by its run id
    d.mkdir()
    summary = helpers.summary_of(records)
    helpers.write_run(McapSink, d / "run.mcap", header, records, summary)
    helpers.write_run(RerunSink, tmp_path / "live.rrd", header, records, summary)
    return d


@pytest.mark.slow
def test_rebuild_writes_an_rrd_equal_to_the_live_one(run_dir, rerun_exe):
    out = rebuild(run_dir)
    assert out.rrd == run_dir / "run.rrd" and out.run.complete
    for args in (
        ["rrd", "verify", str(out.rrd)],
        ["rrd", "compare", "--unordered", str(out.rrd), str(run_dir.parent / "live.rrd")],
    ):
        res = subprocess.run([rerun_exe, *args], capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stdout + res.stderr
    names = sorted(p.name for p in out.figures)
    assert names and all((run_dir / "figures" / n).stat().st_size > 1000 for n in names)


def test_rebuild_from_a_file_into_another_folder(run_dir, tmp_path):
    out = rebuild(run_dir / "run.mcap", tmp_path / "elsewhere", figures=False)
    assert out.rrd == tmp_path / "elsewhere" / "run.rrd" and out.rrd.exists()
    assert out.figures == [] and not (run_dir / "run.rrd").exists()


def test_a_replay_cut_short_leaves_the_runs_rrd_as_it_was(run_dir, monkeypatch):
    """Ctrl-C while run.rrd is rewritten: the old file is kept whole, no partial file left."""
    (run_dir / "run.rrd").write_bytes(b"the run's own recording")
    calls = []

    def interrupted(self, rec):
        calls.append(rec.step)
        if len(calls) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(RerunSink, "write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        rebuild(run_dir, figures=False)
    assert (run_dir / "run.rrd").read_bytes() == b"the run's own recording"
    assert sorted(p.name for p in run_dir.iterdir()) == ["run.mcap", "run.rrd"]
    monkeypatch.undo()
    assert rebuild(run_dir, figures=False).rrd.stat().st_size > 1000  # and whole when not cut


def test_summary_table(run_dir, synthetic):
    _, records = synthetic
    run = read_run(run_dir)
    rows = dict(summary_rows(run))
    assert rows["status"] == "completed" and rows["steps logged"] == "30"
    assert rows["final_T1"] == f"{records[-1].T1:.6g}" and rows["converged"] == "True"
    text = format_summary(run)
    assert run.header.run_id in text and "warning" not in text
    s = summary_object(run.summary)
    assert s.final_T1 == records[-1].T1 and s.extra["note"] == "synthetic"


def test_incomplete_run_needs_recover(run_dir, synthetic):
    data = (run_dir / "run.mcap").read_bytes()
    (run_dir / "run.mcap").write_bytes(data[: len(data) // 2])
    with pytest.raises(UserError, match="--recover"):
        rebuild(run_dir)
    out = rebuild(run_dir, recover=True, figures=False)
    assert not out.run.complete and out.rrd.exists()
    text = format_summary(out.run)
    assert "no (recovered)" in text and "warning: " in text and "unknown" in text


def test_bad_paths(tmp_path):
    with pytest.raises(UserError, match="no run.mcap"):
        read_run(tmp_path)
    with pytest.raises(UserError, match="no such run directory or file"):
        read_run(tmp_path / "missing")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    with pytest.raises(UserError, match="loop: a loop of symbolic links"):
        read_run(tmp_path / "loop")
    (tmp_path / "gone").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(UserError, match="gone: a symbolic link to .*elsewhere, which does not"):
        read_run(tmp_path / "gone")


def test_simulate_and_replay_tables_show_a_summary_the_same_way(synthetic, helpers):
    """A run that never converged has no steps_to_converge: both tables show —, not `None`."""
    _, records = synthetic
    summary = replace(helpers.summary_of(records), converged=False, steps_to_converge=None)
    console = Console(record=True, width=120)
    console.print(summary_table(summary))
    simulate_rows = {
        cells[0]: cells[1]
        for line in console.export_text().splitlines()
        if len(cells := [c.strip() for c in line.strip("│┃ ").split("│")]) == 2
    }
    assert simulate_rows["steps_to_converge"] == "—"
    replay_rows = dict(summary_rows(_ReadRunWith(summary.to_json())))
    for key, value in replay_rows.items():
        if key in simulate_rows:
            assert simulate_rows[key] == value, key


class _ReadRunWith:
    """The little of a ReadRun that `summary_rows` reads: a header and a logged summary."""

    def __init__(self, summary: dict) -> None:
        self.header = SimpleNamespace(run_id="x", method="mfac-akf")
        self.status, self.complete, self.records, self.summary = "completed", True, [], summary
        self.notes: list[str] = []


def test_recover_of_a_log_with_no_complete_step_fails_saying_so(run_dir):
    """Found by a new-user trial: `replay --recover` of a log cut before its first flush
    rebuilt a header-only run.rrd and exited 0."""
    data = (run_dir / "run.mcap").read_bytes()
    (run_dir / "run.mcap").write_bytes(data[: len(data) // 10])  # the header, no whole chunk
    res = CliRunner().invoke(app, ["replay", str(run_dir), "--recover", "--no-figures"])
    assert res.exit_code == 1, res.output
    assert "the log holds no complete step" in res.stderr
    assert "Traceback" not in res.output
