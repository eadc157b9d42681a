"""Reachable target shapes, sampled from gripper poses.

A target is made the only way that guarantees it is reachable: drive the rod to a gripper pose,
let it settle, and take what the camera sees. How hard a target is is measured by how far its
gripper pose is from the home pose, in normalised units (see `TARGET_SCALE`), so that "easy" and
"hard" mean the same thing to every method in a comparison.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from rodctl import fixedla as fla
from rodctl.errors import UserError, pose_text

#: One normalised unit of target offset per axis, as a fraction of the rod length for x and y
#: and in radians for theta: offset 1.0 is a 0.3 L translation or a 60 degree turn.
TARGET_SCALE_FRACTION = (0.3, 0.3)
TARGET_SCALE_THETA = np.pi / 3

#: Candidate poses tried per sampled target before giving up (a candidate can fail to settle).
TARGET_TRIES = 20


def target_scale(rod_length: float) -> np.ndarray:
    """(3,) size of one normalised offset unit: [0.3 L, 0.3 L, pi/3]."""
    fx, fy = TARGET_SCALE_FRACTION
    return np.array([fx * rod_length, fy * rod_length, TARGET_SCALE_THETA])


def _scale(rod_length: float, q: int) -> np.ndarray:
    """(q,) `target_scale` per moved end: q = 3 (the gripper) or 6 (dual-arm, both ends)."""
    scale = target_scale(rod_length)
    return scale if q == 3 else np.tile(scale, q // 3)


def difficulty(pose: np.ndarray, home: np.ndarray, rod_length: float) -> float:
    """Normalised distance of a target pose from the home pose (dual-arm: both ends' (6,))."""
    d = np.asarray(pose) - np.asarray(home)
    return fla.norm(d / _scale(rod_length, d.shape[0]))


def sample_target_pose(
    rng: np.random.Generator,
    home: np.ndarray,
    rod_length: float,
    allowed: Callable[[np.ndarray], bool],
    min_offset: float,
    max_offset: float,
    max_tries: int = 10_000,
) -> np.ndarray:
    """A gripper pose at a normalised offset in [min_offset, max_offset] from `home`.

    The direction is uniform on the unit sphere of normalised offsets and the radius uniform in
    the band; candidates that `allowed` rejects (outside the workspace, unreachable) are redrawn.

    Raises:
        UserError: no allowed pose was found (the band does not fit the workspace).
    """
    q = np.asarray(home).shape[0]  # 3, or 6 in dual-arm: both ends' offsets drawn together
    scale = _scale(rod_length, q)
    for _ in range(max_tries):
        direction = rng.normal(size=(q,))
        direction /= fla.norm(direction)
        radius = rng.uniform(min_offset, max_offset)
        pose = np.asarray(home, dtype=float) + radius * direction * scale
        if allowed(pose):
            return pose
    raise UserError(
        f"run.target: no reachable gripper pose at offset [{min_offset}, {max_offset}] from the "
        f"home pose {pose_text(home)} in {max_tries} tries; widen rod.workspace or lower "
        "run.target.max_offset"
    )


def target_candidates(
    rng: np.random.Generator,
    home: np.ndarray,
    rod_length: float,
    allowed: Callable[[np.ndarray], bool],
    min_offset: float,
    max_offset: float,
    tries: int = TARGET_TRIES,
) -> Iterator[np.ndarray]:
    """Up to `tries` poses of `sample_target_pose`, each drawn only when the caller asks for the
    next (the previous one did not settle, or the camera could not extract it): the one target
    sampler of the environment and of a study's target set."""
    for _ in range(tries):
        yield sample_target_pose(rng, home, rod_length, allowed, min_offset, max_offset)
