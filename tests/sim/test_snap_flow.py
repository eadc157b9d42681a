"""The snap's gradient flow (`QuasiStaticChain._flow`) ends where the flow it replaced ends.

Issue 24's rule: a snap must end at the stable equilibrium the overdamped flow reaches from the
unstable state (the same basin), never silently on another branch. The flow was made cheap
(docs/engines.md, "Snaps"); the previous one is kept as `rodctl/sim/flow_reference.py`. Both run
here from real snap states (tests/sim/data/snap_states.npz: states stored by
`benchmarks/bench_snap.py --save` from collection walks and hard-target episodes, N = 50) and
from one generated at N = 20 (a buckled rod whose gripper is turned until its bow snaps through),
and must end at the same equilibrium: every joint within 1e-6 L (they agree to ~1e-10 L, the
Newton tolerance). `benchmarks/bench_snap.py` runs the same comparison on a few hundred states.
"""

from __future__ import annotations

import copy
import importlib.util

import numpy as np
import pytest
from paths import REPO

from rodctl.config.rod import RodConfig, WorkspaceConfig
from rodctl.sim import RodSim
from rodctl.sim.flow_reference import reference_flow, reference_solve_to
from rodctl.sim.quasistatic import QuasiStaticChain

_spec = importlib.util.spec_from_file_location("bench_snap", REPO / "benchmarks" / "bench_snap.py")
assert _spec is not None and _spec.loader is not None
bench_snap = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_snap)
chain_of, load = bench_snap.chain_of, bench_snap.load

STATES = REPO / "tests/sim/data/snap_states.npz"
SAME = 1e-6  # of L


def both_flows(state: dict) -> tuple[QuasiStaticChain, tuple, tuple, int]:
    """(the chain the current flow ran on, its result, the reference's result, its solves)."""
    args = (state["theta"], state["lam"], state["grip"], state["clamp"])
    ref = reference_flow(chain_of(state), *(a.copy() for a in args))
    chain = chain_of(state)
    new = chain._flow(*(a.copy() for a in args))
    return chain, new, ref, chain.flow_steps + chain.newton_iterations


def check_same_equilibrium(state: dict) -> None:
    chain, new, ref, solves = both_flows(state)
    assert ref[2], "the reference flow converges on the stored states"
    assert new[2], "the flow did not reach a stable equilibrium"
    clamp, grip = state["clamp"], state["grip"]
    assert chain.stable(new[0], new[1], grip, clamp)
    end_new, end_ref = chain._points(new[0], clamp), chain._points(ref[0], clamp)
    start = chain._points(state["theta"], clamp)
    # A real snap: the rod moves by a sizeable fraction of its length ...
    assert np.max(np.abs(end_new - start)) > 0.05 * chain.length
    # ... to the equilibrium the previous flow reaches, and its far end is at the gripper.
    assert np.max(np.abs(end_new - end_ref)) <= SAME * chain.length
    assert np.hypot(*(end_new[-1] - grip[:2])) <= 1e-9 * chain.length
    # The point of the new flow: several times fewer KKT solves than the reference's.
    assert solves * 4 < ref[3]


def test_the_flow_ends_where_the_previous_flow_ends_on_stored_snap_states() -> None:
    states = load(str(STATES))
    assert len(states) >= 4
    for state in states:
        check_same_equilibrium(state)


