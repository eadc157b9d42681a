"""The true Jacobian's small sums in `rodctl/env.py` (`_interpolate`, `_chain_2x2`) give the
bits of the `einsum`s they replace, signed zeros included: every Jacobian error depends on it."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.env import _chain_2x2, _interpolate, _two_point_rows
from rodctl.sim.quasistatic import resample_matrix


def _signed_zeros(rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
    x = x.copy()
    flat = x.reshape(-1)
    flat[rng.integers(0, flat.size, flat.size // 5)] = 0.0
    flat[rng.integers(0, flat.size, flat.size // 5)] = -0.0
    return x


@pytest.mark.parametrize(("segments", "n"), [(50, 100), (25, 100), (20, 7), (100, 100)])
def test_interpolation_is_the_einsum(segments, n):
    rng = np.random.default_rng(segments + n)
    w = resample_matrix(segments, n)
    two = _two_point_rows(w)
    assert two is not None
    for trial in range(40):
        joints = rng.normal(size=(segments + 1, 2)) * 10.0 ** rng.uniform(-6, 1)
        djoints = rng.normal(size=(segments + 1, 2, 3))
        if trial % 2:
            joints, djoints = _signed_zeros(rng, joints), _signed_zeros(rng, djoints)
        if trial % 5 == 0:
            joints = -np.abs(joints)  # negative coordinates: zero weights give -0.0 products
        got = _interpolate(two, joints)
        assert got.tobytes() == np.einsum("ij,jk->ik", w, joints).tobytes()
        got = _interpolate(two, djoints)
        assert got.tobytes() == np.einsum("ij,jkq->ikq", w, djoints).tobytes()


def test_chain_rule_is_the_einsum():
    rng = np.random.default_rng(3)
    for trial in range(200):
        pj = rng.normal(size=(100, 2, 2))
        dpoints = rng.normal(size=(100, 2, 3))
        dpoints[0] = 0.0  # the clamp's joint does not move
        if trial % 2:
            pj, dpoints = _signed_zeros(rng, pj), _signed_zeros(rng, dpoints)
        want = np.einsum("ikl,ilq->ikq", pj, dpoints)
        assert _chain_2x2(pj, dpoints).tobytes() == want.tobytes()


def test_only_two_point_rows_qualify():
    w = np.array(resample_matrix(10, 5))
    assert _two_point_rows(w) is not None
    w[2, 7] = 0.5  # a third weight in a row
    assert _two_point_rows(w) is None
