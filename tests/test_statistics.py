"""Paired statistics: they find a real difference, they do not find one in noise."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.statistics import paired_difference


def test_a_consistent_one_step_advantage_is_significant():
    rng = np.random.default_rng(0)
    ref = rng.integers(8, 20, size=100).astype(float)
    method = ref - 1 + rng.integers(-1, 2, size=100)  # mostly 1 step fewer
    d = paired_difference(list(method), list(ref))
    assert d.n == 100 and d.mean == pytest.approx(np.mean(method - ref))
    assert d.ci_high < 0 and d.p_value < 1e-6 and d.significant()
    assert d.wins > d.losses


def test_noise_alone_is_not_significant():
    rng = np.random.default_rng(1)
    ref = rng.integers(8, 20, size=100).astype(float)
    method = ref + rng.choice([-1.0, 0.0, 1.0], size=100)
    d = paired_difference(list(method), list(ref))
    assert d.ci_low < 0 < d.ci_high and not d.significant()


def test_unpaired_targets_are_dropped_and_tiny_samples_claim_nothing():
    d = paired_difference([10, None, 12, 9], [11, 10, None, 10])
    assert d.n == 2 and d.p_value is None and not d.significant()
    assert paired_difference([None], [1.0]).describe() == "no paired targets"
