"""Small things a user meets at the command line (issue #28): help without placeholders and with
examples, hints for the wrong kind of config, `replay -q`, no progress bar of NaNs before an
error, an aligned `rodctl plugins`, and `config show` naming a file that exists."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.recordings import ros2 as ros2_module

runner = CliRunner()
DEFAULT = str(REPO / "configs/default.yaml")
SMOKE = str(REPO / "configs/compare-smoke.yaml")
SWEEP = str(REPO / "configs/sweep-smoke.yaml")


def test_help_has_no_type_placeholders_and_shows_examples():
    for command in ("simulate", "replay", "compare", "sweep", "train-encoder"):
        res = runner.invoke(app, [command, "--help"], env={"COLUMNS": "100"})
        assert res.exit_code == 0
        assert "<bool>" not in res.output and "{config}" not in res.output.lower(), command
        assert "Examples" in res.output and f"rodctl {command} " in res.output, command


def test_compare_given_an_experiment_config_says_to_simulate_it():
    res = runner.invoke(app, ["compare", DEFAULT])
    assert res.exit_code == 2
    assert "experiment config" in res.output and "rodctl simulate" in res.output
    assert "unknown key" not in res.output


def test_an_error_before_the_first_step_prints_no_progress_bar(tmp_path):
    res = runner.invoke(
        app, ["simulate", DEFAULT, "-o", str(tmp_path), "--set", "run.target.pose=[0.9,0,0]"]
    )
    assert res.exit_code == 2
    assert "nan" not in res.output and res.output.startswith("error: run.target.pose")


@pytest.mark.slow
def test_replay_quiet_prints_only_the_verdict(tmp_path):
    sim = runner.invoke(
        app,
        [
            "simulate", DEFAULT, "-q", "-o", str(tmp_path), "--set", "feature.type=bezier",
            "--set", "run.max_steps=2", "--set", "logging.rerun=false",
            "--set", "logging.figures=false",
        ],
    )  # fmt: skip
    assert sim.exit_code == 0, sim.output
    run_dir = sim.stdout.strip().splitlines()[-1]
    res = runner.invoke(app, ["replay", run_dir, "--verify", "--no-figures", "-q"])
    assert res.exit_code == 0, res.output
    assert "verify: OK" in res.output and "run_id" not in res.output


def test_plugins_columns_line_up_and_config_show_names_a_real_file():
    res = runner.invoke(app, ["plugins"])
    assert res.exit_code == 0
    # The type table (the loaded plug-ins' files follow it, a path as long as it is).
    table = res.output.split("plug-ins loaded:")[0]
    rows = [line for line in table.splitlines() if line.startswith("  ")]
    assert all(len(line) <= 100 for line in rows)
    sources = {line.index(" rodctl (built-in)") for line in rows if "rodctl (built-in)" in line}
    assert len(sources) == 1, "the source column starts at one place"
    shown = runner.invoke(app, ["config", "show", DEFAULT]).output
    (line,) = [x for x in shown.splitlines() if "feature.checkpoint:" in x]
    assert (REPO / line.split("packaged ")[1].strip()).is_file()


def test_sweep_given_another_kind_of_config_says_which_command_runs_it():
    res = runner.invoke(app, ["sweep", DEFAULT])
    assert res.exit_code == 2 and "experiment config" in res.output and "simulate" in res.output
    res = runner.invoke(app, ["sweep", "configs/compare-smoke.yaml"])
    assert res.exit_code == 2 and "rodctl compare" in res.output


def test_a_usage_error_is_one_error_line_then_the_usage_not_a_panel():
    """click's own errors (an unknown option, a missing argument, a value of the wrong type)
    are worded as rodctl's: `error: …` first, then the usage line; exit 2 (`cli.main`)."""
    for args, said in (
        (["simulate", DEFAULT, "--bogus"], "error: No such option: --bogus"),
        (["simulate"], "error: Missing argument 'config'"),
        (["replay", "x", "--tolerance", "abc"], "error: Invalid value for '--tolerance'"),
        (["no-such-command"], "error: No such command 'no-such-command'"),
    ):
        proc = subprocess.run(
            [sys.executable, "-m", "rodctl", *args], capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 2, (args, proc.stderr)
        lines = proc.stderr.splitlines()
        assert lines[0].startswith(said), (args, proc.stderr)
        assert lines[1].startswith("Usage: rodctl"), (args, proc.stderr)
        assert "╭" not in proc.stderr and "Traceback" not in proc.stderr, args
    bare = subprocess.run([sys.executable, "-m", "rodctl"], capture_output=True, text=True)
    assert bare.returncode == 2 and "Commands" in bare.stdout and "error" not in bare.stderr


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["config", "schema", "--compare", "--sweep"], "--compare and --sweep: give one"),
        (["simulate", DEFAULT, "--live-port", "9000"], "--live-port is the port of the --live"),
        (["simulate", DEFAULT, "--live", "--live-port", "99999"], "a port is 0 to 65535"),
        (["replay", DEFAULT, "--tolerance", "1e-9"], "--tolerance is how closely --verify"),
        (["simulate", DEFAULT, "--live-rerun", ""], "--live-rerun is empty"),
        (["compare", SMOKE, "--resume", "runs/x"], "--resume continues runs/x in its own folder"),
        (["sweep", SWEEP, "--resume", "runs/x"], "-o/--out"),
    ],
    ids=[
        "schema-both", "port-without-live", "port-out-of-range", "tolerance-without-verify",
        "empty-live-rerun", "compare-resume-with-out", "sweep-resume-with-out",
    ],
)  # fmt: skip
def test_an_option_that_would_be_silently_ignored_is_refused(args, said, tmp_path):
    """--live-rerun "" and --resume with -o were found ignored by a new-user trial."""
    out = ["-o", str(tmp_path)] if args[0] in ("simulate", "compare", "sweep") else []
    res = runner.invoke(app, [*args, *out])
    assert res.exit_code == 2, res.output
    assert res.output.startswith("error: ") and said in res.output, res.output
    assert not any(tmp_path.iterdir())  # refused before any run folder


