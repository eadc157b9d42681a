"""Table friction in the quasi-static engine: each move is an incremental minimisation.

A rod on a table (`rod.table_friction` = μ) under Coulomb friction is a rate-independent system:
where it settles depends on the path the ends took, not on how fast. Its quasi-static evolution
is the limit of incremental minimisations (the time-discrete "energetic" scheme): from the
settled state θ⁰ of the previous sub-move, the next one minimises

    Φ(θ) = E(θ) + Σ_i μ m g |c_i(θ) − c_i(θ⁰)| + Σ_i μ m g (l/4) |θ_i − θ_i⁰|

subject to both end poses (h(θ) = 0, the chain's end at the gripper): E the chain's elastic
energy (`rodctl/sim/quasistatic.py`), c_i the segment centres, the second sum pymunk's per-segment
pivot joint to the table (max force μ m g) and the third its gear joint (max torque μ m g l/4),
`rodctl/sim/chain.py`'s `_table_joints`. The dissipation is nonsmooth at a stuck segment; it is
smoothed as √(|Δc|² + ε²) and ε is driven down (`EPS_LEVELS`, to 1e-7 L) by continuation, a
primal-dual Newton on the KKT system at each level (the friction forces are unknowns too, kept
inside their cones: Chan, Golub and Mulet's method for total variation, the same smoothed norm),
warm-started from the last level and, after a move's first sub-move, from the previous
sub-move's increment and forces. The friction couples every angle (a segment's centre moves
with every angle before it), so the Hessian is dense: one dense (N+2) solve per Newton step
(`numpy.linalg.solve`, LAPACK and BLAS: unlike the frictionless solve its last bits may depend
on the BLAS kernel). A solution must be a minimum: its Hessian reduced to the constraints'
tangent space positive definite, checked, and where Newton ends on a saddle it is run again with
that Hessian shifted; no segment may turn by more than `MAX_BRANCH_STEP` in one sub-move.

Which path: the move of one control step is split into `substeps` equal sub-moves of the end
poses along their straight line (the gripper's ramp in pymunk is linear in time over the control
period); each sub-move is one incremental minimisation from the last. More sub-moves approach
the continuous quasi-static sweep (measured: 16 and 32 sub-moves agree within 0.01 % of L).
The smoothing lets a stuck segment creep by about ε per sub-move, which adds up over a run:
hence the fine last level.

`TableQuasiStaticSim(cfg)` is the quasi-static engine on this chain. It is not reachable from a
validated config: `rod.table_friction` with `engine: quasistatic` is
refused (`rodctl/config/rod.py`), because the pymunk table it would replace depends on how fast
it is driven by more than the agreement asked for (docs/engines.md, Friction, measured with
`benchmarks/bench_table_friction.py`); this solver agrees with that table's slow-driven limit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from rodctl.config.rod import STANDARD_GRAVITY, RodConfig
from rodctl.sim.quasistatic import (
    MAX_BRANCH_STEP,
    QuasiStaticChain,
    QuasiStaticSim,
    _ends,
    _Model,
)

#: Smoothing widths ε of |Δc| (as fractions of L), coarse to fine: the continuation.
EPS_LEVELS = (1e-3, 1e-5, 1e-7)
#: The levels from a warm start (the last sub-move's increment and friction forces).
WARM_LEVELS = (1e-7,)
#: Newton iterations allowed per smoothing level.
MAX_ITER = 100
#: Sub-moves per control step (the discretised path of the ends).
SUBSTEPS = 16
#: Smallest sub-move, as a fraction of the move, before a failed solve is reported.
MIN_FRACTION = 1.0 / 256.0


class FrictionalChain(QuasiStaticChain):
    """`QuasiStaticChain` on a table with Coulomb coefficient μ (`table_friction`).

    Same constructor (RodSim rebuilds it like the others); `step` moves the ends in `substeps`
    sub-moves, each the incremental minimisation of the module docstring. μ = 0 has no
    dissipation: every sub-move is then the frictionless equilibrium (the same minimisation).
    """

    def __init__(
        self,
        length: float,
        bending_stiffness: float,
        mass_per_length: float,
        segments: int,
        clamp_pose: Sequence[float],
        dt: float = 0.0,
        iterations: int = 0,
        damping_rate: float = 0.0,
        inertia_radius: float = 0.0,
        gripped: bool = True,
        tip_force: Sequence[float] | None = None,
        gravity: Sequence[float] = (0.0, 0.0),
        table_friction: float | None = None,
        table_gravity: float = 9.81,
        movable_clamp: bool = False,
        segment_inertia: float | None = None,
    ) -> None:
        if table_friction is None:
            raise ValueError("a frictional chain needs table_friction")
        if tuple(gravity) != (0.0, 0.0) or tip_force is not None or not gripped:
            raise ValueError("a rod on a table has no in-plane load and is gripped")
        super().__init__(
            length,
            bending_stiffness,
            mass_per_length,
            segments,
            clamp_pose,
            dt,
            iterations,
            damping_rate,
            inertia_radius,
            gripped,
            tip_force,
            gravity,
            None,
            table_gravity,
            movable_clamp,
            segment_inertia,
        )
        self.set_table_friction(table_friction)
        self.substeps = SUBSTEPS
        #: Start each sub-move after the first from the last one's increment and forces.
        self.warm = True
        #: Newton iterations of the frictional solves (all levels), for the record.
        self.friction_iterations = 0
        #: The last sub-move: (its fraction of the move, its increment of θ, its friction forces).
        self._last: tuple[float, np.ndarray, tuple] | None = None

    def set_table_friction(self, mu: float) -> None:
        if not (math.isfinite(mu) and mu >= 0):
            raise ValueError(f"table friction must be finite and >= 0, got {mu}")
        self.table_friction = float(mu)

    def _model(self) -> _Model:
        """The constant parts of the system (`QuasiStaticChain._model`), μ in the key too: the
        torque scale, hence the tolerance, includes the friction."""
        m = self.__dict__.get("_model_cache")
        key = (self.bending_stiffness, self.mass_per_length, self.torque_tol, self.table_friction)
        if m is None or m.key != key:
            m = _Model(self, key)
            self._model_cache = m
        return m

    def pose_jacobian(self) -> tuple[np.ndarray, np.ndarray]:
        """None exists: on a table the shape's response to the gripper is one-sided (which
        segments stick depends on the direction of the move), not a linear map."""
        raise ValueError("a rod on a table has no smooth pose Jacobian (friction is one-sided)")

    def _torque_scale(self) -> float:
        """EI/L + μ ρA g L²: the size of the torques (the friction's included)."""
        mu = self.table_friction or 0.0
        return (
            self.bending_stiffness / self.length
            + mu * self.mass_per_length * self.table_gravity * self.length**2
        )

    # ------------------------------------------------------------------ the step
    def _solve_to(self, grip: np.ndarray, clamp: np.ndarray) -> bool:
        if not (self._finite() and math.isfinite(sum(self.lam.tolist()))):
            self._grip, self._clamp = grip, clamp
            return False
        g0, c0 = self._grip.copy(), self._clamp.copy()
        moving = not (grip.tolist() == g0.tolist() and clamp.tolist() == c0.tolist())
        self._last = None  # the predictor works within one move
        n = max(1, int(self.substeps)) if moving else 1
        ok = True
        for k in range(1, n + 1):
            ok = self._sub_move(g0, c0, grip, clamp, (k - 1) / n, k / n) and ok
            if not ok:
                break
        self._grip, self._clamp = grip, clamp
        return ok

    def _sub_move(
        self,
        g0: np.ndarray,
        c0: np.ndarray,
        grip: np.ndarray,
        clamp: np.ndarray,
        a: float,
        b: float,
    ) -> bool:
        """The sub-move from fraction a to b of the move, halved where a solve fails."""
        done, frac = a, b - a
        while done < b - 1e-15:
            f = min(b, done + frac)
            g = grip if f == 1.0 else g0 + (grip - g0) * f
            c = clamp if f == 1.0 else c0 + (clamp - c0) * f
            result = self._incremental(g, c, f - done)
            if result is not None:
                self._last = (f - done, result[0] - self.theta, result[2])
                self.theta, self.lam = result[0], result[1]
                self._grip, self._clamp = g, c
                self._maybe_straight = False
                self._tangent = None
                done = f
                continue
            if frac <= MIN_FRACTION:
                return False
            frac *= 0.5
        return True

    # ------------------------------------------------------------------ the minimisation
    def _start(self, grip: np.ndarray, clamp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Newton's start: the current state, or from a straight chain (where the constraint
        is degenerate) the smooth curve through both end poses."""
        if self._maybe_straight and float(np.ptp(self.theta)) < 1e-9:
            # The frictionless equilibrium there (found from the Hermite curve).
            saved = (self.theta, self.lam, self._grip, self._clamp, self.snaps, self.converged)
            notes = len(self.snap_notes)
            ok = QuasiStaticChain._solve_to(self, grip.copy(), clamp.copy())
            guess = (self.theta.copy(), self.lam.copy())
            self.theta, self.lam, self._grip, self._clamp, self.snaps, self.converged = saved
            del self.snap_notes[notes:]
            self._maybe_straight = True
            if ok:
                return guess
            return self._hermite_guess(grip, clamp), self.lam.copy()
        return self.theta.copy(), self.lam.copy()

    def _incremental(
        self, grip: np.ndarray, clamp: np.ndarray, frac: float
    ) -> tuple[np.ndarray, np.ndarray, tuple] | None:
        """argmin Φ subject to the end poses (grip, clamp), from the current state as θ⁰:
        (θ, λ, the friction forces), or None when Newton does not converge at some smoothing
        level, would jump branches or ends on a saddle. `frac`: the sub-move's length as a
        fraction of the move (the predictor's scale)."""
        ref_theta = self.theta
        ref_centres = self._centres(ref_theta, self._clamp)
        ref = (grip, clamp, ref_theta, ref_centres)
        starts: list[tuple[np.ndarray, np.ndarray, tuple | None, tuple, bool]] = []
        last = self._last
        if self.warm and last is not None and last[0] == frac:
            # The last sub-move of this move, repeated: its increment and its friction forces
            # (sliding segments keep sliding the same way), from the finer levels only.
            starts.append((ref_theta + last[1], self.lam.copy(), last[2], WARM_LEVELS, False))
        theta0, lam0 = self._start(grip, clamp)
        starts.append((theta0, lam0, None, EPS_LEVELS, False))
        # Where plain Newton fails or ends on a saddle: again with the Hessian convexified on
        # the constraints' tangent space (a descent towards a minimum).
        starts.append((theta0, lam0, None, EPS_LEVELS, True))
        for theta, lam, dual, levels, convexify in starts:
            for eps in levels:
                out = self._newton_eps(theta, lam, ref, eps, convexify, dual)
                if out is None:
                    break
                theta, lam, dual = out
            else:
                jump = float(np.max(np.abs(theta - ref_theta)))
                if not self._maybe_straight and jump > MAX_BRANCH_STEP:
                    continue  # a would-be branch jump (as in the frictionless continuation)
                if self._reduced_pd(theta, lam, ref, levels[-1]):
                    assert dual is not None  # set by the last level's solve
                    return theta, lam, dual
        return None

    def _centres(self, theta: np.ndarray, clamp: np.ndarray) -> np.ndarray:
        pts = self._points(theta, clamp)
        return 0.5 * (pts[:-1] + pts[1:])

    def _system(
        self,
        theta: np.ndarray,
        lam: np.ndarray,
        ref: tuple,
        eps: float,
        dual: tuple | None = None,
        hessian: bool = True,
    ) -> tuple:
        """The smoothed incremental problem at θ, λ: (∇_θ L, dense H or None, A (2, N), h (2,),
        ∇_θ L with the primal friction, the primal friction (f_x, f_y, τ) = ∂D/∂(c, θ), the
        smoothing (s, s_θ, Δc_x, Δc_y, Δθ)). `ref` = (gripper pose, clamp pose, θ⁰, the
        centres at θ⁰). With `dual` = (f_x, f_y, τ) given, the gradient and H use those
        friction forces (the primal-dual Newton of `_newton_eps`): H's friction block is then
        Jᵀ M̃ J with the symmetrised M̃_i = (w I − (f dᵀ + d fᵀ)/(2 s)) / s, which is the
        primal M_i when f is w d/s."""
        grip, clamp, ref_theta, ref_centres = ref
        ends = _ends(grip, clamp)
        m = self._model()
        n, seg = self.segments, self.seg_length
        l0, l1 = lam.tolist()
        grad, diag, z, h0, h1 = self._eval(theta, l0, l1, m, ends)
        cos, sin = z.real, z.imag
        mu = self.table_friction or 0.0
        w = mu * self.segment_mass * self.table_gravity  # μ m g
        # Centres c_i = p_0 + l Σ_{j<i} t_j + (l/2) t_i, their displacement from θ⁰'s.
        px = clamp[0] + seg * (np.cumsum(cos) - 0.5 * cos)
        py = clamp[1] + seg * (np.cumsum(sin) - 0.5 * sin)
        dx, dy = px - ref_centres[:, 0], py - ref_centres[:, 1]
        e2 = (eps * self.length) ** 2
        s = np.sqrt(dx * dx + dy * dy + e2)
        # Spin: μ m g l/4 √(Δθ² + ε_θ²), ε_θ = ε L / (l/4) (the same smoothing in length units).
        ws = w * seg / 4.0
        et2 = (eps * self.length / (seg / 4.0)) ** 2
        dth = theta - ref_theta
        st = np.sqrt(dth * dth + et2)
        prim = (w * dx / s, w * dy / s, ws * dth / st)
        # F_j = Σ_{i>j} f_i + f_j / 2: the friction load carried by segment j's angle.
        fx, fy, tau = prim
        big_fx = np.cumsum(fx[::-1])[::-1] - 0.5 * fx
        big_fy = np.cumsum(fy[::-1])[::-1] - 0.5 * fy
        pgrad = grad + seg * (-sin * big_fx + cos * big_fy) + tau
        if dual is None:
            grad = pgrad
        else:
            fx, fy, tau = dual
            big_fx = np.cumsum(fx[::-1])[::-1] - 0.5 * fx
            big_fy = np.cumsum(fy[::-1])[::-1] - 0.5 * fy
            grad = grad + seg * (-sin * big_fx + cos * big_fy) + tau
        a = np.empty((2, n))
        a[0] = -seg * sin
        a[1] = seg * cos
        h = np.array([h0, h1])
        smooth = (s, st, dx, dy, dth)
        if not hessian:
            return grad, None, a, h, pgrad, prim, smooth
        if dual is None:
            inv = w / s
            mxx = inv * (1.0 - dx * dx / (s * s))
            mxy = -inv * dx * dy / (s * s)
            myy = inv * (1.0 - dy * dy / (s * s))
            spin = ws * et2 / (st * st * st)
        else:
            mxx = (w - fx * dx / s) / s
            mxy = -0.5 * (fx * dy + fy * dx) / (s * s)
            myy = (w - fy * dy / s) / s
            spin = (ws - tau * dth / st) / st
        # Q_k = M_k / 2 + Σ_{i>k} M_i;  H_D[j, k] = l² n_jᵀ Q_max(j,k) n_k for j ≠ k.
        sxx = np.cumsum(mxx[::-1])[::-1] - mxx
        sxy = np.cumsum(mxy[::-1])[::-1] - mxy
        syy = np.cumsum(myy[::-1])[::-1] - myy
        nx, ny = -sin, cos
        qxx, qxy, qyy = sxx + 0.5 * mxx, sxy + 0.5 * mxy, syy + 0.5 * myy
        rx = qxx * nx + qxy * ny  # R_k = Q_k n_k
        ry = qxy * nx + qyy * ny
        hd = seg * seg * (nx[:, None] * rx[None, :] + ny[:, None] * ry[None, :])  # [j, k]
        hd = np.triu(hd, 1)
        hd = hd + hd.T
        # Diagonal: l² n_jᵀ (M_j/4 + Σ_{i>j} M_i) n_j − l t_j·F_j + the spin's curvature.
        dxx, dxy, dyy = sxx + 0.25 * mxx, sxy + 0.25 * mxy, syy + 0.25 * myy
        dd = seg * seg * (nx * nx * dxx + 2 * nx * ny * dxy + ny * ny * dyy)
        dd -= seg * (cos * big_fx + sin * big_fy)
        dd += spin
        hd[np.diag_indices(n)] = dd + diag
        idx = np.arange(n - 1)
        hd[idx, idx + 1] += m.off
        hd[idx + 1, idx] += m.off
        return grad, hd, a, h, pgrad, prim, smooth

    def _converged(self, grad: np.ndarray, h: np.ndarray) -> bool:
        m = self._model()
        return (
            float(np.max(np.abs(grad))) <= m.torque_unit
            and float(np.sum(np.abs(h))) <= m.position_unit
        )

    def _newton_eps(
        self,
        theta: np.ndarray,
        lam: np.ndarray,
        ref: tuple,
        eps: float,
        convexify: bool = False,
        dual: tuple | None = None,
    ) -> tuple[np.ndarray, np.ndarray, tuple] | None:
        """Primal-dual Newton (Chan, Golub and Mulet's for total variation) on one smoothing
        level: the friction forces f (and spin torques τ) are unknowns too, with f s = w d as
        their equation, and stay inside their cones |f| <= w; the angles take the full Newton
        step, halved only while the primal KKT residual blows up. (θ, λ, the friction forces)
        or None. `convexify`: shift H where it is not positive definite on the constraints'
        tangent space (the step is then a descent towards a minimum, not a saddle)."""
        n, seg = self.segments, self.seg_length
        mu = self.table_friction or 0.0
        w = mu * self.segment_mass * self.table_gravity
        ws = w * seg / 4.0
        kkt = np.zeros((n + 2, n + 2))
        if dual is None:
            dual = self._system(theta, lam, ref, eps, hessian=False)[5]
        for _ in range(MAX_ITER):
            grad, hess, a, h, pgrad, prim, smooth = self._system(theta, lam, ref, eps, dual)
            if self._converged(pgrad, h):
                return theta, lam, prim
            self.friction_iterations += 1
            if convexify:
                hess = hess + self._tangent_shift(hess, a) * np.eye(n)
            kkt[:n, :n] = hess
            kkt[:n, n:] = a.T
            kkt[n:, :n] = a
            # The dual equations r = f s − w d = 0 eliminated: δf = (M̃ s δd − r) / s, so the
            # angle rows get −Jᵀ r / s on their right-hand side.
            s, st, dx, dy, dth = smooth
            fx, fy, tau = dual
            rx, ry, rt = fx * s - w * dx, fy * s - w * dy, tau * st - ws * dth
            gx, gy = rx / s, ry / s
            big_x = np.cumsum(gx[::-1])[::-1] - 0.5 * gx
            big_y = np.cumsum(gy[::-1])[::-1] - 0.5 * gy
            nx, ny = a[0] / seg, a[1] / seg
            corr = seg * (nx * big_x + ny * big_y) + rt / st
            rhs = -np.concatenate([grad - corr, h])
            try:
                sol = np.linalg.solve(kkt, rhs)
            except np.linalg.LinAlgError:
                return None
            dtheta, dlam = sol[:n], sol[n:]
            if not np.all(np.isfinite(dtheta)):
                return None
            # Primal step: the full step, halved while the primal residual blows up.
            res0 = (
                float(np.max(np.abs(pgrad))) / self._model().torque_unit
                + float(np.sum(np.abs(h))) / self._model().position_unit
            )
            step = 1.0
            for _ in range(30):
                th2 = theta + step * dtheta
                lam2 = lam + step * dlam
                g2, _, _, h2, _, _, _ = self._system(th2, lam2, ref, eps, hessian=False)
                res2 = (
                    float(np.max(np.abs(g2))) / self._model().torque_unit
                    + float(np.sum(np.abs(h2))) / self._model().position_unit
                )
                # Lenient on purpose: the primal-dual step need not lower the primal residual
                # at once (the dual forces catch up); only a blow-up is cut back.
                if res2 < 4.0 * res0 + 1.0:
                    break
                step *= 0.5
            else:
                return None
            theta, lam = th2, lam2
            # δd = J δθ for the step taken (the centres' linear change), then δf, δτ from the
            # linearised dual equations, and the dual step as far as the cones allow.
            jx = (step * seg) * nx * dtheta
            jy = (step * seg) * ny * dtheta
            ddx = np.cumsum(jx) - 0.5 * jx
            ddy = np.cumsum(jy) - 0.5 * jy
            along = (dx * ddx + dy * ddy) / s
            dfx = (w * ddx - fx * along - rx) / s
            dfy = (w * ddy - fy * along - ry) / s
            dtau = ((ws - tau * dth / st) * (step * dtheta) - rt) / st
            beta = _cone_step(fx, fy, dfx, dfy, w)
            beta = min(beta, _cone_step(tau, np.zeros_like(tau), dtau, np.zeros_like(tau), ws))
            dual = (fx + beta * dfx, fy + beta * dfy, tau + beta * dtau)
        return None

    def _tangent_shift(self, hess: np.ndarray, a: np.ndarray) -> float:
        """The shift σ >= 0 that makes Zᵀ (H + σ I) Z positive definite (its smallest
        eigenvalue at least 1e-3 of the spring scale k), Z a basis of A's null space."""
        q, _ = np.linalg.qr(a.T, mode="complete")
        z = q[:, 2:]
        reduced = z.T @ (0.5 * (hess + hess.T)) @ z
        low = float(np.linalg.eigvalsh(reduced)[0])
        floor = 1e-3 * self._model().k
        return max(0.0, floor - low)

    def _reduced_pd(self, theta: np.ndarray, lam: np.ndarray, ref: tuple, eps: float) -> bool:
        """Whether the smoothed problem's Hessian reduced to the constraints' tangent space is
        positive definite (a minimum, not a saddle): Cholesky of Zᵀ H Z, Z an orthonormal basis
        of A's null space."""
        _, hess, a, _, _, _, _ = self._system(theta, lam, ref, eps)
        assert hess is not None
        q, _ = np.linalg.qr(a.T, mode="complete")
        z = q[:, 2:]
        reduced = z.T @ hess @ z
        try:
            np.linalg.cholesky(0.5 * (reduced + reduced.T))
        except np.linalg.LinAlgError:
            return False
        return True


def _cone_step(fx: np.ndarray, fy: np.ndarray, dx: np.ndarray, dy: np.ndarray, w: float) -> float:
    """Largest β in (0, 1] with |f + β δf| <= w for every segment (0.99 of the way to the cone's
    boundary where it would leave it)."""
    if w <= 0.0:
        return 1.0
    ax = fx + dx
    ay = fy + dy
    outside = ax * ax + ay * ay > w * w
    if not np.any(outside):
        return 1.0
    # |f + β δf|² = w²: a β² + b β + c = 0 with c <= 0 (f inside).
    a = dx * dx + dy * dy
    b = 2.0 * (fx * dx + fy * dy)
    c = fx * fx + fy * fy - w * w
    with np.errstate(invalid="ignore", divide="ignore"):
        root = (-b + np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))) / (2.0 * a)
    return float(min(1.0, 0.99 * float(np.min(root[outside]))))


class TableQuasiStaticSim(QuasiStaticSim):
    """The quasi-static engine (`QuasiStaticSim`) with its rod on a table: `FrictionalChain`
    built from `cfg.table_friction`. Built directly (`TableQuasiStaticSim(cfg)`, `cfg` made with
    `model_copy`), never by `RodSim(cfg)`: validation refuses the table on this engine (module
    docstring). A rod on a table has no smooth Jacobian (friction is one-sided)."""

    _chain_type = FrictionalChain

    def _build_chain(self, cfg: RodConfig) -> None:
        super()._build_chain(cfg)
        self.centerline_jacobian = None  # type: ignore[assignment]  # one-sided on a table

    def _chain_options(self, cfg: RodConfig) -> dict:
        if cfg.table_friction is None:
            raise ValueError("TableQuasiStaticSim needs rod.table_friction")
        return {"table_friction": cfg.table_friction, "table_gravity": STANDARD_GRAVITY}
