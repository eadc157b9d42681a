"""The quasi-static engine's shortcuts give what the generic computations give, bit for bit.

`QuasiStaticSim.health` and `_max_gap` skip building the (N, 3) states, velocities and gaps that
`RodSim.health` and `max(joint_gaps())` read (issue 24: the per-step overhead); `pixel_error`
takes np.mean's sum without its Python layer; the solver's e^{iθ} comes from a buffer. Each is
compared with the generic computation on random inputs, and on NaN, inf (a blow-up) and −0.
"""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.config.rod import RodConfig
from rodctl.env import pixel_error
from rodctl.sim import RodSim
from rodctl.sim.quasistatic import QuasiStaticChain, _ends
from rodctl.sim.rod import RodHealth

G = 9.81


def _same(a: RodHealth, b: RodHealth) -> bool:
    pack = lambda h: np.array(  # noqa: E731
        [h.max_joint_gap, float(h.has_nan), h.kinetic_energy, h.max_speed]
    ).tobytes()
    return pack(a) == pack(b)


@pytest.mark.parametrize("gravity", [(0.0, 0.0), (0.0, -G)])
def test_health_and_gap_match_the_generic_readouts(gravity: tuple[float, float]) -> None:
    sim = RodSim(RodConfig(segments=20, engine="quasistatic", gravity=gravity))
    rng = np.random.default_rng(3)
    for u in rng.uniform(-1, 1, (12, 3)) * np.asarray(sim.cfg.max_step):
        sim.apply(u)
        assert _same(sim.health(), RodSim.health(sim))
        assert sim._max_gap() == float(np.max(sim.chain.joint_gaps()))
    chain = sim.chain
    assert isinstance(chain, QuasiStaticChain)
    for bad in (np.nan, np.inf):
        chain.theta[4] = bad  # a blow-up, injected
        assert _same(sim.health(), RodSim.health(sim))
        assert sim.health().has_nan and sim.health().max_joint_gap == np.inf


def test_pixel_error_is_the_mean_of_the_distances() -> None:
    rng = np.random.default_rng(0)
    for n in (2, 9, 20, 64, 129):
        a, b = rng.normal(size=(2, n, 2)) * 100.0
        d = a - b
        ref = float(np.mean(np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2)))
        assert np.float64(pixel_error(a, b)).tobytes() == np.float64(ref).tobytes()
    assert np.isnan(pixel_error(np.full((5, 2), np.nan), np.zeros((5, 2))))


def test_the_solver_s_rotations_are_those_of_exp_i_theta() -> None:
    """`_eval` takes e^{iθ} from a buffer (no θ·1j temporary): the same bits as np.exp(θ·1j),
    signed zeros, NaN and inf angles included (θ·1j has +0 as its imaginary part for −0)."""
    chain = QuasiStaticChain(0.5, 0.01, 0.1, 20, (0.0, 0.0, 0.0), gravity=(0.0, -G))
    model, rng = chain._model(), np.random.default_rng(1)
    ends = _ends(np.array([0.3, -0.1, 0.2]), np.zeros(3))
    for trial in range(40):
        theta = rng.normal(size=20)
        if trial % 2:
            theta[rng.integers(20, size=5)] = [0.0, -0.0, np.nan, np.inf, -np.inf]
        with np.errstate(invalid="ignore"):
            z = chain._eval(theta, 0.1, -0.2, model, ends)[2]
            assert z.tobytes() == np.exp(theta * 1j).tobytes()