def test_the_flow_ends_where_the_previous_flow_ends_on_a_buckled_rod_snapping_through(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    ws = WorkspaceConfig(
        x_limits=(-0.6, 0.6), y_limits=(-0.6, 0.6), theta_limits=(-4.0, 4.0), max_reach=1.0
    )
    sim = RodSim(RodConfig(segments=20, workspace=ws, engine="quasistatic"))
    length = sim.chain.length
    sim.move_to(np.array([0.6 * length, 0.05, 0.0]))
    sim.move_to(np.array([0.6 * length, 0.0, 0.0]))
    starts: list[dict] = []
    flow = QuasiStaticChain._flow

    def recording(self, theta, lam, grip, clamp):  # noqa: ANN001, ANN202
        state = {p: np.asarray(getattr(self, p), dtype=float) for p in ("length", "segments")}
        state.update(
            bending_stiffness=np.asarray(self.bending_stiffness),
            mass_per_length=np.asarray(self.mass_per_length),
            gravity=np.asarray(self.gravity),
            clamp_pose=self.clamp_pose.copy(),
            gripped=np.asarray(self.gripped),
            theta=theta.copy(),
            lam=lam.copy(),
            grip=grip.copy(),
            clamp=clamp.copy(),
        )
        starts.append(state)
        return flow(self, theta, lam, grip, clamp)

    monkeypatch.setattr(QuasiStaticChain, "_flow", recording)
    for _ in range(40):
        if sim.apply(np.array([0.0, 0.0, -0.05])).snaps:
            break
    assert len(starts) == 1, "the bow did not snap through"
    check_same_equilibrium(starts[0])
    # The env-facing result is that equilibrium too: the snapped rod is the flow's end state.
    assert sim.centerline()[:, 1].max() > 0.15


# ------------------------------------------------------------ the continuation before the flow
def _clone(chain: QuasiStaticChain) -> QuasiStaticChain:
    """A copy to try a move on (the chain never changes its arrays in place)."""
    twin = copy.copy(chain)
    twin.snap_notes = list(chain.snap_notes)
    return twin


def _reference_step(chain: QuasiStaticChain, grip: np.ndarray) -> QuasiStaticChain:
    """The move by the continuation as it was (every try in full), on a copy."""
    twin = _clone(chain)
    reference_solve_to(twin, grip.copy(), twin._clamp.copy())
    return twin


def test_a_path_to_a_fold_goes_on_until_the_fold_and_snaps_once_where_it_did() -> None:
    """The tries after a failed one give up early (`QuasiStaticChain._patience`); only the full
    tries of a 1/512 sub-step may declare the fold. Moves that end just before the fold of a
    buckled N = 20 rod (located by the old continuation to 1e-9 rad), from far and in small
    steps, must go on without a snap to the old continuation's equilibrium, and the move past
    it must snap once, to where the old one snaps. (Declaring the fold when the early-giving-up
    tries of a 1/512 sub-step fail notes a snap on the moves that end 1e-6-1e-7 rad before it.)"""
    ws = WorkspaceConfig(
        x_limits=(-0.6, 0.6), y_limits=(-0.6, 0.6), theta_limits=(-4.0, 4.0), max_reach=1.0
    )
    sim = RodSim(RodConfig(segments=20, workspace=ws, engine="quasistatic"))
    chain = sim.chain
    assert isinstance(chain, QuasiStaticChain)
    length = chain.length
    sim.move_to(np.array([0.6 * length, 0.05, 0.0]))
    sim.move_to(np.array([0.6 * length, 0.0, 0.0]))
    pose = lambda angle: np.array([0.6 * length, 0.0, angle])  # noqa: E731
    angle = 0.0  # turn the gripper until the next turn of 0.05 rad snaps the bow through
    while not _reference_step(chain, pose(angle - 0.05)).snaps:
        chain.step(pose(angle - 0.05))
        angle -= 0.05
    assert chain.snaps == 0 and angle < -0.5
    lo, hi = angle, angle - 0.05  # the fold is between them: bisect with the old continuation
    while lo - hi > 1e-9:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if _reference_step(chain, pose(mid)).snaps else (mid, hi)
    fold = lo

    def check(start: QuasiStaticChain, grip: np.ndarray, snaps: int) -> QuasiStaticChain:
        ref = _reference_step(start, grip)
        now = _clone(start)
        now.step(grip.copy())
        assert now.snaps - start.snaps == ref.snaps - start.snaps == snaps, (grip, now.snap_notes)
        assert now.converged
        far = np.max(
            np.abs(now._points(now.theta, now._clamp) - ref._points(ref.theta, ref._clamp))
        )
        assert far <= (1e-8 if snaps == 0 else SAME) * length
        return now

    for before in (0.1, 0.4):  # from far: the continuation halves its way to the fold
        start = _clone(chain)
        start.step(pose(fold + before))
        for gap in (1e-4, 1e-6, 1e-7):
            check(start, pose(fold + gap), 0)
    path = _clone(chain)  # in small steps up to 1e-7 rad before the fold, then past it
    for gap in (0.02, 0.005, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7):
        path = check(path, pose(fold + gap), 0)
    check(path, pose(fold - 0.01), 1)
