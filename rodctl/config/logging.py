"""Config of what a run writes: MCAP log, Rerun recording, figures.

Owned by `rodctl/logs/`. The MCAP knobs trade crash safety against file size: a chunk is closed
and the file flushed every `flush_every_steps` steps (or earlier when a chunk reaches
`mcap_chunk_size`), so a run killed without warning loses at most that many steps.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rodctl.config.base import StrictModel


class LoggingConfig(StrictModel):
    """Which outputs a run writes next to its summary, and how."""

    mcap: bool = Field(True, description="Write run.mcap (Foxglove-compatible log).")
    rerun: bool = Field(True, description="Write run.rrd (Rerun recording).")
    figures: bool = Field(True, description="Write the paper's figures as PNG under figures/.")
    image_rate_hz: float = Field(
        5.0,
        le=1000.0,
        ge=0.0,
        description="Camera frames logged per second of simulated time, which is the logs' "
        "time (0 = none). The sinks pick the frames by simulated time; at most one per control "
        "step.",
    )
    png_compression: int = Field(
        1, ge=0, le=9, description="PNG (zlib) level of logged camera frames: 0 fast … 9 small."
    )
    mcap_compression: Literal["zstd", "lz4", "none"] = Field(
        "zstd", description="Compression of MCAP chunks."
    )
    mcap_chunk_size: int = Field(
        1 << 20,
        le=1 << 30,
        ge=1024,
        description="Uncompressed bytes after which an MCAP chunk is closed and written.",
    )
    flush_every_steps: int = Field(
        10,
        le=100_000,
        ge=1,
        description="Every this many steps, close the MCAP chunk and flush it to the OS, and send "
        "the buffered Rerun rows; a run killed without warning loses at most these steps.",
    )
