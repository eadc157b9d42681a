"""Benchmark suites: every method on every scenario, paired statistics, a self-contained report."""

from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app

SMOKE = str(REPO / "configs/benchmarks/suite-smoke.yaml")


@pytest.mark.slow
def test_smoke_suite_runs_every_scenario_and_reports_paired_statistics(tmp_path, monkeypatch):
    import rodctl.bench.compare as compare
    from rodctl.executors.local import LocalExecutor

    starts = []  # every pool started: one for the whole suite, not one per scenario
    start = LocalExecutor.start
    monkeypatch.setattr(LocalExecutor, "start", lambda self: (starts.append(1), start(self)))
    monkeypatch.setattr(compare, "make_pool", lambda *a: pytest.fail("a pool per scenario"))
    res = CliRunner().invoke(app, ["compare", SMOKE, "-q", "-o", str(tmp_path), "--workers", "2"])
    assert res.exit_code == 0, res.output
    assert len(starts) == 1
    folder = res.output.strip().splitlines()[-1]
    with open(f"{folder}/results.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["scenario"] for r in rows} == {"nominal", "loose-limit", "event-camera-bump"}
    assert len(rows) == 3 * 3 * 2
    for col in ("excess_steps", "smoothness_translation", "smoothness_rotation", "pose_steps"):
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
    assert {r["finished_before_event"] for r in rows} == {"", "False"}  # the event reached all
    assert {r["seed"] for r in rows} == {"0"}
    stats = json.loads(open(f"{folder}/statistics.json", encoding="utf-8").read())["scenarios"]
    assert set(stats) == {"nominal", "loose-limit", "event-camera-bump"}
    assert "event_peak_error" in stats["event-camera-bump"]["methods"]["ma2022"]["metrics"]
    assert "event_peak_error" not in stats["nominal"]["methods"]["ma2022"]["metrics"]
    assert set(stats["nominal"]["methods"]) == {"ma2022", "aghajanzadeh2022"}  # but the reference
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
    from rodctl.bench.compare import load_compare_config
    from rodctl.bench.suite import scenario_configs

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


@pytest.mark.slow
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
    assert meta["error"] == "interrupted by SIGTERM"  # as a compare says it (it was absent)
    assert meta["scenarios_finished"]["total"] == 3
    cut = [suite / f for f in meta["scenarios"].values()]  # the cut scenario's folder is known
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


@pytest.mark.slow
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
    (name,) = meta["scenarios"].values()  # recorded when it started, inside the suite's folder
    assert not Path(name).is_absolute()
    killed_wall = meta["wall_s"]  # the killed run's time up to then, which --resume adds to
    assert killed_wall > 0
    # the suite moved elsewhere (copied to another disk or machine) resumes as well
    suite = Path(shutil.move(suite, tmp_path / "moved"))
    cut = suite / name
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


def _synthetic_suite(tmp_path: Path, seeds=(0, 1, 2), n=30):
    """Results of the smoke suite's config written without running it: on every seed ma2022
    converges a step or two faster than the reference (but stalls on target 0, unreachable);
    aghajanzadeh2022 is two steps faster on
    seeds 0 and 1 and one slower on seed 2. On event-camera-bump the reference finishes three
    targets of seed 0 before the event (the fastest ones)."""
    import numpy as np

    rng = np.random.default_rng(5)
    folders = {}
    for scenario in ("nominal", "loose-limit", "event-camera-bump"):
        for s in seeds:
            episodes = []
            for t in range(n):
                ref = float(rng.integers(10, 20))
                steps = {
                    "paper-bezier": ref,
                    "ma2022": ref - float(rng.choice([0, 1, 2], p=[0.2, 0.5, 0.3])),
                    "aghajanzadeh2022": ref + (1.0 if s == 2 else -2.0) * float(rng.random() < 0.9),
                }
                for m, k in steps.items():
                    early = scenario == "event-camera-bump" and s == 0 and m == "paper-bezier"
                    early = early and t < 3
                    stalled = scenario == "nominal" and m == "ma2022" and t == 0
                    episodes.append(
                        {
                            "method": m, "target": t, "band": "easy",
                            "outcome": "stalled" if stalled else "converged",
                            "diagnosis": "unreachable" if stalled else None,
                            "steps": k, "steps_to_converge": k, "smoothness": 0.1,
                            "path_length": 0.1, "final_pixel_error": 0.5,
                            "finished_before_event": (
                                early if scenario == "event-camera-bump" else None
                            ),
                        }
                    )  # fmt: skip
            folder = tmp_path / f"{scenario}-seed{s}"
            folder.mkdir()
            data = {"seed": s, "config": {"scenario": scenario}, "episodes": episodes}
            (folder / "results.json").write_text(json.dumps(data))
            folders[f"{scenario}-seed{s}"] = str(folder)
    return folders


def test_a_finding_is_replicated_only_when_every_seed_agrees(tmp_path):
    from rodctl.bench.compare import load_compare_config
    from rodctl.bench.suite import write_suite_outputs

    cfg = load_compare_config(SMOKE, ["seeds=[0, 1, 2]"])
    folders = _synthetic_suite(tmp_path)
    write_suite_outputs(cfg, tmp_path, folders, wall=1.0)
    stats = json.loads((tmp_path / "statistics.json").read_text())
    assert stats["seeds"] == [0, 1, 2] and stats["correction"]["method"] == "holm"
    ma = stats["scenarios"]["nominal"]["methods"]["ma2022"]["metrics"]["steps_to_converge"]
    ag = stats["scenarios"]["nominal"]["methods"]["aghajanzadeh2022"]["metrics"][
        "steps_to_converge"
    ]
    assert ma["significant"] and ma["replicated"] and ma["verdict"] == "replicated"
    assert all(v["mean"] < 0 for v in ma["per_seed"].values())
    # Pooled, aghajanzadeh2022 is faster (seeds 0 and 1 outweigh 2), and significantly so:
    # but seed 2 says the opposite, so the finding does not replicate.
    assert ag["significant"] and ag["mean"] < 0 and ag["per_seed"]["2"]["mean"] > 0
    assert not ag["replicated"] and "seed 2" in ag["verdict"]
    # Raw and adjusted p are both kept; Holm never lowers a p.
    tests = stats["correction"]["pooled_tests"]
    assert tests == 3 * 2  # 3 scenarios x 2 methods x 1 metric with values
    assert ma["p_adjusted"] >= ma["p_value"] and ag["p_adjusted"] >= ag["p_value"]
    assert ag["p_adjusted"] == min(1.0, ag["p_adjusted"])
    assert {(f["scenario"], f["method"], f["replicated"]) for f in stats["findings"]} >= {
        ("nominal", "ma2022", True),
        ("nominal", "aghajanzadeh2022", False),
    }
    summary = (tmp_path / "summary.md").read_text()
    assert "## Findings" in summary and "| nominal | ma2022 |" in summary
    assert "not replicated (seed 2 disagrees in direction)" in summary
    assert "**replicated**" in summary and "Per seed" in summary
    assert "replicated" in (tmp_path / "report.html").read_text()
    # The episodes the event never reached are counted apart and left out of the pairs.
    bump = stats["scenarios"]["event-camera-bump"]
    assert bump["finished_before_event"]["paper-bezier"] == 3
    assert bump["methods"]["ma2022"]["metrics"]["steps_to_converge"]["n"] == 3 * 30 - 3
    assert bump["methods"]["ma2022"]["success_per_seed"]["0"]["both"] == 30 - 3
    assert "Finished before the event" in summary
    diag = stats["scenarios"]["nominal"]["diagnosis"]["ma2022"]
    assert diag["unreachable"] == len(stats["seeds"]) and diag["estimator"] == diag["none"] == 0
    assert "| ma2022 | 3 | 0 | 0 | 3 | 0 | 0 |" in summary  # the per-scenario diagnosis table
    with open(tmp_path / "results.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["seed"] for r in rows} == {"0", "1", "2"} and len(rows) == 3 * 3 * 3 * 30


def test_one_seed_replicates_nothing(tmp_path):
    from rodctl.bench.compare import load_compare_config
    from rodctl.bench.suite import write_suite_outputs

    cfg = load_compare_config(SMOKE)
    write_suite_outputs(cfg, tmp_path, _synthetic_suite(tmp_path, seeds=(0,)), wall=1.0)
    stats = json.loads((tmp_path / "statistics.json").read_text())
    ma = stats["scenarios"]["nominal"]["methods"]["ma2022"]["metrics"]["steps_to_converge"]
    assert ma["significant"] and not ma["replicated"]
    assert ma["verdict"] == "not replicated (one seed)"


def test_seeds_make_one_compare_run_per_scenario_and_seed():
    sc = _scenarios(["seeds=[3, 4]"])
    assert set(sc) == {f"{n}-seed{s}" for n in ("nominal", "loose-limit", "event-camera-bump")
                       for s in (3, 4)}  # fmt: skip
    assert sc["nominal-seed4"]["seed"] == 4 and sc["nominal-seed4"]["scenario"] == "nominal"
    assert "seeds" not in sc["nominal-seed3"]
    assert set(_scenarios([])) == {"nominal", "loose-limit", "event-camera-bump"}


def test_seeds_without_scenarios_or_repeated_are_refused(tmp_path):
    res = CliRunner().invoke(app, ["compare", SMOKE, "-o", str(tmp_path), "--set", "seeds=[1, 1]"])
    assert res.exit_code == 2 and "seeds" in res.output


def test_seeds_with_fixed_target_poses_are_refused(tmp_path):
    """Several seeds over a fixed set of poses would pool the same targets as independent pairs."""
    res = CliRunner().invoke(
        app,
        ["compare", SMOKE, "-o", str(tmp_path), "--set", "seeds=[1, 2]",
         "--set", "targets.poses=[[0.45, 0.05, 0.3], [0.45, -0.05, -0.3]]"],
    )  # fmt: skip
    assert res.exit_code == 2 and "targets.poses fix the poses" in res.output, res.output
    assert not list(tmp_path.iterdir())


def test_each_scenario_records_the_executor_the_suite_ran_on(tmp_path):
    """The scenarios share the suite's one pool, and each scenario's meta.json names the
    executor it ran on (here the example plug-in's `thread`), not the default `local`."""
    res = CliRunner().invoke(
        app,
        ["compare", SMOKE, "-q", "-o", str(tmp_path), "--executor", "thread", "--workers", "2"],
    )
    assert res.exit_code == 0, res.output
    folder = Path(res.output.strip().splitlines()[-1])
    metas = [json.loads(p.read_text()) for p in (folder / "scenarios").glob("*/meta.json")]
    assert len(metas) == 3
    assert all("thread" in json.dumps(m["executor"]) for m in metas), metas[0]["executor"]
