"""The quasi-static engine's first snap flow, kept as the reference its replacement is checked
against (`tests/sim/test_snap_flow.py`, `benchmarks/bench_snap.py`).

`QuasiStaticChain._flow` (rodctl/sim/quasistatic.py) follows the overdamped gradient flow from
the state where the equilibrium path lost stability to the next stable equilibrium. This is the
flow it used until 2026-12-02, unchanged but for the step cap: backward-Euler steps (a KKT solve
with H + I/τ), accepted when the penalised energy E + ρ/2 |h|² (ρ = 1e3 k/l²) does not rise,
τ doubled after an accepted step and quartered after a rejected one, Newton tried once the state
is stable. Its penalty makes it reject steps longer than ~0.01 rad (the constraint's second-order
error, squared and weighted by ρ, outweighs the energy the step gains), so a snap took ~1,000
steps and some ran into the 4,000-step cap; `max_steps` lets a validation run it further.

`accurate_flow` integrates the same gradient flow finely (τ at most 4/k): the judge of where the
flow goes from the states where the previous flow does not converge at all.

`reference_solve_to` is the continuation before the flow as it was until 2026-12-02: every try
after a failed one ran Newton in full, so a snap paid ~60 ms of slowly failing tries before its
flow; the current one gives up early on those tries (`QuasiStaticChain._quick_newton`) and is
checked against it from the same step states (`benchmarks/bench_snap.py`).

Not used by any run: only the validation compares with them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from rodctl.records import SNAP_NOTE

if TYPE_CHECKING:
    from rodctl.sim.quasistatic import QuasiStaticChain


def reference_flow(
    chain: QuasiStaticChain,
    theta: np.ndarray,
    lam: np.ndarray,
    grip: np.ndarray,
    clamp: np.ndarray,
    max_steps: int = 4000,
) -> tuple[np.ndarray, np.ndarray, bool, int]:
    """The old flow from (θ, λ) at the end poses (grip, clamp): (θ, λ, converged, KKT solves)."""
    from rodctl.sim.quasistatic import _SUM, FLOW_RETRY, _ends  # noqa: PLC0415 (no cycle)

    self = chain
    m = self._model()
    k = m.k
    rho = 1e3 * k / m.seg2
    tau = 1.0 / k
    ends = _ends(grip, clamp)
    l0, l1 = lam.tolist()
    grad, diag, z, h0, h1 = self._eval(theta, l0, l1, m, ends)
    solves = 0

    def merit(th: np.ndarray, hx: float, hy: float) -> float:
        return self.energy(th, grip, clamp) + 0.5 * rho * (hx * hx + hy * hy)

    m0 = merit(theta, h0, h1)
    retry_res, since_try = math.inf, 0
    for _ in range(max_steps):
        try:
            solves += 1
            dth, d0, d1, _ = self._newton_step(diag + 1.0 / tau, z, grad, h0, h1, m)
        except (np.linalg.LinAlgError, ValueError):
            tau *= 0.25
            if tau * k < 1e-12:
                break
            continue
        th2, n0, n1 = theta + dth, l0 + d0, l1 + d1
        grad2, diag2, z2, g0, g1 = self._eval(th2, n0, n1, m, ends)
        m2 = merit(th2, g0, g1)
        if math.isfinite(float(_SUM(th2))) and m2 <= m0 + 1e-15 * abs(m0):
            theta, l0, l1, grad, diag, z, h0, h1, m0 = th2, n0, n1, grad2, diag2, z2, g0, g1, m2
            tau *= 2.0
            res = self._measures(grad, h0, h1, m)[0]
            since_try += 1
            due = res < 0.25 * retry_res or since_try >= FLOW_RETRY
            if res < 1e6 and due and self._stable_newton((diag, z, None)):
                before = self.newton_iterations
                th3, lam3, conv, hess = self._newton(theta, np.array([l0, l1]), grip, clamp)
                solves += self.newton_iterations - before
                if conv and self._stable_newton(hess):
                    return th3, lam3, True, solves
                retry_res, since_try = res, 0
        else:
            tau *= 0.25
            if tau * k < 1e-12:
                break
    return theta, np.array([l0, l1]), False, solves


def accurate_flow(
    chain: QuasiStaticChain,
    theta: np.ndarray,
    lam: np.ndarray,
    grip: np.ndarray,
    clamp: np.ndarray,
    tau_max: float = 4.0,
    max_steps: int = 1_000_000,
) -> tuple[np.ndarray, np.ndarray, bool, int]:
    """The gradient flow integrated finely: backward-Euler steps with τ at most `tau_max`/k
    (k = EI/l; the rod's stiffest modes relax at rates up to ~4k, the slow ones that decide
    where it goes at far lower rates; τ k <= 1, 4 and 16 gave the same ends), each accepted when
    it does not raise E + λ'·h + ρ/2 |h|² (ρ = k/l², as `QuasiStaticChain._flow`), else
    halved; Newton once the state is stable and near an equilibrium. Slow (10³–10⁵ steps a
    snap): the judge of which equilibrium the flow reaches where the previous flow does not
    converge at all. Returns (θ, λ, converged, steps)."""
    from rodctl.sim.quasistatic import FLOW_PENALTY, _ends  # noqa: PLC0415 (no cycle)

    self = chain
    m = self._model()
    k = m.k
    rho = FLOW_PENALTY * k / m.seg2
    tau = tau_max / k
    ends = _ends(grip, clamp)
    l0, l1 = lam.tolist()
    grad, diag, z, h0, h1 = self._eval(theta, l0, l1, m, ends)
    e0 = self._flow_energy(z, m)
    for step in range(max_steps):
        dth, d0, d1, _ = self._newton_step(diag + 1.0 / tau, z, grad, h0, h1, m)
        th2, n0, n1 = theta + dth, l0 + d0, l1 + d1
        grad2, diag2, z2, g0, g1 = self._eval(th2, n0, n1, m, ends)
        e2 = self._flow_energy(z2, m)
        before = e0 + n0 * h0 + n1 * h1 + 0.5 * rho * (h0 * h0 + h1 * h1)
        after = e2 + n0 * g0 + n1 * g1 + 0.5 * rho * (g0 * g0 + g1 * g1)
        if not (math.isfinite(after) and after <= before + 1e-15 * abs(before)):
            tau *= 0.5
            continue
        theta, l0, l1, grad, diag, z, h0, h1, e0 = th2, n0, n1, grad2, diag2, z2, g0, g1, e2
        tau = min(2.0 * tau, tau_max / k)
        res = self._measures(grad, h0, h1, m)[0]
        if res < 1e3 and self._stable_newton((diag, z, None)):
            th3, lam3, conv, hess = self._newton(theta, np.array([l0, l1]), grip, clamp)
            if conv and self._stable_newton(hess):
                return th3, lam3, True, step + 1
    return theta, np.array([l0, l1]), False, max_steps


def reference_solve_to(chain: QuasiStaticChain, grip: np.ndarray, clamp: np.ndarray) -> bool:
    """The continuation of `QuasiStaticChain._solve_to` as it was until 2026-12-02 (`self` is
    `chain`): every try, before and after a failed one, runs Newton in full (`MAX_NEWTON`
    iterations of up to 30 step halvings), so that near a fold each of the ~9 halvings down to
    `MIN_FRACTION` of the move pays two slowly failing Newton solves, and the flow's Newton
    tries on the way ran in full too. The current one gives up early on the tries after a
    failure and runs in full only the tries whose failure starts the flow (docs/engines.md,
    "Snaps"); `benchmarks/bench_snap.py` runs both from the same step states. Returns whether
    the step ended converged, as `_solve_to`."""
    # The flow's Newton tries in full too, as until 2026-12-02 (the current flow's are quick).
    chain._quick_newton = chain._newton  # type: ignore[method-assign]
    try:
        return _continuation(chain, grip, clamp)
    finally:
        del chain._quick_newton


def _continuation(chain: QuasiStaticChain, grip: np.ndarray, clamp: np.ndarray) -> bool:
    """`reference_solve_to` without the flow's Newton setting."""
    from rodctl.sim.quasistatic import (  # noqa: PLC0415 (no cycle)
        _MAX,
        MAX_BRANCH_STEP,
        MIN_FRACTION,
    )

    self = chain
    if not (self._finite() and math.isfinite(sum(self.lam.tolist()))):
        self._grip, self._clamp = grip, clamp
        return False
    g0, c0 = self._grip, self._clamp
    # Unchanged end poses (a change of the rod itself, or a free end): there is no path to
    # sub-step along, so where Newton does not reach a stable state near the old one the
    # overdamped gradient flow from the old shape is the rod's response, not a snap.
    moving = not (grip.tolist() == g0.tolist() and clamp.tolist() == c0.tolist())
    clamp_fixed = clamp.tolist() == c0.tolist()
    done, frac = 0.0, 1.0
    ok = True
    while done < 1.0:
        f = min(1.0, done + frac)
        if f == 1.0:
            g, c = grip, clamp
        else:
            g = g0 + (grip - g0) * f
            c = c0 + (clamp - c0) * f
        start = self.theta  # never modified in place: every update makes a new array
        guesses: list[tuple[np.ndarray, np.ndarray]] = [(start, self.lam)]
        if self.gripped and self._maybe_straight and float(np.ptp(start)) < 1e-9:
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
        for guess, lam0 in guesses:
            theta, lam, conv, hess = self._newton(guess, lam0, g, c)
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
