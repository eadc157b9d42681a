"""ShapeServoEnv as Gymnasium sees it: the env checker, seeded determinism, vector envs."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from paths import REPO

import rodctl  # noqa: F401 - importing rodctl registers the environment
from rodctl.config import load_config
from rodctl.env import ShapeServoEnv

FAST = ["feature.type=bezier", "run.max_steps=4", "logging.mcap=false", "logging.rerun=false"]


def _config(*extra: str):
    return load_config(REPO / "configs/default.yaml", [*FAST, *extra])


@pytest.mark.slow
def test_registered_id_makes_an_env_that_passes_the_checker():
    env = gym.make("rodctl/ShapeServo-v0", config=_config(), render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


def test_reset_and_step_follow_the_documented_contract():
    cfg = _config()
    env = ShapeServoEnv(cfg, render_mode="rgb_array")
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    assert obs["centerline"].shape == (cfg.camera.points, 2) and obs["extraction_ok"] == 1
    np.testing.assert_array_equal(obs["applied"], np.zeros(3))
    frame = env.render()
    assert frame.shape == (cfg.camera.height, cfg.camera.width, 3) and frame.dtype == np.uint8
    # A move larger than the speed limit is saturated by the robot and reported.
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0, 0.0]))
    assert info["saturated"].tolist() == [True, False, False]
    np.testing.assert_allclose(obs["applied"], [cfg.rod.max_step[0], 0.0, 0.0], atol=1e-12)
    # Reward is minus the pixel error.
    assert reward == pytest.approx(-info["pixel_error"])
    assert not terminated
    for _ in range(3):
        *_, truncated, info = env.step(np.zeros(3))
    assert truncated, "run.max_steps=4 truncates the fourth step"


@pytest.mark.slow
def test_an_episode_is_a_pure_function_of_config_and_seed():
    env = ShapeServoEnv(_config("camera.render.noise_std=3"))
    runs = []
    for seed in (5, 5, 6):
        obs, _ = env.reset(seed=seed)
        obs2, r, *_ = env.step(np.array([0.004, -0.002, 0.01]))
        runs.append((obs["centerline"].copy(), obs2["centerline"].copy(), r))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]
    assert not np.array_equal(runs[0][1], runs[2][1])  # another noise stream


@pytest.mark.slow
def test_options_give_a_target_and_a_start_pose():
    env = ShapeServoEnv(_config())
    _, info = env.reset(seed=0, options={"target_pose": [0.38, 0.05, 0.6]})
    np.testing.assert_allclose(env.target.pose, [0.38, 0.05, 0.6], atol=1e-6)
    env.reset(seed=0, options={"start_pose": [0.40, 0.0, 0.3]})
    np.testing.assert_allclose(env.home_pose, [0.40, 0.0, 0.3], atol=1e-6)
    with pytest.raises(ValueError, match="unknown options"):
        env.reset(options={"goal": [0, 0, 0]})


@pytest.mark.parametrize(
    ("pose", "said"),
    [
        ([0.3], r"has shape \(1,\); it takes 3 values"),
        ([[0.3, 0.0, 0.0]], r"has shape \(1, 3\)"),
        ("abc", "is not a list of numbers"),
        ([0.3, 0.0, float("nan")], "is not finite"),
    ],
)
@pytest.mark.parametrize("name", ["target_pose", "start_pose"])
def test_a_pose_option_that_is_not_a_pose_is_a_value_error_naming_it(name, pose, said):
    """Found by a new-user trial: target_pose=[0.3] was a bare 'not enough values to unpack'."""
    env = ShapeServoEnv({"rod": {"segments": 20, "engine": "quasistatic"}})
    with pytest.raises(ValueError, match=f"reset: {name} .*{said}"):
        env.reset(options={name: pose})


@pytest.mark.parametrize(
    ("action", "said"),
    [
        ([0.01, 0.0], r"must have shape \(3,\), \[dx, dy, dtheta\]; got \(2,\)"),
        ([[0.01], [0.0], [0.0]], r"got \(3, 1\)"),
        ([float("inf"), 0.0, 0.0], r"\[inf, 0.0, 0.0\] is not finite"),
    ],
)
def test_an_action_that_is_not_a_move_is_a_value_error_naming_it(action, said):
    """Found by a new-user trial: a (2,) action was numpy's reshape error and a (3, 1) one was
    taken silently; a refused action changes nothing."""
    env = ShapeServoEnv({"rod": {"segments": 20, "engine": "quasistatic"}})
    env.reset(seed=0)
    before = env.sim.gripper_pose.copy()
    with pytest.raises(ValueError, match=f"step: .*{said}"):
        env.step(action)
    assert env.steps == 0
    np.testing.assert_array_equal(env.sim.gripper_pose, before)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_env_rolls_out_two_envs(mode):
    envs = gym.make_vec(
        "rodctl/ShapeServo-v0", num_envs=2, vectorization_mode=mode, config=_config()
    )
    try:
        obs, _ = envs.reset(seed=[1, 2])
        assert obs["centerline"].shape == (2, 100, 2)
        rng = np.random.default_rng(0)
        for _ in range(2):
            action = rng.uniform(-1, 1, size=(2, 3)) * envs.single_action_space.high
            obs, reward, terminated, truncated, _ = envs.step(action)
        assert reward.shape == (2,) and np.all(np.isfinite(reward))
    finally:
        envs.close()


def test_random_rollout_until_truncated():
    env = gym.make("rodctl/ShapeServo-v0", config=_config())
    env.reset(seed=0)
    env.action_space.seed(0)
    done, steps = False, 0
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
        steps += 1
    assert steps <= 4
    env.close()


@pytest.mark.slow
def test_a_target_made_once_is_the_target_every_episode_would_make():
    cfg = _config("camera.render.noise_std=3")
    env = ShapeServoEnv(cfg)
    target = env.make_target([0.38, 0.05, 0.6], seed=9)
    env.reset(seed=4, options={"target_pose": [0.38, 0.05, 0.6]})
    np.testing.assert_array_equal(env.target.pixels, target.pixels)  # a clean camera: no noise
    obs_a, _ = env.reset(seed=4, options={"target": target})
    assert env.target is target
    obs_b, _ = env.reset(seed=4, options={"target_pose": [0.38, 0.05, 0.6]})
    np.testing.assert_array_equal(obs_a["centerline"], obs_b["centerline"])


@pytest.mark.parametrize("seed", [-1, 2**63, 2**64, True, 3.5, "5"])
def test_reset_refuses_a_seed_no_config_could_give(seed):
    env = ShapeServoEnv({"rod": {"segments": 20, "engine": "quasistatic"}})
    with pytest.raises(ValueError, match=r"seed .* must be an integer in \[0, 2\*\*63 - 1\]"):
        env.reset(seed=seed)


def test_a_refused_reset_leaves_the_env_as_it_was_and_numpy_seeds_are_taken():
    """Found by a review: a refused option still marked the env seeded, so the next reset()
    drew a seed instead of using the config's."""
    env = ShapeServoEnv({"seed": 7, "rod": {"segments": 20, "engine": "quasistatic"}})
    with pytest.raises(ValueError, match="target_pose"):
        env.reset(options={"target_pose": [0.3]})
    env.reset()
    assert env.episode_seed == 7
    env.reset(seed=np.int64(5))
    assert env.episode_seed == 5 and type(env.episode_seed) is int
