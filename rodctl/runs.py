"""Run directory lifecycle: unique id, resolved config, meta.json status, seeds.

A run directory is ``<parent>/<YYYYmmdd-HHMMSS>_<name>/`` and is never overwritten: when two runs
start in the same second, the later one gets a ``-2``, ``-3``… suffix. `meta.json` is rewritten
atomically (write to a temporary file, then rename) so a crash never leaves it half-written.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pydantic import BaseModel

from rodctl.config import dump_config
from rodctl.errors import RunFailed, UserError, describe_os_error, make_out_folder, out_error
from rodctl.registry import component_provenance, plugin_provenance, stage_provenance
from rodctl.runlock import unlock_run_folder

#: Every consumer of randomness, in a fixed order. Each gets its own independent stream derived
#: from the config's one seed; append new names at the end so existing streams stay unchanged.
SEED_CONSUMERS = (
    "targets",
    "camera",
    "data",
    "torch",
    "sim",
    "probing",
    "compare",
    "sweep",
    "model-data",
)

#: Distributions whose versions meta.json records.
_VERSIONED = (
    "rodctl",
    "numpy",
    "scipy",
    "torch",
    "pymunk",
    "rerun-sdk",
    "mcap",
    "pydantic",
    "opencv-python-headless",
)

STATUSES = ("running", "completed", "failed", "interrupted")


def seed_sequence(seed: int, consumer: str) -> np.random.SeedSequence:
    """The SeedSequence of one named consumer, derived from the experiment seed."""
    try:
        index = SEED_CONSUMERS.index(consumer)
    except ValueError:
        raise KeyError(f"unknown seed consumer {consumer!r}; known: {SEED_CONSUMERS}") from None
    return np.random.SeedSequence(seed, spawn_key=(index,))


def rng(seed: int, consumer: str) -> np.random.Generator:
    """An independent `numpy.random.Generator` for one named consumer."""
    return np.random.Generator(np.random.PCG64(seed_sequence(seed, consumer)))


def torch_seed(seed: int) -> int:
    """The integer to pass to `torch.manual_seed`, derived like every other stream."""
    return int(seed_sequence(seed, "torch").generate_state(1, dtype=np.uint64)[0] >> 1)


def package_versions() -> dict[str, str | None]:
    """Installed versions of the packages a result depends on (None where absent)."""
    out: dict[str, str | None] = {"python": sys.version.split()[0]}
    for dist in _VERSIONED:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def git_sha(here: Path | None = None) -> str | None:
    """The source tree's commit (with a ``-dirty`` suffix for uncommitted changes), if any.

    Read-only: `--no-optional-locks` keeps `git status` from refreshing the index, which
    would create `.git/index.lock` in the user's checkout and race with their own git commands.
    """
    here = here or Path(__file__).resolve().parent
    git = ["git", "--no-optional-locks"]
    try:
        sha = subprocess.run(
            [*git, "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
        )
        if sha.returncode != 0:
            return None
        dirty = subprocess.run(
            [*git, "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def jsonable(value: Any) -> Any:
    """A copy that strict JSON can hold: numpy values as Python ones, NaN and infinity as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray | np.generic):
        return jsonable(value.tolist())
    return value


def write_json_atomic(path: Path, data: Any, *, reserve: int = 0) -> None:
    """Write `jsonable(data)` to `path` via a temporary file and a rename, so readers never see
    half a file and every JSON parser reads it (no NaN).

    Args:
        reserve: pad the file with trailing whitespace (valid JSON) to at least this many
            bytes: space already on disk that `write_json_best_effort` can rewrite in place
            when the disk is full.
    """
    tmp = path.with_name(path.name + ".tmp")
    text = json.dumps(jsonable(data), indent=2, allow_nan=False) + "\n"
    text += " " * max(0, reserve - len(text.encode("utf-8")))
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def write_json_best_effort(path: Path, data: Any, *, reserve: int = 0) -> str | None:
    """Write JSON even on a full disk if at all possible; the error message if not.

    First atomically (`write_json_atomic`). If that fails and the file exists, it is
    overwritten in place *without* truncating it, so no new block is needed while the new text
    fits in the old file's size (a file written with `reserve` has room to spare); the rest is
    blanked with spaces. The text without the bulky descriptive keys is tried when the full one
    does not fit: the status and the error are what must get through.
    """
    try:
        write_json_atomic(path, data, reserve=reserve)
        return None
    except OSError as exc:
        first = describe_os_error(exc)
    try:
        size = path.stat().st_size
    except OSError:
        return first
    for text in (
        json.dumps(jsonable(data), separators=(",", ":"), allow_nan=False),
        json.dumps(
            jsonable({k: v for k, v in data.items() if k not in _BULKY}),
            separators=(",", ":"),
            allow_nan=False,
        ),
    ):
        raw = text.encode("utf-8")
        if len(raw) > size:
            continue
        try:
            with path.open("r+b") as fh:
                fh.write(raw + b" " * (size - len(raw)))
            return None
        except OSError:
            continue
    return first


