"""Helpers for the compare / sweep / executor tests: run the CLI in a child process, signal it
once some episodes have finished, and read what it left behind."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from paths import REPO

#: Columns that measure time: the only ones allowed to differ between two runs of one config.
TIMING = ("wall_time_s",)


def rows(folder: Path, timing: bool = False) -> list[dict[str, str]]:
    """results.csv as dicts (without the timing columns unless asked)."""
    with (folder / "results.csv").open() as fh:
        out = list(csv.DictReader(fh))
    return out if timing else [{k: v for k, v in r.items() if k not in TIMING} for r in out]


def journal(folder: Path) -> list[dict]:
    path = folder / "results.jsonl"
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def children(pid: int) -> list[int]:
    """Every descendant of `pid` (from /proc), nearest first."""
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        kids.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        for c in kids.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def alive(pid: int) -> bool:
    """True if `pid` runs (a zombie counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


@dataclass
class Interrupted:
    folder: Path
    returncode: int
    stop_seconds: float  # from the signal to the process's exit
    leftovers: list[int]  # descendants still alive 5 s after the exit
    stderr: str


def interrupt(
    args: list[str],
    out: Path,
    after_rows: int,
    sig: int,
    to_worker: bool = False,
    timeout: float = 240.0,
) -> Interrupted:
    """Run `rodctl ARGS --out OUT -q` in a child process, send `sig` once `after_rows` episodes
    are in results.jsonl (to the process, or to one of its worker processes), and wait."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "rodctl", *args, "--out", str(out), "-q"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    deadline = time.monotonic() + timeout
    folder = None
    try:
        while time.monotonic() < deadline:
            found = sorted(p for p in out.iterdir() if p.is_dir())
            if found:
                folder = found[-1]
                if len(journal(folder)) >= after_rows:
                    break
            if proc.poll() is not None:
                raise AssertionError(f"finished before the signal: {proc.communicate()}")
            time.sleep(0.1)
        else:
            raise AssertionError("no episode finished in time")
        descendants = children(proc.pid)
        target = proc.pid
        if to_worker:
            workers = [p for p in descendants if "spawn_main" in cmdline(p)]
            assert workers, f"no worker process among {descendants}"
            target = workers[0]
        t0 = time.monotonic()
        os.kill(target, sig)
        stdout, stderr = proc.communicate(timeout=120)
        stop = time.monotonic() - t0
        end = time.monotonic() + 5
        while any(alive(p) for p in descendants) and time.monotonic() < end:
            time.sleep(0.1)
        assert folder is not None
        assert stdout.strip().splitlines()[-1] == str(folder), stdout
        return Interrupted(
            folder, proc.returncode, stop, [p for p in descendants if alive(p)], stderr
        )
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def send_self_after(folder_parent: Path, after_rows: int, sig: int = signal.SIGINT) -> None:
    """In a thread: send `sig` to this process once a run under `folder_parent` has
    `after_rows` rows in its journal (an in-process run interrupted like from a terminal)."""
    import threading

    def watch() -> None:
        end = time.monotonic() + 120
        while time.monotonic() < end:
            found = sorted(p for p in folder_parent.iterdir() if p.is_dir())
            if found and len(journal(found[-1])) >= after_rows:
                os.kill(os.getpid(), sig)
                return
            time.sleep(0.05)

    threading.Thread(target=watch, daemon=True).start()
