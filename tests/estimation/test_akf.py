"""The AKF Jacobian estimate (docs/method.md §3) on synthetic linear systems with known J."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.estimation.akf import AdaptiveKalmanJacobian, clip_psd, igg3_factor

P, Q = 6, 3
STEP = np.array([0.01, 0.01, 0.05])  # the loop's per-step bound [m, m, rad]


def true_jacobian(rng: np.random.Generator) -> np.ndarray:
    """A (6, 3) J with entries O(10-100) and a weaker theta column, as features see the rod."""
    J = rng.normal(0.0, 30.0, (P, Q))
    J[:, 2] *= 0.3
    return J


def informative_moves(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(-1.0, 1.0, (n, Q)) * STEP


def rel_err(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.linalg.norm(A - B) / np.linalg.norm(B))


@pytest.mark.parametrize("seed", range(5))
def test_recovers_known_jacobian_within_2_percent_from_noisy_data(seed):
    rng = np.random.default_rng(seed)
    J = true_jacobian(rng)
    est = AdaptiveKalmanJacobian(P, Q)
    J0 = J * (1.0 + 0.3 * rng.normal(size=J.shape))  # a poor start, 30 % per entry
    est.reset(J0)
    assert rel_err(est.J, J) > 0.1
    for u in informative_moves(rng, 100):
        est.update(J @ u + rng.normal(0.0, 1e-3, P), u)
    assert rel_err(est.J, J) < 0.02


@pytest.mark.parametrize("seed", range(3))
def test_tracks_an_abrupt_change_of_jacobian(seed):
    rng = np.random.default_rng(10 + seed)
    J1 = true_jacobian(rng)
    J2 = 1.5 * J1 + rng.normal(0.0, 10.0, J1.shape)
    est = AdaptiveKalmanJacobian(P, Q)
    est.reset(J1)
    for u in informative_moves(rng, 100):
        est.update(J1 @ u + rng.normal(0.0, 1e-3, P), u)
    assert rel_err(est.J, J1) < 0.02
    assert rel_err(est.J, J2) > 0.3
    alphas = []
    for u in informative_moves(rng, 60):
        est.update(J2 @ u + rng.normal(0.0, 1e-3, P), u)
        alphas.append(est.info()["alpha"])
    assert min(alphas[:3]) < 1.0  # the change was seen as an outlier and the prior inflated
    assert rel_err(est.J, J2) < 0.02


def test_igg3_factor_shape():
    c0, c1, floor = 1.5, 6.0, 1e-3
    assert igg3_factor(0.0, c0, c1, floor) == 1.0
    assert igg3_factor(c0, c0, c1, floor) == 1.0
    xs = np.linspace(c0, c1, 200)
    a = np.array([igg3_factor(x, c0, c1, floor) for x in xs])
    assert np.all(np.diff(a) <= 0.0)  # decreasing
    assert igg3_factor(c0 + 1e-9, c0, c1, floor) == pytest.approx(1.0, abs=1e-6)  # continuous
    assert a[-1] == floor  # reaches 0 at c1 (the typo-fixed form), clamped to the floor
    assert igg3_factor(100.0, c0, c1, floor) == floor
    assert igg3_factor(-3.0, c0, c1, floor) == igg3_factor(3.0, c0, c1, floor)


def test_alpha_is_one_for_small_residuals_and_drops_for_outliers():
    rng = np.random.default_rng(3)
    J = true_jacobian(rng)
    est = AdaptiveKalmanJacobian(P, Q)
    est.reset(J)
    alphas = []
    for u in informative_moves(rng, 30):
        est.update(J @ u + rng.normal(0.0, 1e-4, P), u)
        alphas.append(est.info()["alpha"])
    assert np.median(alphas) == 1.0
    u = STEP * np.array([1.0, -1.0, 0.5])
    est.update(J @ u + 5.0, u)  # a gross outlier: every feature jumps by 5
    info = est.info()
    assert info["innovation"] > 6.0
    assert info["alpha"] < 0.01


def test_dead_zone_skips_the_update():
    rng = np.random.default_rng(4)
    J = true_jacobian(rng)
    est = AdaptiveKalmanJacobian(P, Q, dead_zone=1e-4)
    est.reset(J * 1.1)
    J_before, P_before = est.J, est.P
    est.update(rng.normal(0.0, 1.0, P), np.array([3e-5, -3e-5, 5e-5]))
    assert est.info()["skipped"] == 1.0
    np.testing.assert_array_equal(est.J, J_before)
    np.testing.assert_array_equal(est.P, P_before)


@pytest.mark.slow
@pytest.mark.parametrize("r_update", ["eq33", "eq32"])
def test_noise_estimates_stay_psd_over_10000_random_steps(r_update):
    rng = np.random.default_rng(5)
    J = true_jacobian(rng)
    q_min, r_min = 1e-8, 1e-8
    est = AdaptiveKalmanJacobian(P, Q, r_update=r_update, q_min=q_min, r_min=r_min)
    est.reset(np.zeros((P, Q)))
    # Eigenvalues are computed to about eps * ||A||, so "PSD" means >= floor up to that.
    worst_q = worst_r = np.inf
    for k in range(10_000):
        if k % 2500 == 0:
            J = true_jacobian(rng)  # abrupt changes
        u = rng.uniform(-1.0, 1.0, Q) * STEP * rng.choice([1e-2, 0.1, 1.0, 10.0])
        noise = rng.normal(0.0, rng.choice([1e-4, 1e-2, 1.0]), P)
        if rng.random() < 0.02:
            noise += rng.normal(0.0, 50.0, P)  # outliers
        est.update(J @ u + noise, u)
        Qk, Rk = est.Q, est.R
        np.testing.assert_array_equal(Qk, Qk.T)
        np.testing.assert_array_equal(Rk, Rk.T)
        wq, wr = np.linalg.eigvalsh(Qk), np.linalg.eigvalsh(Rk)
        worst_q = min(worst_q, (wq[0] - q_min) / max(wq[-1], 1.0))
        worst_r = min(worst_r, (wr[0] - r_min) / max(wr[-1], 1.0))
    assert np.all(np.isfinite(est.J))
    assert worst_q >= -1e-12
    assert worst_r >= -1e-12


def test_clip_psd_raises_only_the_low_eigenvalues():
    rng = np.random.default_rng(6)
    V, _ = np.linalg.qr(rng.normal(size=(5, 5)))
    w = np.array([-2.0, -1e-3, 1e-9, 0.5, 3.0])
    A = (V * w) @ V.T
    B = clip_psd(A, 1e-6)
    np.testing.assert_allclose(np.linalg.eigvalsh(B), [1e-6, 1e-6, 1e-6, 0.5, 3.0], atol=1e-12)
    C = (V * np.array([1.0, 2.0, 3.0, 4.0, 5.0])) @ V.T
    np.testing.assert_allclose(clip_psd(C, 1e-6), 0.5 * (C + C.T), atol=0)


def test_reset_restores_the_initial_covariances():
    est = AdaptiveKalmanJacobian(P, Q, p0=2.0, q0=3.0, r0=4.0)
    rng = np.random.default_rng(7)
    for u in informative_moves(rng, 5):
        est.update(rng.normal(size=P), u)
    est.reset(np.ones((P, Q)))
    np.testing.assert_array_equal(est.J, np.ones((P, Q)))
    np.testing.assert_array_equal(est.P, 2.0 * np.eye(P * Q))
    np.testing.assert_array_equal(est.Q, 3.0 * np.eye(P * Q))
    np.testing.assert_array_equal(est.R, 4.0 * np.eye(P))
    with pytest.raises(ValueError, match="shape"):
        est.reset(np.ones((Q, P)))


def test_invalid_thresholds_are_rejected():
    with pytest.raises(ValueError, match="c0 must be smaller than c1"):
        AdaptiveKalmanJacobian(P, Q, c0=5.0, c1=3.0)
    with pytest.raises(ValueError, match="forgetting"):
        AdaptiveKalmanJacobian(P, Q, forgetting=1.0)
