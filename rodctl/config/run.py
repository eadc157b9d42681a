"""Config of the experiment loop: step budget, targets and stopping criteria.

Owned by `rodctl/experiment.py`.
"""

from __future__ import annotations

from pydantic import Field

from rodctl.config.base import StrictModel


class RunConfig(StrictModel):
    """How long a run lasts and when it stops."""

    max_steps: int = Field(200, ge=1, description="Step limit, probing steps included.")
