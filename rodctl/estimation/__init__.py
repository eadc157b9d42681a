"""Estimates of the deformation Jacobian J in Delta s ~ J Delta r.

docs/method.md §3 (the paper's AKF) and docs/baselines.md (the baselines' estimates).

The paper's adaptive Kalman filter, the baselines' Broyden / windowed least-squares updates and
the offline ASAP model all honour one protocol (`base.JacobianEstimator`), so the loop swaps
them by config alone. Online methods start from the probing fit in `probing`.
"""

from typing import Any

from rodctl.estimation.akf import AdaptiveKalmanJacobian
from rodctl.estimation.asap import OfflineJacobian, asap_from_centerline, asap_jacobian
from rodctl.estimation.base import JacobianEstimator
from rodctl.estimation.broyden import BroydenJacobian
from rodctl.estimation.probing import fit_jacobian, probe_moves
from rodctl.estimation.windowed_ls import WindowedLsJacobian

__all__ = [
    "AdaptiveKalmanJacobian",
    "BroydenJacobian",
    "JacobianEstimator",
    "OfflineJacobian",
    "WindowedLsJacobian",
    "asap_from_centerline",
    "asap_jacobian",
    "fit_jacobian",
    "make_estimator",
    "probe_moves",
]


def make_estimator(cfg: Any, p: int, q: int, *, camera: Any = None) -> JacobianEstimator:
    """The estimator `cfg` describes for a (p, q) Jacobian, made by its registered factory.

    Online estimators start at J = 0 until `reset(J0)` (the probing fit); the offline model
    builds its Jacobian in `prepare(first_pixels)` with the calibrated `camera`.
    """
    from rodctl.registry import ESTIMATORS, BuildContext, load_plugins

    load_plugins()
    return ESTIMATORS.build(cfg, BuildContext(points=0, p=p, q=q, camera=camera))
