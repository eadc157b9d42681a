"""The loop's bookkeeping: what the estimator is told, and how bad setups end."""

from __future__ import annotations

import json

import numpy as np
from paths import REPO
from typer.testing import CliRunner

import rodctl.experiment as experiment_module
from rodctl.cli import app
from rodctl.config import load_config
from rodctl.experiment import Experiment
from rodctl.vision import Extraction

FAST = ["feature.type=bezier", "logging.mcap=false", "logging.rerun=false", "logging.figures=false"]


def test_a_lost_frame_pairs_the_next_feature_change_with_both_moves(monkeypatch):
    """When the camera loses the rod for a step, the next good frame's Delta s was caused by
    two moves: the estimator must get their sum, not the last move alone."""
    cfg = load_config(REPO / "configs/default.yaml", [*FAST, "run.max_steps=12"])
    seen: list[np.ndarray] = []

    real = experiment_module.make_estimator

    def recording_estimator(*args, **kwargs):
        est = real(*args, **kwargs)
        update = est.update

        def spy(ds, dr):
            seen.append(np.array(dr, dtype=float))
            return update(ds, dr)

        est.update = spy
        return est

    monkeypatch.setattr(experiment_module, "make_estimator", recording_estimator)
    exp = Experiment(cfg, run_id="lost")
    extract = exp.extractor.extract
    calls = {"n": 0}

    def flaky(image, gripper_pose=None):
        calls["n"] += 1
        # Call 1 is the target, 2 the initial frame, 3-6 the probes; lose control step 7.
        if calls["n"] == 2 + 4 + 3:
            return Extraction(np.full((100, 2), np.nan), ok=False, note="occluded (test)")
        return extract(image, gripper_pose)

    exp.extractor.extract = flaky
    exp.run()
    recs = exp.records
    lost = [r.step for r in recs if not r.extraction_ok]
    assert lost == [7]
    # Updates happen at good control steps only: 5, 6, 8, 9, ... (step 7 had no feature).
    control_good = [r for r in recs if r.phase == "control" and r.extraction_ok]
    assert len(seen) == len(control_good)
    by_step = {r.step: r for r in recs}
    i8 = [r.step for r in control_good].index(8)
    np.testing.assert_array_equal(seen[i8], by_step[7].u + by_step[8].u)
    i6 = [r.step for r in control_good].index(6)
    np.testing.assert_array_equal(seen[i6], by_step[6].u)
    # The lost frame decides nothing: the run did not converge on it.
    assert by_step[7].s.tolist() == by_step[6].s.tolist()


def test_a_nan_command_ends_the_run_as_diverged_without_moving(monkeypatch):
    cfg = load_config(REPO / "configs/default.yaml", [*FAST, "run.max_steps=30"])
    real = experiment_module.make_controller

    def broken(*args, **kwargs):
        ctl = real(*args, **kwargs)
        ctl.command = lambda s, s_star, J, r: np.array([np.nan, 0.0, 0.0])
        return ctl

    monkeypatch.setattr(experiment_module, "make_controller", broken)
    exp = Experiment(cfg, run_id="nan")
    summary = exp.run()
    assert summary.outcome == "diverged" and summary.status == "failed"
    last, before = exp.records[-1], exp.records[-2]
    assert np.array_equal(last.gripper, before.gripper) and not np.any(last.u)


def test_bad_setup_found_before_any_step_leaves_no_running_run(tmp_path):
    runner = CliRunner()
    # A missing checkpoint is found while building the stages: no run directory at all.
    res = runner.invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--out",
            str(tmp_path / "a"),
            "--set",
            "feature.checkpoint=/nope.pt",
        ],
    )
    assert res.exit_code == 2 and "/nope.pt" in res.output
    assert not (tmp_path / "a").exists() or not any((tmp_path / "a").iterdir())
    # A rod the simulator cannot damp is found when the rod is built: the run directory says
    # failed, with the reason, never "running".
    res = runner.invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--out",
            str(tmp_path / "b"),
            "--set",
            "feature.type=bezier",
            "--set",
            "rod.length=0.1",
        ],
    )
    assert res.exit_code == 2 and "rod.inertia_radius" in res.output
    (run_dir,) = (tmp_path / "b").iterdir()
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "failed" and "rod" in meta["error"]
    # An impossible feature/N combination: exit 2, not a traceback.
    res = runner.invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--out",
            str(tmp_path / "c"),
            "--set",
            "feature.type=bezier",
            "--set",
            "camera.points=3",
        ],
    )
    assert res.exit_code == 2 and "camera.points=3" in res.output
    assert "Traceback" not in res.output


def test_a_compare_config_given_to_simulate_says_so(tmp_path):
    res = CliRunner().invoke(
        app, ["simulate", str(REPO / "configs/compare-smoke.yaml"), "--out", str(tmp_path)]
    )
    assert res.exit_code == 2 and "rodctl compare" in res.output
