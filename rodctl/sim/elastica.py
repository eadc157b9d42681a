"""Reference solutions of the inextensible planar elastica, used to validate the chain.

Why it lives in the package and not in tests: the tests, the benchmark and any later check
("is this settled shape an equilibrium?") need the same oracles, and none of them may depend on
the simulator they judge. Everything here is the continuum rod (no discretisation) solved to
~1e-9 with scipy.

* `circular_arc`: exact; a rod under a pure end moment M is an arc of curvature M/EI
  (the elastica's pure-end-moment case).
* `cantilever_tip_load`: shooting solve of θ'' = −α cos θ, θ(0) = 0, θ'(1) = 0, α = P L²/EI,
  for a dead transverse tip load (reproduces Bisshopp & Drucker / Mattiasson's table).
* `two_pose_equilibrium`: the rod held at both end poses — Kirchhoff statics
  x' = cos θ, y' = sin θ, EI θ'' = n_x sin θ − n_y cos θ with constant internal force (n_x, n_y)
  (the Kirchhoff rod equations), solved by `scipy.integrate.solve_bvp` from a guess shape.
  The problem has several equilibria; the one found is the one nearest the guess, so seed it with
  the shape being judged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_bvp, solve_ivp
from scipy.optimize import brentq


def _frame(pose: Sequence[float]) -> tuple[np.ndarray, float]:
    p = np.asarray(pose, dtype=float)
    return p[:2], float(p[2])


def _guess_profile(guess: np.ndarray, start_pose, end_pose, length: float) -> tuple:
    """The BVP solvers' starting profile from a guess shape: (p0, p1, th0, th1, s, xy, theta,
    kappa, dkappa) in units of L. The guess's angles are pinned to the start angle, and the end
    angle to the guess's branch of 2π."""
    guess = np.asarray(guess, dtype=float)
    p0, th0 = _frame(start_pose)
    p1, th1 = _frame(end_pose)
    s = np.linspace(0.0, 1.0, guess.shape[0])
    xy = (guess[:, :2] - p0) / length
    if guess.shape[1] >= 3:
        theta = np.unwrap(guess[:, 2])
    else:
        d = np.diff(guess[:, :2], axis=0)
        chord = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        theta = np.interp(s, 0.5 * (s[1:] + s[:-1]), chord)
    theta = theta + th0 - theta[0]
    th1 = th1 + 2 * np.pi * np.round((theta[-1] - th1) / (2 * np.pi))
    kappa = np.gradient(theta, s)
    dkappa = np.gradient(kappa, s)
    return p0, p1, th0, th1, s, xy, theta, kappa, dkappa


