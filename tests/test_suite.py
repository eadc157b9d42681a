"""Benchmark suites: every method on every scenario, paired statistics, a self-contained report."""

from __future__ import annotations

import csv
import json
import re

from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app

SMOKE = str(REPO / "configs/benchmarks/suite-smoke.yaml")


def test_smoke_suite_runs_every_scenario_and_reports_paired_statistics(tmp_path):
    res = CliRunner().invoke(app, ["compare", SMOKE, "-q", "-o", str(tmp_path), "--workers", "2"])
    assert res.exit_code == 0, res.output
    folder = res.output.strip().splitlines()[-1]
    with open(f"{folder}/results.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["scenario"] for r in rows} == {"nominal", "loose-limit"}
    assert len(rows) == 2 * 3 * 2
    for col in ("excess_steps", "smoothness_translation", "smoothness_rotation", "step_bound"):
        assert all(r[col] != "" for r in rows if r["outcome"] == "converged"), col
    # The scenario's change really reached its episodes: the loose limit is in its config.
    loose = tmp_path / next(iter(tmp_path.iterdir())).name / "scenarios" / "loose-limit.yaml"
    assert "0.25" in loose.read_text()
    stats = json.loads(open(f"{folder}/statistics.json", encoding="utf-8").read())
    assert set(stats) == {"nominal", "loose-limit"}
    assert set(stats["nominal"]) == {"ma2022", "aghajanzadeh2022"}  # all but the reference
    summary = open(f"{folder}/summary.md", encoding="utf-8").read()
    assert "Paired against **paper-bezier**" in summary and "## loose-limit" in summary
    page = open(f"{folder}/report.html", encoding="utf-8").read()
    assert "data:image/png;base64," in page  # figures inline
    assert not re.search(r"""(src|href)=["']https?://""", page)  # opens with no network


def test_a_scenario_key_that_does_not_exist_is_named(tmp_path):
    res = CliRunner().invoke(
        app,
        ["compare", SMOKE, "-o", str(tmp_path), "--set", "scenarios.nominal.set={rod.lenght: 1}"],
    )
    assert res.exit_code == 2 and "scenarios.nominal" in res.output and "lenght" in res.output
