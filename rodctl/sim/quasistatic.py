"""The quasi-static engine: the settled equilibrium of the pymunk chain, solved directly.

Why: the experiment only ever uses *settled* shapes, and the settled shape of the Hencky chain of
`rodctl/sim/chain.py` is the minimiser of its energy with both end poses given. No dynamics
(masses' inertia, the fictitious rotary inertia, damping, time step, solver iterations) enters
it; gravity enters through the real masses ρA·l. Solving that minimisation by Newton's method
costs a few O(N) linear solves per control step instead of hundreds of physics steps.

The chain is the same as the pymunk one, term for term (module docstring of `chain.py`):

* N segments of length l = L/N, tangent angles θ_0..θ_{N-1}; joint points
  p_0 = clamp, p_{k+1} = p_k + l t_k with t_k = (cos θ_k, sin θ_k);
* energy  E(θ) = k_e/2 (θ_0 − θ_c)² + Σ_{i=1}^{N-1} k/2 (θ_i − θ_{i-1})² + k_e/2 (θ_g − θ_{N-1})²
  − Σ_i m g·c_i,  with k = EI/l, k_e = 2EI/l (the clamp's and gripper's half cells),
  m = ρA·l and c_i = p_i + (l/2) t_i the segment centres (gravity lumped at the centres, as
  pymunk applies it);
* constraint  h(θ) = l Σ_i t_i − (g − p_0) = 0: the chain's far end is at the gripper.

Newton on the KKT system of the Lagrangian E + λ·h (N angles + 2 multipliers): the Hessian H of
the Lagrangian in θ is tridiagonal (springs) plus a diagonal (gravity and the constraint's
curvature), and the constraint Jacobian A is a 2-row border, so each Newton step is one banded
solve with four right-hand sides (LAPACK's tridiagonal gtsv: −∇L, the rows of A, e_{N−1}) and a
2×2 Schur complement S = A H⁻¹ Aᵀ: O(N). A full step that does not reduce the residual is halved
(backtracking line search). Newton starts from a tangent predictor, the previous equilibrium plus
(dθ/dg)·Δg by the implicit-function theorem, from the columns the previous step's last solve left
(`_predict`).

Stability: at every converged equilibrium the Hessian reduced to the constraints' tangent space
must be positive definite. By Sylvester's law of inertia on the block factorisation of the KKT
matrix, that holds exactly when (negative pivots of H) + (positive eigenvalues of S) = 2; the
pivots of the tridiagonal H come from its LDLᵀ recurrence. The path is followed by continuation:
the end poses move along their straight line in sub-steps that are halved when Newton fails,
lands on an unstable equilibrium or moves the shape by more than `MAX_BRANCH_STEP` (a would-be
branch jump). When the sub-step is below `MIN_FRACTION` of the move and still fails, the path has
lost stability (a fold: snap-through); after a failed try, the tries that cannot declare the fold
give up early (`QuasiStaticChain._patience`). The engine then follows the overdamped gradient flow
θ' = −∇E (projected on the constraints) by backward-Euler steps — a Newton step with the shift
I/τ added to H, τ growing as the flow settles — to the next stable equilibrium, counts a snap
and keeps a note of it (`QuasiStaticChain.snap_notes`). A jump inside a converged sub-step is
caught by a heuristic only (no segment turns more than `MAX_BRANCH_STEP` in one sub-step).

No BLAS call in the solve (LAPACK's gtsv is a plain loop; the few products are
elementwise), so results do not depend on the BLAS kernel.

Not supported (refused at config validation, `rodctl/config/rod.py`): table friction.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np

from rodctl.config.rod import RodConfig
from rodctl.records import SNAP_NOTE
from rodctl.sim.rod import ApplyResult, RodHealth, RodSim, register_engine


@functools.cache
def _gtsv():  # noqa: ANN202 (an f2py function)
    """LAPACK's tridiagonal solver (Gaussian elimination with partial pivoting): the banded
    solve of `scipy.linalg.solve_banded` with one sub- and super-diagonal, without its per-call
    overhead. Loaded on first use, and without importing scipy.linalg (`rodctl.sim.lapack`):
    that costs ~0.27 s of CPU at start-up, for one routine."""
    from rodctl.sim.lapack import dgtsv  # noqa: PLC0415 (on first use: see the docstring)

    return dgtsv()


#: The reductions as bare ufunc methods (`ndarray.sum`/`max` add a Python layer per call).
_SUM = np.add.reduce
_MAX = np.maximum.reduce

#: Newton iterations allowed per solve before the sub-step is halved.
MAX_NEWTON = 25
#: Largest change of any segment angle (rad) in one continuation sub-step: more is treated as a
#: possible branch jump and the sub-step is halved.
MAX_BRANCH_STEP = 0.35
#: Smallest continuation sub-step, as a fraction of the move; below it the path has a fold.
MIN_FRACTION = 1.0 / 512.0
#: The tries after a failed one that cannot start the flow give up after this many Newton
#: iterations, or when none of this many step lengths 1, 1/2, ... of a Newton step lowers the
#: residual (`QuasiStaticChain._patience`; a full Newton tries 30).
QUICK_NEWTON = 6
QUICK_LENGTHS = 2
#: Backward-Euler gradient-flow steps allowed for one snap.
MAX_FLOW_STEPS = 4000
#: Accepted flow steps after a failed Newton try before the next one (unless the residual has
#: fallen 4-fold since).
FLOW_RETRY = 50
#: The flow's merit E + λ·h + ρ/2 |h|² takes ρ = FLOW_PENALTY · k/l² (`QuasiStaticChain._flow`).
FLOW_PENALTY = 1.0
#: Residual tolerances: torque residual relative to the chain's torque scale, and the gripper
#: constraint relative to L.
TORQUE_TOL = 1e-9
#: A full Newton step smaller than this times sqrt(tolerance) (rad) on every angle ends the
#: iteration: the residual afterwards is of the order of the step's square.
CONVERGED_STEP = 0.3
POSITION_TOL = 1e-12


class QuasiStaticChain:
    """The chain of `RodChain` at static equilibrium: same constructor, same readouts.

    The constructor takes `RodChain`'s arguments so that `RodSim` can rebuild either engine's
    chain the same way (a grasp slip, a movable clamp); the dynamics-only ones (`dt`,
    `iterations`, `damping_rate`, `inertia_radius`, `segment_inertia`) do not enter a settled
    shape and are kept only for the record. `step(target, clamp_target)` moves the end poses to
    the given ones and solves the new equilibrium by continuation (one call = one settled move).

    Args:
        length, bending_stiffness, mass_per_length, segments, clamp_pose, gripped, tip_force,
        gravity, movable_clamp: as for `RodChain`.
        table_friction: must be None (not supported: see the module docstring).
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
        if tip_force is not None and gripped:
            raise ValueError("a tip force needs a free end (gripped=False)")
        if table_friction is not None:
            raise ValueError("the quasi-static engine has no table friction")
        if int(segments) < 2:
            raise ValueError("the quasi-static chain needs at least 2 segments")
        self.length = float(length)
        self.segments = int(segments)
        self.seg_length = self.length / self.segments
        self.dt = float(dt)
        self.bending_stiffness = float(bending_stiffness)
        self.mass_per_length = float(mass_per_length)
        self.gravity = (float(gravity[0]), float(gravity[1]))
        self.table_friction: float | None = None
        self.table_gravity = float(table_gravity)
        self.segment_inertia = segment_inertia
        self.tip_force = None if tip_force is None else np.asarray(tip_force, dtype=float)
        self.gripped = bool(gripped)
        self.clamp_pose = np.asarray(clamp_pose, dtype=float).copy()
        self._clamp = self.clamp_pose.copy()
        #: Not None when the clamp may move (the `RodChain` attribute RodSim tests).
        self.clamp_body: object | None = True if movable_clamp else None
        self.gripper: object | None = True if gripped else None
        n, seg = self.segments, self.seg_length
        self.theta = np.full(n, self._clamp[2])
        self.lam = np.zeros(2)
        self._grip = np.array(
            [
                self._clamp[0] + n * seg * math.cos(self._clamp[2]),
                self._clamp[1] + n * seg * math.sin(self._clamp[2]),
                self._clamp[2],
            ]
        )
        self.steps = 0
        #: The chain may be straight (built so, or placed): Newton cannot start from there.
        self._maybe_straight = True
        self.converged = True
        self.snaps = 0
        self.snap_notes: list[str] = []
        self.newton_iterations = 0
        #: Backward-Euler steps the snap flows took (diagnostics, `benchmarks/bench_snap.py`).
        self.flow_steps = 0
        #: Convergence tolerance on the torque residual, relative to the chain's torque scale.
        self.torque_tol = TORQUE_TOL
        # Gravity weights: segment j's angle moves the centres of j (by l/2) and of all after it.
        self._weights = n - np.arange(n) - 0.5

    # ------------------------------------------------------------------ the model
    @property
    def segment_mass(self) -> float:
        return self.mass_per_length * self.seg_length

    def _stiffness(self) -> tuple[float, float]:
        k = self.bending_stiffness / self.seg_length
        return k, 2.0 * k

    def _torque_scale(self) -> float:
        """EI/L + ρA|g|L² + |P|L: the size of the torques, for the residual tolerance."""
        key = (self.bending_stiffness, self.mass_per_length)
        cached = self.__dict__.get("_scale_cache")
        if cached is None or cached[0] != key:
            g = math.hypot(*self.gravity)
            tip = 0.0 if self.tip_force is None else float(np.hypot(*self.tip_force))
            scale = (
                self.bending_stiffness / self.length
                + self.mass_per_length * g * self.length**2
                + tip * self.length
            )
            cached = (key, scale)
            self._scale_cache = cached
        return cached[1]

    def _model(self) -> _Model:
        """The constant parts of the system for the current EI, ρA and tolerance (cached)."""
        m = self.__dict__.get("_model_cache")
        key = (self.bending_stiffness, self.mass_per_length, self.torque_tol)
        if m is None or m.key != key:
            m = _Model(self, key)
            self._model_cache = m
        return m

    def _eval(
        self, theta: np.ndarray, l0: float, l1: float, m: _Model, ends: tuple
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        """(∇_θ L, main diagonal of H, z = e^{iθ} (N,) complex, h_x, h_y) at θ, λ = (l0, l1);
        `ends` = (θ_clamp, θ_gripper, gripper x − clamp x, gripper y − clamp y). H's
        off-diagonal is the constant −k; the constraint Jacobian is A = l (−sin θ, cos θ).

        Few numpy calls on purpose: at N = 50 a call costs more than its O(N) algebra. The
        springs' gradient is τ_j − τ_{j+1} with τ = k_j Δθ over the padded angles
        [θ_c, θ, θ_g] (k_j = k_e at the two ends, 0 at a free end); the body loads (gravity at
        the centres, a dead tip load) and the constraint's λ·A are all of the form
        α_j cos θ_j + β_j sin θ_j, in the gradient and in H's diagonal alike, so one complex
        product ζ·z gives both (its imaginary part the gradient, its real part the diagonal)."""
        pad = m.pad
        pad[0] = ends[0]
        m.pad_mid[...] = theta
        pad[-1] = ends[1]
        tau = m.tau
        np.subtract(m.pad_hi, m.pad_lo, out=tau)
        tau *= m.kk
        grad = np.subtract(m.tau_lo, m.tau_hi)
        # e^{iθ} as exp of a complex buffer whose real part stays 0 and whose imaginary part
        # is θ + 0: the bits of exp(θ·1j), whose imaginary part is θ·1 + 0·0 (a −0 angle gives
        # +0 there), without the complex temporary.
        np.add(theta, 0.0, out=m.zarg_imag)
        z = np.exp(m.zarg)
        seg = m.seg
        lam = complex(-seg * l0, seg * l1)
        prod = z * lam if m.wg is None else (m.wg + lam) * z
        grad += prod.imag
        diag = np.add(m.diag0, prod.real)
        if not self.gripped:
            return grad, diag, z, 0.0, 0.0
        zs = complex(_SUM(z))
        return grad, diag, z, seg * zs.real - ends[2], seg * zs.imag - ends[3]

    def _grad_hess(
        self, theta: np.ndarray, lam: np.ndarray, grip: np.ndarray, clamp: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(∇_θ L, main diagonal of H, A (2, N), h (2,)); H's off-diagonal is the constant −k."""
        l0, l1 = lam.tolist()
        grad, diag, z, h0, h1 = self._eval(theta, l0, l1, self._model(), _ends(grip, clamp))
        a = np.empty((2, self.segments))
        np.multiply(z.imag, -self.seg_length, out=a[0])  # A = l (−sin θ_j, cos θ_j)
        np.multiply(z.real, self.seg_length, out=a[1])
        return grad, diag, a, np.array([h0, h1])

    def _offdiag(self) -> np.ndarray:
        """H's constant off-diagonal −k (N−1,) (do not modify)."""
        return self._model().off

    def _kkt_solve(
        self, diag: np.ndarray, a: np.ndarray, rhs_theta: np.ndarray, rhs_h: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Solve [H Aᵀ; A 0] [x; y] = [rhs_theta; rhs_h] (rhs_theta (N,) or (N, q)) with one
        tridiagonal solve of H against [rhs, Aᵀ] and the 2×2 Schur complement S = A H⁻¹ Aᵀ.

        Returns (x, y, S); y and S are None for a free-ended chain (no constraint). The
        general form (the gradient flow, the Jacobian); Newton's steps use `_newton_step`."""
        if not self.gripped:
            return self._tridiag(diag, rhs_theta), None, None
        q = 1 if rhs_theta.ndim == 1 else rhs_theta.shape[1]
        rhs = np.empty((self.segments, q + 2), order="F")
        rhs[:, :q] = rhs_theta.reshape(self.segments, q)
        rhs[:, q:] = a.T
        sol = self._tridiag(diag, rhs)
        hy, hinv_at = sol[:, :q], sol[:, q:]
        both = _mat2(a, sol)  # [A H⁻¹ rhs | S]
        schur = both[:, q:]
        # A x = rhs_h with x = H⁻¹ (rhs − Aᵀ y)  ->  S y = A H⁻¹ rhs − rhs_h (2×2, explicit).
        b = both[:, :q] - rhs_h.reshape(2, q)
        (s00, s01), (s10, s11) = schur.tolist()
        det = s00 * s11 - s01 * s10
        if det == 0.0 or det != det:
            raise np.linalg.LinAlgError("singular Schur complement")
        y = np.array([s11 * b[0] - s01 * b[1], s00 * b[1] - s10 * b[0]]) / det
        x = hy - hinv_at[:, :1] * y[0] - hinv_at[:, 1:] * y[1]
        if rhs_theta.ndim == 1:
            return x[:, 0], y[:, 0], schur
        return x, y, schur

    def _tridiag(self, diag: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """H⁻¹ rhs for H = tridiag(−k, diag, −k) (LAPACK gtsv, partial pivoting)."""
        off = self._model().off
        # f2py copies every argument it is not told to overwrite: the inputs stay intact.
        _, _, _, x, info = _gtsv()(off, diag, off, rhs)
        if info != 0:
            raise np.linalg.LinAlgError(f"singular tridiagonal system (gtsv info {info})")
        return x

    def _newton_step(
        self, diag: np.ndarray, z: np.ndarray, grad: np.ndarray, h0: float, h1: float, m: _Model
    ) -> tuple[np.ndarray, float, float, tuple | None]:
        """One Newton step of the KKT system: (dθ, dλ_x, dλ_y, what the solve left over).

        One gtsv call solves H against four columns at once: −∇L, the two rows of Aᵀ and the
        unit vector e_{N−1}; the 2×2 Schur complement S = A H⁻¹ Aᵀ and the four products
        A H⁻¹(·) come from one complex sum (A = l (−Im, Re) of e^{iθ}). Left over, for the
        stability check and the tangent predictor: (S, A H⁻¹ e_{N−1}, the solution columns)."""
        if not self.gripped:
            return self._tridiag(diag, -grad), 0.0, 0.0, None
        seg, off = m.seg, m.off
        np.negative(grad, out=m.rhs_grad)
        np.multiply(z.imag, -seg, out=m.rhs_a0)
        np.multiply(z.real, seg, out=m.rhs_a1)
        _, _, _, sol, info = m.gtsv(off, diag, off, m.rhs)
        if info != 0:
            raise np.linalg.LinAlgError(f"singular tridiagonal system (gtsv info {info})")
        r0, r1, r2, r3 = _SUM(z[:, None] * sol, axis=0).tolist()  # Σ e^{iθ} (H⁻¹ columns)
        s00, s01 = -seg * r1.imag, -seg * r2.imag
        s10, s11 = seg * r1.real, seg * r2.real
        det = s00 * s11 - s01 * s10
        if det == 0.0 or det != det:
            raise np.linalg.LinAlgError("singular Schur complement")
        # A x = −h with x = H⁻¹ (−∇L − Aᵀ y)  ->  S y = A H⁻¹(−∇L) + h.
        b0, b1 = h0 - seg * r0.imag, h1 + seg * r0.real
        y0 = (s11 * b0 - s01 * b1) / det
        y1 = (s00 * b1 - s10 * b0) / det
        cols = sol.T
        dth = cols[0] - cols[1] * y0
        dth -= cols[2] * y1
        return dth, y0, y1, ((s00, s01, s10, s11), (-seg * r3.imag, seg * r3.real), cols)

    def _measures(self, grad: np.ndarray, h0: float, h1: float, m: _Model) -> tuple[float, float]:
        """(residual in units of the tolerance (<= 1: converged), merit for the line search)."""
        sq = grad * grad
        g = math.sqrt(float(_MAX(sq))) / m.torque_unit
        hh = (abs(h0) + abs(h1)) / m.position_unit
        merit = float(_SUM(sq)) / m.scale2 + (h0 * h0 + h1 * h1) / m.seg2
        return max(g, hh), merit

    def _newton(
        self,
        theta: np.ndarray,
        lam: np.ndarray,
        grip: np.ndarray,
        clamp: np.ndarray,
        iterations: int = MAX_NEWTON,
        lengths: int = 30,
    ) -> tuple[np.ndarray, np.ndarray, bool, tuple]:
        """Newton with backtracking on the KKT residual; (θ, λ, converged, hess) where hess =
        (diag of H, e^{iθ}, the last solve's left-overs or None) at the last linearisation.
        At most `iterations` iterations, each trying at most `lengths` step lengths 1, 1/2, ...
        (fewer: the continuation's tries after a failed one, `_quick_newton`)."""
        m = self._model()
        ends = _ends(grip, clamp)
        l0, l1 = lam.tolist()
        # The methods and constants as locals: a step is a few dozen small calls, and at N = 50
        # their Python overhead is as large as their arithmetic.
        evaluate, measures, newton_step = self._eval, self._measures, self._newton_step
        converged_step, absolute = m.converged_step, np.abs
        grad, diag, z, h0, h1 = evaluate(theta, l0, l1, m, ends)
        res, merit = measures(grad, h0, h1, m)
        for _ in range(iterations):
            if res <= 1.0:
                return theta, np.array([l0, l1]), True, (diag, z, None)
            self.newton_iterations += 1
            try:
                dth, d0, d1, info = newton_step(diag, z, grad, h0, h1, m)
            except (np.linalg.LinAlgError, ValueError):
                return theta, np.array([l0, l1]), False, (diag, z, None)
            top = float(_MAX(absolute(dth)))
            if top != top:
                return theta, np.array([l0, l1]), False, (diag, z, None)
            if top < converged_step:
                # Quadratic convergence: the residual after this step is O(step²), far below
                # the tolerance; the Hessian at θ stands for the one at θ + dθ.
                return theta + dth, np.array([l0 + d0, l1 + d1]), True, (diag, z, info)
            step = 1.0
            for _ in range(lengths):
                th2 = theta + step * dth if step != 1.0 else theta + dth
                m0, m1 = l0 + step * d0, l1 + step * d1
                grad2, diag2, z2, g0, g1 = evaluate(th2, m0, m1, m, ends)
                res2, merit2 = measures(grad2, g0, g1, m)
                if res2 <= 1.0 or merit2 < (1.0 - 1e-4 * step) * merit:
                    break
                step *= 0.5
            else:
                return theta, np.array([l0, l1]), False, (diag, z, None)
            theta, l0, l1, grad, diag, z, h0, h1 = th2, m0, m1, grad2, diag2, z2, g0, g1
            res, merit = res2, merit2
        return theta, np.array([l0, l1]), res <= 1.0, (diag, z, None)

    def stable(
        self,
        theta: np.ndarray | None = None,
        lam: np.ndarray | None = None,
        grip: np.ndarray | None = None,
        clamp: np.ndarray | None = None,
        hessian: tuple | None = None,
    ) -> bool:
        """Whether the equilibrium (default: the current one) is stable: the Hessian reduced to
        the tangent space of the end-position constraint is positive definite.

        By Sylvester's law of inertia on [H Aᵀ; A 0] = [I 0; A H⁻¹ I] [H 0; 0 −S] [...]ᵀ, that
        is: (negative eigenvalues of H) + (positive eigenvalues of S = A H⁻¹ Aᵀ) = 2; the
        negative eigenvalues of the tridiagonal H are its negative L D Lᵀ pivots.
        `hessian`: (diag, A) already computed at this state."""
        if hessian is None:
            theta = self.theta if theta is None else theta
            lam = self.lam if lam is None else lam
            grip = self._grip if grip is None else grip
            clamp = self._clamp if clamp is None else clamp
            _, diag, a, _ = self._grad_hess(theta, lam, grip, clamp)
        else:
            diag, a = hessian
        negative = self._negative_pivots(diag)
        if negative is None:
            return False
        if not self.gripped:
            return negative == 0
        try:
            hinv_at = self._tridiag(diag, a.T)
        except (np.linalg.LinAlgError, ValueError):
            return False
        (s00, s01), (s10, s11) = _mat2(a, hinv_at).tolist()
        return negative + _positive_eigenvalues(s00, s01, s10, s11) == 2

    def _stable_newton(self, hess: tuple) -> bool:
        """`stable` at the end of `_newton`, reusing its last solve's Schur complement."""
        diag, z, info = hess
        if info is None:
            a = np.empty((2, self.segments))
            np.multiply(z.imag, -self.seg_length, out=a[0])
            np.multiply(z.real, self.seg_length, out=a[1])
            return self.stable(hessian=(diag, a))
        negative = self._negative_pivots(diag)
        if negative is None:
            return False
        if not self.gripped:
            return negative == 0
        return negative + _positive_eigenvalues(*info[0]) == 2

    def _negative_pivots(self, diag: np.ndarray) -> int | None:
        """How many pivots of H = L D Lᵀ (tridiag(−k, diag, −k)) are negative (None: a zero
        or NaN pivot); > 2 is returned as 3 (unstable whatever S)."""
        k = self._model().k
        off2 = k * k
        values = iter(diag.tolist())
        pivot = next(values)
        negative = pivot < 0.0
        try:
            for di in values:
                pivot = di - off2 / pivot
                if pivot < 0.0:
                    negative += 1
                    if negative > 2:
                        return 3
        except ZeroDivisionError:
            return None
        if pivot == 0.0 or pivot != pivot:
            return None
        return int(negative)

    def _predict(self, grip: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Tangent predictor: the current equilibrium plus (dθ/dg, dλ/dg) · (grip − g), from the
        implicit-function theorem on the KKT system (see `pose_jacobian`), with the columns the
        last Newton solve left over; None when there are none for this state, or the
        prediction turns a segment by more than `MAX_BRANCH_STEP`."""
        tangent = self.__dict__.get("_tangent")
        if tangent is None or tangent[0] is not self.theta:
            return None
        m = self._model()
        if tangent[1] != m.key:
            return None
        (s00, s01, s10, s11), (aw0, aw1), cols = tangent[2]
        gx, gy, gt = grip.tolist()
        ox, oy, ot = self._grip.tolist()
        r = m.ke * (gt - ot)
        b0, b1 = r * aw0 - (gx - ox), r * aw1 - (gy - oy)
        det = s00 * s11 - s01 * s10
        y0 = (s11 * b0 - s01 * b1) / det
        y1 = (s00 * b1 - s10 * b0) / det
        dth = cols[3] * r - cols[1] * y0
        dth -= cols[2] * y1
        if not float(_MAX(np.abs(dth))) <= MAX_BRANCH_STEP:
            return None
        l0, l1 = self.lam.tolist()
        return self.theta + dth, np.array([l0 + y0, l1 + y1])

    def energy(
        self,
        theta: np.ndarray | None = None,
        grip: np.ndarray | None = None,
        clamp: np.ndarray | None = None,
    ) -> float:
        """Potential energy (J) of the chain: springs, gravity, dead tip load."""
        theta = self.theta if theta is None else theta
        grip = self._grip if grip is None else grip
        clamp = self._clamp if clamp is None else clamp
        k, ke = self._stiffness()
        e = 0.5 * ke * (theta[0] - clamp[2]) ** 2 + 0.5 * k * float(np.sum(np.diff(theta) ** 2))
        if self.gripped:
            e += 0.5 * ke * (grip[2] - theta[-1]) ** 2
        pts = self._points(theta, clamp)
        if self.gravity != (0.0, 0.0):
            centres = 0.5 * (pts[:-1] + pts[1:])
            gx, gy = self.gravity
            e -= self.segment_mass * float(np.sum(centres[:, 0] * gx + centres[:, 1] * gy))
        if self.tip_force is not None:
            e -= float(self.tip_force[0] * pts[-1, 0] + self.tip_force[1] * pts[-1, 1])
        return e

    # ------------------------------------------------------------------ solving
    def equilibrate(self) -> bool:
        """Solve the equilibrium at the current end poses from the current shape (free end:
        the cantilever). Returns whether it converged to a stable equilibrium; a Newton failure
        or an unstable result goes through the gradient flow (a snap, noted)."""
        return self._solve_to(self._grip.copy(), self._clamp.copy())

    def step(
        self, target: np.ndarray | None = None, clamp_target: np.ndarray | None = None
    ) -> None:
        """Move the gripper to `target` and the clamp to `clamp_target` (None: stay), along
        their straight line, following the equilibrium path; one call = one settled move."""
        if clamp_target is not None and self.clamp_body is None:
            raise ValueError("this chain's clamp is fixed (built with movable_clamp=False)")
        grip = self._grip.copy() if target is None else np.asarray(target, dtype=float).copy()
        if not self.gripped:
            grip = self._grip.copy()
        clamp = (
            self._clamp.copy()
            if clamp_target is None
            else np.asarray(clamp_target, dtype=float).copy()
        )
        self.converged = self._solve_to(grip, clamp)
        self.steps += 1

    def _solve_to(self, grip: np.ndarray, clamp: np.ndarray) -> bool:
        if not (self._finite() and math.isfinite(sum(self.lam.tolist()))):
            self._grip, self._clamp = grip, clamp
            return False
        g0, c0 = self._grip, self._clamp
        # Unchanged end poses (a change of the rod itself, or a free end): there is no path to
        # sub-step along, so where Newton does not reach a stable state near the old one the
        # overdamped gradient flow from the old shape is the rod's response, not a snap.
        clamp_fixed = clamp.tolist() == c0.tolist()
        moving = not (clamp_fixed and grip.tolist() == g0.tolist())
        done, frac = 0.0, 1.0
        ok = True
        quick = False  # after a failed try: Newton gives up early (`_patience`)
        while done < 1.0:
            f = min(1.0, done + frac)
            if f == 1.0:
                g, c = grip, clamp
            else:
                g = g0 + (grip - g0) * f
                c = c0 + (clamp - c0) * f
            start = self.theta  # never modified in place: every update makes a new array
            guesses: list[tuple[np.ndarray, np.ndarray]] = [(start, self.lam)]
            straight = self.gripped and self._maybe_straight and float(np.ptp(start)) < 1e-9
            if straight:
                # A straight chain: the end-position constraint is degenerate along the rod
                # (its Jacobian has rank 1), so Newton cannot start there; start from a smooth
                # curve through both end poses instead.
                guesses = [(self._hermite_guess(g, c), self.lam)]
            elif self.gripped and clamp_fixed:
                # Along the path, start from the tangent predictor (1-2 Newton iterations
                # instead of 3-5); where it does not lead to an accepted state, from the old one.
                predicted = self._predict(g)
                if predicted is not None:
                    guesses.insert(0, predicted)
            newton, starts = self._patience(quick and not straight, moving, done, frac, f)
            for guess, lam0 in guesses[:starts]:
                theta, lam, conv, hess = newton(guess, lam0, g, c)
                good = (
                    conv
                    and float(_MAX(np.abs(theta - self.theta))) <= MAX_BRANCH_STEP
                    and self._stable_newton(hess)
                )
                if good:
                    break
            if good:
                self.theta, self.lam, self._grip, self._clamp = theta, lam, g, c
                self._tangent = None if hess[2] is None else (theta, self._model().key, hess[2])
                self._maybe_straight = False
                done = f
                frac = min(2.0 * frac, 1.0)
                continue
            if moving and frac > MIN_FRACTION:
                quick = True
                frac *= 0.5
                # Where the halved sub-step still reaches the end of the move (done + frac >= 1:
                # after a success the sub-step doubles past it), the next try would be this one
                # again, from the same state to the same end poses, and fail the same way (a
                # near-fold try costs ~1.5 ms): skip it as failed. The same sub-steps, states
                # and snap as without the skip, about half the Newton solves before a snap.
                while f == 1.0 and done + frac >= 1.0 and frac > MIN_FRACTION:
                    frac *= 0.5
                if not (f == 1.0 and done + frac >= 1.0):
                    continue
            # The path has lost stability here: follow the gradient flow to a stable state.
            theta, lam, conv = self._flow(self.theta.copy(), self.lam.copy(), g, c)
            jump = float(np.max(np.abs(theta - self.theta)))
            if not moving:
                self.theta, self.lam = theta, lam
                ok = conv
                break
            self.snaps += 1
            self.snap_notes.append(
                f"{SNAP_NOTE} the equilibrium path lost stability at gripper "
                f"{[round(float(v), 5) for v in g]}, clamp {[round(float(v), 5) for v in c]}; "
                f"followed the gradient flow to the next stable equilibrium (largest segment "
                f"turn {jump:.3f} rad{'' if conv else ', NOT converged'})"
            )
            self.theta, self.lam, self._grip, self._clamp = theta, lam, g, c
            done = f
            ok = ok and conv
            if not conv:
                break
        self._grip, self._clamp = grip, clamp
        return ok

    def _patience(
        self, quick: bool, moving: bool, done: float, frac: float, f: float
    ) -> tuple[Callable[..., tuple[np.ndarray, np.ndarray, bool, tuple]], int]:
        """(the Newton a continuation try runs, from how many of its starts). In full
        (`_newton`, from the tangent predictor and then from the last state) for a step's
        first try and for every try whose failure starts the gradient flow (a sub-step of
        `MIN_FRACTION`, or the move's end within it), so that a fold is declared exactly where
        the full tries fail, as before; after a failed try (`quick`) the others run
        `_quick_newton` from the first start only.

        Near a fold nearly every try after the first fails, and a full Newton fails slowly
        (~10 iterations with ~15 line-search evaluations each, ~1.5 ms); a try that succeeds
        there takes 1-4 full Newton steps. Giving up early changes no snap or equilibrium: a
        try given up that would have succeeded is only halved and tried again from the same
        stable state, and the fold is declared by the full tries only. Not from a straight
        chain (the Hermite guess, `_solve_to`): there a smaller sub-step is the harder one (the
        end-position constraint is nearer degenerate), so every try runs in full, as before;
        giving up early there left a heavy stiff rod unable to reach its home pose."""
        final = not moving or frac <= MIN_FRACTION or (f == 1.0 and done + MIN_FRACTION >= 1.0)
        return (self._newton, 2) if final or not quick else (self._quick_newton, 1)

    def _quick_newton(
        self, theta: np.ndarray, lam: np.ndarray, grip: np.ndarray, clamp: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, bool, tuple]:
        """`_newton` giving up after `QUICK_NEWTON` iterations or when the step lengths 1 and
        1/2 (`QUICK_LENGTHS`) do not lower the residual (`_patience`). Also the flow's Newton
        tries on the way: from the ghost of the fold a full Newton failed slowly (about half a
        flow's CPU time until 2026-12-02; `reference_solve_to` still runs it so); near the
        equilibrium Newton takes full steps, and a quick Newton that converges is the full one,
        step for step."""
        return self._newton(theta, lam, grip, clamp, QUICK_NEWTON, QUICK_LENGTHS)

    def _flow(
        self, theta: np.ndarray, lam: np.ndarray, grip: np.ndarray, clamp: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, bool]:
        """Overdamped gradient flow θ' = −P ∇E on the constraint manifold, by backward-Euler
        steps (each a KKT solve with H + I/τ) to the next stable equilibrium; ends with Newton
        (`_quick_newton`: see there) once the state is stable.

        A step is accepted when it does not raise the augmented Lagrangian
        E + λ'·h + ρ/2 |h|² with the step's own multipliers λ' and a mild ρ = k/l² (the merit the
        KKT step is a descent step for: E alone, or with a stiff penalty, also counts the
        constraint's second-order error λ·h, which rejected every step longer than ~0.01 rad).
        τ doubles after an accepted step and halves after a rejected one (pseudo-transient
        continuation). Validated against the previous flow (`rodctl/sim/flow_reference.py`) on
        real snap states: the same equilibrium, `tests/sim/test_snap_flow.py`."""
        m = self._model()
        k = m.k
        rho = FLOW_PENALTY * k / m.seg2
        tau = 1.0 / k
        ends = _ends(grip, clamp)
        l0, l1 = lam.tolist()
        grad, diag, z, h0, h1 = self._eval(theta, l0, l1, m, ends)
        e0 = self._flow_energy(z, m)
        # Newton is tried once the flow is near a stable state, then again only after the
        # residual has fallen 4-fold or FLOW_RETRY accepted steps later.
        retry_res, since_try = math.inf, 0
        for _ in range(MAX_FLOW_STEPS):
            self.flow_steps += 1
            try:
                # One backward-Euler step: the KKT solve with H + I/τ.
                dth, d0, d1, _ = self._newton_step(diag + 1.0 / tau, z, grad, h0, h1, m)
            except (np.linalg.LinAlgError, ValueError):
                tau *= 0.5
                if tau * k < 1e-12:
                    break
                continue
            th2, n0, n1 = theta + dth, l0 + d0, l1 + d1
            grad2, diag2, z2, g0, g1 = self._eval(th2, n0, n1, m, ends)
            e2 = self._flow_energy(z2, m)
            before = e0 + n0 * h0 + n1 * h1 + 0.5 * rho * (h0 * h0 + h1 * h1)
            after = e2 + n0 * g0 + n1 * g1 + 0.5 * rho * (g0 * g0 + g1 * g1)
            if math.isfinite(after) and after <= before + 1e-15 * abs(before):
                theta, l0, l1, grad, diag, z, h0, h1, e0 = th2, n0, n1, grad2, diag2, z2, g0, g1, e2
                tau *= 2.0
                res = self._measures(grad, h0, h1, m)[0]
                since_try += 1
                due = res < 0.25 * retry_res or since_try >= FLOW_RETRY
                if res < 1e6 and due and self._stable_newton((diag, z, None)):
                    lam = np.array([l0, l1])
                    th3, lam3, conv, hess = self._quick_newton(theta, lam, grip, clamp)
                    if conv and self._stable_newton(hess):
                        return th3, lam3, True
                    retry_res, since_try = res, 0
            else:
                tau *= 0.5
                if tau * k < 1e-12:
                    break
        return theta, np.array([l0, l1]), False

    def _flow_energy(self, z: np.ndarray, m: _Model) -> float:
        """The chain's energy, up to a constant of the end poses, at the angles `_eval` was last
        called with (its padded angles are still in `m.pad`; z = e^{iθ}): the springs
        ½ Σ k_j Δθ_j² plus the body loads −Σ Re(w_j e^{iθ_j}) (gravity at the centres, the tip
        load: `energy` without the terms that do not depend on θ)."""
        d = np.subtract(m.pad_hi, m.pad_lo)
        e = 0.5 * float(_SUM(m.kk * d * d))
        if m.wg is not None:
            e -= float(_SUM((m.wg * z).real))
        return e

    def _hermite_guess(self, grip: np.ndarray, clamp: np.ndarray) -> np.ndarray:
        """Segment angles along the cubic Hermite curve between the two end poses."""
        t = (np.arange(self.segments) + 0.5) / self.segments
        m0 = self.length * np.array([math.cos(clamp[2]), math.sin(clamp[2])])
        m1 = self.length * np.array([math.cos(grip[2]), math.sin(grip[2])])
        d = grip[:2] - clamp[:2]
        # P'(t) of the Hermite cubic.
        dp = (
            np.outer(6 * t * t - 6 * t, -d)
            + np.outer(3 * t * t - 4 * t + 1, m0)
            + np.outer(3 * t * t - 2 * t, m1)
        )
        ang = np.unwrap(np.arctan2(dp[:, 1], dp[:, 0]))
        return ang + 2 * math.pi * round((clamp[2] - ang[0]) / (2 * math.pi))

    # ------------------------------------------------------------------ the true Jacobian
    def pose_jacobian(self) -> tuple[np.ndarray, np.ndarray]:
        """(dθ/dg (N, 3), dλ/dg (2, 3)) of the current equilibrium with respect to the gripper
        pose g = [x, y, θ_g], by the implicit-function theorem on the KKT system: one more
        banded solve with three right-hand sides.

        F(θ, λ; g) = 0 with F = (∇_θ E + Aᵀλ, h): ∂F/∂g has −k_e in row N−1 for θ_g (the gripper
        spring) and −I in the h rows for (x, y), so [H Aᵀ; A 0] [dθ; dλ] = −∂F/∂g.
        """
        if not self.gripped:
            raise ValueError("a free-ended chain has no gripper pose")
        _, diag, a, _ = self._grad_hess(self.theta, self.lam, self._grip, self._clamp)
        _, ke = self._stiffness()
        rhs_t = np.zeros((self.segments, 3))
        rhs_t[-1, 2] = ke
        rhs_h = np.zeros((2, 3))
        rhs_h[0, 0] = 1.0
        rhs_h[1, 1] = 1.0
        dth, dlam, _ = self._kkt_solve(diag, a, rhs_t, rhs_h)
        assert dlam is not None  # a gripped chain has its multipliers
        return dth, dlam

    def joint_points_jacobian(self) -> np.ndarray:
        """(N+1, 2, 3) d(joint points)/d(gripper pose): p_k = p_0 + l Σ_{j<k} t_j."""
        dth, _ = self.pose_jacobian()
        seg = self.seg_length
        c, s = np.cos(self.theta), np.sin(self.theta)
        out = np.zeros((self.segments + 1, 2, 3))
        out[1:, 0, :] = np.cumsum(-seg * s[:, None] * dth, axis=0)
        out[1:, 1, :] = np.cumsum(seg * c[:, None] * dth, axis=0)
        return out

    # ------------------------------------------------------------------ readouts (RodChain's)
    def _points(self, theta: np.ndarray, clamp: np.ndarray) -> np.ndarray:
        seg = self.seg_length
        pts = np.empty((self.segments + 1, 2))
        pts[0] = clamp[:2]
        pts[1:, 0] = clamp[0] + np.cumsum(seg * np.cos(theta))
        pts[1:, 1] = clamp[1] + np.cumsum(seg * np.sin(theta))
        return pts

    def _tangents(self) -> np.ndarray:
        """e^{iθ} (N,) complex of the current angles (cached per state: the readouts after a
        step share it)."""
        cached = self.__dict__.get("_z_cache")
        if cached is None or cached[0] is not self.theta:
            cached = (self.theta, np.exp(1j * self.theta))
            self._z_cache = cached
        return cached[1]

    def _finite(self) -> bool:
        """Whether the angles are all finite (their sum is: NaN and inf propagate)."""
        return math.isfinite(float(_SUM(self.theta)))

    def _joints(self) -> np.ndarray:
        """The joint points of the current state (cached per state: do not modify)."""
        cached = self.__dict__.get("_points_cache")
        clamp = self._clamp.tolist()
        if cached is None or cached[0] is not self.theta or cached[1] != clamp:
            # p_0 = clamp, p_{k+1} = p_k + l e^{iθ_k}, as one complex cumulative sum.
            w = np.empty(self.segments + 1, dtype=np.complex128)
            w[0] = complex(clamp[0], clamp[1])
            np.multiply(self._tangents(), self.seg_length, out=w[1:])
            np.add.accumulate(w, out=w)  # np.cumsum's loop without its Python layer
            cached = (self.theta, clamp, w.view(np.float64).reshape(self.segments + 1, 2))
            self._points_cache = cached
        return cached[2]

    def joint_points(self) -> np.ndarray:
        """(N+1, 2) centreline at the joints, clamp end first (exact: the chain is closed)."""
        return self._joints().copy()

    def segment_states(self) -> np.ndarray:
        """(N, 3) segment centres and angles [x, y, angle], world frame."""
        pts = self.joint_points()
        return np.column_stack([0.5 * (pts[:-1] + pts[1:]), self.theta])

    def segment_velocities(self) -> np.ndarray:
        """(N, 3) zeros: a settled equilibrium does not move (NaN if the state is not finite)."""
        bad = not np.all(np.isfinite(self.theta))
        return np.full((self.segments, 3), math.nan if bad else 0.0)

    def joint_gaps(self) -> np.ndarray:
        """(N+1,) or (N,): the interior and clamp joints are closed by construction; the last
        entry is how far the chain's end is from the gripper (the constraint residual)."""
        gaps = np.zeros(self.segments + (1 if self.gripped else 0))
        if self.gripped:
            gaps[-1] = self._end_gap()
        if not self._finite():
            gaps[:] = math.nan
        return gaps

    def _end_gap(self) -> float:
        """How far the chain's end is from the gripper (m): `joint_gaps`' last entry."""
        ex, ey = self._joints()[-1].tolist()
        gx, gy, _ = self._grip.tolist()
        return math.hypot(ex - gx, ey - gy)

    def max_speed(self) -> float:
        return 0.0 if self._finite() else math.nan

    def kinetic_energy(self) -> float:
        return self.max_speed()

    def current_clamp_pose(self) -> np.ndarray:
        return self._clamp.copy()

    def gripper_pose(self) -> np.ndarray:
        """(3,) gripper pose; the free end's pose without a gripper."""
        if not self.gripped:
            end = self.joint_points()[-1]
            return np.array([end[0], end[1], self.theta[-1]])
        return self._grip.copy()

    def place(self, states: np.ndarray, gripper_pose: Sequence[float] | None = None) -> None:
        """Put the chain into a given shape (`RodChain.place`): the segment angles are kept,
        the positions follow from them; the multipliers restart at 0."""
        states = np.asarray(states, dtype=float)
        if states.shape != (self.segments, 3):
            raise ValueError(f"states must be ({self.segments}, 3), got {states.shape}")
        self.theta = states[:, 2].copy()
        self.lam = np.zeros(2)
        self._maybe_straight = True
        if gripper_pose is not None and self.gripped:
            self._grip = np.asarray(gripper_pose, dtype=float).copy()

    # ------------------------------------------------------------------ changing the rod
    def set_bending_stiffness(self, bending_stiffness: float) -> None:
        if not (math.isfinite(bending_stiffness) and bending_stiffness > 0):
            raise ValueError(f"bending stiffness must be finite and > 0, got {bending_stiffness}")
        self.lam = self.lam * (bending_stiffness / self.bending_stiffness)
        self.bending_stiffness = float(bending_stiffness)

    def set_mass_per_length(self, mass_per_length: float) -> None:
        if not (math.isfinite(mass_per_length) and mass_per_length > 0):
            raise ValueError(f"mass per length must be finite and > 0, got {mass_per_length}")
        self.mass_per_length = float(mass_per_length)

    def set_table_friction(self, mu: float) -> None:
        raise ValueError("the quasi-static engine has no table friction")


class QuasiStaticSim(RodSim):
    """`RodSim` on the quasi-static engine: the same policy layer (workspace, speed limits,
    clipping, home pose, events, divergence), the chain's equilibrium solved directly.

    Built by `RodSim(cfg)` when `cfg.engine == "quasistatic"`. One control step is one
    continuation solve (`QuasiStaticChain.step`); the simulated clock advances by
    `control_period` per step. `settled` is False when Newton and the gradient flow could not
    reach a stable equilibrium; a snap-through is counted in `ApplyResult.snaps` with a note.
    """

    # The quasi-static chain stands in for pymunk's `RodChain` (it has every member that
    # RodSim's shared code uses) without being a subclass: `_qs` is it, typed.
    _chain_type = QuasiStaticChain  # type: ignore[assignment]

    def _build_chain(self, cfg: RodConfig) -> None:
        self.dt = float(cfg.control_period)
        self.omega1 = math.nan
        self._damping_rate = 0.0
        self.chain = self._chain_type(  # type: ignore[assignment]  # see _chain_type
            length=cfg.length,
            bending_stiffness=cfg.bending_stiffness,
            mass_per_length=cfg.mass_per_length,
            segments=cfg.segments,
            clamp_pose=cfg.clamp_pose,
            dt=self.dt,
            gravity=cfg.gravity,
            movable_clamp=cfg.arms == 2,  # dual-arm: the clamp pose is a second input
            **self._chain_options(cfg),
        )
        self._snap_seen = 0

    def _chain_options(self, cfg: RodConfig) -> dict:
        """More arguments for the chain: none here (a table's: `rodctl.sim.friction`)."""
        return {}

    @property
    def _qs(self) -> QuasiStaticChain:
        """The chain this engine builds (`_build_chain`, `_rebuild`), as its own type."""
        chain = self.chain
        assert isinstance(chain, QuasiStaticChain)
        return chain

    @property
    def _move_steps(self) -> int:
        return 1

    def _is_slow(self) -> bool:
        """Settled means solved: a quasi-static state has no speed to wait on."""
        return bool(self._qs.converged)

    def _settle(self, target: np.ndarray) -> tuple[bool, bool]:
        """Nothing to wait for: the step's solve already is the settled state."""
        if not self._qs._finite():
            return False, True
        return bool(self._qs.converged), False

    def _max_gap(self) -> float:
        """`max(joint_gaps())` after a move `_settle` found not diverged: the angles are finite
        there, so the gaps are zeros but the last (a free end: all zeros)."""
        c = self._qs
        return c._end_gap() if c.gripped else 0.0

    def health(self) -> RodHealth:
        """`RodSim.health` without building the (N, 3) states and velocities (the env asks every
        step): with finite angles the velocities are zeros and the gaps zeros but the end's, so
        only the joints decide `has_nan` (their sum is finite exactly when they all are: the
        coordinates are metres, far from overflow); with a NaN or inf angle every figure is
        the non-finite one `RodSim.health` gives."""
        c = self._qs
        if not c._finite():
            return RodHealth(math.inf, True, math.nan, math.nan)
        gap = c._end_gap() if c.gripped else 0.0
        return RodHealth(
            max_joint_gap=gap if math.isfinite(gap) else math.inf,
            has_nan=not math.isfinite(float(_SUM(c._joints(), axis=None))),
            kinetic_energy=0.0,
            max_speed=0.0,
        )

    def _hold(self) -> ApplyResult:
        """After a change of the rod itself: re-solve at the same end poses."""
        if self._diverged:
            return ApplyResult(False, False, False, True, np.zeros(3), 0.0)
        self._qs.step(None)
        settled, diverged = self._settle(self.gripper_pose)
        diverged = diverged or self._gaps_too_wide()
        if diverged:
            self._diverged = True
            settled = False
        return ApplyResult(settled, False, False, diverged, np.zeros(3), 0.0, sim_steps=1)

    def snapshot(self) -> dict:
        c = self._qs
        return {
            "chain": c,
            "state": (c.theta.copy(), c.lam.copy(), c._grip.copy(), c._clamp.copy()),
            "steps": c.steps,
            "snaps": (c.snaps, len(c.snap_notes)),
            "converged": c.converged,
            "diverged": self._diverged,
        }

    def restore(self, snap: dict) -> None:
        if snap["chain"] is not self.chain:
            raise RuntimeError("restore: the chain was rebuilt since the snapshot")
        c = self._qs
        theta, lam, grip, clamp = snap["state"]
        c.theta, c.lam, c._grip, c._clamp = theta.copy(), lam.copy(), grip.copy(), clamp.copy()
        c.steps = snap["steps"]
        c.snaps = snap["snaps"][0]
        del c.snap_notes[snap["snaps"][1] :]
        self._snap_seen = min(self._snap_seen, len(c.snap_notes))  # later notes are reported
        c.converged = snap["converged"]
        self._diverged = snap["diverged"]

    def _rebuild(self, held: int, movable_clamp: bool) -> None:
        notes, snaps = self._qs.snap_notes, self._qs.snaps
        super()._rebuild(held, movable_clamp)
        self._qs.snap_notes, self._qs.snaps = notes, snaps

    def _counted(self, run: Callable[..., ApplyResult], *args: object) -> ApplyResult:
        before = self._qs.snaps
        result = run(*args)
        result.snaps = self._qs.snaps - before
        return result

    def apply(self, u: np.ndarray) -> ApplyResult:
        return self._counted(super().apply, u)

    def move_to(self, pose: np.ndarray) -> ApplyResult:
        return self._counted(super().move_to, pose)

    def move_clamp(self, pose: np.ndarray, max_step: np.ndarray | None = None) -> ApplyResult:
        return self._counted(super().move_clamp, pose, max_step)

    def slip_grasp(self, ds: float) -> ApplyResult:
        return self._counted(super().slip_grasp, ds)

    def set_bending_stiffness(self, bending_stiffness: float) -> ApplyResult:
        return self._counted(super().set_bending_stiffness, bending_stiffness)

    def set_mass_per_length(self, mass_per_length: float) -> ApplyResult:
        return self._counted(super().set_mass_per_length, mass_per_length)

    def _home_state(self) -> dict:
        c = self._qs
        return {
            "home": self._home.copy(),
            "state": (c.theta.copy(), c.lam.copy(), c._grip.copy()),
            "steps": c.steps,
        }

    def _put_home_state(self, state: dict) -> None:
        self._home = state["home"].copy()
        theta, lam, grip = state["state"]
        self._qs.theta, self._qs.lam, self._qs._grip = theta.copy(), lam.copy(), grip.copy()
        self._qs.steps = state["steps"]

    def take_snap_notes(self) -> list[str]:
        """The snap notes since the last call (the env logs them with the step)."""
        notes = self._qs.snap_notes[self._snap_seen :]
        self._snap_seen = len(self._qs.snap_notes)
        return list(notes)

    def centerline_jacobian(self) -> np.ndarray:
        """(N+1, 2, 3) d(joint points)/d(gripper pose [x, y, θ]) at the current equilibrium."""
        return self._qs.joint_points_jacobian()


class _Model:
    """The parts of a chain's KKT system that stay constant while EI, ρA and the tolerance do:
    the springs' part of H, the loads' complex weights, the tolerance units and the
    right-hand-side buffer of `_newton_step` (column 3 is the fixed unit vector e_{N−1})."""

    __slots__ = (
        "key", "k", "ke", "seg", "seg2", "off", "diag0", "kk", "pad", "pad_mid", "pad_lo",
        "pad_hi", "wg", "scale2", "torque_unit", "position_unit", "converged_step", "rhs",
        "rhs_grad", "rhs_a0", "rhs_a1", "gtsv", "zarg", "zarg_imag", "tau", "tau_lo", "tau_hi",
    )  # fmt: skip

    def __init__(self, chain: QuasiStaticChain, key: tuple) -> None:
        n, seg = chain.segments, chain.seg_length
        k, ke = chain._stiffness()
        self.key, self.k, self.ke, self.seg, self.seg2 = key, k, ke, seg, seg * seg
        self.off = np.full(n - 1, -k)
        self.diag0 = np.full(n, 2.0 * k)
        self.diag0[0] = k + ke
        self.diag0[-1] = k + ke if chain.gripped else k
        # Spring constants of the N+1 links of the padded angles [θ_c, θ_0..θ_{N-1}, θ_g].
        self.kk = np.full(n + 1, k)
        self.kk[0] = ke
        self.kk[-1] = ke if chain.gripped else 0.0
        self.pad = np.zeros(n + 2)
        self.pad_mid, self.pad_lo, self.pad_hi = self.pad[1:-1], self.pad[:-1], self.pad[1:]
        # i·θ for `_eval`'s e^{iθ}: the real part stays 0, the imaginary part is written.
        self.zarg = np.zeros(n, dtype=np.complex128)
        self.zarg_imag = self.zarg.imag
        self.tau = np.empty(n + 1)
        self.tau_lo, self.tau_hi = self.tau[:-1], self.tau[1:]
        # Body loads as complex weights: gravity at the centres (segment j's angle moves the
        # centres of j, by l/2, and of all after it) and a dead tip load.
        gx, gy = chain.gravity
        wg: np.ndarray | None = None
        if gx or gy:
            wg = ((chain.segment_mass * seg) * chain._weights) * complex(gx, -gy)
        if chain.tip_force is not None:
            px, py = chain.tip_force.tolist()
            wg = (0.0 if wg is None else wg) + np.full(n, seg * complex(px, -py))
        self.wg = wg
        scale = chain._torque_scale()
        self.scale2 = scale * scale
        self.torque_unit = chain.torque_tol * scale
        self.position_unit = POSITION_TOL * chain.length
        self.converged_step = CONVERGED_STEP * math.sqrt(chain.torque_tol)
        self.rhs = np.zeros((n, 4), order="F")
        self.rhs[-1, 3] = 1.0
        self.rhs_grad, self.rhs_a0, self.rhs_a1 = self.rhs[:, 0], self.rhs[:, 1], self.rhs[:, 2]
        self.gtsv = _gtsv()


def _ends(grip: np.ndarray, clamp: np.ndarray) -> tuple[float, float, float, float]:
    """(θ_clamp, θ_gripper, gripper x − clamp x, gripper y − clamp y) as floats."""
    gx, gy, gt = grip.tolist()
    cx, cy, ct = clamp.tolist()
    return ct, gt, gx - cx, gy - cy


def _positive_eigenvalues(s00: float, s01: float, s10: float, s11: float) -> int:
    """Positive eigenvalues of the (symmetrised) 2×2 matrix; −9 when it is singular."""
    det = s00 * s11 - 0.25 * (s01 + s10) ** 2
    if det < 0:
        return 1
    if det > 0:
        return 2 if s00 + s11 > 0 else 0
    return -9


def _mat2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(2, N) times (N, q) by elementwise products and numpy sums, not BLAS: the same bits
    under every BLAS kernel (`replay --verify` compares runs across kernels)."""
    return (a[:, :, None] * b[None, :, :]).sum(axis=1)


@functools.lru_cache(maxsize=8)
def resample_matrix(segments: int, n: int) -> np.ndarray:
    """(n, N+1) the linear map from the joints of a chain of N equal segments to `n` points
    equally spaced in arc length (what `resample_polyline` does for such a chain). Its
    derivative along any inextensible motion is this same matrix: arc length does not change.
    Cached per (N, n) and read-only (the env asks for it every control step)."""
    q = np.linspace(0.0, float(segments), n)
    idx = np.minimum(np.floor(q).astype(int), segments - 1)
    frac = q - idx
    w = np.zeros((n, segments + 1))
    w[np.arange(n), idx] = 1.0 - frac
    w[np.arange(n), idx + 1] += frac
    w.flags.writeable = False
    return w


register_engine("quasistatic", QuasiStaticSim)
