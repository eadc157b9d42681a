"""`rodctl simulate` end to end: run directory contract, determinism, crash safety, replay.

These runs use the Bezier feature so they do not depend on the trained autoencoder checkpoint;
the default (autoencoder) config is exercised by tests/test_shipped_configs.py.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config.logging import LoggingConfig
from rodctl.env import ShapeServoEnv
from rodctl.logs.mcap import McapSink, read_mcap
from rodctl.replay import read_run, summary_object

runner = CliRunner()
FAST = ["--set", "feature.type=bezier", "--set", "run.max_steps=40"]
RERUN = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")


def simulate(tmp_path: Path, *extra: str) -> Path:
    result = runner.invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--out",
            str(tmp_path),
            "-q",
            *FAST,
            *extra,
        ],
    )
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    assert run_dir.parent == tmp_path
    return run_dir


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return simulate(tmp_path_factory.mktemp("sim"))


@pytest.mark.slow
def test_run_directory_contract(run_dir):
    names = {p.name for p in run_dir.iterdir()}
    assert {"config.yaml", "meta.json", "summary.json", "run.mcap", "run.rrd", "figures"} <= names
    assert {p.name for p in (run_dir / "figures").iterdir()} >= {
        "shapes.png",
        "t1.png",
        "commands.png",
    }
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "completed" and meta["seed"] == 0
    assert meta["started_at"] and meta["ended_at"] and meta["versions"]["pymunk"] == "7.3.1"
    summary = json.loads((run_dir / "summary.json").read_text())
    for key in (
        "status",
        "method",
        "steps",
        "converged",
        "steps_to_converge",
        "final_T1",
        "final_pixel_error",
        "wall_time_s",
        "steps_per_s",
    ):
        assert key in summary
    assert summary["method"] == "bezier/akf/mfac"
    # The easy default target converges well inside 40 steps, probing included.
    assert summary["converged"] is True and summary["outcome"] == "converged"
    assert summary["final_pixel_error"] < 1.0
    assert summary["steps"] == summary["steps_to_converge"]


@pytest.mark.slow
def test_log_agrees_with_summary(run_dir):
    run = read_mcap(run_dir / "run.mcap")
    summary = json.loads((run_dir / "summary.json").read_text())
    assert run.complete and run.status == "completed"
    assert [r.step for r in run.records] == list(range(summary["steps"] + 1))
    assert run.records[-1].pixel_error == summary["final_pixel_error"]
    phases = [r.phase for r in run.records]
    assert phases[0] == "initial" and phases[1:5] == ["probe"] * 4
    assert all(p == "control" for p in phases[5:])


@pytest.mark.slow
def test_same_config_gives_identical_logs(run_dir, tmp_path):
    again = simulate(tmp_path)
    assert (again / "run.mcap").read_bytes() == (run_dir / "run.mcap").read_bytes()
    if RERUN:
        cmp = subprocess.run(
            [
                RERUN,
                "rrd",
                "compare",
                "--unordered",
                str(run_dir / "run.rrd"),
                str(again / "run.rrd"),
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert cmp.returncode == 0, cmp.stdout + cmp.stderr


@pytest.mark.slow
def test_files_pass_rerun_validators(run_dir):
    if not RERUN:
        pytest.skip("rerun CLI not found")
    for cmd in (["mcap", "check", "run.mcap"], ["rrd", "verify", "run.rrd"]):
        res = subprocess.run(
            [RERUN, *cmd], cwd=run_dir, capture_output=True, text=True, timeout=120
        )
        assert res.returncode == 0, res.stdout + res.stderr


@pytest.mark.slow
def test_replay_verify_passes_on_a_fresh_run(run_dir, tmp_path):
    result = runner.invoke(app, ["replay", str(run_dir), "--verify", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "verify: OK" in result.output
    assert (tmp_path / "run.rrd").exists() and (tmp_path / "figures" / "t1.png").exists()


@pytest.mark.slow
def test_replay_verify_reports_an_altered_value(run_dir, tmp_path):
    run = read_run(run_dir)
    run.records[7].pixel_error += 1e-9
    sink = McapSink(tmp_path / "run.mcap", LoggingConfig())
    sink.open(run.header)
    for rec in run.records:
        sink.write(rec)
    sink.close(summary_object(run.summary), "completed")
    result = runner.invoke(app, ["replay", str(tmp_path), "--verify", "--no-figures"])
    assert result.exit_code == 1, result.output
    assert "FAILED" in result.output and "step 7: pixel_error differs" in result.output


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["truncated", "random"])
def test_replay_of_a_broken_file_exits_2(run_dir, tmp_path, kind):
    data = (run_dir / "run.mcap").read_bytes()
    bad = tmp_path / "run.mcap"
    bad.write_bytes(data[: len(data) // 2] if kind == "truncated" else os.urandom(4096))
    result = runner.invoke(app, ["replay", str(bad)])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and "run.mcap" in result.output


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_half_way_leaves_an_interrupted_readable_run(tmp_path, sig):
    """A long run stopped by a signal: exit 1, meta `interrupted`, the MCAP opens with every
    step logged so far, and both files pass the validators."""
    cmd = [
        sys.executable,
        "-m",
        "rodctl",
        "simulate",
        str(REPO / "configs/default.yaml"),
        "--out",
        str(tmp_path),
        "-q",
        "--set",
        "feature.type=bezier",
        "--set",
        "run.max_steps=3000",
        "--set",
        "run.pixel_tolerance=1e-6",
        "--set",
        "run.stall_window=3000",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    mcap = None
    while time.monotonic() < deadline:
        found = list(tmp_path.glob("*/run.mcap"))
        if found and found[0].stat().st_size > 50_000:  # a few flushed chunks of steps
            mcap = found[0]
            break
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.1)
    assert mcap is not None, "the run never logged anything"
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    assert "Traceback" not in err and "interrupted" in err
    run_dir = mcap.parent
    assert out.strip().splitlines()[-1] == str(run_dir)
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "interrupted"
    run = read_mcap(mcap)
    assert run.complete and run.status == "interrupted"
    assert len(run.records) > 5
    assert [r.step for r in run.records] == list(range(len(run.records)))
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["steps"] == run.records[-1].step
    if RERUN:
        for check in (["mcap", "check", str(mcap)], ["rrd", "verify", str(run_dir / "run.rrd")]):
            res = subprocess.run([RERUN, *check], capture_output=True, text=True, timeout=120)
            assert res.returncode == 0, res.stdout + res.stderr
    if sig == signal.SIGINT:
        # The interrupted run replays bit for bit as far as it got.
        res = runner.invoke(
            app,
            [
                "replay",
                str(run_dir),
                "--verify",
                "--no-figures",
                "--out",
                str(tmp_path / "replayed"),
            ],
        )
        assert res.exit_code == 0, res.output
        n = len(run.records)  # the initial frame and summary["steps"] steps
        assert (
            f"verify: OK, {n} records (the initial frame and {summary['steps']} steps) identical"
            in res.output
        )


@pytest.mark.slow
def test_bad_target_is_a_user_error(tmp_path):
    result = runner.invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--out",
            str(tmp_path),
            *FAST,
            "--set",
            "run.target.pose=[2.0, 0, 0]",
        ],
    )
    assert result.exit_code == 2, result.output
    assert "run.target.pose" in result.output and "Traceback" not in result.output


def test_an_episode_that_cannot_start_ends_its_run_as_failed(tmp_path, monkeypatch):
    """An exception in the first reset (here forced; a camera with the rod behind it was one
    before its check) was a traceback, and the run folder stayed `running`."""

    def broken_reset(self, *args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(ShapeServoEnv, "reset", broken_reset)
    args = ["simulate", str(REPO / "configs/default.yaml"), "--out", str(tmp_path), *FAST]
    result = runner.invoke(app, args)
    assert result.exit_code == 1, result.output
    (run,) = tmp_path.iterdir()
    said = "the episode could not start: RuntimeError: boom"
    assert f"error: {said} (the traceback is in {run / 'error.txt'})" in result.output
    meta = json.loads((run / "meta.json").read_text())
    assert (meta["status"], meta["error"]) == ("failed", said)
    assert "broken_reset" in (run / "error.txt").read_text()
