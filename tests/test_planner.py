"""The planner reference (rodctl/planner.py): its pose is within tolerance through the real
camera, it never needs more steps than the straight path to the target pose, a target no pose
can make gets no plan (as the diagnosis calls it unreachable), and the benchmark script counts
the methods that beat it."""

from __future__ import annotations

import csv
import importlib.util
import json

import numpy as np
import pytest
from paths import REPO

from rodctl.config import ExperimentConfig, load_config
from rodctl.diagnosis import pose_search
from rodctl.env import ShapeServoEnv, Target
from rodctl.metrics import pose_steps
from rodctl.planner import PlannerError, check_plannable, grid_min_error, make_target, plan

SMALL = [
    "feature.type=bezier", "logging.mcap=false", "logging.rerun=false", "logging.figures=false",
    "rod.engine=quasistatic", "rod.segments=20",
]  # fmt: skip

#: A target 5 speed-limited steps from home that the tolerance meets earlier (measured: 4).
POSE = [0.40, 0.05, 0.5]


def _cfg(*over: str) -> ExperimentConfig:
    return load_config(REPO / "configs/default.yaml", [*SMALL, *over])


@pytest.fixture(scope="module")
def planned():
    cfg = _cfg()
    target = make_target(cfg, POSE)
    return cfg, target, plan(cfg, target)


def test_the_plans_pose_is_within_tolerance_through_the_real_camera(planned):
    """An episode's own environment, driven `steps` times by the plan's move, sees (rendered and
    extracted, as an episode does) a centerline within the tolerance; each move is within the
    speed limit, and one step fewer is not within it."""
    cfg, target, p = planned
    assert p.steps is not None and p.move is not None
    env = ShapeServoEnv(cfg)
    env.reset(options={"target": target})
    assert np.all(np.abs(p.move) <= env.max_step * (1 + 1e-9))
    errors = []
    for _ in range(p.steps):
        _, _, _, _, info = env.step(p.move)
        assert not info["saturated"].any() and not info["clipped"]
        errors.append(info["pixel_error"])
    assert info["extraction_ok"] and errors[-1] < cfg.run.pixel_tolerance
    assert all(e >= cfg.run.pixel_tolerance for e in errors[:-1])
    assert abs(errors[-1] - p.pixel_error) < 1e-9


def test_the_planner_never_needs_more_than_the_straight_path_to_the_target_pose(planned):
    """pose_steps (the straight path to the target pose) is one of its candidates; on this
    target the tolerance is met a step short of the target pose, and the planner finds that."""
    cfg, target, p = planned
    env = ShapeServoEnv(cfg)
    env.reset(options={"target": target})
    k0 = pose_steps(env.task.home_pose, target.pose, env.max_step)
    assert p.pose_steps == k0 == 5
    assert p.steps is not None and p.steps <= k0
    assert p.steps == 4
    # One step fewer than the plan: the search found no pose in B_(k-1) within tolerance.
    assert p.levels[-1][0] == p.steps - 1 and p.levels[-1][1] >= cfg.run.pixel_tolerance


def test_a_target_no_pose_can_make_gets_no_plan_and_the_diagnosis_calls_it_unreachable():
    """The whole target moved sideways in the image, clamp end included: no gripper pose makes
    it. The planner has no plan, and diagnosis's pose search from the start stops short of the
    tolerance, not clipped and not still improving: `unreachable`."""
    cfg = _cfg()
    t = make_target(cfg, POSE)
    moved = Target(t.pose, t.centerline, t.pixels + np.array([15.0, 0.0]), t.difficulty)
    p = plan(cfg, moved)
    assert p.steps is None and p.pose is None
    assert p.best_error > cfg.run.pixel_tolerance
    env = ShapeServoEnv(cfg)
    env.reset(options={"target": moved})
    best, clipped, capped = pose_search(env, 20)
    assert best > cfg.run.pixel_tolerance and not clipped and not capped
    assert p.best_error <= best + 1e-9  # the planner searched at least where the diagnosis did


@pytest.mark.parametrize(
    ("over", "field"),
    [
        (["run.events=[{at_step: 3, type: stiffness, factor: 0.5}]"], "run.events"),
        (["rod.arms=2"], "rod.arms"),
        (["rod.engine=pymunk", "rod.table_friction=0.5"], "rod.table_friction"),
    ],
)
def test_configs_the_planner_cannot_plan_for_are_refused_by_name(over, field):
    with pytest.raises(PlannerError, match=field.replace(".", r"\.")):
        check_plannable(_cfg(*over))


def _bench():
    spec = importlib.util.spec_from_file_location(
        "bench_planner", REPO / "benchmarks/bench_planner.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_benchmark_counts_the_episodes_that_beat_the_planner(tmp_path, capsys):
    """A compare folder of one target and two made-up methods: one converged a step under the
    planner once its probing is taken off, one did not; the script says so, and refuses a folder
    without results.csv or with a column missing (exit 2)."""
    cfg = _cfg()
    bench = _bench()
    assert bench.main([str(tmp_path)]) == 2
    assert "no results.csv" in capsys.readouterr().err
    (tmp_path / "results.json").write_text(
        json.dumps({"config": {"base": cfg.model_dump(mode="json")}, "targets": []}),
        encoding="utf-8",
    )
    rows = [
        {"method": "quick", "steps": 7, "probe_steps": 4},  # 7 - 4 = 3 < 4: beats when unprobed
        {"method": "slow", "steps": 9, "probe_steps": 0},
    ]
    with (tmp_path / "results.csv").open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=bench.NEEDED)
        w.writeheader()
        for r in rows:
            w.writerow(
                {"scenario": "nominal", "seed": 0, "target": 0, "target_x": POSE[0],
                 "target_y": POSE[1], "target_theta": POSE[2], "converged": True,
                 "pose_steps": 5, **r}
            )  # fmt: skip
    assert bench.main([str(tmp_path), "--out", str(tmp_path / "plans.csv")]) == 0
    out = capsys.readouterr().out
    assert "| quick | 1 | 0 | 0 | +3.00 | 1 | 0 | -1.00 |" in out
    assert "| slow | 1 | 0 | 0 | +5.00 | 0 | 0 | +5.00 |" in out
    assert "quick target 0: 7 steps (4 probing) against planner 4" in out
    plans = list(csv.DictReader((tmp_path / "plans.csv").open(encoding="utf-8")))
    assert plans[0]["planner_steps"] == "4" and plans[0]["pose_steps"] == "5"
    with (tmp_path / "results.csv").open("w", encoding="utf-8") as fh:
        fh.write("scenario,seed,method\nnominal,0,quick\n")
    assert bench.main([str(tmp_path)]) == 2
    assert "lacks the column(s) target" in capsys.readouterr().err


def test_a_grid_over_one_step_fewer_finds_no_pose_within_tolerance_either(planned):
    """The search is local; fits started from a grid of 3^3 poses over the poses one step short
    of the plan find none within tolerance either, and over the plan's own budget they do."""
    cfg, target, p = planned
    below, _ = grid_min_error(cfg, target, p.steps - 1, 3)
    assert below >= cfg.run.pixel_tolerance
    at, pose = grid_min_error(cfg, target, p.steps, 3)
    assert at < cfg.run.pixel_tolerance and pose is not None
