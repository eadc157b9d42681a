"""`Outcome`: how an episode ended, the one definition that the loop, the config's `run.expect`
and the batch summaries share. It imports nothing from rodctl, so every layer may use it."""

from __future__ import annotations

import enum


class Outcome(enum.StrEnum):
    """How an episode ended; the value is what records, summaries and results.csv hold."""

    CONVERGED = "converged"  # pixel error (and T1 if asked) below tolerance
    STALLED = "stalled"  # no progress while the descent direction J^T e has vanished
    PINNED = "pinned"  # no progress while every command is clipped by the workspace
    STEP_LIMIT = "step_limit"  # run.max_steps reached
    DIVERGED = "diverged"  # NaN, a joint gap, or a non-finite command
    LOST_TRACKING = "lost_tracking"  # the camera lost the rod for too many frames
    COMPLETED = "completed"  # an open-loop (scripted) path reached its end
    INTERRUPTED = "interrupted"  # SIGINT / SIGTERM between two steps
    ERROR = "error"  # an exception inside the episode

    @property
    def status(self) -> str:
        """The run status this outcome closes the logs and meta.json with."""
        if self is Outcome.INTERRUPTED:
            return "interrupted"
        if self in (Outcome.DIVERGED, Outcome.LOST_TRACKING, Outcome.ERROR):
            return "failed"
        return "completed"


#: The outcomes a config may declare it reaches (`run.expect`): what the method and the set-up
#: decide, not an interruption or an exception.
EXPECTABLE = tuple(o for o in Outcome if o not in (Outcome.INTERRUPTED, Outcome.ERROR))
