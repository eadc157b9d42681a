"""Config of what a run writes: MCAP log, Rerun recording, figures, and any other sink.

Owned by `rodctl/logs/` (the sink types: `rodctl/logs/sinks.py`). The MCAP knobs trade crash
safety against file size: a chunk is closed and the file flushed every `flush_every_steps`
steps (or earlier when a chunk reaches `mcap_chunk_size`), so a run killed without warning
loses at most that many steps.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, model_validator

from rodctl.config.base import StageConfig, StageSlot, StrictModel
from rodctl.registry import depends_on_stages

#: One output sink, chosen by `type` among every type registered in `rodctl.registry.SINKS`.
SinkSlot = Annotated[StageConfig, StageSlot("sink")]


@depends_on_stages
class LoggingConfig(StrictModel):
    """Which outputs a run writes next to its summary, and how."""

    # The sinks' union is built from the registry when first needed (after the plug-ins).
    model_config = ConfigDict(defer_build=True)

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
    sinks: list[SinkSlot] = Field(
        default_factory=list,
        description="More sinks, each by `type` with its options (a plug-in's, e.g. a CSV table; "
        "`rodctl plugins` lists the types). MCAP, Rerun and figures are switched by the keys "
        "above (docs/plugins.md).",
    )

    @model_validator(mode="after")
    def _switched_sinks_not_listed(self) -> LoggingConfig:
        """A built-in sink with its own switch (`mcap: true`) is not listed in `sinks` too."""
        for i, sink in enumerate(self.sinks):
            switch: Any = getattr(sink, "switch", None)
            name = sink.type
            if switch:
                raise ValueError(
                    f"sinks[{i}]: the {name!r} sink is switched by logging.{switch}: true, not "
                    "listed in logging.sinks"
                )
        return self

    @property
    def writes_episode_logs(self) -> bool:
        """Whether an episode run with this config writes a log file (MCAP, Rerun or a listed
        sink): what a study's `keep_logs` keeps."""
        return self.mcap or self.rerun or bool(self.sinks)


#: What a study says of `keep_logs: true` where the base's logging writes no log file.
NO_LOGS_TO_KEEP = (
    "keep_logs: true keeps each episode's run.mcap (or run.rrd, or a sink's file), but "
    "base.logging writes none of them (mcap and rerun false, no sinks): set "
    "base.logging.mcap=true, or leave keep_logs out"
)
