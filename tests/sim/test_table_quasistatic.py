"""Table friction in the quasi-static engine (`rodctl/sim/friction.py`): each sub-move of the
ends is an incremental minimisation of elastic energy plus Coulomb dissipation.

`rod.table_friction` stays refused with `engine: quasistatic` at validation (docs/engines.md,
Friction: the shipped pymunk table's settled shapes depend on how fast it is driven, by more
than the 0.2 % of L asked for); these tests build the rods with `model_copy` (no validation).
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from rodctl.config.rod import RodConfig
from rodctl.sim import RodSim
from rodctl.sim.friction import FrictionalChain, TableQuasiStaticSim

L = 0.5
N = 20
MOVES = ([0.01, -0.01, 0.05], [-0.004, 0.01, -0.05], [0.01, 0.006, 0.0])


def table_sim(mu: float, substeps: int = 8, **rod: object) -> RodSim:
    cfg = RodConfig(segments=N, table_friction=mu, **rod)  # type: ignore[arg-type]
    sim = TableQuasiStaticSim(cfg.model_copy(update={"engine": "quasistatic"}))
    assert isinstance(sim.chain, FrictionalChain)
    sim.chain.substeps = substeps
    return sim


def gap(a: RodSim, b: RodSim) -> float:
    return float(np.max(np.hypot(*(a.centerline() - b.centerline()).T)))


def elastic_residual(sim: RodSim) -> float:
    """The chain's torque and end-position residual without friction, in units of its Newton
    tolerance (<= 1: a frictionless equilibrium)."""
    chain = sim.chain
    m = chain._model()
    grip, clamp = chain._grip, chain._clamp
    ends = (clamp[2], grip[2], grip[0] - clamp[0], grip[1] - clamp[1])
    l0, l1 = chain.lam.tolist()
    grad, _, _, h0, h1 = chain._eval(chain.theta, l0, l1, m, ends)
    return chain._measures(grad, h0, h1, m)[0]


def test_the_refusal_stays() -> None:
    with pytest.raises(ValidationError, match="table_friction"):
        RodConfig(table_friction=0.5, engine="quasistatic")


def test_a_frictionless_table_settles_on_the_frictionless_equilibrium() -> None:
    # mu = 0: the incremental minimisation has no dissipation, so every settled shape must be
    # an equilibrium of the springs alone, the one the frictionless engine finds on the same
    # moves; a faint table (the smoothed friction path active) lands there too.
    plain = RodSim(RodConfig(segments=N, engine="quasistatic"))
    zero, faint = table_sim(0.0, substeps=2), table_sim(1e-9, substeps=2)
    for u in MOVES:
        for sim in (plain, zero, faint):
            assert sim.apply(np.array(u)).settled
        assert elastic_residual(zero) <= 1.0
        assert gap(zero, plain) < 1e-8 * L
        assert gap(faint, plain) < 1e-6 * L
    with pytest.raises(ValueError, match="table_friction"):
        FrictionalChain(L, 5e-3, 0.0785, N, (0.0, 0.0, 0.0))


def test_friction_makes_the_shape_depend_on_the_path() -> None:
    target = np.array([-0.02, 0.01, 0.1])
    shapes = {}
    for mu in (None, 0.5):
        for detour in (False, True):
            sim = (
                RodSim(RodConfig(segments=N, engine="quasistatic"))
                if mu is None
                else table_sim(mu, substeps=4)
            )
            home = sim.home_pose
            if detour:
                assert sim.move_to(home + np.array([0.0, -0.03, 0.0])).settled
            assert sim.move_to(home + target).settled
            np.testing.assert_allclose(sim.gripper_pose, home + target, atol=1e-12)
            shapes[mu, detour] = sim.centerline()
    frictionless = float(np.abs(shapes[None, False] - shapes[None, True]).max())
    table = float(np.abs(shapes[0.5, False] - shapes[0.5, True]).max())
    assert frictionless < 1e-7 * L  # one equilibrium, whatever the path
    assert table > 1e-3 * L  # the table holds the rod where the path left it


def test_the_table_agrees_with_pymunk_driven_slowly() -> None:
    # The quasi-static sweep is the limit of a table driven ever more slowly with an ever
    # smaller solver error: pymunk at 16x the control period and 80 solver iterations agrees
    # within 0.023 % of L on 20 random moves at N = 20 (docs/engines.md, Friction). Here: the
    # home drive from the straight rod, three moves, and a friction change with a move
    # (measured 0.030 %; the shipped pymunk table, driven 16x faster, is 0.17 % away).
    cfg = RodConfig(segments=N, table_friction=0.5)
    slow = RodSim(cfg.model_copy(update={"control_period": 1.6, "iterations": 80}))
    sim = table_sim(0.5)
    worst = gap(slow, sim)
    for u in MOVES:
        assert slow.apply(np.array(u)).settled and sim.apply(np.array(u)).settled
        worst = max(worst, gap(slow, sim))
    for s in (slow, sim):
        assert s.set_table_friction(0.3).settled
        assert s.apply(np.array([-0.01, -0.01, -0.05])).settled
    worst = max(worst, gap(slow, sim))
    assert worst < 5e-4 * L, f"{worst / L:.4%} of L"
