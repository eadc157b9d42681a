"""The learned Jacobian (rodctl/estimation/learned.py) on synthetic data: fit, online step."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.errors import UserError
from rodctl.estimation.learned import (
    LearnedEstimatorConfig,
    LearnedJacobian,
    RbfJacobianModel,
    state_vector,
)
from rodctl.training.learned import fit_rbf

R_SCALE = np.array([0.01, 0.01, 0.05])


def true_field(X: np.ndarray) -> np.ndarray:
    """A smooth, state-dependent (p = 4, q = 3) Jacobian field over 4-D states."""
    base = np.array([[300.0, 20.0, 5.0], [-40.0, 250.0, 8.0], [10.0, 30.0, 60.0], [5, -5, 40]])
    a = np.array([[80.0, 0, 10], [0, -60, 0], [20, 0, 15], [0, 10, -20]])
    b = np.array([[0, 40.0, 0], [30, 0, -5], [0, 0, 25], [10, 0, 0]])
    return base + np.sin(X[:, 0])[:, None, None] * a + (X[:, 1] * X[:, 2])[:, None, None] * b


def synthetic_pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gen = np.random.default_rng(seed)
    X = gen.uniform(-1.0, 1.0, (n, 4))
    dR = gen.uniform(-1.0, 1.0, (n, 3)) * R_SCALE
    dS = np.einsum("npq,nq->np", true_field(X), dR) + gen.normal(0.0, 1e-3, (n, 4))
    return X, dR, dS


@pytest.fixture(scope="module")
def model() -> RbfJacobianModel:
    X, dR, dS = synthetic_pairs(2000, 0)
    return fit_rbf(X, dR, dS, centres=60, width=2.0, ridge=1e-6, r_scale=R_SCALE, seed=0)


def test_rbf_recovers_a_known_jacobian_field(model):
    X = np.random.default_rng(1).uniform(-0.9, 0.9, (200, 4))
    J_true = true_field(X)
    err = np.linalg.norm(model.predict(X) - J_true, axis=(1, 2)) / np.linalg.norm(
        J_true, axis=(1, 2)
    )
    assert np.mean(err) < 0.05
    # a constant model (the field's mean) is far worse: the network learned the dependence on x
    const = np.linalg.norm(J_true.mean(axis=0) - J_true, axis=(1, 2)) / np.linalg.norm(
        J_true, axis=(1, 2)
    )
    assert np.mean(err) < 0.3 * np.mean(const)


def line(theta: float, n: int = 30) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return t * np.array([[np.cos(theta), np.sin(theta)]]) * 400.0 + 50.0


def estimator_on_lines(eta: float, window: int = 1) -> LearnedJacobian:
    """A learned estimator whose state comes from straight centerlines (K = 3: d = 8)."""
    gen = np.random.default_rng(2)
    X = []
    for th in gen.uniform(-0.5, 0.5, 300):
        x, _ = state_vector(line(th), np.array([th]), 3)
        X.append(x)
    X = np.array(X)
    dR = gen.uniform(-1, 1, (300, 3)) * R_SCALE
    J = np.array([[100.0, 0.0, 3.0], [0.0, 100.0, 5.0]])
    model = fit_rbf(X, dR, dR @ J.T, centres=10, width=2.0, ridge=1e-8, r_scale=R_SCALE)
    model.state_points = 3
    return LearnedJacobian(2, 3, model, home_pose=np.zeros(3), learning_rate=eta, window=window)


def test_a_unit_rate_step_reproduces_the_last_move_and_reset_forgets_it():
    est = estimator_on_lines(1.0)
    J0 = est.prepare(line(0.0))
    np.testing.assert_allclose(J0, [[100.0, 0.0, 3.0], [0.0, 100.0, 5.0]], atol=1.0)
    dr = np.array([0.004, -0.002, 0.01])
    ds = np.array([1.0, 2.0])  # nothing like J0 dr: a changed rod
    est.observe(line(0.0), np.zeros(3))  # same state after the move
    J1 = est.update(ds, dr)
    np.testing.assert_allclose(J1 @ dr, ds, rtol=1e-9, atol=1e-9)
    assert est.info()["residual"] > 0.1 and est.info()["weight_change"] > 0.0
    est.reset(np.zeros((2, 3)))
    np.testing.assert_allclose(est.prepare(line(0.0)), J0)


def test_zero_learning_rate_keeps_the_offline_model():
    est = estimator_on_lines(0.0)
    J0 = est.prepare(line(0.1))
    est.observe(line(0.1), np.zeros(3))
    np.testing.assert_allclose(est.update(np.array([1.0, 2.0]), np.array([0.004, 0, 0])), J0)


def test_the_model_round_trips_and_a_crafted_file_is_refused(tmp_path):
    model = estimator_on_lines(0.5).model
    path = tmp_path / "model.npz"
    model.save(path)
    back = RbfJacobianModel.load(path)
    assert back.digest() == model.digest()
    X = np.random.default_rng(3).uniform(-1, 1, (5, 8))
    np.testing.assert_allclose(back.predict(X), model.predict(X))
    bad = tmp_path / "pickled.npz"
    np.savez(bad, meta=np.array([{"format": "x"}], dtype=object), centres=np.zeros((1, 4)))
    with pytest.raises(UserError, match="not a valid rodctl learned Jacobian model"):
        RbfJacobianModel.load(bad)
    with pytest.raises(UserError, match="not found"):
        RbfJacobianModel.load(tmp_path / "missing.npz")
    # Found by a new-user trial: a YAML given as the model was said to hold pickled data,
    # "load it unsafely using allow_pickle"
    text = tmp_path / "config.yaml"
    text.write_text("estimator: {type: learned}\n")
    with pytest.raises(UserError, match="not an .npz archive") as err:
        RbfJacobianModel.load(text)
    assert "pickle" not in str(err.value)


def test_a_config_without_a_trained_model_says_how_to_train_one():
    from rodctl.estimation import make_estimator

    with pytest.raises(UserError, match="rodctl train-model"):
        make_estimator(LearnedEstimatorConfig(checkpoint=None), 6, 3)
