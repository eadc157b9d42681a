"""make_estimator builds every configured method; each honours the JacobianEstimator protocol."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import TypeAdapter

from rodctl.config.experiment import EstimatorConfig
from rodctl.estimation import (
    AdaptiveKalmanJacobian,
    BroydenJacobian,
    OfflineJacobian,
    WindowedLsJacobian,
    make_estimator,
)

ADAPTER = TypeAdapter(EstimatorConfig)


@pytest.mark.parametrize(
    ("section", "cls"),
    [
        ({"type": "akf", "c0": 1.0, "c1": 4.0}, AdaptiveKalmanJacobian),
        ({"type": "broyden", "gamma": 0.5}, BroydenJacobian),
        ({"type": "windowed_ls", "window": 4}, WindowedLsJacobian),
        ({"type": "offline"}, OfflineJacobian),
    ],
)
def test_each_config_type_builds_a_working_estimator(section, cls):
    est = make_estimator(ADAPTER.validate_python(section), 6, 3)
    assert isinstance(est, cls)
    J = np.random.default_rng(0).normal(0.0, 30.0, (6, 3))
    est.reset(J)
    u = np.array([0.01, -0.01, 0.02])
    out = est.update(J @ u, u)
    assert out.shape == (6, 3)
    np.testing.assert_allclose(out, J, rtol=1e-6)  # consistent data leaves J where it is
    assert all(isinstance(v, float) for v in est.info().values())


def test_akf_config_rejects_misordered_thresholds():
    with pytest.raises(ValueError, match="c0 must be smaller than c1"):
        ADAPTER.validate_python({"type": "akf", "c0": 5.0, "c1": 3.0})


def test_offline_config_rejects_fractions_outside_the_rod():
    with pytest.raises(ValueError):
        ADAPTER.validate_python({"type": "offline", "servoed": [0.5, 1.2]})
