"""Analytic rod shapes of exact length, for testing and benchmarking the camera without a simulator.

A planar inextensible rod is fully described by its tangent angle theta(s) along arc length s:
``x(s) = x0 + int cos theta``, ``y(s) = y0 + int sin theta``. Each shape here is a theta(s), so its
length is exact by construction and the end poses follow the pose contract (theta is the tangent
pointing from clamp to gripper). The curves are integrated finely (Simpson on a dense grid) and then
sampled at equal arc length, which is exactly how a simulator's ground truth is resampled.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: Names accepted by `rod_shape`.
SHAPES = ("straight", "arc", "arc_down", "s_shape", "tight_tip", "tight_tip_down", "hook", "loop")


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def _theta_fn(name: str, length: float) -> Callable[[np.ndarray], np.ndarray]:
    two_pi = 2.0 * np.pi
    table: dict[str, Callable[[np.ndarray], np.ndarray]] = {
        "straight": lambda s: np.zeros_like(s),
        # constant curvature: a circular arc turning 1.6 rad towards +y
        "arc": lambda s: 1.6 * s / length,
        "arc_down": lambda s: -1.6 * s / length,
        # one full sine period of tangent angle: bends up, then down, ends parallel to the clamp
        "s_shape": lambda s: 1.1 * np.sin(two_pi * s / length),
        # almost straight, then a strong bend over the last fifth (gripper turned by 2.4 rad)
        "tight_tip": lambda s: 2.4 * (s / length) ** 8,
        "tight_tip_down": lambda s: -2.4 * (s / length) ** 8,
        # a U-turn: the gripper end comes back next to the rod, pointing the other way
        "hook": lambda s: 3.3 * _smoothstep((s / length - 0.25) / 0.6),
        # a loop: the tangent turns by 2*pi, so the rod crosses itself (at about 45 degrees)
        "loop": lambda s: two_pi * _smoothstep((s / length - 0.1) / 0.8),
    }
    try:
        return table[name]
    except KeyError:
        raise ValueError(f"unknown shape {name!r}; known: {SHAPES}") from None


def centerline_from_theta(
    theta_fn: Callable[[np.ndarray], np.ndarray],
    length: float,
    points: int,
    clamp_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
    fine: int = 20001,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrate a tangent-angle function into a centerline sampled at equal arc length.

    Args:
        theta_fn: maps arc length s (array, metres) to the tangent angle relative to the clamp.
        length: rod length L (m).
        points: number of samples M (both ends included).
        clamp_pose: (3,) pose of the clamped end [x, y, theta].
        fine: integration grid size (odd).

    Returns:
        ((M, 2) centerline in metres, clamp end first; (3,) gripper pose [x, y, theta]).
    """
    s = np.linspace(0.0, length, fine)
    th = theta_fn(s) + clamp_pose[2]
    ds = s[1] - s[0]
    # cumulative trapezoid on the fine grid (error ~ ds^2, i.e. ~1e-10 m here)
    c, sn = np.cos(th), np.sin(th)
    x = np.concatenate([[0.0], np.cumsum((c[1:] + c[:-1]) * ds / 2)]) + clamp_pose[0]
    y = np.concatenate([[0.0], np.cumsum((sn[1:] + sn[:-1]) * ds / 2)]) + clamp_pose[1]
    sq = np.linspace(0.0, length, points)
    line = np.column_stack([np.interp(sq, s, x), np.interp(sq, s, y)])
    gripper = np.array([x[-1], y[-1], th[-1]])
    return line, gripper


def rod_shape(
    name: str,
    length: float = 0.5,
    points: int = 100,
    clamp_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """A named test shape (see `SHAPES`) as ((M, 2) centerline, (3,) gripper pose)."""
    return centerline_from_theta(_theta_fn(name, length), length, points, clamp_pose)


def random_shape(
    rng: np.random.Generator, length: float = 0.5, points: int = 100, max_turn: float = 2.5
) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random shape: theta(s) a random sum of three modes, |theta| <= max_turn.

    Args:
        rng: the random source.
        length: rod length (m).
        points: number of samples.
        max_turn: bound on the tangent angle (rad).

    Returns:
        ((M, 2) centerline, (3,) gripper pose).
    """
    coef = rng.uniform(-1.0, 1.0, size=3)
    coef *= max_turn / max(np.abs(coef).sum(), 1e-9) * rng.uniform(0.2, 1.0)

    def theta(s: np.ndarray) -> np.ndarray:
        t = s / length
        return coef[0] * t + coef[1] * np.sin(np.pi * t) + coef[2] * t**4

    return centerline_from_theta(theta, length, points)
