"""A synthetic dual-arm points recording: a known smooth nonlinear map from two end poses to
tracked points, moved by a smooth random motion, observed with tracker noise.

What it stands for: a deformable linear object held by two grippers moving in a plane at about
10 Hz, its shape seen by a tracker as the x, y of `points` points (p = 2 points), the grippers'
poses [x, y, theta] logged beside (q = 6). The shape is the cubic Hermite curve between the two
end positions with tangents along the end angles, scaled by the object's length: smooth and
nonlinear in the poses, so its Jacobian changes along the motion, as a real rod's does. Used to
test the estimators on long noisy p = 20, q = 6 data (issue #26) and as a documented example of
the points format (docs/recordings.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class PointsRecording:
    """Per-frame tracked points and end-effector poses (rodctl's points dataset, in memory).

    Attributes:
        t: (T,) frame times in seconds, increasing.
        points: (T, N, 2) tracked points, x, y (metres or pixels: the file says which).
        poses: (T, E, 3) end-effector poses [x, y, theta] (metres, radians), E = 1 or 2.
        units: "m" or "px", the unit of `points`.
        images: per frame, the camera frame (H, W, 3) uint8 RGB the run logs on
            /camera/image, or None (camera-frame imports keep those at the logging image
            rate; None for recordings without frames).
    """

    t: np.ndarray
    points: np.ndarray
    poses: np.ndarray
    units: str = "m"
    images: list[np.ndarray | None] | None = None

    @property
    def q(self) -> int:
        """Command dimension: 3 per end effector."""
        return 3 * int(self.poses.shape[1])

    @property
    def r(self) -> np.ndarray:
        """(T, q) the poses flattened per frame (end 0 first)."""
        return self.poses.reshape(len(self.t), -1)


def hermite_points(poses: np.ndarray, n: int, length: float) -> np.ndarray:
    """n points of the cubic Hermite curve between two end poses, (..., 2, 3) -> (..., n, 2).

    The curve starts at end 0, leaves it along theta_0, and reaches end 1 arriving along
    theta_1 (both tangents scaled by `length`), so a straight object along +x has theta = 0 at
    both ends (the contract's pose convention).
    """
    poses = np.asarray(poses, dtype=float)
    tau = np.linspace(0.0, 1.0, n)
    h00 = 2 * tau**3 - 3 * tau**2 + 1
    h10 = tau**3 - 2 * tau**2 + tau
    h01 = -2 * tau**3 + 3 * tau**2
    h11 = tau**3 - tau**2
    p0, p1 = poses[..., 0, :2], poses[..., 1, :2]
    m0 = length * np.stack([np.cos(poses[..., 0, 2]), np.sin(poses[..., 0, 2])], axis=-1)
    m1 = length * np.stack([np.cos(poses[..., 1, 2]), np.sin(poses[..., 1, 2])], axis=-1)
    w = [h[:, None] for h in (h00, h10, h01, h11)]
    return (
        w[0] * p0[..., None, :]
        + w[1] * m0[..., None, :]
        + w[2] * p1[..., None, :]
        + w[3] * m1[..., None, :]
    )


def dual_arm_recording(
    steps: int,
    *,
    seed: int = 0,
    points: int = 10,
    length: float = 0.7,
    noise: float = 0.001,
    rate: float = 10.0,
) -> PointsRecording:
    """A `steps + 1`-frame recording of two grippers moving an object of `length` metres.

    Each gripper follows a smooth random motion (a few sinusoids of random phase per axis): the
    ends move 4-18 mm per frame, the angles a few degrees, inside a workspace that keeps the
    object between straight and strongly bent. The tracker adds Gaussian noise of `noise`
    metres (standard deviation) to every point coordinate.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(steps + 1) / rate
    home = np.array([[0.0, 0.0, 0.0], [0.8 * length, 0.0, 0.0]])
    amp = np.array([0.12 * length, 0.12 * length, 0.5])  # x, y (m), theta (rad)
    poses = np.repeat(home[None], steps + 1, axis=0)
    for e in range(2):
        for a in range(3):
            for period in (2.3, 3.7, 6.1):  # seconds
                phase = rng.uniform(0.0, 2 * np.pi)
                poses[:, e, a] += (amp[a] / 3.0) * np.sin(2 * np.pi * t / period + phase)
    clean = hermite_points(poses, points, length)
    tracked = clean + rng.normal(0.0, noise, clean.shape)
    return PointsRecording(t=t, points=tracked, poses=poses, units="m")
