"""One journal per run folder, results.jsonl: one final row per episode, and `--resume`.

Why: `compare` and `sweep` append each finished episode to results.jsonl (`ResultsLog`) and
`--resume` reads it back. A resumed run that re-runs an episode (compare's figure target, for
its records) would write a second final row for it, and two processes on one folder would both
run the missing episodes (the folder's lock refuses the second: `rodctl.runlock`). So:

- `dedupe` is the one reading rule for results.jsonl: per episode key the last final row wins
  (a final row is any outcome but `interrupted`); a key with no final row keeps its last row.
  Writers append a final row only for a key that has none (`ResultsLog.append`), and
  `compact` rewrites the file to the deduped rows when a resumed run superseded some (an
  interrupted row replaced by the episode's final one), so each key appears once.
- `start_run` makes a run folder with its config hash in meta.json, or reopens the `--resume`
  folder after checking that the config hashes the same (`open_resumed_run`); `finished_rows`
  is what a resumed run keeps.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from rodctl.bench.tasks import EpisodeTask, row_key
from rodctl.errors import UserError
from rodctl.registry import component_provenance
from rodctl.runlock import lock_run_folder
from rodctl.runs import RunDir, jsonable

#: The outcome of an episode that did not finish; every other outcome is final.
INTERRUPTED = "interrupted"


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


class ResultsLog:
    """results.jsonl: one JSON line per finished episode, appended and fsync'ed at once.

    The crash-safe record of a run: whatever stops it (SIGKILL, power loss), every episode that
    finished is on disk, and `--resume` reads them back. A line cut by a crash is ignored.
    One final row per episode key (this module): a final row for a key that already has
    one is not written again, and `read` dedupes (the last final row per key wins).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._final: dict[tuple, dict[str, Any]] | None = None
        self._tail_checked = False

    def append(self, row: dict[str, Any]) -> dict[str, Any]:
        """Write `row`; returns the journal's row for its episode (an earlier final row of the
        same key, which stays the record, with `row`'s in-memory `_` fields)."""
        if self._final is None:
            self._final = {row_key(r): r for r in self.read() if is_final(r)}
        clean = {k: v for k, v in row.items() if not k.startswith("_")}
        key = row_key(row)
        if is_final(row) and key in self._final:
            return {**self._final[key], **{k: v for k, v in row.items() if k.startswith("_")}}
        line = json.dumps(jsonable(clean))
        with self.path.open("a", encoding="utf-8") as fh:
            if not self._tail_checked and fh.tell() > 0 and not self._ends_with_newline():
                fh.write("\n")  # after a line a crash cut: this row must not be glued to it
            self._tail_checked = True
            fh.write(line + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        if is_final(row):
            self._final[key] = json.loads(line)
        return row

    def _ends_with_newline(self) -> bool:
        with self.path.open("rb") as fh:
            fh.seek(-1, os.SEEK_END)
            return fh.read(1) == b"\n"

    def _read_all(self) -> list[dict[str, Any]]:
        if not self.path.is_file():
            return []
        rows = []
        for line in self.path.read_text(encoding="utf-8").splitlines():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return rows

    def read(self) -> list[dict[str, Any]]:
        """Every whole row written so far (a torn last line is skipped), one per episode key."""
        return dedupe(self._read_all(), row_key)

    def compact(self) -> None:
        """Drop the rows later ones superseded (an interrupted episode run again to its end)."""
        try:
            compact(self.path, self._read_all(), row_key)
        except OSError:
            pass  # left as it is: every reader dedupes the same way


def finished_rows(log: ResultsLog, tasks: Sequence[EpisodeTask]) -> dict[tuple, dict[str, Any]]:
    """The rows of `log` (an earlier, interrupted run) that `--resume` keeps, by episode key.

    An episode counts as finished whatever its outcome except `interrupted`. A task that wants
    its records runs again anyway (compare's figure target: its records are not in the log).
    """
    wanted = {t.key for t in tasks if not t.want_records}
    out = {}
    for row in log.read():
        key = row_key(row)
        if key in wanted and is_final(row):
            out[key] = row
    return out


def config_hash(data: Any) -> str:
    """sha256 of a resolved config (canonical JSON): what `--resume` requires unchanged."""
    text = json.dumps(jsonable(data), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _dotted_diff(old: Any, new: Any, prefix: str = "") -> list[str]:
    """The dotted keys whose values differ between two plain-data configs."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new), key=str):
            out += _dotted_diff(old.get(k), new.get(k), f"{prefix}{k}.")
        return out
    return [] if old == new else [prefix.rstrip(".") or "(whole config)"]


def open_resumed_run(folder: str | Path, command: str, hashed: dict[str, Any]) -> RunDir:
    """Reopen `folder` (a run of `command`) to finish it; its config must hash the same.

    Raises:
        UserError: not a run folder of that command, or the config changed (names the keys).
    """
    path = Path(folder)
    meta_path = path / "meta.json"
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise UserError(f"--resume {path}: not a run folder ({meta_path}: {exc})") from None
    if meta.get("command") != command:
        raise UserError(
            f"--resume {path}: a run of `rodctl {meta.get('command')}`, not `rodctl {command}`"
        )
    old = meta.get("resume", {}).get("hashed")
    if old is None:
        raise UserError(f"--resume {path}: meta.json has no config hash to check against")
    if config_hash(old) != config_hash(hashed):
        changed = [
            c.removeprefix("config.") if c != "targets" else "the targets file's poses"
            for c in _dotted_diff(jsonable(old), jsonable(hashed))
        ]
        raise UserError(
            f"--resume {path}: the config changed since that run (resume needs the same "
            f"config; workers and executor may differ): {', '.join(changed[:10])}"
            + (f" and {len(changed) - 10} more" if len(changed) > 10 else "")
        )
    lock_run_folder(path, command)  # held until run.finish; refused if in use
    run = RunDir(path=path, meta=meta)
    run.meta.update(status="running", ended_at=None)
    run.meta.pop("error", None)
    run.meta.setdefault("resumed", []).append({"argv": list(sys.argv)})
    run.write_meta()
    return run


def start_run(
    out: str,
    cfg: Any,
    command: str,
    hashed: dict[str, Any],
    resume: str | None,
    executor: str | None = None,
) -> RunDir:
    """A new run folder (config hash in meta.json; `executor`: the `--executor` kind, its
    factory recorded as the run's `executor`), or the `--resume` one reopened."""
    if resume is not None:
        return open_resumed_run(resume, command, hashed)
    run = RunDir.create(out, cfg, command=command)
    lock_run_folder(run.path, command)  # held until run.finish
    run.meta["resume"] = {"config_hash": config_hash(hashed), "hashed": jsonable(hashed)}
    if executor is not None:
        run.meta.update(component_provenance(None, executor))
    run.write_meta()
    return run
