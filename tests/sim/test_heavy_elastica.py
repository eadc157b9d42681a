"""The heavy-elastica reference solutions, checked before they judge the chain under gravity.

Sources: the small-deflection cantilever q L^4 / 8 EI (tip angle q L^3 / 6 EI); Greenhill's
self-buckling load of an upright heavy column, (q L^3 / EI)_cr = 7.837 (A. G. Greenhill, 1881;
Timoshenko & Gere, Theory of Elastic Stability, 2nd ed., §2.13). No published large-deflection
table of the self-weight cantilever was available to us (neither in the repository's references
nor through search), so the large-deflection cases are checked between two independent solvers
at tight tolerance: shooting (DOP853, rtol 1e-12) and `scipy.integrate.solve_bvp`.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from rodctl.sim.elastica import (
    _integrate_heavy_cantilever,
    circular_arc,
    heavy_cantilever,
    heavy_two_pose_equilibrium,
    heavy_two_pose_shooting,
    two_pose_equilibrium,
)


def test_small_load_matches_linear_beam_theory() -> None:
    w = 1e-3
    sol = heavy_cantilever(w)
    assert sol.deflection == pytest.approx(w / 8, rel=1e-5)  # q L^4 / 8 EI
    assert -sol.tip_angle == pytest.approx(w / 6, rel=1e-5)  # q L^3 / 6 EI
    assert sol.curvature0 == pytest.approx(-w / 2, rel=1e-5)  # clamp moment q L^2 / 2


@pytest.mark.slow
def test_large_load_is_stiffer_than_linear_theory_and_monotonic() -> None:
    loads = [1.0, 5.0, 10.0, 20.0, 50.0, 100.0]
    drops = [heavy_cantilever(w).deflection for w in loads]
    assert all(a < b for a, b in zip(drops, drops[1:], strict=False))
    assert all(d < w / 8 for d, w in zip(drops, loads, strict=True))
    assert drops[-1] < 1.0  # an inextensible rod cannot drop more than its length


def test_greenhill_self_buckling_load() -> None:
    # The upright column (clamp angle pi/2) stays straight below 7.837 and buckles above: the
    # bifurcation is where a vanishing clamp curvature still satisfies the free-end condition.
    def tip_moment(w: float) -> float:
        return float(_integrate_heavy_cantilever(w, np.pi / 2, -1e-7 * w)[3, -1])

    critical = brentq(tip_moment, 6.0, 9.0, xtol=1e-10)
    assert critical == pytest.approx(7.837, abs=5e-4)
    straight = heavy_cantilever(7.5, np.pi / 2)
    assert straight.tip_angle == pytest.approx(np.pi / 2, abs=1e-9)
    bent = heavy_cantilever(8.5, np.pi / 2)
    assert abs(bent.tip_angle - np.pi / 2) > 0.3


@pytest.mark.slow
@pytest.mark.parametrize("w", [1.0, 10.0, 100.0])
def test_cantilever_shooting_and_two_pose_bvp_agree(w: float) -> None:
    # Give the BVP both end poses of the free-end solution: it must find the same shape with a
    # zero force and zero moment at the tip (the free end), from a perturbed guess.
    cant = heavy_cantilever(w)
    s = np.linspace(0, 1, 101)
    shape = cant.shape(s)
    length, ei = 1.0, 1.0
    guess = shape[:, :2] + 0.03 * np.sin(np.pi * s)[:, None]
    sol = heavy_two_pose_equilibrium(length, ei, (0, 0, 0), shape[-1], guess, (0.0, -w))
    assert sol.success, sol.message
    np.testing.assert_allclose(sol.at(s), shape, atol=1e-6)
    tip = sol._interp(1.0)  # type: ignore[operator]
    np.testing.assert_allclose(tip[3:], [0.0, 0.0, 0.0], atol=1e-5)  # kappa, p_x, p_y


@pytest.mark.slow
def test_two_pose_bvp_and_shooting_recover_manufactured_solutions() -> None:
    # Manufactured problems: integrate the six equations forward from a random clamp curvature
    # and force, take the end pose reached as the gripper pose; both solvers must recover that
    # exact shape from perturbed starting points (BVP: a bent guess; shooting: a wrong force).
    rng = np.random.default_rng(7)
    length, ei = 0.5, 5e-3
    s = np.linspace(0, 1, 81)
    ss = np.linspace(0, length, 51)
    for _ in range(4):
        w = rng.uniform(1.0, 100.0)
        load = (0.0, -w * ei / length**3)
        k0, px, py = rng.uniform(-3, 3), rng.uniform(-10, 10), rng.uniform(0.3, 1.0) * w
        truth = solve_ivp(
            lambda _s, z, w=w: [
                np.cos(z[2]),
                np.sin(z[2]),
                z[3],
                z[4] * np.sin(z[2]) - z[5] * np.cos(z[2]),
                0.0,
                w,
            ],
            (0, 1),
            [0, 0, 0, k0, px, py],
            method="DOP853",
            rtol=1e-12,
            atol=1e-13,
            dense_output=True,
        )
        z = truth.sol(s)
        exact = np.column_stack([z[0] * length, z[1] * length, z[2]])
        end = exact[-1]
        guess = exact[:, :2] + 0.01 * np.sin(np.pi * s)[:, None]
        bvp = heavy_two_pose_equilibrium(length, ei, (0, 0, 0), end, guess, load, tol=1e-9)
        assert bvp.success, bvp.message
        ze = truth.sol(ss / length)
        want = np.column_stack([ze[0] * length, ze[1] * length, ze[2]])
        assert np.abs(bvp.at(ss) - want).max() < 1e-6
        shot = heavy_two_pose_shooting(
            length, ei, (0, 0, 0), end, [k0 + 0.1, px * 1.05, py * 0.95], load
        )
        assert shot.success, shot.message
        assert np.abs(shot.at(ss) - want).max() < 1e-8
        np.testing.assert_allclose(shot.force0 * length**2 / ei, [px, py], atol=1e-6)


def test_zero_load_reduces_to_the_weightless_solver() -> None:
    end = (0.35, 0.15, 0.9)
    guess = circular_arc(0.5, 0.9 / 0.5, np.linspace(0, 0.5, 41))  # a bent start, same turn
    heavy = heavy_two_pose_equilibrium(0.5, 5e-3, (0, 0, 0), end, guess, (0.0, 0.0))
    light = two_pose_equilibrium(0.5, 5e-3, (0, 0, 0), end, guess)
    assert heavy.success and light.success
    ss = np.linspace(0, 0.5, 21)
    np.testing.assert_allclose(heavy.at(ss), light.at(ss), atol=1e-7)
    np.testing.assert_allclose(heavy.force0, light.force, atol=1e-6)
