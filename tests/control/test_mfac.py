"""The MFAC law (paper eq. 24, docs/method.md §5): closed form, weights, steady state."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from rodctl.control.mfac import (
    DEFAULT_MFAC_WEIGHTS,
    MfacController,
    MfacControllerConfig,
    mfac_cost,
    mfac_step,
)

P, Q = 6, 3


def random_inputs(rng: np.random.Generator) -> dict:
    w = rng.uniform(0.05, 1.0, 7)
    return {
        "J": rng.normal(0.0, 30.0, (P, Q)),
        "J_prev": rng.normal(0.0, 30.0, (P, Q)),
        "e": rng.normal(0.0, 1.0, P),
        "s": rng.normal(0.0, 1.0, P),
        "r": rng.normal(0.0, 0.1, Q),
        "u_prev": rng.normal(0.0, 0.01, Q),
        "weights": w / w.sum(),
    }


def fd_newton_minimiser(f, x0: np.ndarray, h: float = 1e-2, iters: int = 3) -> np.ndarray:
    """Minimise f by Newton steps on central-difference gradient and Hessian of f alone.

    For a quadratic f the differences are exact up to rounding, so this is a numerical
    minimiser that never sees eq. 24's algebra and still reaches ~1e-12.
    """
    x = np.array(x0, dtype=float)
    n = x.size
    E = np.eye(n) * h
    for _ in range(iters):
        g = np.array([(f(x + E[i]) - f(x - E[i])) / (2 * h) for i in range(n)])
        H = np.empty((n, n))
        for i in range(n):
            for j in range(n):
                H[i, j] = (
                    f(x + E[i] + E[j])
                    - f(x + E[i] - E[j])
                    - f(x - E[i] + E[j])
                    + f(x - E[i] - E[j])
                ) / (4 * h * h)
        x = x - np.linalg.solve(H, g)
    return x


@pytest.mark.parametrize("seed", range(10))
def test_closed_form_equals_a_numerical_minimiser_of_the_cost(seed):
    kw = random_inputs(np.random.default_rng(seed))
    u = mfac_step(**kw)

    def cost(x):
        return mfac_cost(x, **kw)

    np.testing.assert_allclose(u, fd_newton_minimiser(cost, np.zeros(Q)), atol=1e-8)
    # A black-box quasi-Newton minimiser agrees too, to its own (looser) precision.
    res = minimize(cost, np.zeros(Q), method="BFGS", options={"gtol": 1e-12})
    np.testing.assert_allclose(u, res.x, atol=1e-5 * np.abs(u).max())
    assert cost(u) <= res.fun


def test_raising_omega6_lowers_the_command_norm():
    rng = np.random.default_rng(1)
    kw = random_inputs(rng)
    base = np.array(DEFAULT_MFAC_WEIGHTS)
    norms = []
    for w6 in (0.01, 0.1, 0.3, 0.6):
        w = base.copy()
        w[5] = 0.0
        w = w / w.sum() * (1.0 - w6)
        w[5] = w6
        norms.append(np.linalg.norm(mfac_step(**{**kw, "weights": w})))
    assert np.all(np.diff(norms) < 0.0)


def test_at_rest_the_law_balances_error_against_amplitude_and_home_terms():
    """At a fixed point u_k = u_{k-1} = 0: w1 J^T e = w2 J^T s + w5 r (docs/method.md §5)."""
    rng = np.random.default_rng(2)
    J = rng.normal(0.0, 30.0, (P, Q))
    w = np.array([0.5, 0.02, 0.2, 0.05, 0.03, 0.1, 0.1])
    s0 = rng.normal(0.0, 1.0, P)
    r_star = np.array([0.05, -0.04, 0.2])
    s_star = s0 + J @ r_star  # reachable target of the linear plant s = s0 + J r
    ctl = MfacController(w)
    r = np.zeros(Q)
    for _ in range(2000):
        u = ctl.command(s0 + J @ r, s_star, J, r)
        r = r + u
    assert np.linalg.norm(u) < 1e-12  # at rest
    s = s0 + J @ r
    e = s_star - s
    np.testing.assert_allclose(w[0] * J.T @ e, w[1] * J.T @ s + w[4] * r, atol=1e-10)
    assert np.linalg.norm(e) > 1e-3 * np.linalg.norm(s_star - s0)  # a real steady-state error


def test_with_small_regulation_weights_the_steady_state_error_is_small():
    rng = np.random.default_rng(3)
    J = rng.normal(0.0, 30.0, (P, Q))
    s0 = rng.normal(0.0, 0.3, P)
    s_star = s0 + J @ np.array([0.05, -0.04, 0.2])
    ctl = MfacController(DEFAULT_MFAC_WEIGHTS)
    r = np.zeros(Q)
    for _ in range(300):
        r = r + ctl.command(s0 + J @ r, s_star, J, r)
    e0 = np.linalg.norm(s_star - s0)
    assert np.linalg.norm(s_star - (s0 + J @ r)) < 1e-3 * e0


def test_previous_increment_is_the_pose_difference_not_the_last_output():
    """The loop saturates u; the w4 / w7 terms must see the increment that was really made."""
    rng = np.random.default_rng(4)
    kw = random_inputs(rng)
    ctl = MfacController(kw["weights"])
    r0 = np.array([0.01, 0.02, 0.1])
    ctl.command(kw["s"], kw["s"] + kw["e"], kw["J_prev"], r0)
    applied = np.array([0.004, -0.01, 0.05])  # whatever the loop allowed
    r1 = r0 + applied
    u = ctl.command(kw["s"], kw["s"] + kw["e"], kw["J"], r1)
    expected = mfac_step(**{**kw, "r": r1, "u_prev": applied})
    np.testing.assert_allclose(u, expected, rtol=1e-12)
    ctl.reset()  # after a reset there is no previous increment
    u0 = ctl.command(kw["s"], kw["s"] + kw["e"], kw["J"], r1)
    np.testing.assert_allclose(
        u0, mfac_step(**{**kw, "J_prev": kw["J"], "r": r1, "u_prev": np.zeros(Q)}), rtol=1e-12
    )


def test_weights_are_validated_with_a_clear_message():
    with pytest.raises(ValueError, match="sum to 1"):
        MfacControllerConfig(weights=(0.5, 0.1, 0.1, 0.1, 0.1, 0.1, 0.2))
    with pytest.raises(ValueError, match="positive"):
        MfacControllerConfig(weights=(0.6, 0.0, 0.1, 0.1, 0.0, 0.1, 0.1))
    assert abs(sum(MfacControllerConfig().weights) - 1.0) < 1e-12
    with pytest.raises(ValueError):
        MfacController([0.5, 0.5])
