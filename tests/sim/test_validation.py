"""The settled chain against the elastica, at the default N = 50.

Goals from issue #3: the gripper-held circular arc within 0.1 % of L everywhere, the cantilever
table within 0.1 % on tip deflection, random reachable gripper poses within 0.5 % of L of the
two-pose boundary-value solution.
"""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.config.rod import RodConfig, WorkspaceConfig
from rodctl.sim import RodChain, RodSim, first_mode_rate, stable_dt_limit
from rodctl.sim.elastica import cantilever_tip_load, circular_arc, two_pose_equilibrium

L, EI, RHO_A = 0.5, 5e-3, 0.0785


def settled_cantilever(alpha: float, segments: int) -> RodChain:
    """A free-ended chain under a dead tip load P = alpha EI / L^2 along +y, run to rest."""
    radius = RodConfig().inertia_radius
    chain = RodChain(
        length=L,
        bending_stiffness=EI,
        mass_per_length=RHO_A,
        segments=segments,
        clamp_pose=(0.0, 0.0, 0.0),
        dt=0.5 * stable_dt_limit(L, EI, RHO_A, segments, radius),
        iterations=20,
        damping_rate=2 * first_mode_rate(L, EI, RHO_A, segments, radius, free_end=True),
        inertia_radius=radius,
        gripped=False,
        tip_force=(0.0, alpha * EI / L**2),
    )
    for _ in range(1000):
        chain.run(20)
        if chain.max_speed() < 1e-9:
            return chain
    raise AssertionError(f"cantilever alpha={alpha} N={segments} did not come to rest")


@pytest.mark.parametrize("alpha", [1.0, 2.0, 5.0, 10.0])
def test_cantilever_tip_matches_elastica_within_0p1_percent(alpha: float) -> None:
    chain = settled_cantilever(alpha, 50)
    tip = chain.joint_points()[-1]
    ref = cantilever_tip_load(alpha)
    assert tip[1] / L == pytest.approx(ref.deflection, rel=1e-3)
    assert 1 - tip[0] / L == pytest.approx(ref.shortening, rel=1e-3)
    assert chain.gripper_pose()[2] == pytest.approx(ref.tip_angle, rel=1e-3)
    # Whole shape, not only the tip.
    s = np.linspace(0, 1, 51)
    np.testing.assert_allclose(chain.joint_points() / L, ref.shape(s)[:, :2], atol=1e-3)


def test_cantilever_error_is_second_order_in_segments() -> None:
    # The 2EI/l clamp spring makes the discretisation error O(1/N^2); with EI/l it would be O(1/N).
    ref = cantilever_tip_load(1.0).deflection
    err25 = settled_cantilever(1.0, 25).joint_points()[-1, 1] / L - ref
    err50 = settled_cantilever(1.0, 50).joint_points()[-1, 1] / L - ref
    assert 3.0 < err25 / err50 < 5.0


@pytest.fixture(scope="module")
def open_sim() -> RodSim:
    """A default rod in a workspace wide enough for a half circle (gripper at x = 0, theta = pi)."""
    ws = WorkspaceConfig(
        x_limits=(-0.6, 0.6), y_limits=(-0.6, 0.6), theta_limits=(-4.0, 4.0), max_reach=1.0
    )
    return RodSim(RodConfig(workspace=ws))


@pytest.mark.slow
@pytest.mark.parametrize("turn", [1.0, 2.0, np.pi])
def test_gripper_held_arc_within_0p1_percent(open_sim: RodSim, turn: float) -> None:
    # Clamp at the origin along +x, gripper at the end pose of an arc turning by `turn`: the
    # equilibrium is that arc (pure end moment), up to a half circle.
    sim = open_sim
    s = np.linspace(0, L, sim.cfg.segments + 1)
    arc = circular_arc(L, turn / L, s)
    result = sim.move_to(arc[-1])
    assert result.settled and not result.clipped and not result.diverged
    err = np.hypot(*(sim.centerline() - arc[:, :2]).T)
    assert err.max() < 1e-3 * L
    sim.move_to(sim.home_pose)


@pytest.mark.slow
def test_random_reachable_poses_match_two_pose_bvp_within_0p5_percent() -> None:
    sim = RodSim(RodConfig())
    rng = np.random.default_rng(3)
    s = np.linspace(0, L, sim.cfg.segments + 1)
    checked = 0
    while checked < 4:
        pose = sim.home_pose + rng.uniform(-1, 1, 3) * np.array([0.12, 0.12, 0.8])
        allowed, clipped = sim.clip_pose(pose)
        if clipped:
            continue
        result = sim.move_to(allowed)
        assert result.settled and not result.diverged
        line = sim.centerline()
        ref = two_pose_equilibrium(L, EI, sim.cfg.clamp_pose, sim.gripper_pose, line)
        assert ref.success, ref.message
        err = np.hypot(*(ref.at(s)[:, :2] - line).T)
        assert err.max() < 5e-3 * L, f"pose {allowed}: max error {err.max() / L:.2%} of L"
        checked += 1
