"""The agreement criterion of issue 24 on a small case: the paper's law (Bezier stand-in feature,
AKF, MFAC) on four sampled targets, once on the pymunk chain and once on the quasi-static engine:
the same outcome on >= 95 % of the episodes and the steps within +-1 on >= 90 %, counted by the
study's own pairing (benchmarks/bench_agreement.py, which runs the full study)."""

from __future__ import annotations

import importlib.util

import pytest
from paths import REPO

from rodctl.config import validate_config
from rodctl.env import ShapeServoEnv
from rodctl.episode import run_episode
from rodctl.method import Method

_spec = importlib.util.spec_from_file_location(
    "bench_agreement", REPO / "benchmarks" / "bench_agreement.py"
)
bench_agreement = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_agreement)

METHOD = {
    "feature": {"type": "bezier", "degree": 4},
    "estimator": {"type": "akf", "p0": 10.0},
    "controller": {"type": "mfac", "weights": [0.7, 0.0001, 0.1, 0.05, 0.0001, 0.0498, 0.1]},
    "run": {"max_steps": 60, "target": {"min_offset": 0.1, "max_offset": 0.3}},
}


def test_both_engines_agree_on_a_small_case() -> None:
    poses = None
    rows: dict[str, list[dict]] = {}
    for engine in bench_agreement.ENGINES:
        cfg = validate_config(
            {**METHOD, "rod": {"segments": 25, "engine": engine}, "camera": {"points": 40}},
            "test config",
        )
        env = ShapeServoEnv(cfg)
        if poses is None:  # the same target poses for both engines
            poses = [env.make_target(seed=k).pose for k in range(4)]
        rows[engine] = []
        for k, pose in enumerate(poses):
            res = run_episode(env, Method.from_config(cfg), options={"target_pose": pose})
            x, y, theta = (float(v) for v in pose)
            rows[engine].append(
                {"scenario": "nominal", "method": "paper-bezier", "target": k, "target_x": x,
                 "target_y": y, "target_theta": theta, "outcome": res.outcome.value,
                 "steps": res.summary.steps}
            )  # fmt: skip
    result = bench_agreement.agreement(rows["pymunk"], rows["quasistatic"])
    assert result["pairs"] == 4 and result["unpaired"] == 0
    assert bench_agreement.passes(result), bench_agreement.report(result)
    # The pairing itself: a different outcome and a step count two apart both count against it.
    worse = [dict(r) for r in rows["quasistatic"]]
    worse[0]["outcome"] = "stalled"
    worse[1]["steps"] = int(worse[1]["steps"]) + 2
    bad = bench_agreement.agreement(rows["pymunk"], worse)
    assert bad["same_outcome"] == 0.75 and bad["steps_within_one"] == 0.75
    assert not bench_agreement.passes(bad) and len(bad["disagreements"]) == 2


def test_the_step_agreement_is_split_by_the_outcome_both_runs_ended_on() -> None:
    """The report's addition (not a goal): the step agreement of the episodes both runs
    converged apart from those both stalled, and which run ends on which outcome where they
    differ; crafted rows, no simulation."""

    def row(k: int, outcome: str, steps: int) -> dict:
        pose = {"target_x": 0.1 * k, "target_y": 0.0, "target_theta": 0.0}
        return {"scenario": "s", "method": "m", "target": k, **pose, "outcome": outcome,
                "steps": steps}  # fmt: skip

    a = [row(0, "converged", 10), row(1, "converged", 12), row(2, "stalled", 30),
         row(3, "stalled", 40), row(4, "stalled", 25), row(5, "converged", 9)]  # fmt: skip
    b = [row(0, "converged", 11), row(1, "converged", 15), row(2, "stalled", 30),
         row(3, "stalled", 60), row(4, "converged", 25), row(5, "stalled", 30)]  # fmt: skip
    result = bench_agreement.agreement(a, b)
    assert result["by_outcome"] == {"converged": (2, 1), "stalled": (2, 1)}
    assert result["outcome_changes"] == {("stalled", "converged"): 1, ("converged", "stalled"): 1}
    assert result["stalled_error_gaps"] == []  # the crafted rows have no final pixel error
    errors = [0.5, 0.6, 1.5, 1.2, 1.4, 0.9, 0.5, 0.6, 1.6, 1.7, 0.9, 1.3]
    for r, px in zip(a + b, errors, strict=True):
        r["final_pixel_error"] = px
    gaps = bench_agreement.agreement(a, b)["stalled_error_gaps"]
    assert gaps == pytest.approx([0.1, 0.5])  # targets 2 and 3, both stalled
    text = bench_agreement.report(result, names=("pymunk", "pymunk-b"))
    assert "stalled -> converged: 1" in text and "pymunk vs pymunk-b" in text
