"""Notices said once per run, even when the run's episodes are spread over worker processes.

Why: a notice such as "this checkpoint was trained for another set-up" is said where the
config is validated or the stage built, and a compare validates and builds in its own process
(the preflight) and again in every worker for every episode. A set in each process says it once
per process; `say_once` says it once per run: when the command process starts local worker
processes (`share_with_workers`, called by the local executor before it spawns them), it gives
them a folder of markers through the environment (`ENV`), and the first process to create a
notice's marker (O_EXCL, atomic) is the one that prints it. Without such a folder (one process,
or workers on other machines) it is once per process.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import sys
import tempfile
from pathlib import Path

#: The environment variable naming the marker folder that the run's processes share.
ENV = "RODCTL_NOTICES_DIR"

#: Notices already said (or seen said) in this process, by key.
_SAID: set[str] = set()


def _claim(folder: str, key: str) -> bool:
    """Whether this process is the first of the run to say `key` (creates its marker)."""
    marker = Path(folder) / hashlib.sha256(key.encode()).hexdigest()[:32]
    try:
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    except FileExistsError:
        return False
    except OSError:
        return True  # no marker (folder gone, disk full): saying it twice beats never
    return True


def say_once(key: str, text: str) -> None:
    """Print `text` on stderr unless `key` was said already in this run (see the module doc)."""
    if key in _SAID:
        return
    _SAID.add(key)
    folder = os.environ.get(ENV)
    if folder and not _claim(folder, key):
        return
    print(text, file=sys.stderr, flush=True)


def share_with_workers() -> None:
    """Make the notices of this process and of the worker processes it starts next shared:
    a marker folder in the environment (inherited at spawn), holding what was said already.
    Idempotent; the folder is removed when the process exits."""
    folder = os.environ.get(ENV)
    if not folder or not Path(folder).is_dir():
        folder = tempfile.mkdtemp(prefix="rodctl-notices-")
        os.environ[ENV] = folder
        atexit.register(shutil.rmtree, folder, True)
    for key in _SAID:
        _claim(folder, key)
