"""The Controller protocol: from the feature error and the Jacobian estimate to a pose increment."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Controller(Protocol):
    """Computes the next command u_k = Delta r_k (q,) for a feature-space shape servo.

    Optional attributes the episode reads: `open_loop` (True: the law ignores the feature and
    J, so there is no probing and nothing converges) and `done` (True: nothing left to do; an
    open-loop run then ends as `completed`).
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