def test_resume_takes_the_first_runs_own_out_folder(tmp_path):
    """Found by a new-user trial: the first run's command with --resume added was refused for
    its -o, though it names the folder the run is in."""
    run = tmp_path / "20261204-000000_compare-smoke"
    res = runner.invoke(app, ["compare", SMOKE, "-o", str(tmp_path), "--resume", str(run)])
    assert res.exit_code == 2 and "own folder" not in res.output, res.output
    assert f"--resume {run}" in res.output  # refused for what it is: no such run folder


def test_train_encoder_dataset_that_is_not_a_regular_file_says_so(tmp_path):
    """A FIFO (or a device) given as --dataset exists: "no such file" was wrong."""
    pytest.importorskip("torch")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    res = runner.invoke(
        app, ["train-encoder", DEFAULT, "--dataset", str(fifo), "-o", str(tmp_path)]
    )
    assert res.exit_code == 2, res.output
    assert f"--dataset {fifo}: not a regular file" in res.output
    res = runner.invoke(app, ["train-encoder", DEFAULT, "--dataset", str(tmp_path / "no.npz")])
    assert res.exit_code == 2 and "no such file" in res.output


@pytest.mark.parametrize("value", ["nan", "-1", "inf"])
def test_a_tolerance_that_is_not_a_finite_number_at_least_0_says_so(tmp_path, value):
    """Found by a new-user trial: nan was refused as 'Input should be greater than or equal to
    0'."""
    res = runner.invoke(app, ["import", str(tmp_path / "x.csv"), "--tolerance", value])
    assert res.exit_code == 2
    assert f"{float(value)} is not a finite number >= 0" in res.output


def test_an_interrupt_no_command_handles_is_named_by_its_signal_and_exits_1(tmp_path, monkeypatch):
    """Found by a review: a SIGTERM (raised as KeyboardInterrupt('SIGTERM')) that no command
    handled was reported as SIGINT, exit 130; one rule: interrupted is exit 1."""

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(ros2_module, "export_ros2", stopped)
    res = runner.invoke(app, ["export", str(tmp_path), "--ros2", str(tmp_path / "bag")])
    assert res.exit_code == 1
    assert res.output.strip() == "error: interrupted by SIGTERM"