#: meta.json keys a full disk may have to go without (descriptive, also in the MCAP header).
_BULKY = ("numeric_env", "versions", "argv", "plugins", "stages")

#: Bytes meta.json keeps on disk so that its final status can be written on a full disk.
META_RESERVE = 16_384


#: What a run folder holds before anything ran: `RunDir.create`'s files, the encoder
#: checkpoint copied in at the start (`rodctl.portable`) and a batch run's journal lock
#: (`rodctl.runlock`).
_START_FILES = frozenset({"config.yaml", "meta.json", "encoder.npz", "encoder.pt", "journal.lock"})


class NamedConfig(Protocol):
    """A config a run directory is made for (an experiment, compare, sweep or suite config: a
    pydantic model with these fields)."""

    @property
    def name(self) -> str: ...

    @property
    def seed(self) -> int: ...


@dataclass
class RunDir:
    """One run's output folder and its meta.json."""

    path: Path
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def run_id(self) -> str:
        """The folder name, e.g. ``20261123-101500_default``; also the Rerun recording id."""
        return self.path.name

    @classmethod
    def create(
        cls, parent: str | Path, cfg: NamedConfig, command: str, argv: list[str] | None = None
    ) -> RunDir:
        """Make a new, unique run directory under `parent` and write config.yaml and meta.json.

        `cfg` is any config with a `name` and a `seed` (an experiment or a compare config).
        """
        parent = make_out_folder(parent)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        base = f"{stamp}_{cfg.name}"
        for n in range(1, 10_000):
            path = parent / (base if n == 1 else f"{base}-{n}")
            try:
                path.mkdir()
                break
            except FileExistsError:
                continue
            except OSError as exc:
                raise out_error("--out", parent, "cannot create a run directory", exc) from None
        else:  # pragma: no cover - 10k runs in one second
            raise UserError(f"{parent}: too many runs named {base!r}")
        run = cls(path=path)
        run.meta = {
            "run_id": path.name,
            "command": command,
            "status": "running",
            "argv": list(sys.argv if argv is None else argv),
            "seed": cfg.seed,
            "versions": package_versions(),
            "git_sha": git_sha(),
            # Who built the method: every plug-in loaded, every built-in it was allowed to
            # replace, and the registered factory of each stage (docs/reliability.md).
            "plugins": plugin_provenance(),
            "stages": stage_provenance(cfg),
            # ... and of its mid-run events and sinks (compare, sweep: `executor` too).
            **component_provenance(cfg),
            "started_at": _now(),
            "ended_at": None,
        }
        assert isinstance(cfg, BaseModel)  # every config is a pydantic model
        try:
            run.write_meta()
            (path / "config.yaml").write_text(dump_config(cfg), encoding="utf-8")
        except OSError as exc:
            # Nothing has run yet: leave no half-written run directory behind.
            shutil.rmtree(path, ignore_errors=True)
            raise RunFailed(f"cannot start the run in {parent}: {describe_os_error(exc)}") from None
        return run

    def write_meta(self) -> None:
        """Rewrite meta.json from `self.meta` (keeping `META_RESERVE` bytes on disk for it)."""
        write_json_atomic(self.path / "meta.json", self.meta, reserve=META_RESERVE)

    def discard_if_empty(self) -> bool:
        """Remove the run directory if it holds only what `create` wrote, and the encoder
        checkpoint a run copies in before its first step (`rodctl.portable`: encoder.npz or
        encoder.pt): bad input found after it was made (an unreachable target, a rod that does
        not settle, a file that is not a dataset) leaves nothing, as bad input found before
        does. True when it was removed."""
        try:
            if {p.name for p in self.path.iterdir()} <= _START_FILES:
                shutil.rmtree(self.path)
                return True
        except OSError:
            pass
        return False

    def finish(self, status: str, **extra: Any) -> str | None:
        """Record the terminal status (completed, failed or interrupted) and the end time.

        Never raises for a full disk: returns the error message when meta.json could not be
        written at all (the caller says so), else None.
        """
        if status not in STATUSES[1:]:
            raise ValueError(f"terminal status must be one of {STATUSES[1:]}, got {status!r}")
        self.meta.update(status=status, ended_at=_now(), **extra)
        try:
            return write_json_best_effort(self.path / "meta.json", self.meta, reserve=META_RESERVE)
        finally:
            unlock_run_folder(self.path)  # the run's journal lock, if it took one
