"""Where episodes run: this process, a local process pool, or Ray (`base.Executor`)."""

from rodctl.executors.base import (
    MAX_RETRIES,
    Done,
    Executor,
    clear_stop,
    make_executor,
    request_stop,
    sigterm_as_interrupt,
    stop_handlers,
    stop_reason,
)

__all__ = [
    "MAX_RETRIES",
    "Done",
    "Executor",
    "clear_stop",
    "make_executor",
    "request_stop",
    "sigterm_as_interrupt",
    "stop_handlers",
    "stop_reason",
]
