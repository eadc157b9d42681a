"""When each process of a command reaches each of its phases: for `benchmarks/bench_startup.py`.

Why: on a loaded 2-core machine the wall time of `rodctl simulate` says little, and its CPU
time says nothing of which process the command waits for. With `RODCTL_TIMELINE` set to a file,
the command and its helper processes (`rodctl.helper_process`) each append one line per phase
they reach: `pid role event monotonic_s cpu_s` (the system-wide monotonic clock, so that the
lines of several processes compare; the CPU time of that process so far). Unset, `mark` costs
one dictionary lookup.
"""

from __future__ import annotations

import os
import time

#: The environment variable naming the file the lines go to (appended to; never truncated).
ENV = "RODCTL_TIMELINE"


def mark(role: str, event: str) -> None:
    """Append `role event` with the time now, if `RODCTL_TIMELINE` names a file (never raises:
    a timeline that cannot be written is no reason for a run to fail)."""
    path = os.environ.get(ENV)
    if not path:
        return
    line = f"{os.getpid()} {role} {event} {time.monotonic():.6f} {time.process_time():.6f}\n"
    try:
        # One short write with O_APPEND: the lines of several processes do not interleave.
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line.encode())
        finally:
            os.close(fd)
    except OSError:
        pass
