"""Control laws: from the feature error and the Jacobian estimate to a pose increment.

The paper's MFAC law (eq. 24), the baselines' saturated pseudo-inverse and box-QP steps, and a
scripted path all honour one protocol (`base.Controller`). Per-axis saturation of the command is
the loop's job, not the law's, so every method is limited the same way.
"""

from rodctl.control.base import Controller
from rodctl.control.factory import make_controller
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
