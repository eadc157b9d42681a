"""Dual-arm reach: the ends never end up further apart than the arms' reach, unclipped."""

import numpy as np
import pytest

from rodctl.config.rod import RodConfig
from rodctl.env import ShapeServoEnv
from rodctl.sim import RodSim


@pytest.mark.parametrize("engine", ["quasistatic", "pymunk"])
def test_moving_the_x0_end_away_is_clipped_to_the_reach(engine):
    sim = RodSim.at_home(RodConfig(arms=2, engine=engine, segments=20))
    reach = sim._reach()
    sim.move_to(np.array([0.485, 0.0, 0.0]))  # just inside the reach of 0.49 m
    res = sim.apply(np.array([0.0, 0.0, 0.0, -0.01, 0.0, 0.0]))  # the x0 end moves away
    dist = float(np.hypot(*(sim.gripper_pose[:2] - sim.clamp_pose[:2])))
    assert dist <= reach + 1e-12
    assert res.clipped


def test_a_six_value_pose_beyond_the_reach_is_clipped():
    sim = RodSim.at_home(RodConfig(arms=2, engine="quasistatic", segments=20))
    pose = np.array([0.43, 0.08, 0.5, -0.15, -0.05, 0.0])  # the ends 0.58 m apart, rod 0.5 m
    out, changed = sim.clip_pose(pose)
    assert changed
    assert float(np.hypot(*(out[:2] - out[3:5]))) <= sim._reach() + 1e-12


def test_a_start_pose_of_the_wrong_length_is_refused():
    env = ShapeServoEnv({"rod": {"segments": 20, "engine": "quasistatic"}})
    with pytest.raises(ValueError, match=r"start_pose .* has shape \(6,\); it takes 3 values"):
        env.reset(options={"start_pose": [0.4, 0.0, 0.0, -0.1, 0.0, 0.0]})
