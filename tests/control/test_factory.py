"""make_controller builds every configured law; each honours the Controller protocol."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import TypeAdapter

from rodctl.config.experiment import ControllerConfig
from rodctl.control import (
    MfacController,
    PinvController,
    QpController,
    ScriptedController,
    make_controller,
)

ADAPTER = TypeAdapter(ControllerConfig)
MAX = np.array([0.01, 0.01, 0.05])


@pytest.mark.parametrize(
    ("section", "cls"),
    [
        ({"type": "mfac"}, MfacController),
        ({"type": "pinv", "gain": 0.3}, PinvController),
        ({"type": "qp", "r_weights": [2.0, 2.0, 0.5]}, QpController),
        ({"type": "scripted", "waypoints": [[0.4, 0.1, 0.0]]}, ScriptedController),
    ],
)
def test_each_config_type_builds_a_law_that_moves_towards_its_goal(section, cls):
    ctl = make_controller(
        ADAPTER.validate_python(section), home_pose=np.array([0.4, 0.2, 0.0]), max_step=MAX
    )
    assert isinstance(ctl, cls)
    ctl.reset()
    J = np.random.default_rng(0).normal(0.0, 30.0, (6, 3))
    s = np.zeros(6)
    s_star = J @ np.array([0.002, -0.001, 0.004])
    u = np.clip(ctl.command(s, s_star, J, np.zeros(3)), -MAX, MAX)
    assert u.shape == (3,)
    if cls is ScriptedController:
        np.testing.assert_allclose(u, [0.0, -0.01, 0.0])  # towards y = 0.1 from y = 0.2
    else:
        assert np.linalg.norm(s_star - J @ u) < np.linalg.norm(s_star)


def test_scripted_needs_waypoints():
    with pytest.raises(ValueError, match="waypoints"):
        ADAPTER.validate_python({"type": "scripted"})
