"""Benchmark suites: every method on every scenario, paired statistics, a self-contained report."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
import time
from pathlib import Path

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
    assert {r["scenario"] for r in rows} == {"nominal", "loose-limit", "event-camera-bump"}
    assert len(rows) == 3 * 3 * 2
    for col in ("excess_steps", "smoothness_translation", "smoothness_rotation", "step_bound"):
        assert all(r[col] != "" for r in rows if r["outcome"] == "converged"), col
    # The event metrics exist exactly where the event happened.
    for r in rows:
        bumped = r["scenario"] == "event-camera-bump"
        assert (r["event_peak_error"] != "") == bumped, r
        if bumped and r["outcome"] == "converged":
            assert int(r["event_steps_to_converge"]) == int(r["steps"]) - 3
    # The scenario's change really reached its episodes: the loose limit is in its config.
    loose = tmp_path / next(iter(tmp_path.iterdir())).name / "scenarios" / "loose-limit.yaml"
    assert "0.25" in loose.read_text()
    stats = json.loads(open(f"{folder}/statistics.json", encoding="utf-8").read())
    assert set(stats) == {"nominal", "loose-limit", "event-camera-bump"}
    assert "event_peak_error" in stats["event-camera-bump"]["ma2022"]
    assert "event_peak_error" not in stats["nominal"]["ma2022"]
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


def _scenarios(overrides):
    from rodctl.compare import load_compare_config
    from rodctl.suite import scenario_configs

    cfg = load_compare_config(SMOKE, overrides)
    return scenario_configs(cfg, REPO / "configs/benchmarks", SMOKE)


def test_method_set_reaches_every_method_whose_stage_has_the_field():
    sc = _scenarios(["scenarios.nominal.method_set={feature.degree: 3}"])
    methods = sc["nominal"]["methods"]
    assert methods["paper-bezier"]["feature"]["degree"] == 3
    assert methods["ma2022"]["feature"]["degree"] == 3
    assert "degree" not in methods["aghajanzadeh2022"]["feature"]  # nodes: no such field
    assert sc["loose-limit"]["methods"]["ma2022"]["feature"]["degree"] == 4  # one scenario only


def test_a_method_set_key_no_method_has_is_named(tmp_path):
    res = CliRunner().invoke(
        app,
        [
            "compare", SMOKE, "-o", str(tmp_path),
            "--set", "scenarios.nominal.method_set={feature.checkpoint: auto}",
        ],
    )  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "scenarios.nominal.method_set.feature.checkpoint" in res.output
    assert "no method's feature has a field 'checkpoint'" in res.output


def test_a_scenario_may_set_a_material_over_the_resolved_default_rod():
    sc = _scenarios(["scenarios.nominal.set={rod.material: {name: silicone_tube}}"])
    assert sc["nominal"]["base"]["rod"] == {"material": {"name": "silicone_tube"}}
    # ... and over a base that names a material of its own.
    sc = _scenarios(
        [
            "base.rod.material={name: nitinol_wire}",
            "scenarios.nominal.set={rod.material: {name: silicone_tube}}",
        ]
    )
    assert sc["nominal"]["base"]["rod"]["material"] == {"name": "silicone_tube"}
    assert sc["loose-limit"]["base"]["rod"]["material"] == {"name": "nitinol_wire"}


def _suite_with_two_episodes_done(
    out: Path, workers: int, stdout: int | None, stderr: int = subprocess.PIPE
) -> subprocess.Popen:
    """Start the smoke suite into `out` in a subprocess; return once two episodes are in its
    journals (or it ended, or 240 s passed)."""
    from batch_helpers import journal

    out.mkdir()
    args = [sys.executable, "-m", "rodctl", "compare", SMOKE, "--workers", str(workers), "-q"]
    proc = subprocess.Popen([*args, "--out", str(out)], cwd=REPO, stdout=stdout, stderr=stderr)
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        done = [journal(p) for p in out.glob("*/scenarios/*") if p.is_dir()]
        if sum(len(j) for j in done) >= 2:
            break
        time.sleep(0.05)
    return proc


def test_a_stopped_suite_says_interrupted_and_resume_finishes_it(tmp_path):
    """SIGTERM during a suite: the suite's meta.json says `interrupted` (not `failed`), the
    scenarios done so far are kept, and `--resume` runs the rest to a complete suite."""
    import os
    import signal

    from batch_helpers import journal

    out = tmp_path / "runs"
    proc = _suite_with_two_episodes_done(out, workers=2, stdout=subprocess.PIPE)
    assert proc.poll() is None, "the suite finished before the signal"
    os.kill(proc.pid, signal.SIGTERM)
    printed, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    (suite,) = [p for p in out.iterdir() if p.is_dir()]
    assert printed.decode().strip().splitlines()[-1] == str(suite)  # what --resume takes
    assert b"scenarios finished" in err
    meta = json.loads((suite / "meta.json").read_text())
    assert meta["status"] == "interrupted", meta
    cut = [Path(f) for f in meta["scenarios"].values()]  # the cut scenario's folder is known
    kept = {f: len([r for r in journal(f) if r["outcome"] != "interrupted"]) for f in cut}
    assert sum(kept.values()) >= 2
    res = CliRunner().invoke(app, ["compare", SMOKE, "-q", "--resume", str(suite)])
    assert res.exit_code == 0, res.output
    assert json.loads((suite / "meta.json").read_text())["status"] == "completed"
    with open(suite / "results.csv", encoding="utf-8") as fh:
        assert len(list(csv.DictReader(fh))) == 3 * 3 * 2
    # One folder per scenario: the cut one was continued, its finished episodes not run again
    # (but for the figure target's, whose step records the figures need: by design).
    assert len([p for p in (suite / "scenarios").iterdir() if p.is_dir()]) == 3
    for f in cut:
        keys = [(r["method"], r["target"]) for r in journal(f) if r["outcome"] != "interrupted"]
        assert len(set(keys)) == 6, keys
        again = {k for k in keys if keys.count(k) > 1}
        assert len({t for _, t in again}) <= 1, again  # only the figure target's episodes


def test_a_killed_suite_resumes_its_cut_scenario_in_the_same_folder(tmp_path):
    """SIGKILL (or a power cut) gives the suite no chance to say anything: meta.json still says
    `running`. `--resume` must still continue the cut scenario's folder, keeping its finished
    episodes, instead of starting that scenario again in a new one."""
    import os
    import signal

    from batch_helpers import journal

    out = tmp_path / "runs"
    proc = _suite_with_two_episodes_done(out, workers=1, stdout=None, stderr=subprocess.DEVNULL)
    assert proc.poll() is None, "the suite finished before the kill"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)
    (suite,) = [p for p in out.iterdir() if p.is_dir()]
    meta = json.loads((suite / "meta.json").read_text())
    assert meta["status"] == "running", meta  # nobody could say otherwise
    (cut,) = [Path(f) for f in meta["scenarios"].values()]  # recorded when it started
    killed_wall = meta["wall_s"]  # the killed run's time up to then, which --resume adds to
    assert killed_wall > 0
    before = {(r["method"], r["target"]) for r in journal(cut) if r["outcome"] != "interrupted"}
    assert len(before) >= 2
    res = CliRunner().invoke(app, ["compare", SMOKE, "-q", "--resume", str(suite)])
    assert res.exit_code == 0, res.output
    assert json.loads((suite / "meta.json").read_text())["status"] == "completed"
    assert len([p for p in (suite / "scenarios").iterdir() if p.is_dir()]) == 3
    keys = [(r["method"], r["target"]) for r in journal(cut) if r["outcome"] != "interrupted"]
    assert set(keys) >= before and len(set(keys)) == 6
    resumed = json.loads((suite / "meta.json").read_text())["wall_s"]
    assert resumed > killed_wall
    said = re.search(r"wall time (\d+) s", (suite / "summary.md").read_text())
    # both runs counted; summary.md rounds to whole seconds (29.8 s reads 30 s)
    assert said and killed_wall < int(said.group(1)) + 1 and int(said.group(1)) <= resumed + 1
    again = {k for k in keys if keys.count(k) > 1}
    assert len({t for _, t in again}) <= 1, again  # only the figure target's episodes
