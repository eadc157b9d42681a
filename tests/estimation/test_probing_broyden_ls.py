"""Probing fit, Broyden and windowed least squares on linear data with a known J."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.estimation.broyden import BroydenJacobian
from rodctl.estimation.probing import fit_jacobian, probe_moves
from rodctl.estimation.windowed_ls import WindowedLsJacobian

P, Q = 6, 3
STEP = np.array([0.01, 0.01, 0.05])


def known_J(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, 30.0, (P, Q))


def test_probe_moves_visit_each_axis_and_return_home():
    size = np.array([0.005, 0.005, 0.03])
    moves = probe_moves(Q, size)
    assert moves.shape == (Q + 1, Q)
    np.testing.assert_allclose(moves.sum(axis=0), 0.0, atol=1e-15)
    np.testing.assert_array_equal(moves[:Q], np.diag(size))
    assert np.linalg.matrix_rank(moves) == Q
    with pytest.raises(ValueError):
        probe_moves(Q, np.array([0.005, 0.0, 0.03]))


def test_probing_fit_recovers_a_linear_jacobian():
    J = known_J(0)
    dR = probe_moves(Q, np.array([0.005, 0.005, 0.03]))
    np.testing.assert_allclose(fit_jacobian(dR @ J.T, dR), J, rtol=1e-10, atol=1e-10)


def test_probing_fit_is_least_squares_with_noise():
    rng = np.random.default_rng(1)
    J = known_J(1)
    dR = rng.uniform(-1, 1, (40, Q)) * STEP
    dS = dR @ J.T + rng.normal(0.0, 1e-3, (40, P))
    Jhat = fit_jacobian(dS, dR)
    # The residual is orthogonal to the moves: the normal equations hold.
    np.testing.assert_allclose((dS - dR @ Jhat.T).T @ dR, 0.0, atol=1e-12)


def test_probing_fit_refuses_moves_that_miss_an_axis():
    dR = np.array([[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.01, 0.01, 0.0]])
    with pytest.raises(ValueError, match="span only 2 of 3"):
        fit_jacobian(np.zeros((3, P)), dR)


@pytest.mark.parametrize("seed", range(3))
def test_broyden_recovers_a_constant_jacobian(seed):
    rng = np.random.default_rng(seed)
    J = known_J(seed)
    est = BroydenJacobian(P, Q)
    est.reset(J + rng.normal(0.0, 20.0, J.shape))
    # Each update removes the error along its move; varied moves remove it all.
    for u in rng.uniform(-1, 1, (100, Q)) * 0.01:
        est.update(J @ u, u)
    np.testing.assert_allclose(est.J, J, rtol=1e-8, atol=1e-8)


def test_broyden_update_satisfies_the_secant_and_keeps_orthogonal_directions():
    rng = np.random.default_rng(4)
    J0 = known_J(4)
    est = BroydenJacobian(P, Q, gamma=1.0)
    est.reset(J0)
    u = np.array([0.01, -0.004, 0.02])
    ds = rng.normal(size=P)
    J1 = est.update(ds, u)
    np.testing.assert_allclose(J1 @ u, ds, atol=1e-12)
    v = np.cross(u, rng.normal(size=Q))  # orthogonal to u
    np.testing.assert_allclose(J1 @ v, J0 @ v, atol=1e-12)


def test_broyden_dead_zone():
    est = BroydenJacobian(P, Q, dead_zone=1e-4)
    est.reset(known_J(5))
    J_before = est.J
    est.update(np.ones(P), np.array([1e-5, 0.0, 0.0]))
    assert est.info()["skipped"] == 1.0
    np.testing.assert_array_equal(est.J, J_before)


def test_windowed_ls_is_exact_on_linear_data_once_the_window_spans_all_axes():
    rng = np.random.default_rng(6)
    J = known_J(6)
    est = WindowedLsJacobian(P, Q, window=5, ridge=1e-9)
    est.reset(np.zeros((P, Q)))
    for u in rng.uniform(-1, 1, (5, Q)) * STEP:
        est.update(J @ u, u)
    np.testing.assert_allclose(est.J, J, rtol=1e-4)


def test_windowed_ls_forgets_pairs_older_than_the_window():
    rng = np.random.default_rng(7)
    J1, J2 = known_J(7), known_J(8)
    est = WindowedLsJacobian(P, Q, window=6, ridge=1e-12)
    est.reset(J1)
    for u in rng.uniform(-1, 1, (20, Q)) * STEP:
        est.update(J1 @ u, u)
    for u in rng.uniform(-1, 1, (6, Q)) * STEP:
        est.update(J2 @ u, u)
    np.testing.assert_allclose(est.J, J2, rtol=1e-6)


def test_windowed_ls_keeps_unobserved_directions_when_moves_are_collinear():
    J0, J = known_J(9), known_J(10)
    est = WindowedLsJacobian(P, Q, window=10, ridge=1e-6)
    est.reset(J0)
    d = np.array([1.0, 0.0, 0.0])
    for a in np.linspace(0.002, 0.01, 10):
        est.update(J @ (a * d), a * d)
    Jhat = est.J
    np.testing.assert_allclose(Jhat[:, 0], J[:, 0], rtol=1e-3)  # observed column learnt
    np.testing.assert_allclose(Jhat[:, 1:], J0[:, 1:], rtol=1e-12)  # the rest untouched
