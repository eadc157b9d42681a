"""The reference solutions themselves, checked against published numbers before they judge the sim.

Sources: Bisshopp & Drucker (1945) / Mattiasson (1981) cantilever table, the
closed-form circular arc, and the elliptic-integral clamped-clamped buckled elastica
(Timoshenko & Gere §2.7).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import ellipe, ellipk

from rodctl.sim.elastica import cantilever_tip_load, circular_arc, two_pose_equilibrium

# alpha: (w/L, u/L, tip angle or None) — Mattiasson 1981, Table 1.
MATTIASSON = {
    1.0: (0.30172, 0.05643, 0.46135),
    2.0: (0.49346, 0.16064, None),
    5.0: (0.71379, 0.38763, None),
    10.0: (0.81061, 0.55500, 1.43029),
}


@pytest.mark.parametrize("alpha", sorted(MATTIASSON))
def test_cantilever_shooting_reproduces_mattiasson_table(alpha: float) -> None:
    sol = cantilever_tip_load(alpha)
    w, u, tip = MATTIASSON[alpha]
    assert sol.deflection == pytest.approx(w, abs=6e-6)
    assert sol.shortening == pytest.approx(u, abs=6e-6)
    if tip is not None:
        assert sol.tip_angle == pytest.approx(tip, abs=6e-6)
    # The shape ends where the tip figures say, and the tip is moment-free.
    end = sol.shape(np.array([0.0, 1.0]))
    np.testing.assert_allclose(end[0], [0.0, 0.0, 0.0], atol=1e-12)
    tip_pose = [1 - sol.shortening, sol.deflection, sol.tip_angle]
    np.testing.assert_allclose(end[1], tip_pose, atol=1e-9)


def test_cantilever_small_load_matches_linear_beam_theory() -> None:
    # w/L -> alpha/3 as alpha -> 0 (Euler-Bernoulli P L^3 / 3 EI).
    alpha = 1e-3
    assert cantilever_tip_load(alpha).deflection == pytest.approx(alpha / 3, rel=1e-5)


def test_circular_arc_quarter_and_half_circle() -> None:
    length = 0.5
    quarter = circular_arc(length, (np.pi / 2) / length, np.array([length]))[0]
    np.testing.assert_allclose(quarter, [2 / np.pi * length, 2 / np.pi * length, np.pi / 2])
    half = circular_arc(length, np.pi / length, np.array([length]))[0]
    np.testing.assert_allclose(half, [0.0, 2 / np.pi * length, np.pi], atol=1e-15)
    # A rotated, shifted clamp moves the arc rigidly.
    s = np.linspace(0, length, 7)
    base = circular_arc(length, 2.0, s)
    moved = circular_arc(length, 2.0, s, clamp_pose=(0.1, -0.2, np.pi / 2))
    np.testing.assert_allclose(moved[:, 0], 0.1 - base[:, 1], atol=1e-15)
    np.testing.assert_allclose(moved[:, 1], -0.2 + base[:, 0], atol=1e-15)


def test_two_pose_solver_recovers_an_arc_from_a_perturbed_guess() -> None:
    length, ei = 0.5, 5e-3
    s = np.linspace(0, length, 41)
    arc = circular_arc(length, 2.5 / length, s)
    guess = arc[:, :2] + 0.01 * np.sin(np.pi * s / length)[:, None]
    sol = two_pose_equilibrium(length, ei, arc[0], arc[-1], guess)
    assert sol.success
    np.testing.assert_allclose(sol.points, arc, atol=1e-7)
    np.testing.assert_allclose(sol.force, [0.0, 0.0], atol=1e-7)  # a pure moment: no force


# e/L: (P L^2/EI, y_mid/L), Timoshenko & Gere §2.7.
BUCKLED = {0.9: (41.570, 0.19492), 0.7: (46.612, 0.31431)}


@pytest.mark.parametrize("e_over_l", sorted(BUCKLED))
def test_two_pose_solver_matches_clamped_clamped_buckling_closed_form(e_over_l: float) -> None:
    # e/L = 2E(k)/K(k) - 1, P L^2/EI = 16 K(k)^2, y_mid/L = k/K(k), with m = k^2.
    m = brentq(lambda m: 2 * ellipe(m) / ellipk(m) - 1 - e_over_l, 1e-9, 0.999)
    k = np.sqrt(m)
    length, ei = 1.0, 1.0
    s = np.linspace(0, 1, 61)
    guess = np.stack([e_over_l * s, 0.3 * (1 - np.cos(2 * np.pi * s)) / 2], axis=1)
    sol = two_pose_equilibrium(length, ei, (0, 0, 0), (e_over_l, 0, 0), guess)
    assert sol.success
    mid = sol.at(np.array([0.5]))[0]
    assert mid[1] == pytest.approx(k / ellipk(m), abs=1e-6)
    assert -sol.force[0] == pytest.approx(16 * ellipk(m) ** 2, rel=1e-5)  # compression
    load, y_mid = BUCKLED[e_over_l]
    assert mid[1] == pytest.approx(y_mid, abs=6e-6)
    assert -sol.force[0] == pytest.approx(load, abs=6e-4)
