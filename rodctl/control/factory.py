"""Build the configured `Controller` from its config (one branch per union member)."""

from __future__ import annotations

import numpy as np

from rodctl.config.controller import (
    ControllerConfig,
    MfacControllerConfig,
    PinvControllerConfig,
    QpControllerConfig,
    ScriptedControllerConfig,
)
from rodctl.control.base import Controller
from rodctl.control.mfac import MfacController
from rodctl.control.pinv import PinvController
from rodctl.control.qp import QpController
from rodctl.control.scripted import ScriptedController


def make_controller(
    cfg: ControllerConfig, *, home_pose: np.ndarray, max_step: np.ndarray
) -> Controller:
    """The law `cfg` describes.

    Args:
        cfg: the controller config.
        home_pose: (3,) gripper pose at the start of the run, world frame (scripted waypoints
            are absolute; the others see r relative to it).
        max_step: (3,) the loop's per-axis saturation of u (the QP's bounds, the scripted
            step size).
    """
    if isinstance(cfg, MfacControllerConfig):
        return MfacController(cfg.weights)
    if isinstance(cfg, PinvControllerConfig):
        return PinvController(gain=cfg.gain, error_limit=cfg.error_limit, rcond=cfg.rcond)
    if isinstance(cfg, QpControllerConfig):
        return QpController(max_step, gain=cfg.gain, r_weights=cfg.r_weights)
    if isinstance(cfg, ScriptedControllerConfig):
        return ScriptedController(
            cfg.waypoints, home_pose=home_pose, max_step=max_step, tolerance=cfg.tolerance
        )
    raise TypeError(f"unknown controller config {type(cfg).__name__}")
