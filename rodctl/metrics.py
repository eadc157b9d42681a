"""Per-episode metrics that make methods comparable: a reference step count, the excess over it,
smoothness per axis, and whether a mid-run event reached the episode.

Why these and not raw step counts: under a common speed limit every working method is slowed by
the same limit, so "converges fastest" is best read against `pose_steps`, the steps the speed
limit needs to carry the gripper to the target pose (`excess_steps` = steps to converge -
pose_steps). It is NOT a lower bound: the pixel tolerance can be met at a pose short of the
target pose, so a method can beat it and `excess_steps` can be negative (docs/statistics.md).
Smoothness is counted over the control law's moves only, from rest: probing moves are the same
for every probing method and say nothing about its law, and a method without probing must not
be credited for not probing. Each axis is divided by its speed limit so
that metres and radians add up in one unit ("speed limits").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from rodctl.records import StepRecord, scheduled_events


def pose_steps(home: np.ndarray, target: np.ndarray, max_step: np.ndarray) -> int:
    """Steps to the target pose at the speed limit: max_i ceil(|target_i - home_i| /
    max_step_i), the fewest moves that carry the gripper from `home` exactly to `target`.

    Not a lower bound on steps to converge: the pixel tolerance is often met at a pose short of
    the target pose (the oracle converged 5-7 steps under it on some targets), so a method may
    beat it and `excess_steps` may be negative, by several steps."""
    ratio = np.abs(np.asarray(target, float) - np.asarray(home, float)) / np.asarray(max_step)
    return int(math.ceil(float(np.max(ratio)) - 1e-9))


def control_moves(records: Sequence[StepRecord]) -> np.ndarray:
    """(K, q) the moves the control law made (probing and the initial record left out); q = 3,
    or 6 when both ends moved (dual-arm)."""
    us = [r.u for r in records if r.phase == "control"]
    q = len(records[0].u) if records else 3
    return np.array(us, dtype=float).reshape(-1, q)


def smoothness(records: Sequence[StepRecord], max_step: np.ndarray) -> tuple[float, float]:
    """(translation, rotation): summed change of the law's moves, from rest, per speed limit.

    translation = sum_k ||(Δu_x / m_x, Δu_y / m_y)||, rotation = sum_k |Δu_θ| / m_θ, with
    Δu_k = u_k - u_{k-1} over the control moves and u_0 = 0 (the gripper starts at rest).
    Dual-arm (q = 6): the sums over both ends (each end's translation norm, each rotation).
    """
    us = control_moves(records) / np.asarray(max_step, dtype=float)
    if len(us) == 0:
        return 0.0, 0.0
    du = np.diff(np.vstack([np.zeros(us.shape[1]), us]), axis=0)
    # Row norms by elementwise arithmetic (no BLAS: the same bits on every machine).
    trans = np.sqrt(du[:, 0] ** 2 + du[:, 1] ** 2)
    rot = np.abs(du[:, 2])
    if du.shape[1] == 6:
        trans = trans + np.sqrt(du[:, 3] ** 2 + du[:, 4] ** 2)
        rot = rot + np.abs(du[:, 5])
    return float(np.sum(trans)), float(np.sum(rot))


def near_origin_steps(records: Sequence[StepRecord], tolerance: float) -> int | None:
    """Steps from the first control step with pixel error below 2 x tolerance to the last step
    (the convergence step), or None when it never got there. The paper's "fastest near the
    origin" claim is about this final approach."""
    for r in records:
        if r.phase == "control" and r.extraction_ok and r.pixel_error < 2.0 * tolerance:
            return int(records[-1].step - r.step)
    return None


def finished_before_event(records: Sequence[StepRecord], has_events: bool) -> bool | None:
    """True when the config schedules mid-run events but the episode ended before the first of
    them fired (no record carries an event line): the event never reached it, so it says nothing
    about the event and the suite leaves it out of that scenario's comparisons. None: no events
    are scheduled."""
    if not has_events:
        return None
    return not any(scheduled_events(r.events) for r in records)


def after_event(records: Sequence[StepRecord], converged: bool) -> tuple[float | None, int | None]:
    """(peak pixel error from the first mid-run event on, steps from that event to convergence).

    The event is applied before its step's move, so the error of that step's record is the
    first one it can show. Frames the camera could not extract are left out of the peak. Both
    are None when no event happened (the episode ended first); the steps are None unless the
    episode converged.
    """
    first = next((r.step for r in records if scheduled_events(r.events)), None)
    if first is None:
        return None, None
    errors = [r.pixel_error for r in records if r.step >= first and r.extraction_ok]
    peak = float(max(errors)) if errors else None
    return peak, (int(records[-1].step - first) if converged else None)
