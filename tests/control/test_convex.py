"""The Yu et al. 2023 law (rodctl/control/convex.py): the exact ball-constrained step."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.control.convex import ConvexController, ball_least_squares


def objective(A, b, lam, v):
    return 0.5 * np.sum((b - A @ v) ** 2) + 0.5 * lam * np.sum(v**2)


@pytest.mark.parametrize("q", [3, 6])
def test_inside_the_ball_it_is_the_ridge_solution_and_on_it_the_best_point(q):
    gen = np.random.default_rng(q)
    A = gen.normal(0.0, 1.0, (8, q))
    small = A @ gen.normal(0.0, 0.1, q)  # reachable well inside the ball
    v = ball_least_squares(A, small, 0.01)
    np.testing.assert_allclose(v, np.linalg.solve(A.T @ A + 0.01 * np.eye(q), A.T @ small))
    far = A @ gen.normal(0.0, 5.0, q)
    v = ball_least_squares(A, far, 0.01)
    assert np.linalg.norm(v) == pytest.approx(1.0, abs=1e-9)
    pts = gen.normal(0.0, 1.0, (500, q))
    pts /= np.maximum(np.linalg.norm(pts, axis=1, keepdims=True), 1.0)  # inside the unit ball
    best = min(objective(A, far, 0.01, p) for p in pts)
    assert objective(A, far, 0.01, v) <= best + 1e-12


def test_the_command_respects_the_speed_limit_and_heads_for_the_target():
    max_step = np.array([0.01, 0.01, 0.05])
    J = np.array([[300.0, 0, 10], [0, 300.0, 20], [50, 20, 100], [0, 0, 80]])
    ctl = ConvexController(max_step, gain=0.5, reg=0.1, error_limit=10.0)
    e = np.array([40.0, -30.0, 10.0, 5.0])
    u = ctl.command(np.zeros(4), e, J, np.zeros(3))
    assert np.linalg.norm(u / max_step) <= 1.0 + 1e-9
    assert (J @ u) @ e > 0.0  # the predicted change points towards the target
