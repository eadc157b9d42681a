"""Every command's --help, through Typer's CliRunner and through a real subprocess."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app

runner = CliRunner()


def _commands() -> list[list[str]]:
    import typer.main

    group = typer.main.get_command(app)
    out = [[]]
    for name, cmd in group.commands.items():
        out.append([name])
        for sub in getattr(cmd, "commands", {}):
            out.append([name, sub])
    return out


COMMANDS = _commands()


def test_expected_commands_exist():
    names = {tuple(c) for c in COMMANDS}
    expected = {
        ("simulate",),
        ("replay",),
        ("compare",),
        ("train-encoder",),
        ("config", "show"),
        ("config", "schema"),
    }
    assert expected <= names


@pytest.mark.parametrize("cmd", COMMANDS, ids=lambda c: " ".join(c) or "rodctl")
def test_help_cli_runner(cmd):
    result = runner.invoke(app, [*cmd, "--help"])
    assert result.exit_code == 0, result.output
    assert "Usage" in result.output


@pytest.mark.slow
@pytest.mark.parametrize("cmd", COMMANDS, ids=lambda c: " ".join(c) or "rodctl")
def test_help_subprocess(cmd):
    proc = subprocess.run(
        [sys.executable, "-m", "rodctl", *cmd, "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Usage" in proc.stdout


def test_config_show_prints_resolved_yaml(repo):
    result = runner.invoke(app, ["config", "show", str(repo / "configs/default.yaml")])
    assert result.exit_code == 0
    assert "rod:" in result.stdout and "bending_stiffness" in result.stdout


def test_version_and_config_show_derived_values():
    from rodctl import __version__

    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"rodctl {__version__}"
    res = CliRunner().invoke(app, ["config", "show", str(REPO / "configs/default.yaml")])
    assert res.exit_code == 0
    assert "#   rod.home_pose: [0.4, 0.1, 0.5]" in res.output
    assert "#   camera.cx: 319.5" in res.output and "rod.dt:" in res.output
    assert "0000000" not in res.output  # floats print cleanly


@pytest.mark.slow
def test_simulate_json_prints_one_parseable_object(tmp_path):
    res = CliRunner().invoke(
        app,
        ["simulate", str(REPO / "configs/default.yaml"), "--json", "-o", str(tmp_path),
         "--set", "run.max_steps=3", "--set", "logging.rerun=false",
         "--set", "logging.figures=false"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    import json

    data = json.loads(res.stdout)
    assert data["steps"] == 3 and data["run_dir"].startswith(str(tmp_path))


@pytest.mark.parametrize("config", ["compare-smoke.yaml", "benchmarks/suite-smoke.yaml"])
def test_ray_missing_is_bad_input_and_leaves_no_run_folder(tmp_path, monkeypatch, config):
    monkeypatch.setitem(sys.modules, "ray", None)  # as on an install without the extra
    res = CliRunner().invoke(
        app,
        ["compare", str(REPO / "configs" / config), "--executor", "ray", "--out", str(tmp_path)],
    )
    assert res.exit_code == 2, res.output
    assert "rodctl[ray]" in res.output
    assert list(tmp_path.iterdir()) == []


def test_an_unreachable_compare_target_leaves_no_run_folder(tmp_path):
    """Found once the folder (with its journal lock) existed: exit 2 and nothing left."""
    res = CliRunner().invoke(
        app,
        ["compare", str(REPO / "configs/compare-smoke.yaml"), "-q", "--out", str(tmp_path),
         "--set", "targets.poses=[[5,5,0]]"],
    )  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "is unusable" in res.output and list(tmp_path.iterdir()) == [], res.output


def test_a_compare_folders_config_reruns_as_that_compare(tmp_path):
    """Its resolved config.yaml says `scenarios: null`: a compare again, not an empty suite."""
    first = CliRunner().invoke(
        app,
        ["compare", str(REPO / "configs/compare-smoke.yaml"), "-q", "--out", str(tmp_path / "a")],
    )
    assert first.exit_code == 0, first.output
    folder = Path(first.output.strip().splitlines()[-1])
    again = CliRunner().invoke(
        app, ["compare", str(folder / "config.yaml"), "-q", "--out", str(tmp_path / "b")]
    )
    assert again.exit_code == 0, again.output
    rerun = Path(again.output.strip().splitlines()[-1])

    def rows(run: Path) -> list[dict]:  # every column but the wall time
        with (run / "results.csv").open() as fh:
            return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in csv.DictReader(fh)]

    assert len(rows(folder)) > 0 and rows(rerun) == rows(folder), "not the same compare"


def test_bad_input_after_the_checkpoint_copy_leaves_no_run_folder(tmp_path):
    """The default config copies its encoder into the run folder before the target is made;
    an unreachable target found then is still bad input: exit 2 and no folder left."""
    res = CliRunner().invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--set",
            "run.target.pose=[5,5,0]",
            "--out",
            str(tmp_path),
        ],
    )
    assert res.exit_code == 2, res.output
    assert "out of reach" in res.output
    assert list(tmp_path.iterdir()) == []
