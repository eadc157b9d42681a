"""The baselines' laws (docs/baselines.md): saturated pinv, box QP, and the scripted path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from rodctl.control.pinv import PinvController
from rodctl.control.qp import QpController, solve_box_qp
from rodctl.control.scripted import ScriptedController

P, Q = 6, 3
MAX = np.array([0.01, 0.01, 0.05])


def test_pinv_step_removes_lambda_of_a_reachable_error():
    rng = np.random.default_rng(0)
    J = rng.normal(0.0, 30.0, (P, Q))
    s = rng.normal(size=P)
    s_star = s + J @ np.array([0.002, -0.001, 0.004])  # small, reachable, within sat
    u = PinvController(gain=0.5, error_limit=10.0).command(s, s_star, J, np.zeros(Q))
    np.testing.assert_allclose(s + J @ u, s + 0.5 * (s_star - s), atol=1e-12)


def test_pinv_saturates_the_error_per_component():
    J = np.vstack([np.eye(Q), np.zeros((P - Q, Q))]) * 10.0
    e = np.array([5.0, -0.1, 0.2, 0.0, 0.0, 0.0])
    u = PinvController(gain=1.0, error_limit=0.5).command(np.zeros(P), e, J, np.zeros(Q))
    np.testing.assert_allclose(u, [0.05, -0.01, 0.02], atol=1e-12)  # 5.0 clipped to 0.5


def test_pinv_moves_towards_the_target_sign_convention():
    rng = np.random.default_rng(1)
    J = rng.normal(0.0, 30.0, (P, Q))
    s = np.zeros(P)
    s_star = J @ np.array([1.0, 1.0, 1.0])  # far: saturation bites
    u = PinvController().command(s, s_star, J, np.zeros(Q))
    assert np.linalg.norm(s_star - (s + J @ u)) < np.linalg.norm(s_star - s)


@pytest.mark.parametrize("seed", range(20))
def test_box_qp_equals_an_independent_solver_and_respects_bounds(seed):
    rng = np.random.default_rng(seed)
    J = rng.normal(0.0, 30.0, (P, Q))
    e = rng.normal(0.0, rng.choice([0.01, 0.3, 3.0]), P)  # some steps bind, some do not
    R = np.diag(rng.uniform(0.1, 10.0, Q))
    lam = 0.3
    u = QpController(MAX, gain=lam, r_weights=np.diag(R)).command(np.zeros(P), e, J, None)
    assert np.all(np.abs(u) <= MAX + 1e-15)
    # Same problem as a bounded linear least squares: || [J; R^1/2] u - [lam e; 0] ||^2.
    A = np.vstack([J, np.sqrt(R)])
    b = np.concatenate([lam * e, np.zeros(Q)])
    ref = lsq_linear(A, b, bounds=(-MAX, MAX), method="bvls", tol=1e-14)
    np.testing.assert_allclose(u, ref.x, atol=1e-10)


def test_box_qp_interior_solution_is_the_unconstrained_one():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(Q, Q))
    H = A @ A.T + np.eye(Q)
    g = rng.normal(size=Q) * 1e-3
    u = solve_box_qp(H, g, -np.ones(Q), np.ones(Q))
    np.testing.assert_allclose(u, -np.linalg.solve(H, g), atol=1e-14)


def test_box_qp_with_every_axis_pushed_out_sits_on_the_corner():
    H = np.eye(Q)
    u = solve_box_qp(H, np.array([-5.0, 5.0, -5.0]), -np.ones(Q), np.ones(Q))
    np.testing.assert_array_equal(u, [1.0, -1.0, 1.0])


def test_scripted_controller_visits_waypoints_in_bounded_steps():
    home = np.array([0.3, 0.1, 0.2])
    wps = np.array([[0.33, 0.1, 0.2], [0.33, 0.05, 0.0], [0.31, 0.05, 0.1]])
    ctl = ScriptedController(wps, home_pose=home, max_step=MAX)
    pose = home.copy()
    visited = []
    garbage = np.full(P, np.nan)  # s, s* and J are ignored
    for _ in range(100):
        if ctl.done:
            break
        u = ctl.command(garbage, garbage, np.full((P, Q), np.nan), pose - home)
        assert np.all(np.abs(u) <= MAX + 1e-15)
        pose = pose + u
        for i, w in enumerate(wps):
            if np.allclose(pose, w, atol=1e-12) and (not visited or visited[-1] != i):
                visited.append(i)
    assert ctl.done
    assert visited == [0, 1, 2]
    np.testing.assert_allclose(pose, wps[-1], atol=1e-12)
    np.testing.assert_array_equal(ctl.command(garbage, garbage, None, pose - home), np.zeros(3))
    ctl.reset()
    assert not ctl.done and ctl.index == 0


def test_scripted_controller_skips_waypoints_already_reached():
    home = np.zeros(3)
    ctl = ScriptedController([[0.0, 0.0, 0.0], [0.005, 0.0, 0.0]], home_pose=home, max_step=MAX)
    u = ctl.command(None, None, None, np.zeros(3))
    np.testing.assert_allclose(u, [0.005, 0.0, 0.0])
    assert ctl.index == 1