def circular_arc(
    length: float,
    curvature: float,
    s: np.ndarray,
    clamp_pose: Sequence[float] = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """Points of a circular arc of constant curvature starting at `clamp_pose`.

    Args:
        length: rod length L (m); only used to check `s`.
        curvature: κ = M/EI (1/m); positive turns left (counter-clockwise).
        s: (M,) arc lengths in [0, L].
        clamp_pose: (3,) start pose [x, y, theta].

    Returns:
        (M, 3) [x, y, theta] along the arc, world frame.
    """
    s = np.asarray(s, dtype=float)
    if np.any(s < -1e-12) or np.any(s > length * (1 + 1e-12)):
        raise ValueError("arc lengths must lie in [0, length]")
    p0, th0 = _frame(clamp_pose)
    theta = curvature * s
    if abs(curvature) < 1e-12:
        xl, yl = s, np.zeros_like(s)
    else:
        xl = np.sin(theta) / curvature
        yl = (1.0 - np.cos(theta)) / curvature
    c, sn = np.cos(th0), np.sin(th0)
    return np.stack([p0[0] + c * xl - sn * yl, p0[1] + sn * xl + c * yl, th0 + theta], axis=1)


@dataclass(frozen=True)
class CantileverSolution:
    """Tip-loaded cantilever, in units of L (clamp at the origin along +x, load along +y).

    Attributes:
        alpha: P L²/EI.
        deflection: w/L, tip displacement along the load.
        shortening: u/L, tip displacement along the rod's undeformed axis, towards the clamp.
        tip_angle: θ(L) (rad).
        curvature0: θ'(0) L, the clamp curvature (the shooting unknown).
    """

    alpha: float
    deflection: float
    shortening: float
    tip_angle: float
    curvature0: float

    def shape(self, s: np.ndarray) -> np.ndarray:
        """(M, 3) [x/L, y/L, theta] at normalised arc lengths `s` in [0, 1]."""
        sol = _integrate_cantilever(self.alpha, self.curvature0, np.asarray(s, dtype=float))
        return np.stack([sol[2], sol[3], sol[0]], axis=1)


def _cantilever_rhs(alpha: float):
    def rhs(_s: float, z: np.ndarray) -> list[float]:
        th, k, _x, _y = z
        return [k, -alpha * np.cos(th), np.cos(th), np.sin(th)]

    return rhs


def _integrate_cantilever(alpha: float, k0: float, s_eval: np.ndarray | None = None) -> np.ndarray:
    sol = solve_ivp(
        _cantilever_rhs(alpha),
        (0.0, 1.0),
        [0.0, k0, 0.0, 0.0],
        method="DOP853",
        rtol=1e-12,
        atol=1e-13,
        t_eval=s_eval,
    )
    return sol.y


def cantilever_tip_load(alpha: float) -> CantileverSolution:
    """Shooting solution of the cantilever under a dead transverse tip load.

    Solves θ'' = −α cos θ on s ∈ [0, 1] with θ(0) = 0 and θ'(1) = 0 (moment-free tip) by root
    finding on θ'(0) ∈ (0, α] (θ'(0) = α x(1) ≤ α).

    Args:
        alpha: P L²/EI ≥ 0.

    Returns:
        The tip deflection, shortening and angle, and the solution for `shape`.
    """
    if alpha < 0:
        raise ValueError("alpha must be >= 0 (flip the load direction instead)")
    if alpha == 0:
        return CantileverSolution(0.0, 0.0, 0.0, 0.0, 0.0)

    def tip_moment(k0: float) -> float:
        return float(_integrate_cantilever(alpha, k0)[1, -1])

    k0 = brentq(tip_moment, 1e-9 * alpha, alpha, xtol=1e-14, rtol=1e-14)
    th, _k, x, y = _integrate_cantilever(alpha, k0)[:, -1]
    return CantileverSolution(float(alpha), float(y), float(1.0 - x), float(th), float(k0))


@dataclass(frozen=True)
class TwoPoseSolution:
    """A rod held at two end poses (from `two_pose_equilibrium`).

    Attributes:
        success: whether solve_bvp converged to its tolerance.
        s: (M,) arc lengths (m) of the returned points.
        points: (M, 3) [x, y, theta] at `s`, world frame.
        force: (2,) internal force (n_x, n_y) (N), constant along the rod.
        message: solve_bvp's message.
    """

    success: bool
    s: np.ndarray
    points: np.ndarray
    force: np.ndarray
    message: str
    _sol: object
    _start: np.ndarray

    def at(self, s: np.ndarray) -> np.ndarray:
        """(M, 3) [x, y, theta] at arc lengths `s` (m), from the BVP's interpolant."""
        length = float(self.s[-1])
        z = self._sol.sol(np.asarray(s, dtype=float) / length)  # type: ignore[attr-defined]
        return np.stack(
            [self._start[0] + z[0] * length, self._start[1] + z[1] * length, z[2]], axis=1
        )


def two_pose_equilibrium(
    length: float,
    bending_stiffness: float,
    start_pose: Sequence[float],
    end_pose: Sequence[float],
    guess: np.ndarray,
    tol: float = 1e-8,
) -> TwoPoseSolution:
    """Equilibrium of a weightless rod whose two end poses are both prescribed.

    Unknowns, in units of L and EI: x, y, θ, κ = θ' along s ∈ [0, 1] and the constant internal
    force p = (n_x, n_y) L²/EI; equations x' = cos θ, y' = sin θ, θ' = κ, κ' = p_x sin θ − p_y cos θ
    (moment balance m' + r' × n = 0); six boundary conditions fix
    (x, y, θ) at both ends.

    Args:
        length: L (m).
        bending_stiffness: EI (N m²), only to give `force` its units.
        start_pose: (3,) clamped end [x, y, theta], world frame.
        end_pose: (3,) other end [x, y, theta]; theta is the tangent pointing away from the start.
        guess: (M, 2) or (M, 3) points along the rod (equal arc-length spacing, start first) of
            the shape to start from — selects the equilibrium branch. Angles, if absent, are
            taken from the chords.
        tol: solve_bvp tolerance.

    Returns:
        The solution; check `success`.
    """
    p0, p1, th0, th1, s, xy, theta, kappa, dkappa = _guess_profile(
        guess, start_pose, end_pose, length
    )
    # Least-squares guess of the force from κ' = p_x sin θ − p_y cos θ.
    a = np.stack([np.sin(theta), -np.cos(theta)], axis=1)
    p_guess = np.linalg.lstsq(a, dkappa, rcond=None)[0]

    def rhs(_s: np.ndarray, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        th, k = z[2], z[3]
        return np.vstack([np.cos(th), np.sin(th), k, p[0] * np.sin(th) - p[1] * np.cos(th)])

    end = (p1 - p0) / length

    def bc(za: np.ndarray, zb: np.ndarray, _p: np.ndarray) -> np.ndarray:
        return np.array([za[0], za[1], za[2] - th0, zb[0] - end[0], zb[1] - end[1], zb[2] - th1])

    z0 = np.vstack([xy[:, 0], xy[:, 1], theta, kappa])
    sol = solve_bvp(rhs, bc, s, z0, p=p_guess, tol=tol, max_nodes=100_000)
    z = sol.sol(s)
    pts = np.stack([p0[0] + z[0] * length, p0[1] + z[1] * length, z[2]], axis=1)
    force = np.asarray(sol.p, dtype=float) * bending_stiffness / length**2
    return TwoPoseSolution(
        success=bool(sol.status == 0),
        s=s * length,
        points=pts,
        force=force,
        message=str(sol.message),
        _sol=sol,
        _start=p0.copy(),
    )


# ---------------------------------------------------------------------------- heavy elastica
#
# The rod under a distributed dead load f (N/m, world frame; f = ρA g for self-weight). In units
# of L and EI: w = f L³/EI, p = n L²/EI, and the six first-order equations
#
#     x' = cos θ,  y' = sin θ,  θ' = κ,  κ' = p_x sin θ − p_y cos θ,  p_x' = −w_x,  p_y' = −w_y
#
# (force balance n' + f = 0 and moment balance m' + r' × n = 0 with m = EI θ', n the force the
# distal part exerts on the proximal one). With w = 0 they reduce to `two_pose_equilibrium`.


def _heavy_rhs(load: np.ndarray):
    wx, wy = float(load[0]), float(load[1])

    def rhs(_s, z):
        th, k, px, py = z[2], z[3], z[4], z[5]
        c, sn = np.cos(th), np.sin(th)
        zero = 0.0 * th  # the shape of th: a scalar for solve_ivp, (M,) for solve_bvp
        return np.array([c, sn, k, px * sn - py * c, zero - wx, zero - wy])

    return rhs


def normalised_load(
    length: float, bending_stiffness: float, mass_per_length: float, gravity: Sequence[float]
) -> np.ndarray:
    """w = ρA g L³ / EI (2,), the dimensionless distributed load of a heavy rod."""
    g = np.asarray(gravity, dtype=float)
    return mass_per_length * g * length**3 / bending_stiffness


@dataclass(frozen=True)
class HeavyCantileverSolution:
    """Self-weight cantilever in units of L: clamp at the origin, clamp angle `clamp_angle`,
    load w = q L³/EI along −y.

    Attributes:
        load: w = q L³/EI.
        clamp_angle: θ(0) (rad).
        deflection: −y(1), the tip's drop (positive downwards).
        shortening: cos θ0 − x(1), the tip's pull-back along x (1 − x(1) when horizontal).
        tip_angle: θ(1) (rad).
        curvature0: θ'(0) L (the shooting unknown).
    """

    load: float
    clamp_angle: float
    deflection: float
    shortening: float
    tip_angle: float
    curvature0: float

    def shape(self, s: np.ndarray) -> np.ndarray:
        """(M, 3) [x/L, y/L, theta] at normalised arc lengths `s` in [0, 1] (sorted)."""
        z = _integrate_heavy_cantilever(
            self.load, self.clamp_angle, self.curvature0, np.asarray(s, dtype=float)
        )
        return np.stack([z[0], z[1], z[2]], axis=1)


def _integrate_heavy_cantilever(
    load: float, clamp_angle: float, k0: float, s_eval: np.ndarray | None = None
) -> np.ndarray:
    # Free end, p(1) = 0, and the load (0, −w): p' = (0, w) gives p(s) = (0, −w (1 − s)).
    z0 = [0.0, 0.0, clamp_angle, k0, 0.0, -load]
    sol = solve_ivp(
        _heavy_rhs(np.array([0.0, -load])),
        (0.0, 1.0),
        z0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-13,
        t_eval=s_eval,
    )
    return sol.y


def heavy_cantilever(load: float, clamp_angle: float = 0.0) -> HeavyCantileverSolution:
    """Shooting solution of a cantilever bending under its own weight (free end).

    With a free end the internal force is known in closed form, p(s) = (0, −w (1 − s)), so one
    unknown remains: the clamp curvature κ0, found by root finding on the tip moment κ(1) = 0.
    The clamp moment balances the weight's moment about the clamp, so |κ0 L| ≤ w/2; the root is
    bracketed on a grid first, searched from the downward-bending side (for an upright clamp
    above Greenhill's load that picks the branch buckled to the right, not the straight one).

    Args:
        load: w = q L³/EI ≥ 0 (gravity along −y).
        clamp_angle: θ(0) in (−π/2, π/2]: 0 = horizontal, π/2 = upright (Greenhill's column).

    Returns:
        The tip figures and the solution for `shape`.
    """
    if load < 0:
        raise ValueError("load must be >= 0")

    def tip_moment(k0: float) -> float:
        return float(_integrate_heavy_cantilever(load, clamp_angle, k0)[3, -1])

    if load == 0:
        k0 = 0.0
    else:
        grid = np.linspace(-0.5 * load - 1e-9, 0.5 * load + 1e-9, 81)
        vals = [tip_moment(k) for k in grid]
        bracket = next(
            (grid[i], grid[i + 1]) for i in range(80) if np.sign(vals[i]) != np.sign(vals[i + 1])
        )
        k0 = brentq(tip_moment, *bracket, xtol=1e-14, rtol=1e-14)
    x, y, th = _integrate_heavy_cantilever(load, clamp_angle, k0)[:3, -1]
    return HeavyCantileverSolution(
        float(load),
        float(clamp_angle),
        float(-y),
        float(np.cos(clamp_angle) - x),
        float(th),
        float(k0),
    )


@dataclass(frozen=True)
class HeavyTwoPoseSolution:
    """A heavy rod held at two end poses (from `heavy_two_pose_equilibrium` or the shooting).

    Attributes:
        success: the solver converged to its tolerance.
        s: (M,) arc lengths (m) of `points`.
        points: (M, 3) [x, y, theta] at `s`, world frame.
        force0: (2,) internal force (N) at the start (clamp) end; n(s) = force0 − f s.
        message: the solver's message.
    """

    success: bool
    s: np.ndarray
    points: np.ndarray
    force0: np.ndarray
    message: str
    _interp: object
    _start: np.ndarray

    def at(self, s: np.ndarray) -> np.ndarray:
        """(M, 3) [x, y, theta] at arc lengths `s` (m)."""
        length = float(self.s[-1])
        z = self._interp(np.asarray(s, dtype=float) / length)  # type: ignore[operator]
        return np.stack(
            [self._start[0] + z[0] * length, self._start[1] + z[1] * length, z[2]], axis=1
        )


def heavy_two_pose_equilibrium(
    length: float,
    bending_stiffness: float,
    start_pose: Sequence[float],
    end_pose: Sequence[float],
    guess: np.ndarray,
    distributed_load: Sequence[float],
    tol: float = 1e-8,
) -> HeavyTwoPoseSolution:
    """Equilibrium of a rod under a distributed dead load with both end poses prescribed.

    The six first-order equations above, solved with `scipy.integrate.solve_bvp` from a guess
    shape (which selects the equilibrium branch; seed it with the shape being judged). Six
    boundary conditions fix (x, y, θ) at both ends.

    Args:
        length: L (m).
        bending_stiffness: EI (N m²).
        start_pose: (3,) clamped end [x, y, theta], world frame.
        end_pose: (3,) gripper end [x, y, theta].
        guess: (M, 2) or (M, 3) points at equal arc-length spacing, start first.
        distributed_load: (2,) f (N/m, world frame), e.g. ρA·g.
        tol: solve_bvp tolerance.
    """
    w = np.asarray(distributed_load, dtype=float) * length**3 / bending_stiffness
    p0, p1, th0, th1, s, xy, theta, kappa, dkappa = _guess_profile(
        guess, start_pose, end_pose, length
    )
    # Least-squares guess of p(0) from κ' = (p0 − w s) × ... (linear in p0).
    a = np.stack([np.sin(theta), -np.cos(theta)], axis=1)
    rhs_known = dkappa + s * (w[0] * np.sin(theta) - w[1] * np.cos(theta))
    p_guess = np.linalg.lstsq(a, rhs_known, rcond=None)[0]
    end = (p1 - p0) / length

    def bc(za: np.ndarray, zb: np.ndarray) -> np.ndarray:
        return np.array([za[0], za[1], za[2] - th0, zb[0] - end[0], zb[1] - end[1], zb[2] - th1])

    z0 = np.vstack([xy[:, 0], xy[:, 1], theta, kappa, p_guess[0] - w[0] * s, p_guess[1] - w[1] * s])
    sol = solve_bvp(_heavy_rhs(w), bc, s, z0, tol=tol, max_nodes=100_000)
    z = sol.sol(s)
    pts = np.stack([p0[0] + z[0] * length, p0[1] + z[1] * length, z[2]], axis=1)
    return HeavyTwoPoseSolution(
        success=bool(sol.status == 0),
        s=s * length,
        points=pts,
        force0=z[4:6, 0] * bending_stiffness / length**2,
        message=str(sol.message),
        _interp=sol.sol,
        _start=p0.copy(),
    )


def heavy_two_pose_shooting(
    length: float,
    bending_stiffness: float,
    start_pose: Sequence[float],
    end_pose: Sequence[float],
    initial: Sequence[float],
    distributed_load: Sequence[float],
) -> HeavyTwoPoseSolution:
    """The same problem as `heavy_two_pose_equilibrium`, by single shooting: an independent check.

    Unknowns (κ(0) L, p_x(0), p_y(0)); the residual is the end pose reached by integrating the six
    equations with DOP853 at rtol 1e-12, solved by `scipy.optimize.root` (hybr). Start it from
    the BVP's answer or any nearby guess.

    Args:
        initial: (3,) starting guess of (κ0 L, p_x(0), p_y(0)).
        (others as `heavy_two_pose_equilibrium`)
    """
    from scipy.optimize import root

    p0, th0 = _frame(start_pose)
    p1, th1 = _frame(end_pose)
    w = np.asarray(distributed_load, dtype=float) * length**3 / bending_stiffness
    end = (p1 - p0) / length
    rhs = _heavy_rhs(w)

    def shoot(v: np.ndarray, dense: bool = False):
        return solve_ivp(
            rhs,
            (0.0, 1.0),
            [0.0, 0.0, th0, v[0], v[1], v[2]],
            method="DOP853",
            rtol=1e-12,
            atol=1e-13,
            dense_output=dense,
        )

    def residual(v: np.ndarray) -> np.ndarray:
        zb = shoot(v).y[:, -1]
        return np.array([zb[0] - end[0], zb[1] - end[1], zb[2] - th1])

    res = root(residual, np.asarray(initial, dtype=float), method="hybr", tol=1e-13)
    sol = shoot(res.x, dense=True)
    s = np.linspace(0.0, 1.0, 101)
    z = sol.sol(s)
    ok = bool(res.success and np.max(np.abs(residual(res.x))) < 1e-9)
    return HeavyTwoPoseSolution(
        success=ok,
        s=s * length,
        points=np.stack([p0[0] + z[0] * length, p0[1] + z[1] * length, z[2]], axis=1),
        force0=np.array([res.x[1], res.x[2]]) * bending_stiffness / length**2,
        message=str(res.message),
        _interp=sol.sol,
        _start=p0.copy(),
    )
