"""Small things a user meets at the command line (issue #28): help without placeholders and with
examples, hints for the wrong kind of config, `replay -q`, no progress bar of NaNs before an
error, an aligned `rodctl plugins`, and `config show` naming a file that exists."""

from __future__ import annotations

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app

runner = CliRunner()
DEFAULT = str(REPO / "configs/default.yaml")


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
