"""The sink protocol: what the loop (and replay) hands every output writer."""

from __future__ import annotations

from typing import Protocol

from rodctl.records import RunHeader, RunSummary, StepRecord


class Sink(Protocol):
    """Receives a run as plain records. Must leave a readable file after `close`, whatever the
    status, and must not lose what was written before an exception or a signal."""

    def open(self, header: RunHeader) -> None:
        """Start the output; called once, before the first step."""

    def write(self, record: StepRecord) -> None:
        """Append one step."""

    def close(self, summary: RunSummary | None, status: str) -> None:
        """Finalise the output. `status` is "completed", "failed" or "interrupted"."""
