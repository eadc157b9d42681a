"""Plug-ins: the example package adds a feature, an estimator and a controller that every command
sees; a plug-in that fails to import is named, with exit code 2 and no traceback."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import textwrap

import pytest
from paths import REPO, plugin_installed
from typer.testing import CliRunner

from rodctl.cli import app

needs_plugin = pytest.mark.skipif(
    not plugin_installed(), reason="example plug-in not installed (pip install -e examples/plugin)"
)
PLUGIN_TYPES = ("navarro_fourier", "navarro_rls", "navarro_dls")
QUIET = ["--set", "logging.rerun=false", "--set", "logging.figures=false"]


@needs_plugin
def test_plugins_command_lists_the_example_plugin_with_its_source():
    res = CliRunner().invoke(app, ["plugins"])
    assert res.exit_code == 0, res.output
    for t in PLUGIN_TYPES:
        line = next(ln for ln in res.output.splitlines() if ln.strip().startswith(t))
        assert "plug-in rodctl-navarro2018" in line
    assert "mfac" in res.output and "rodctl (built-in)" in res.output


@needs_plugin
def test_config_schema_knows_the_plugin_types():
    res = CliRunner().invoke(app, ["config", "schema"])
    schema = json.loads(res.output)
    text = json.dumps(schema)
    for t in PLUGIN_TYPES:
        assert f'"{t}"' in text
    res = CliRunner().invoke(app, ["config", "schema", "--compare"])
    assert all(f'"{t}"' in res.output for t in PLUGIN_TYPES)


@needs_plugin
def test_simulate_runs_the_plugin_method_to_convergence(tmp_path):
    res = CliRunner().invoke(
        app,
        ["simulate", str(REPO / "examples/plugin/navarro2018.yaml"), "-q", "-o", str(tmp_path)]
        + QUIET,
    )
    assert res.exit_code == 0, res.output
    run_dir = res.output.strip().splitlines()[-1]
    summary = json.loads((tmp_path / run_dir.split("/")[-1] / "summary.json").read_text())
    assert summary["outcome"] == "converged"
    assert summary["method"] == "navarro_fourier/navarro_rls/navarro_dls"


@pytest.mark.slow
@needs_plugin
def test_compare_runs_the_plugin_beside_builtin_methods_in_worker_processes(tmp_path):
    res = CliRunner().invoke(
        app, ["compare", str(REPO / "examples/plugin/compare.yaml"), "-q", "-o", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    folder = res.output.strip().splitlines()[-1]
    with open(f"{folder}/results.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    mine = [r for r in rows if r["method"] == "navarro2018"]
    assert len(mine) == 2 and all(r["outcome"] == "converged" for r in mine), mine
    assert {r["method"] for r in rows} == {"navarro2018", "paper-bezier", "ma2022"}


@pytest.mark.slow
def test_a_plugin_that_fails_to_import_is_named_with_exit_code_2(tmp_path):
    dist = tmp_path / "broken_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        textwrap.dedent(
            """
            [rodctl.plugins]
            broken = rodctl_no_such_module_xyz
            """
        )
    )
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    for args in (["plugins"], ["config", "show", str(REPO / "configs/default.yaml")]):
        proc = subprocess.run(
            [sys.executable, "-m", "rodctl", *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=120,
        )
        assert proc.returncode == 2, (args, proc.stdout, proc.stderr)
        assert "broken" in proc.stderr and "rodctl_no_such_module_xyz" in proc.stderr
        assert "Traceback" not in proc.stderr
