"""Helpers of the fault-injection suite."""

from __future__ import annotations

import os
from pathlib import Path


def fill(folder: Path) -> None:
    """Fill a filesystem to the last byte (unbuffered writes, smaller and smaller)."""
    for name, size in (("filler", 65536), ("filler2", 512), ("filler3", 1)):
        try:
            fd = os.open(folder / name, os.O_WRONLY | os.O_CREAT)
        except OSError:
            return
        try:
            while True:
                os.write(fd, b"\0" * size)
        except OSError:
            pass
        finally:
            os.close(fd)
