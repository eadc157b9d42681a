"""The sink protocol: what the loop (and replay) hands every output writer."""

from __future__ import annotations

import warnings
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


def raise_or_warn(errors: list[BaseException], status: str, what: str) -> None:
    """The sinks' policy for failures while closing: raise for a completed run; otherwise
    warn, so that a closing failure never masks the exception that ended the run."""
    if not errors:
        return
    if status == "completed":
        raise errors[0]
    warnings.warn(f"{what}: {errors[0]!r}", RuntimeWarning, stacklevel=3)
