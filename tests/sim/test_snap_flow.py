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

import importlib.util

import numpy as np
import pytest
from paths import REPO

from rodctl.config.rod import RodConfig, WorkspaceConfig
from rodctl.sim import RodSim
from rodctl.sim.flow_reference import reference_flow
from rodctl.sim.quasistatic import QuasiStaticChain

_spec = importlib.util.spec_from_file_location("bench_snap", REPO / "benchmarks" / "bench_snap.py")
bench_snap = importlib.util.module_from_spec(_spec)
assert _spec.loader is not None
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
