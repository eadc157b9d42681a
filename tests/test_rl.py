"""The environments for RL libraries (rodctl/rl.py): observations inside their spaces, the
checkers of Gymnasium and Stable-Baselines3 without a warning, normalised actions, the success
bonus and a vectorised `compute_reward` for HER."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from paths import REPO

import rodctl
from rodctl.config import load_config
from rodctl.env import ShapeServoEnv
from rodctl.rl import ShapeServoGoalEnv, ShapeServoRLEnv

#: A small rod and camera: ~5 ms a step on a quiet machine.
TINY = [
    "feature.type=bezier",
    "logging.mcap=false",
    "logging.rerun=false",
    "rod.segments=10",
    "rod.settle_speed_tol=0.01",
    "camera.points=20",
    "camera.width=320",
    "camera.height=240",
    "camera.fx=280",
    "camera.fy=280",
]


def _config(*extra: str):
    return load_config(REPO / "configs/default.yaml", [*TINY, *extra])


@pytest.mark.slow
def test_every_observation_stays_inside_its_space_for_1000_random_steps():
    # Half the steps in metres at twice the speed limit (the robot saturates, the workspace
    # clips), half normalised; the core's observation is checked at every step too.
    cfg = _config("run.max_steps=100", "run.target.pose=null")
    envs = [
        ShapeServoRLEnv(cfg, normalize_actions=False, normalize_observations=True),
        ShapeServoGoalEnv(cfg, normalize_actions=True, normalize_observations=False),
    ]
    core_space = envs[0].core.observation_space
    rng = np.random.default_rng(0)
    beyond_limit = 0
    for env in envs:
        obs, _ = env.reset(seed=1)
        for _ in range(500):
            high = env.action_space.high
            action = rng.uniform(-2.0, 2.0, 3) * high
            obs, _, terminated, truncated, _ = env.step(action.astype(np.float32))
            core = env.core_observation
            assert core_space.contains(core), core
            assert env.observation_space.contains(obs), obs
            for value in obs.values():
                assert not isinstance(value, np.ndarray) or value.dtype == np.float32
            beyond_limit += bool(np.any(np.abs(core["applied"]) > env.core.max_step))
            if terminated or truncated:
                env.reset()
    # Moves clipped at the reach limit exceed one axis's speed limit: the case the space allows.
    assert beyond_limit > 0


@pytest.mark.slow
@pytest.mark.parametrize("env_id", [rodctl.RL_ENV_ID, rodctl.GOAL_ENV_ID])
def test_stable_baselines3_and_gymnasium_checkers_pass_without_warnings(env_id):
    from gymnasium.utils.env_checker import check_env as gymnasium_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = gym.make(env_id, config=_config("run.max_steps=20"), success_bonus=5.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check(env.unwrapped)
        if env_id == rodctl.RL_ENV_ID:
            gymnasium_check(env.unwrapped)
    for space in (env.observation_space, env.action_space, ShapeServoEnv().observation_space):
        assert len(repr(space)) < 500, repr(space)
    env.close()


def test_a_normalised_action_moves_by_its_share_of_the_speed_limit():
    cfg = _config()
    env = ShapeServoRLEnv(cfg)
    env.reset(seed=0)
    obs, reward, *_, info = env.step(np.array([1.0, -0.5, 0.25], dtype=np.float32))
    applied = env.core_observation["applied"]
    np.testing.assert_allclose(applied, [0.01, -0.005, 0.0125], atol=1e-12)
    np.testing.assert_allclose(obs["applied"], [1.0, -0.5, 0.25], atol=1e-6)
    assert reward == pytest.approx(-info["pixel_error"])
    assert not info["is_success"]
    # Beyond [-1, 1] an action is the limit, as the robot would saturate it.
    env.step(np.array([3.0, 0.0, 0.0], dtype=np.float32))
    assert env.core_observation["applied"][0] == pytest.approx(0.01, abs=1e-12)


def test_the_success_bonus_is_paid_on_convergence():
    pose = [0.38, 0.05, 0.6]
    start = {"target_pose": pose, "start_pose": pose}
    for env in (
        ShapeServoRLEnv(_config(), success_bonus=7.0),
        ShapeServoGoalEnv(_config(), success_bonus=7.0),
    ):
        env.reset(seed=0, options=start)
        obs, reward, terminated, _, info = env.step(np.zeros(3, dtype=np.float32))
        assert terminated and info["is_success"]
        assert reward == pytest.approx(7.0 - info["pixel_error"], abs=1e-3)


def test_compute_reward_is_vectorised_and_knows_lost_frames():
    env = ShapeServoGoalEnv(_config())
    obs, _ = env.reset(seed=0)
    goal, achieved = obs["desired_goal"], obs["achieved_goal"]
    single = env.compute_reward(achieved, goal, {"extraction_ok": True})
    # Pixel distances: the normalised units are scaled back.
    pixels = np.linalg.norm(((achieved - goal) * 160.0).reshape(-1, 2), axis=1).mean()
    assert single == pytest.approx(-pixels, rel=1e-5)
    batch = env.compute_reward(
        np.stack([achieved, goal]), np.stack([goal, goal]), np.array([{}, {"extraction_ok": 0}])
    )
    assert batch.shape == (2,)
    assert batch[0] == pytest.approx(single)
    assert batch[1] == pytest.approx(-np.hypot(320, 240)), "a lost frame costs the diagonal"
    assert env.compute_reward(goal, goal, None) == 0.0


@pytest.mark.slow
def test_the_ppo_example_trains_and_evaluates(tmp_path, monkeypatch):
    import runpy

    monkeypatch.chdir(REPO)
    example = runpy.run_path(str(REPO / "examples/rl/train_ppo.py"))
    sets = [a for s in [*TINY, "run.max_steps=8"] for a in ("--set", s)]
    result = example["main"](["--steps", "32", "--n-steps", "16", "--out", str(tmp_path), *sets])
    assert (tmp_path / "ppo_shapeservo.zip").is_file()
    assert 1 <= result["episode_steps"] <= 8 and result["train_steps"] == 32


@pytest.mark.parametrize("flag", ["normalize_actions", "normalize_observations"])
def test_a_normalisation_flag_that_is_not_a_bool_is_refused(flag):
    """Found by a new-user trial: normalize_actions="no" was read as True."""
    with pytest.raises(TypeError, match=f"{flag} must be True or False, got 'no'"):
        ShapeServoRLEnv({"rod": {"segments": 20, "engine": "quasistatic"}}, **{flag: "no"})


def test_a_frame_not_wholly_seen_costs_the_diagonal_in_every_form():
    """Found by a new-user trial: with the rod partly hidden (a bridged frame, extraction_ok 0)
    the core and RL forms charged the bridged points' error (-36.6), the goal form the
    diagonal (-800), for the same step."""
    box = "{at_step: 1, type: occluder, action: add, box: [145, 80, 175, 160]}"
    cfg = _config(f"run.events=[{box}]")
    diagonal = -float(np.hypot(cfg.camera.width, cfg.camera.height))
    for env in (ShapeServoEnv(cfg), ShapeServoRLEnv(cfg), ShapeServoGoalEnv(cfg)):
        env.reset(seed=0)
        _, reward, _, _, info = env.step(np.zeros(3))
        assert not info["extraction_ok"] and np.isfinite(info["pixel_error"]), type(env)
        assert reward == pytest.approx(diagonal), type(env)
