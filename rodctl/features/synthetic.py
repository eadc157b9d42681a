"""Rod-like synthetic centerlines, for testing and benchmarking the feature machinery alone.

The simulator's reachable shapes form a 3-D family (one per gripper pose [x, y, theta]). This
module makes a comparable 3-parameter family without any physics: the tangent angle along the rod
is a cubic polynomial of the normalised arc length, theta(rho) = a rho + b rho^2 + c rho^3
(clamp tangent 0), integrated to a curve of fixed length and mapped to pixels by a fixed
similarity transform (image v axis pointing down, like a camera). Shapes range from straight to
C and S shapes whose tip turns by up to about 5 rad. It is a stand-in with the right
dimensionality and smoothness, not a model of the rod: acceptance figures for the real feature
come from shapes collected through the simulator and the camera.
"""

from __future__ import annotations

import numpy as np

#: Default pixel transform: rod of 300 px, clamp at (120, 240), x to the right, y up -> v down.
DEFAULT_LENGTH_PX = 300.0
DEFAULT_ORIGIN_PX = (120.0, 240.0)


def rod_like_centerlines(
    rng: np.random.Generator,
    count: int,
    points: int = 100,
    *,
    length_px: float = DEFAULT_LENGTH_PX,
    origin_px: tuple[float, float] = DEFAULT_ORIGIN_PX,
    turn: float = 1.0,
) -> np.ndarray:
    """Random rod-like centerlines in pixels, clamp end first.

    Args:
        rng: the random source of the shape parameters.
        count: B, number of shapes.
        points: N, points per centerline, equally spaced in arc length.
        length_px: curve length in pixels.
        origin_px: pixel position of the clamp end.
        turn: scale of the tangent-angle coefficients; 1 turns the tip by less than pi for 90 %
            of shapes (at most about 5 rad).

    Returns:
        (B, N, 2) float64 pixel centerlines.
    """
    params = rng.uniform(-1.0, 1.0, size=(count, 3)) * turn * np.array([2.0, 2.0, 1.5])
    return centerlines_from_params(params, points, length_px=length_px, origin_px=origin_px)


def centerlines_from_params(
    params: np.ndarray,
    points: int = 100,
    *,
    length_px: float = DEFAULT_LENGTH_PX,
    origin_px: tuple[float, float] = DEFAULT_ORIGIN_PX,
) -> np.ndarray:
    """Centerlines whose tangent angle is theta(rho) = a rho + b rho^2 + c rho^3.

    Args:
        params: (B, 3) coefficients [a, b, c] in radians.
        points: N, output points equally spaced in arc length.
        length_px: curve length in pixels.
        origin_px: pixel position of the clamp end.

    Returns:
        (B, N, 2) float64 pixel centerlines.
    """
    params = np.atleast_2d(np.asarray(params, dtype=np.float64))
    fine = 16 * (points - 1) + 1  # integrate on a fine grid, then take every 16th point
    rho = np.linspace(0.0, 1.0, fine)
    theta = params[:, :1] * rho + params[:, 1:2] * rho**2 + params[:, 2:3] * rho**3  # (B, F)
    ds = length_px / (fine - 1)
    # trapezoidal integration of (cos theta, sin theta) ds
    dx = 0.5 * (np.cos(theta[:, 1:]) + np.cos(theta[:, :-1])) * ds
    dy = 0.5 * (np.sin(theta[:, 1:]) + np.sin(theta[:, :-1])) * ds
    x = np.concatenate([np.zeros((len(params), 1)), np.cumsum(dx, axis=1)], axis=1)
    y = np.concatenate([np.zeros((len(params), 1)), np.cumsum(dy, axis=1)], axis=1)
    pts = np.stack([origin_px[0] + x, origin_px[1] - y], axis=-1)  # v points down
    return pts[:, ::16, :]
