"""The run folder's lock: an OS lock held for the whole run, so two processes never write one
folder (two `--resume` at once would both run the missing episodes and write them twice).

`lock_run_folder` takes an exclusive `fcntl.flock` on ``<folder>/journal.lock`` before the
folder is touched and keeps it until the run ends (`RunDir.finish` releases it; the OS drops it
when the process dies, SIGKILL included, so a killed run can always be resumed). A second process
is refused, exit 2, with the holder's pid, command and start time, which the holder writes into
the lock file. The journal the lock protects is `rodctl.bench.journal`.
"""

from __future__ import annotations

import fcntl
import json
import os
import sys
from datetime import UTC, datetime
from pathlib import Path

from rodctl.errors import UserError

#: The lock file in a run folder (its text: the holder's pid, command and start time).
LOCK_NAME = "journal.lock"

_HELD: dict[Path, int] = {}  # run folder -> the open lock file's descriptor


def lock_run_folder(folder: Path, command: str) -> None:
    """Hold the run folder's journal lock until `unlock_run_folder` (or the process's end).

    Raises:
        UserError: another process holds it; the message names that process.
    """
    folder = Path(folder).resolve()
    if folder in _HELD:
        return
    path = folder / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise UserError(f"{folder}: cannot open the run folder's lock {path}: {exc}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = _describe_holder(fd)
        os.close(fd)
        raise UserError(
            f"{folder}: the run folder is in use by {holder}; two processes must not write one "
            "journal. Wait for it to end (or stop it), then --resume"
        ) from None
    info = {
        "pid": os.getpid(),
        "command": command,
        "argv": list(sys.argv),
        "started_at": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode("utf-8"), 0)
    except OSError:
        pass  # a full disk: the lock holds all the same, only the holder's description is lost
    _HELD[folder] = fd


def unlock_run_folder(folder: Path) -> None:
    """Release the lock `lock_run_folder` took (a no-op when this process does not hold it)."""
    fd = _HELD.pop(Path(folder).resolve(), None)
    if fd is None:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _describe_holder(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 65536, 0).decode("utf-8"))
        argv = " ".join(str(a) for a in info.get("argv") or [])
        return (
            f"pid {info['pid']} (rodctl {info['command']}: `{argv}`, started {info['started_at']})"
        )
    except (OSError, ValueError, KeyError, TypeError):
        return "another process (it has not written its pid yet)"
