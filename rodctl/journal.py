"""One journal per run folder: an OS lock held for the whole run, and one final row per episode.

Why: `compare` and `sweep` append each finished episode to results.jsonl and `--resume` reads
it back. Two processes on one folder (two `--resume` at once) would both run the missing
episodes and write them twice; a resumed run that re-runs an episode (compare's figure target,
for its records) would write a second final row for it. So:

- `lock_run_folder` takes an exclusive `fcntl.flock` on ``<folder>/journal.lock`` before the
  folder is touched and keeps it until the run ends (the OS drops it when the process dies,
  SIGKILL included, so a killed run can always be resumed). A second process is refused, exit
  2, with the holder's pid, command and start time, which the holder writes into the lock file.
- `dedupe` is the one reading rule for results.jsonl: per episode key the last final row wins
  (a final row is any outcome but `interrupted`); a key with no final row keeps its last row.
  Writers append a final row only for a key that has none (`ResultsLog.append`), and
  `compact` rewrites the file to the deduped rows when a resumed run superseded some (an
  interrupted row replaced by the episode's final one), so each key appears once.
"""

from __future__ import annotations

import fcntl
import json
import os
import sys
from collections.abc import Callable, Iterable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rodctl.errors import UserError

#: The lock file in a run folder (its text: the holder's pid, command and start time).
LOCK_NAME = "journal.lock"

#: The outcome of an episode that did not finish; every other outcome is final.
INTERRUPTED = "interrupted"

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


def is_final(row: dict[str, Any]) -> bool:
    """A row that records how an episode ended (anything but `interrupted`)."""
    return row.get("outcome") != INTERRUPTED


def dedupe(rows: Iterable[dict[str, Any]], key: Callable[[dict], Any]) -> list[dict[str, Any]]:
    """One row per episode key: the last final row, else the last row; in file order of the
    rows kept. Rows without a key (not episode rows) are kept as they are."""
    rows = list(rows)
    chosen: dict[Any, int] = {}
    keyless: list[int] = []
    for i, row in enumerate(rows):
        try:
            k = key(row)
        except (KeyError, TypeError):
            keyless.append(i)
            continue
        j = chosen.get(k)
        if j is None or is_final(row) or not is_final(rows[j]):
            chosen[k] = i
    return [rows[i] for i in sorted([*chosen.values(), *keyless])]


def compact(path: Path, rows: list[dict[str, Any]], key: Callable[[dict], Any]) -> None:
    """Rewrite the journal `path` (whose whole rows are `rows`) to `dedupe(rows)` when that
    drops any, atomically (a temporary file, fsync, rename). A write error leaves the file as
    it was: its readers dedupe the same way."""
    kept = dedupe(rows, key)
    if len(kept) == len(rows):
        return
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("w", encoding="utf-8") as fh:
            for row in kept:
                fh.write(json.dumps(row) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
