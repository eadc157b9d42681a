"""Control laws: from the feature error and the Jacobian estimate to a pose increment.

The paper's MFAC law (eq. 24), the baselines' saturated pseudo-inverse and box-QP steps, and a
scripted path all honour one protocol (`base.Controller`); each registers itself with its config
model in `rodctl.registry.CONTROLLERS`. Per-axis saturation of the command is
the loop's job, not the law's, so every method is limited the same way.
"""

from typing import Any

import numpy as np

from rodctl.control.base import Controller
from rodctl.control.mfac import MfacController, mfac_cost, mfac_step
from rodctl.control.pinv import PinvController
from rodctl.control.qp import QpController, solve_box_qp
from rodctl.control.scripted import ScriptedController

__all__ = [
    "Controller",
    "MfacController",
    "PinvController",
    "QpController",
    "ScriptedController",
    "make_controller",
    "mfac_cost",
    "mfac_step",
    "solve_box_qp",
]


def make_controller(cfg: Any, *, home_pose: np.ndarray, max_step: np.ndarray) -> Controller:
    """The law `cfg` describes, made by its registered factory.

    Args:
        cfg: a registered controller config.
        home_pose: (3,) gripper pose at the start of the run, world frame (scripted waypoints
            are absolute; the others see r relative to it).
        max_step: (3,) the per-axis saturation of u (the QP's bounds, the scripted step size).
    """
    from rodctl.registry import CONTROLLERS, BuildContext, load_plugins

    load_plugins()
    ctx = BuildContext(points=0, home_pose=np.asarray(home_pose), max_step=np.asarray(max_step))
    return CONTROLLERS.build(cfg, ctx)
