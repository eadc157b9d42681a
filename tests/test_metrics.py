"""Comparison metrics and stop rules on constructed episodes: pose steps, excess steps, probing
left out of smoothness, the final approach, and a pinned gripper told apart from a stall."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from rodctl import metrics
from rodctl.config.run import RunConfig
from rodctl.episode import Outcome, StopRule
from rodctl.records import SNAP_NOTE, StepRecord

MAX = np.array([0.01, 0.01, 0.05])


def rec(step, phase="control", u=(0.0, 0.0, 0.0), px=5.0, clipped=False, J=None, s=None):
    J = np.eye(6, 3) if J is None else J
    s = np.zeros(6) if s is None else s
    return StepRecord(
        step=step, sim_time=0.1 * step, phase=phase, gripper=np.zeros(3),
        centerline=np.zeros((3, 2)), extracted=np.zeros((4, 2)), projected_truth=np.zeros((4, 2)),
        u=np.asarray(u, float), u_raw=np.asarray(u, float), s=s, s_target=np.ones(6),
        T1=1.0, J=J, J_singular_values=np.ones(3), pixel_error=px, clipped=clipped,
    )  # fmt: skip


def test_pose_steps_is_the_slowest_axis_under_the_speed_limit():
    assert metrics.pose_steps([0, 0, 0], [0.035, -0.01, 0.1], MAX) == 4
    assert metrics.pose_steps([0.4, 0.1, 0.5], [0.4, 0.1, 0.5], MAX) == 0
    assert metrics.pose_steps([0, 0, 0], [0.0, 0.0, 0.3], MAX) == 6  # exactly 6 full steps


def test_smoothness_leaves_out_probing_and_starts_from_rest():
    probes = [rec(i, "probe", u=(0.005, -0.005, 0.03)) for i in range(1, 5)]
    law = [rec(5, u=(0.01, 0.0, 0.0)), rec(6, u=(0.01, 0.0, 0.0)), rec(7, u=(0.0, 0.0, 0.05))]
    trans, rot = metrics.smoothness([rec(0, "initial"), *probes, *law], MAX)
    # From rest to (1, 0, 0) speed limits: 1; then no change; then (-1, 0, +1): 1 and 1.
    assert trans == pytest.approx(2.0) and rot == pytest.approx(1.0)
    # The probing moves change nothing.
    assert metrics.smoothness([rec(0, "initial"), *law], MAX) == (trans, rot)


def test_near_origin_counts_the_final_approach():
    errs = [9.0, 4.0, 1.9, 1.5, 1.2, 0.9]
    recs = [rec(i + 1, px=e) for i, e in enumerate(errs)]
    assert metrics.near_origin_steps(recs, 1.0) == 3  # from step 3 (1.9 px) to step 6
    assert metrics.near_origin_steps(recs[:2], 1.0) is None


def test_after_an_event_the_peak_error_and_the_steps_to_converge():
    errs = [9.0, 6.0, 4.0, 7.5, 3.0, 0.8]  # the event at step 3 (before its move)
    recs = [rec(i + 1, px=e) for i, e in enumerate(errs)]
    recs[2].events = ["stiffness x 0.5"]
    recs[4].extraction_ok = False  # a lost frame does not count in the peak
    recs[4].pixel_error = 50.0
    assert metrics.after_event(recs, converged=True) == (7.5, 3)  # peak 7.5, steps 3 -> 6
    assert metrics.after_event(recs, converged=False) == (7.5, None)
    assert metrics.after_event(recs[:2], converged=True) == (None, None)  # no event yet


def _rule(window=4):
    rule = StopRule(RunConfig(stall_window=window, stall_improvement=0.02, stall_gradient=0.05))
    rule.reset()
    return rule


def test_a_gripper_held_by_the_workspace_is_pinned_not_at_the_step_limit():
    rule = _rule()
    method = SimpleNamespace(failure=None, open_loop=False, finished=False)
    out = [rule.check(rec(k, px=36.9, clipped=True), method) for k in range(1, 7)]
    assert out[:4] == [None] * 4 and out[4] is Outcome.PINNED


def test_no_progress_with_a_vanished_descent_direction_is_a_stall():
    rule = _rule()
    method = SimpleNamespace(failure=None, open_loop=False, finished=False)
    J = np.zeros((6, 3))
    J[:3, :3] = np.eye(3)
    s = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])  # e = (0, 0, 0, 1, 1, 1): J^T e = 0
    out = [rule.check(rec(k, px=3.0, J=J, s=s), method) for k in range(1, 7)]
    assert out[4] is Outcome.STALLED
    # With a descent direction left, no progress alone is not a stall.
    rule = _rule()
    out = [rule.check(rec(k, px=3.0), method) for k in range(1, 7)]
    assert all(o is None for o in out)


def test_an_episode_no_event_reached_is_flagged():
    recs = [rec(i + 1) for i in range(5)]
    assert metrics.finished_before_event(recs, has_events=True) is True
    assert metrics.finished_before_event(recs, has_events=False) is None
    recs[3].events = ["stiffness x 0.5"]
    assert metrics.finished_before_event(recs, has_events=True) is False


def test_a_snap_note_of_the_engine_is_not_a_mid_run_event():
    """The quasi-static engine's snap-through notes travel with a step's event lines (to /log);
    they must neither mark an episode as reached by an event nor start the event metrics."""
    recs = [rec(i + 1, px=e) for i, e in enumerate([9.0, 6.0, 4.0, 2.0])]
    recs[1].events = [f"{SNAP_NOTE} the equilibrium path lost stability at gripper [...]"]
    assert metrics.finished_before_event(recs, has_events=True) is True
    assert metrics.after_event(recs, converged=True) == (None, None)
    recs[2].events = [*recs[2].events, "stiffness x 0.5"]
    assert metrics.finished_before_event(recs, has_events=True) is False
    assert metrics.after_event(recs, converged=True) == (4.0, 1)
