"""Build the configured `JacobianEstimator` from its config (one branch per union member)."""

from __future__ import annotations

from rodctl.config.estimator import (
    AkfEstimatorConfig,
    BroydenEstimatorConfig,
    EstimatorConfig,
    OfflineEstimatorConfig,
    WindowedLsEstimatorConfig,
)
from rodctl.estimation.akf import AdaptiveKalmanJacobian
from rodctl.estimation.asap import OfflineJacobian
from rodctl.estimation.base import JacobianEstimator
from rodctl.estimation.broyden import BroydenJacobian
from rodctl.estimation.windowed_ls import WindowedLsJacobian


def make_estimator(cfg: EstimatorConfig, p: int, q: int) -> JacobianEstimator:
    """The estimator `cfg` describes, for a (p, q) Jacobian.

    Online estimators start at J = 0; the loop probes (`run.probe_size`), then calls
    `reset(J0)`.
    The offline estimator has no Jacobian until the loop calls `reset` with the ASAP model
    (`rodctl.estimation.asap.asap_from_centerline`) composed with the camera projection.
    """
    if isinstance(cfg, AkfEstimatorConfig):
        return AdaptiveKalmanJacobian(
            p,
            q,
            p0=cfg.p0,
            q0=cfg.q0,
            r0=cfg.r0,
            c0=cfg.c0,
            c1=cfg.c1,
            alpha_floor=cfg.alpha_floor,
            forgetting=cfg.forgetting,
            r_update=cfg.r_update,
            q_min=cfg.q_min,
            r_min=cfg.r_min,
            dead_zone=cfg.dead_zone,
        )
    if isinstance(cfg, BroydenEstimatorConfig):
        return BroydenJacobian(p, q, gamma=cfg.gamma, dead_zone=cfg.dead_zone)
    if isinstance(cfg, WindowedLsEstimatorConfig):
        return WindowedLsJacobian(p, q, window=cfg.window, ridge=cfg.ridge, dead_zone=cfg.dead_zone)
    if isinstance(cfg, OfflineEstimatorConfig):
        return OfflineJacobian(p, q)
    raise TypeError(f"unknown estimator config {type(cfg).__name__}")
