"""Dual-arm (`rod.arms: 2`): the x0 end held by a second arm, both ends moved, q = 6.

Small rods (N = 20) and the quasi-static engine where the engine does not matter.
"""

from __future__ import annotations

import re
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import yaml
from gymnasium.utils.env_checker import check_env
from paths import REPO
from typer.testing import CliRunner

from rodctl.bench.compare import load_compare_config, method_config
from rodctl.bench.suite import scenario_configs
from rodctl.bench.target_set import read_target_file
from rodctl.cli import app
from rodctl.config import ConfigError, ExperimentConfig, load_config, validate_config
from rodctl.config.compare import CompareConfig
from rodctl.config.rod import RodConfig
from rodctl.env import ShapeServoEnv
from rodctl.episode import run_episode
from rodctl.errors import UserError
from rodctl.features.autoencoder import encoder_fingerprint
from rodctl.logs import codec, schemas
from rodctl.logs.mcap import McapSink, read_mcap
from rodctl.method import Method
from rodctl.replay import compare_records
from rodctl.rl import ShapeServoRLEnv
from rodctl.sim import RodSim

N = 20


def rod(**kw) -> RodConfig:
    return RodConfig(segments=N, arms=2, **kw)


def test_one_arm_dump_is_unchanged_and_clamp_arm_needs_two():
    assert "arms" not in RodConfig().model_dump()
    assert "clamp_arm" not in RodConfig().model_dump()
    two = rod().model_dump()
    assert two["arms"] == 2 and two["clamp_arm"]["max_step"] == (0.01, 0.01, 0.05)
    assert RodConfig.model_validate(two) == rod()  # a resolved dual-arm config loads again
    one = ExperimentConfig()
    assert "arms" not in encoder_fingerprint(one)["rod"]  # the packaged encoder's, unchanged
    dual = one.model_copy(update={"rod": rod()})
    assert encoder_fingerprint(dual)["rod"]["arms"] == 2  # a one-arm encoder does not fit
    with pytest.raises(UserError, match="arms: 2"):
        validate_config({"run": {"target": {"pose": [0.4, 0.1, 0.5, 0, 0, 0]}}}, "test")
    with pytest.raises(UserError, match="clamp_arm"):
        validate_config({"rod": {"clamp_arm": {"max_step": [0.02, 0.02, 0.1]}}}, "test")
    with pytest.raises(UserError, match="clamp_pose"):
        validate_config({"rod": {"arms": 2, "clamp_pose": [0.3, 0.0, 0.0]}}, "test")


def test_start_poses_are_checked_against_each_arms_workspace():
    """The x0 end's start and target poses lie in rod.clamp_arm.workspace, the gripper's start
    within the smaller reach of the two arms; a workspace given in part keeps the x0 end's
    defaults (not the gripper's, which exclude the default clamp pose)."""
    part = {"rod": {"arms": 2, "clamp_arm": {"workspace": {"max_reach": 0.9}}}}
    ws = validate_config(part, "test").rod.clamp_arm.workspace
    assert (ws.x_limits, ws.y_limits, ws.max_reach) == ((-0.2, 0.25), (-0.35, 0.35), 0.9)
    outside = {"arms": 2, "clamp_arm": {"workspace": {"x_limits": [-0.1, 0.1]}}}
    with pytest.raises(UserError, match=r"rod\.clamp_pose \[0\.2.*rod\.clamp_arm\.workspace"):
        validate_config({"rod": {**outside, "clamp_pose": [0.2, 0.0, 0.0]}}, "test")
    target = {"pose": [0.4, 0.1, 0.3, 0.6, 0.0, 0.0]}  # the x0 end's x beyond 0.25 m
    with pytest.raises(UserError, match=r"run\.target\.pose: the x0 end's pose \[0\.6.*clamp_arm"):
        validate_config({"rod": {"arms": 2}, "run": {"target": target}}, "test")
    far = {"arms": 2, "home_pose": [0.45, 0.0, 0.0]}  # 0.45 m of a 0.5 m rod: 0.9 L
    validate_config({"rod": far}, "test")
    with pytest.raises(UserError, match=r"home_pose.*0\.25 m.*smaller of the two arms"):
        validate_config({"rod": {**far, "clamp_arm": {"workspace": {"max_reach": 0.5}}}}, "test")


