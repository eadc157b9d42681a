"""`run_episode` on the env's public API only: made by `gymnasium.make` and wrapped, it gives the
episode the plain `ShapeServoEnv` gives, bit for bit."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import (
    FilterObservation,
    FlattenObservation,
    FrameStackObservation,
    TimeLimit,
)
from paths import REPO

import rodctl  # noqa: F401 - importing rodctl registers the environment
from rodctl.config import load_config
from rodctl.env import ShapeServoEnv
from rodctl.episode import Outcome, run_episode
from rodctl.method import Method

FAST = [
    "feature.type=bezier",
    "rod.segments=24",
    "camera.points=24",
    "run.max_steps=9",
    "logging.mcap=false",
    "logging.rerun=false",
    "logging.figures=false",
]


class _Tagged(gym.ObservationWrapper):
    """A user's wrapper that adds a key and keeps what the method reads."""

    def observation(self, observation):
        return {**observation, "tag": np.ones(1)}


class _Frames:
    """A sink that keeps the step and image shape of every record it is given."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, tuple[int, ...] | None]] = []
        self.status: str | None = None

    def open(self, header) -> None:
        pass

    def write(self, rec) -> None:
        self.frames.append((rec.step, None if rec.image is None else rec.image.shape))

    def close(self, summary, status) -> None:
        self.status = status


def _same(a, b) -> None:
    assert a.outcome is b.outcome and a.summary.steps == b.summary.steps
    assert len(a.records) == len(b.records)
    for ra, rb in zip(a.records, b.records, strict=True):
        for name in ("sim_time", "gripper", "centerline", "extracted", "u", "s", "J"):
            np.testing.assert_array_equal(getattr(ra, name), getattr(rb, name), err_msg=name)
        assert (ra.pixel_error, ra.extraction_ok, ra.phase) == (
            rb.pixel_error,
            rb.extraction_ok,
            rb.phase,
        )
    skip = {"run_id", "setup_time_s", "time_per_step_ms"}
    ea = {k: v for k, v in a.summary.extra.items() if k not in skip}
    eb = {k: v for k, v in b.summary.extra.items() if k not in skip}
    assert ea == eb


@pytest.fixture(scope="module")
def cfg():
    return load_config(REPO / "configs/default.yaml", FAST)


@pytest.fixture(scope="module")
def plain(cfg):
    return run_episode(ShapeServoEnv(cfg), Method.from_config(cfg))


def test_run_episode_on_gym_make_gives_the_plain_envs_episode(cfg, plain):
    env = gym.make("rodctl/ShapeServo-v0", config=cfg)  # OrderEnforcing, PassiveEnvChecker
    assert env is not env.unwrapped
    _same(run_episode(env, Method.from_config(cfg)), plain)


def test_run_episode_on_an_observation_wrapper_gives_the_same_episode_and_frames(cfg, plain):
    sink = _Frames()
    env = _Tagged(TimeLimit(ShapeServoEnv(cfg), max_episode_steps=100))
    _same(run_episode(env, Method.from_config(cfg), sinks=[sink]), plain)
    shape = (cfg.camera.height, cfg.camera.width, 3)
    assert sink.frames == [(r.step, shape) for r in plain.records]
    assert sink.status == "completed"


def test_a_time_limit_wrapper_ends_the_episode_as_step_limit(cfg, plain):
    limit = 6
    assert plain.summary.steps > limit  # the plain episode goes on past the wrapper's limit
    env = TimeLimit(gym.make("rodctl/ShapeServo-v0", config=cfg), max_episode_steps=limit)
    result = run_episode(env, Method.from_config(cfg))
    assert result.outcome is Outcome.STEP_LIMIT and result.summary.steps == limit
    for ra, rb in zip(result.records, plain.records[: limit + 1], strict=True):
        np.testing.assert_array_equal(ra.gripper, rb.gripper)
        assert ra.pixel_error == rb.pixel_error


def test_an_env_that_is_not_a_servo_env_is_refused_before_it_is_reset():
    class Other(gym.Env):
        observation_space = gym.spaces.Discrete(2)
        action_space = gym.spaces.Discrete(2)

        def reset(self, *, seed=None, options=None):
            raise AssertionError("reset must not be called")

    with pytest.raises(TypeError, match="Other is not a ServoEnv"):
        run_episode(gym.wrappers.OrderEnforcing(Other()), method=None)


@pytest.mark.parametrize(
    ("wrap", "said"),
    [
        (FlattenObservation, "observation is a ndarray, not a dict"),
        (lambda e: FilterObservation(e, ["centerline", "target"]), "without extraction_ok"),
        (lambda e: FrameStackObservation(e, 2), r"centerline of shape \(2, 24, 2\)"),
    ],
)
def test_a_wrapper_that_hides_what_a_method_reads_is_named(cfg, wrap, said):
    """Found by a new-user trial: these failed inside the method ('numpy.ndarray' object has
    no attribute 'get', KeyError: 'applied', a shape error), after the logs were opened."""
    sink = _Frames()
    env = wrap(gym.make("rodctl/ShapeServo-v0", config=cfg))
    with pytest.raises(TypeError, match=said):
        run_episode(env, Method.from_config(cfg), sinks=[sink])
    assert sink.frames == []  # refused before anything was logged
