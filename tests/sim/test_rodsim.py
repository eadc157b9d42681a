"""RodSim as the loop uses it: moves, limits, workspace, readouts, health, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from rodctl.config.rod import RodConfig, WorkspaceConfig
from rodctl.errors import UserError
from rodctl.sim import RodChain, RodSim, resample_polyline, stable_dt_limit

L = 0.5
CAMERA_X, CAMERA_Y = (-0.2, 0.7), (-0.45, 0.45)


@pytest.fixture(scope="module")
def sim() -> RodSim:
    return RodSim(RodConfig())


def test_home_is_a_gently_bent_settled_pose_inside_workspace_and_camera(sim: RodSim) -> None:
    home = sim.home_pose
    np.testing.assert_allclose(sim.gripper_pose, home, atol=1e-9)
    assert not sim.clip_pose(home)[1]
    assert home[1] != 0 and home[2] != 0  # not the straight-push buckling bifurcation
    line = sim.centerline()
    assert line.shape == (51, 2)
    np.testing.assert_allclose(line[0], [0.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(line[-1], home[:2], atol=1e-5)
    assert np.all((line[:, 0] > CAMERA_X[0]) & (line[:, 0] < CAMERA_X[1]))
    assert np.all((line[:, 1] > CAMERA_Y[0]) & (line[:, 1] < CAMERA_Y[1]))
    bend = np.ptp(np.unwrap(np.arctan2(*np.diff(line, axis=0).T[::-1])))
    assert 0.2 < bend < 2.0  # a shallow S: tangent from about -0.6 to 1.0 rad
    health = sim.health()
    assert not health.has_nan and health.max_joint_gap < 1e-4
    assert health.max_speed < sim.cfg.settle_speed_tol


def test_home_equilibrium_is_unique_along_different_approaches() -> None:
    # Reach home once directly and once after a detour on the other side: same shape.
    a = RodSim(RodConfig())
    b = RodSim(RodConfig())
    b.move_to(b.home_pose + np.array([-0.08, -0.15, -0.6]))
    b.move_to(b.home_pose)
    assert np.abs(a.centerline() - b.centerline()).max() < 1e-4 * L


def test_apply_moves_gripper_by_u_and_settles(sim: RodSim) -> None:
    before = sim.gripper_pose
    t0 = sim.sim_time
    u = np.array([0.006, -0.004, 0.03])
    r = sim.apply(u)
    assert r.settled and not (r.clipped or r.refused or r.diverged)
    assert not r.saturated.any()
    np.testing.assert_allclose(r.u_applied, u, atol=1e-9)
    np.testing.assert_allclose(sim.gripper_pose, before + u, atol=1e-9)
    assert sim.sim_time == pytest.approx(t0 + sim.cfg.control_period + r.settle_time, abs=sim.dt)
    assert sim.health().max_speed < sim.cfg.settle_speed_tol
    # The rod follows the gripper: its end is where the gripper is.
    np.testing.assert_allclose(sim.centerline()[-1], sim.gripper_pose[:2], atol=5e-5)
    sim.apply(-u)


def test_apply_saturates_each_axis_at_max_step(sim: RodSim) -> None:
    before = sim.gripper_pose
    r = sim.apply(np.array([0.05, -0.002, -0.3]))
    np.testing.assert_array_equal(r.saturated, [True, False, True])
    np.testing.assert_allclose(r.u_applied, [0.01, -0.002, -0.05], atol=1e-9)
    np.testing.assert_allclose(sim.gripper_pose - before, r.u_applied, atol=1e-12)
    sim.move_to(sim.home_pose)


def test_clip_pose_pulls_unreachable_poses_into_the_workspace(sim: RodSim) -> None:
    ws = sim.cfg.workspace
    pose, clipped = sim.clip_pose(np.array([0.9, 0.05, 0.1]))  # beyond the reach and x limit
    assert clipped
    assert np.hypot(*pose[:2]) <= ws.max_reach * L + 1e-12
    assert ws.x_limits[0] <= pose[0] <= ws.x_limits[1]
    pose, clipped = sim.clip_pose(np.array([0.2, -0.9, -3.0]))
    assert clipped
    assert pose[1] == ws.y_limits[0] and pose[2] == ws.theta_limits[0]
    inside = np.array([0.3, 0.1, 0.4])
    pose, clipped = sim.clip_pose(inside)
    assert not clipped
    np.testing.assert_array_equal(pose, inside)


def test_move_past_reach_is_clipped_and_recorded() -> None:
    sim = RodSim(RodConfig())
    r = sim.move_to(np.array([0.6, 0.0, 0.0]))
    assert r.clipped and not r.refused and r.settled
    assert np.hypot(*sim.gripper_pose[:2]) == pytest.approx(0.98 * L, abs=1e-9)
    # The chain is inextensible: the rod still spans the clamp-gripper distance with tiny gaps.
    assert sim.health().max_joint_gap < 1e-4


@pytest.mark.slow
def test_refuse_mode_does_not_move() -> None:
    clip_mode_home = RodSim(RodConfig()).centerline()
    sim = RodSim(RodConfig(workspace=WorkspaceConfig(on_violation="refuse")))
    before = sim.gripper_pose
    line = sim.centerline()
    # Building (straight rod, then the same path to home) is not affected by the mode.
    np.testing.assert_array_equal(line, clip_mode_home)
    # Walk up to the y limit, then one step further.
    assert not sim.move_to(np.array([0.3, 0.349, before[2]])).refused
    at_edge = sim.gripper_pose
    r = sim.apply(np.array([0.0, 0.005, 0.0]))
    assert r.refused and r.clipped and not r.diverged
    np.testing.assert_array_equal(r.u_applied, np.zeros(3))
    np.testing.assert_array_equal(sim.gripper_pose, at_edge)
    sim.move_to(before)
    assert np.abs(sim.centerline() - line).max() < 1e-4 * L


def test_two_runs_with_the_same_config_are_bit_identical() -> None:
    cfg = RodConfig(segments=30)
    rng = np.random.default_rng(7)
    commands = rng.uniform(-1, 1, (4, 3)) * np.array(cfg.max_step)
    runs = []
    for _ in range(2):
        sim = RodSim(cfg)
        for u in commands:
            sim.apply(u)
        runs.append((sim.centerline(), sim.gripper_pose, sim.sim_time))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]


def test_resampled_centerline_is_equally_spaced_and_keeps_the_ends(sim: RodSim) -> None:
    joints = sim.centerline()
    pts = sim.centerline(100)
    assert pts.shape == (100, 2)
    np.testing.assert_allclose(pts[[0, -1]], joints[[0, -1]])
    steps = np.hypot(*np.diff(pts, axis=0).T)
    np.testing.assert_allclose(steps, steps.mean(), rtol=2e-3)  # chords of equal arcs
    assert steps.sum() == pytest.approx(L, rel=1e-3)


def test_resample_polyline_on_a_known_polyline() -> None:
    poly = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    np.testing.assert_allclose(
        resample_polyline(poly, 4), [[0, 0], [1, 0], [1, 1], [1, 2]], atol=1e-15
    )
    with pytest.raises(ValueError):
        resample_polyline(poly, 1)


def test_nan_is_reported_as_diverged_and_the_rod_stops_moving() -> None:
    sim = RodSim(RodConfig(segments=20))
    sim.chain.bodies[7].angular_velocity = float("nan")  # a blow-up, injected
    r = sim.apply(np.array([0.005, 0.0, 0.0]))
    assert r.diverged and not r.settled
    assert sim.health().has_nan
    pose = sim.gripper_pose
    r2 = sim.apply(np.array([0.005, 0.0, 0.0]))
    assert r2.diverged and not r2.settled
    np.testing.assert_array_equal(sim.gripper_pose, pose)


def test_unstable_time_step_is_caught_not_silent() -> None:
    cfg = RodConfig()
    limit = stable_dt_limit(L, cfg.bending_stiffness, cfg.mass_per_length, 50, cfg.inertia_radius)
    with pytest.raises(UserError) as err:
        RodSim(RodConfig(dt=6 * limit))
    # The pose as a user writes it (not numpy's reprs), and what went wrong in words.
    assert "home pose [0.4, 0.1, 0.5] (it diverged); check rod.dt" in str(err.value)


def test_settle_budget_exhaustion_is_reported() -> None:
    sim = RodSim(RodConfig(segments=20))
    sim.cfg.max_settle_time = 5 * sim.dt  # a 1 cm move cannot come to rest in 5 steps
    r = sim.apply(np.array([0.01, 0.01, 0.05]))
    assert not r.settled and not r.diverged
    assert r.settle_time == pytest.approx(5 * sim.dt)
    np.testing.assert_allclose(sim.gripper_pose[:2], sim.home_pose[:2] + 0.01, atol=1e-9)


def test_config_rejects_home_outside_workspace_and_tip_force_with_gripper() -> None:
    with pytest.raises(ValidationError, match="home_pose"):
        RodConfig(home_pose=(0.6, 0.3, 0.0))  # 0.67 m from the clamp, rod is 0.5 m
    with pytest.raises(ValueError, match="free end"):
        RodChain(L, 5e-3, 0.0785, 10, (0, 0, 0), 1e-3, 10, 0.0, 0.3, tip_force=(0.0, 1.0))


def test_clamp_pose_is_honoured() -> None:
    clamp = (0.1, -0.05, 0.3)
    sim = RodSim(RodConfig(clamp_pose=clamp))
    line = sim.centerline()
    np.testing.assert_allclose(line[0], clamp[:2], atol=1e-5)
    # Segment tangents at s = l/2, 3l/2, 5l/2, extrapolated (quadratic) to the clamp, s = 0.
    t0, t1, t2 = (np.arctan2(*(line[i + 1] - line[i])[::-1]) for i in (0, 1, 2))
    assert (15 * t0 - 10 * t1 + 3 * t2) / 8 == pytest.approx(clamp[2], abs=1e-3)
    # The default home pose is expressed in the clamp frame.
    home = sim.home_pose
    c, s = np.cos(clamp[2]), np.sin(clamp[2])
    local = np.array([[c, s], [-s, c]]) @ (home[:2] - clamp[:2])
    np.testing.assert_allclose(local, [0.8 * L, 0.2 * L], atol=1e-12)
