"""Estimates of the deformation Jacobian J in Delta s ~ J Delta r (method-notes sections 1, 4).

The paper's adaptive Kalman filter, the baselines' Broyden / windowed least-squares updates and
the offline ASAP model all honour one protocol (`base.JacobianEstimator`), so the loop swaps
them by config alone. Online methods start from the probing fit in `probing`.
"""

from rodctl.estimation.akf import AdaptiveKalmanJacobian
from rodctl.estimation.asap import OfflineJacobian, asap_from_centerline, asap_jacobian
from rodctl.estimation.base import JacobianEstimator
from rodctl.estimation.broyden import BroydenJacobian
from rodctl.estimation.factory import make_estimator
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
