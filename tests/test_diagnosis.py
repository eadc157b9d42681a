"""The diagnosis of a failed episode: a target no pose can make is `unreachable`; one the true
Jacobian reaches from the same state is the `estimator`'s fault; pinned is the workspace."""

from __future__ import annotations

import numpy as np
import pytest
from paths import REPO

from rodctl.bench.episodes import run_episode_task
from rodctl.bench.tasks import EpisodeTask
from rodctl.config import load_config
from rodctl.diagnosis import diagnose, pose_search
from rodctl.env import ShapeServoEnv, Target

FAST = ["feature.type=bezier", "logging.mcap=false", "logging.rerun=false", "logging.figures=false"]


def _env_at_home(shift_px: float):
    cfg = load_config(REPO / "configs/default.yaml", [*FAST, "run.max_steps=40"])
    env = ShapeServoEnv(cfg)
    env.reset()
    t = env.target
    # The whole target shape moved sideways in the image, clamp end included: the clamp does
    # not move, so no gripper pose can make it.
    moved = Target(t.pose, t.centerline, t.pixels + np.array([shift_px, 0.0]), t.difficulty)
    env.reset(options={"target": moved})
    return env, cfg


def _diagnosed_task(env, cfg) -> EpisodeTask:
    """The compare worker's task for the env's target, with the diagnosis asked for."""
    t = env.target
    return EpisodeTask(
        config=cfg.model_dump(mode="json"), method="m", target=0,
        pose=tuple(float(v) for v in t.pose), target_difficulty=t.difficulty, seed=0,
        target_view={"centerline": t.centerline, "pixels": t.pixels}, diagnose=True,
    )  # fmt: skip


@pytest.mark.slow
def test_a_compare_episode_on_a_target_no_pose_can_make_stalls_and_is_unreachable():
    """Through the compare worker: the episode stalls, then its row says why."""
    env, cfg = _env_at_home(shift_px=15.0)
    row = run_episode_task(_diagnosed_task(env, cfg))
    assert row["outcome"] == "stalled" and row["diagnosis"] == "unreachable", row
    assert row["error"] == ""


@pytest.mark.slow
def test_a_target_the_true_jacobian_reaches_blames_the_estimator_and_pinned_the_workspace():
    env, cfg = _env_at_home(shift_px=0.0)
    assert diagnose(env, cfg, "stalled", estimator_steps=30) == "estimator"
    assert diagnose(env, cfg, "pinned") == "workspace"
    assert diagnose(env, cfg, "converged") is None


@pytest.mark.slow
def test_a_search_cut_off_while_still_improving_is_inconclusive():
    """Unreachable means the search stopped improving short of the tolerance; one that only ran
    out of iterations (here: one) says nothing either way."""
    from rodctl.diagnosis import pose_search

    env, cfg = _env_at_home(shift_px=15.0)
    snap = env.sim.snapshot()
    best, _, capped = pose_search(env, 1)
    assert capped and best > cfg.run.pixel_tolerance
    env.sim.restore(snap)
    best_full, _, capped_full = pose_search(env, 20)
    assert best_full <= best and not capped_full  # given room, it stops at its minimum


# --- dual-arm (rod.arms: 2, q = 6): the search moves both ends, each in its own box -------------

DUAL = [*FAST, "rod.arms=2", "rod.engine=quasistatic", "rod.segments=20", "run.max_steps=80"]


def _dual_env(*over: str, scale: float = 1.0, shift_px: float = 0.0):
    """A dual-arm env at home whose target is the default one scaled about its centroid and
    moved sideways in the image."""
    cfg = load_config(REPO / "configs/default.yaml", [*DUAL, *over])
    env = ShapeServoEnv(cfg)
    env.reset()
    t = env.target
    c = t.pixels.mean(axis=0)
    pixels = c + scale * (t.pixels - c) + np.array([shift_px, 0.0])
    env.reset(options={"target": Target(t.pose, t.centerline, pixels, t.difficulty)})
    return env, cfg


def test_a_dual_arm_search_moves_both_ends_and_stops_at_the_x0_ends_workspace():
    """The whole target moved sideways: no gripper pose makes it (one arm: `unreachable`, the
    test above), both ends together do; with the x0 end's own box too narrow for it, the search
    stops short, clipped, and says `workspace`, not `inconclusive`."""
    env, cfg = _dual_env(shift_px=15.0)
    best, _, _ = pose_search(env, 20)
    assert best < cfg.run.pixel_tolerance
    assert np.any(np.abs(env.sim.clamp_pose) > 1e-3)  # the x0 end moved
    narrow = "rod.clamp_arm.workspace.x_limits=[-0.001,0.001]"
    env, cfg = _dual_env(narrow, shift_px=15.0)
    best, clipped, capped = pose_search(env, 20)
    assert best > cfg.run.pixel_tolerance and clipped and not capped
    assert abs(env.sim.clamp_pose[0]) <= 0.001 + 1e-9  # it stayed in its box


def test_a_dual_arm_episode_that_stalls_on_a_shape_no_pose_makes_is_unreachable():
    """Through the compare worker at q = 6: a target 5 % smaller than the rod (no pose of the
    two ends makes it) stalls the episode, and its row says `unreachable`."""
    env, cfg = _dual_env(scale=0.95)
    row = run_episode_task(_diagnosed_task(env, cfg))
    assert row["outcome"] == "stalled" and row["diagnosis"] == "unreachable", row
    assert row["error"] == ""


def test_the_oracle_method_reused_by_a_later_diagnosis_moves_the_rod_as_a_fresh_one():
    """An autoencoder's oracle method is built once per config and process (issue 24): a second
    diagnosis with it makes the same moves, to the bit, as one with a method built for it."""
    import rodctl.diagnosis as diagnosis

    over = ["logging.mcap=false", "logging.rerun=false", "logging.figures=false"]
    cfg = load_config(REPO / "configs/default.yaml", [*over, "rod.engine=quasistatic"])
    assert cfg.feature.type == "autoencoder"

    def moves() -> tuple[bool, bytes]:
        env = ShapeServoEnv(cfg)
        env.reset()
        t = env.target
        moved = Target(t.pose, t.centerline, t.pixels + np.array([6.0, 0.0]), t.difficulty)
        env.reset(options={"target": moved})
        done = diagnosis.true_jacobian_converges(env, cfg, 6)
        return done, env.sim.centerline().tobytes() + env.frame.extracted.tobytes()

    diagnosis._ORACLE_METHODS.clear()
    fresh = moves()
    assert moves() == fresh and len(diagnosis._ORACLE_METHODS) == 1  # built once, used twice
    diagnosis._ORACLE_METHODS.clear()
