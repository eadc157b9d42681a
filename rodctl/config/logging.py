"""Config of what a run writes: MCAP log, Rerun recording, figures.

Owned by `rodctl/logs/`.
"""

from __future__ import annotations

from pydantic import Field

from rodctl.config.base import StrictModel


class LoggingConfig(StrictModel):
    """Which outputs a run writes next to its summary."""

    mcap: bool = Field(True, description="Write run.mcap (Foxglove-compatible log).")
    rerun: bool = Field(True, description="Write run.rrd (Rerun recording).")
    figures: bool = Field(True, description="Write the paper's figures as PNG under figures/.")
