"""The Controller protocol: from the feature error and the Jacobian estimate to a pose increment."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


class Controller(Protocol):
    """Computes the next command u_k = Delta r_k (q,) for a feature-space shape servo.

    The optional hooks a method reads are declared on `OpenLoopController`.
    """

    def reset(self) -> None:
        """Forget the command history (start of a run)."""
        ...

    def command(
        self, s: np.ndarray, s_target: np.ndarray, J: np.ndarray, r: np.ndarray
    ) -> np.ndarray:
        """Next pose increment, before saturation.

        Args:
            s: (p,) current feature s_{k-1}.
            s_target: (p,) target feature s*.
            J: (p, q) current Jacobian estimate J_k.
            r: (q,) current gripper pose relative to the run's home pose, r_{k-1}.

        Returns:
            (q,) pose increment u_k = [dx, dy, dtheta].
        """
        ...


@runtime_checkable
class OpenLoopController(Controller, Protocol):
    """A controller with the optional open-loop hooks (`ScriptedController` has them).

    A controller without them is closed-loop: probed for J_0 and stopped by the stop rule.
    """

    @property
    def open_loop(self) -> bool:
        """True: the law ignores the feature and J, so there is no probing and nothing
        converges; the run ends when `done`."""
        ...

    @property
    def done(self) -> bool:
        """True: nothing left to do; an open-loop run then ends as `completed`."""
        ...