def test_a_start_pose_given_to_reset_is_checked_too():
    env = ShapeServoEnv(_env_config())
    with pytest.raises(UserError, match=r"(?s)start_pose.*clamp_pose \[0\.5.*clamp_arm\.workspace"):
        env.reset(seed=0, options={"start_pose": [0.4, 0.1, 0.3, 0.5, 0.0, 0.0]})
    with pytest.raises(UserError, match=r"(?s)start_pose.*home_pose \[0\.9"):
        env.reset(seed=0, options={"start_pose": [0.9, 0.0, 0.0]})


def test_a_target_pose_outside_the_x0_ends_workspace_exits_2_naming_the_field(tmp_path):
    config = tmp_path / "bad.yaml"
    config.write_text("rod: {arms: 2}\nrun: {target: {pose: [0.4, 0.1, 0.3, 0.0, 0.5, 0.0]}}\n")
    res = CliRunner().invoke(app, ["simulate", str(config), "-o", str(tmp_path / "out")])
    out = " ".join((res.stdout + (res.stderr or "")).split())
    assert res.exit_code == 2 and "Traceback" not in out, out
    assert "run.target.pose: the x0 end's pose [0.0, 0.5, 0.0]" in out, out


@pytest.mark.parametrize("engine", ["pymunk", "quasistatic"])
def test_both_ends_move_each_with_its_own_speed_limit(engine):
    sim = RodSim(rod(engine=engine, clamp_arm={"max_step": [0.004, 0.004, 0.02]}))
    g0, c0 = sim.gripper_pose, sim.clamp_pose
    res = sim.apply(np.array([0.02, 0.0, 0.0, 0.02, -0.003, 0.05]))
    assert res.settled and not res.diverged
    np.testing.assert_array_equal(res.saturated, [True, False, False, True, False, True])
    np.testing.assert_allclose(res.u_applied, [0.01, 0.0, 0.0, 0.004, -0.003, 0.02], atol=1e-9)
    np.testing.assert_allclose(sim.gripper_pose - g0, [0.01, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(sim.clamp_pose - c0, [0.004, -0.003, 0.02], atol=1e-9)
    # The rod is held by both ends: its first joint is where the second arm put the x0 end.
    np.testing.assert_allclose(sim.centerline()[0], sim.clamp_pose[:2], atol=2e-4)
    np.testing.assert_allclose(sim.end_poses, np.r_[sim.gripper_pose, sim.clamp_pose])


def test_the_x0_end_stays_in_its_workspace_and_refuses_when_told():
    ws = {"x_limits": [-0.005, 0.25], "y_limits": [-0.35, 0.35]}
    sim = RodSim(rod(engine="quasistatic", clamp_arm={"workspace": ws}))
    res = sim.apply(np.array([0.0, 0.0, 0.0, -0.01, 0.0, 0.0]))
    assert res.clipped and not res.refused
    assert sim.clamp_pose[0] == pytest.approx(-0.005)
    refuse = {"workspace": {**ws, "on_violation": "refuse"}}
    strict = RodSim(rod(engine="quasistatic", clamp_arm=refuse))
    before = strict.end_poses
    res = strict.apply(np.array([0.005, 0.0, 0.0, -0.01, 0.0, 0.0]))
    assert res.refused
    np.testing.assert_array_equal(strict.end_poses, before)


def test_the_engines_agree_on_a_dual_arm_move():
    """pymunk's settled rod and the quasi-static equilibrium after the same both-ends move."""
    shapes = []
    for engine in ("pymunk", "quasistatic"):
        sim = RodSim(rod(engine=engine))
        for _ in range(3):
            res = sim.apply(np.array([-0.01, 0.01, 0.05, 0.01, 0.005, -0.05]))
            assert res.settled
        shapes.append(sim.centerline())
    assert np.max(np.linalg.norm(shapes[0] - shapes[1], axis=1)) < 2e-3 * 0.5  # 0.2 % of L


def _env_config(**run) -> ExperimentConfig:
    return validate_config(
        {
            "rod": {"arms": 2, "engine": "quasistatic", "segments": 30},
            "camera": {"points": 40},
            "run": {"max_steps": 5, **run},
        },
        "test",
    )


def test_env_spaces_are_q6_and_pass_check_env():
    env = ShapeServoEnv(_env_config())
    assert env.action_space.shape == (6,)
    obs, info = env.reset(seed=3)
    assert obs["gripper"].shape == (6,) and obs["applied"].shape == (6,)
    assert env.task.home_pose.shape == (6,) and env.target.pose.shape == (6,)
    obs, *_ = env.step(np.array([0.0, 0.0, 0.0, 0.005, 0.0, 0.0]))
    np.testing.assert_allclose(obs["applied"], [0, 0, 0, 0.005, 0, 0], atol=1e-9)
    np.testing.assert_allclose(obs["gripper"][3:], env.sim.clamp_pose)
    check_env(env, skip_render_check=True)
    try:  # optional (the `rl` extra), and it imports torch: only where it is installed
        from stable_baselines3.common.env_checker import check_env as sb3_check  # noqa: PLC0415
    except ImportError:
        return
    rl = ShapeServoRLEnv(_env_config())
    assert rl.action_space.shape == (6,)
    sb3_check(rl, warn=False)


def test_dual_arm_scenarios_load():
    suite = str(REPO / "configs/benchmarks/suite-dual-arm.yaml")
    runs = scenario_configs(load_compare_config(suite), REPO / "configs/benchmarks", suite)
    for name in ("dual-arm", "dual-arm-large", "dual-arm-yu2023"):
        assert load_config(REPO / f"configs/scenarios/{name}.yaml").rod.arms == 2
    names = {run["scenario"] for run in runs.values()}
    assert names == {"dual-arm-nominal", "dual-arm-large-deformation"}
    for run in runs.values():
        cfg = CompareConfig.model_validate(run)
        for method in cfg.methods:
            assert method_config(cfg, method).rod.arms == 2


@pytest.mark.parametrize("name", ["dual-arm", "dual-arm-yu2023"])
def test_a_short_dual_arm_episode_converges(name, tmp_path):
    """The paper's method and the learned model (q = 6) on a small quasi-static rod; the MCAP
    log carries the x0 end's pose (/rod/clamp) and reads back to the same records."""
    over = ["rod.engine=quasistatic", "rod.segments=30", "run.max_steps=40"]
    if name == "dual-arm":  # the packaged one-arm encoder, not a quick one trained here
        over += ["feature.checkpoint=null", "feature.other_setup=accept"]
    cfg = load_config(REPO / f"configs/scenarios/{name}.yaml", over)
    sink = McapSink(tmp_path / "run.mcap", cfg.logging)
    result = run_episode(ShapeServoEnv(cfg), Method.from_config(cfg), sinks=[sink], seed=0)
    assert result.outcome.value == "converged", result.summary
    assert result.summary.final_pixel_error < cfg.run.pixel_tolerance
    last = result.records[-1]
    assert last.clamp is not None and len(last.u) == 6
    assert np.any(np.abs(last.clamp - np.asarray(cfg.rod.clamp_pose)) > 1e-4)  # it moved
    extra = result.summary.extra  # both ends' poses, as home_pose and target_pose
    assert extra["final_gripper"] == [*last.gripper.tolist(), *last.clamp.tolist()]
    assert len(extra["home_pose"]) == len(extra["target_pose"]) == 6
    logged = read_mcap(tmp_path / "run.mcap", images=False)
    assert logged.header.home_pose.shape == (6,)
    assert compare_records(logged.records, result.records) == []
    for message, schema in (
        (codec.clamp_state_message(last), schemas.CLAMP_STATE),
        (codec.control_message(last), schemas.CONTROL),
        (codec.header_to_json(result.header), schemas.RUN_HEADER),
    ):
        jsonschema.validate(message, schema)  # the q = 6 messages fit their channels' schemas


def _dual_arm_compare(tmp_path, poses):
    """A one-method dual-arm compare config on a small quasi-static rod, with given targets."""
    data = {
        "name": "dual-targets",
        "base": {
            "rod": {"arms": 2, "engine": "quasistatic", "segments": N},
            "run": {"max_steps": 12},
            "logging": {"mcap": False, "rerun": False, "figures": False},
        },
        "methods": {
            "ma2022": {
                "feature": {"type": "bezier", "degree": 4},
                "estimator": {"type": "broyden", "gamma": 1.0},
                "controller": {"type": "pinv", "gain": 0.8, "error_limit": 50.0},
            }
        },
        "targets": {"poses": poses},
        "workers": 1,
    }
    path = tmp_path / "compare.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_dual_arm_compare_takes_six_value_target_poses_and_says_so_in_targets_yaml(tmp_path):
    """targets.poses of 6 values (both ends) at rod.arms: 2; the targets.yaml it writes names
    what a pose holds and reads back as a dual-arm targets.file, refused on one arm."""
    home = RodSim(rod()).home_end_poses
    pose = [float(v) for v in home + np.array([-0.01, 0.01, 0.05, 0.005, 0.0, 0.03])]
    config = _dual_arm_compare(tmp_path, [pose])
    res = CliRunner().invoke(app, ["compare", str(config), "--out", str(tmp_path), "-q"])
    assert res.exit_code == 0, res.output
    written = Path(res.stdout.strip().splitlines()[-1]) / "targets.yaml"
    header = written.read_text().splitlines()[0]
    assert "[x, y, theta, x0_x, x0_y, x0_theta]" in header and "x0 end's" in header
    (again,) = read_target_file(written, arms=2)
    assert np.allclose(again, pose, atol=1e-3)  # the settled poses, both ends
    with pytest.raises(ConfigError, match=r"targets\.file .*item 0 has 6 values.*one arm"):
        read_target_file(written, arms=1)


@pytest.mark.parametrize(
    "over, match",
    [
        (["base.rod.arms=1"], r"targets\.poses: item 0 has 6 values.*one arm"),
        (["targets.poses=[[0.5, 0.0, 0.0]]"], r"targets\.poses: item 0 has 3 values.*two arms"),
        (["targets.poses=null", "targets.file=three.yaml"], r"targets\.file .*three\.yaml.*3 val"),
    ],
)
def test_target_poses_of_the_wrong_length_for_the_arms_exit_2_naming_the_field(
    tmp_path, over, match
):
    (tmp_path / "three.yaml").write_text("targets:\n  - [0.5, 0.0, 0.0]\n")
    config = _dual_arm_compare(tmp_path, [[0.5, 0.0, 0.0, 0.0, 0.0, 0.0]])
    args = ["compare", str(config), "--out", str(tmp_path / "out"), "-q"]
    res = CliRunner().invoke(app, args + [a for o in over for a in ("--set", o)])
    out = res.stdout + (res.stderr or "")
    assert res.exit_code == 2, out
    assert "Traceback" not in out
    assert re.search(match, " ".join(out.split())), out


def test_a_sweep_refuses_six_value_target_poses_on_one_arm(tmp_path):
    """A sweep shares compare's targets (`given_target_poses`): the same check, exit 2."""
    sweep = str(REPO / "configs/sweep-smoke.yaml")
    over = ["--set", "targets.poses=[[0.4, 0.1, 0.5, 0.0, 0.0, 0.0]]", "--set", "seeds=[0]"]
    res = CliRunner().invoke(app, ["sweep", sweep, *over, "-o", str(tmp_path / "out"), "-q"])
    out = res.stdout + (res.stderr or "")
    assert res.exit_code == 2 and "Traceback" not in out, out
    assert re.search(r"targets\.poses: item 0 has 6 values.*one arm", " ".join(out.split())), out
    assert not (tmp_path / "out").exists()  # refused before anything is created
