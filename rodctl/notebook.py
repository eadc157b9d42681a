"""Results in a notebook: `rodctl.load_run` and `rodctl.load_results` (docs/python-api.md).

`load_results` takes the folder of a compare, sweep or suite (or one of its results files) and
returns a pandas DataFrame with one row per episode. A finished run is read from results.csv; a
run still going, or interrupted, from results.jsonl (every episode as it finished, the same
columns as results.csv for a compare). pandas is optional (`pip install -e ".[notebook]"`): the
rest of rodctl does not need it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rodctl.errors import UserError


def _pandas() -> Any:
    try:
        import pandas
    except ImportError:
        raise ModuleNotFoundError(
            "rodctl.load_results returns a pandas DataFrame and needs pandas: "
            "pip install pandas (or pip install -e '.[notebook]')",
            name="pandas",
        ) from None
    return pandas


def results_file(path: str | Path) -> Path:
    """The results file of a run folder: results.csv, else results.jsonl; a file as given.

    Raises:
        UserError: no such folder or file, a folder with neither results file, or a file that
            is not a `.csv` or `.jsonl` (a run's results.json, summary.md or config.yaml).
    """
    p = Path(path)
    if p.is_file():
        if p.suffix.lower() not in (".csv", ".jsonl"):
            raise UserError(
                f"{p}: not a results file: load_results reads a compare, sweep or suite "
                "folder, or its results.csv or results.jsonl"
            )
        return p
    if not p.is_dir():
        raise UserError(f"{p}: no such run folder or results file")
    for name in ("results.csv", "results.jsonl"):
        if (p / name).is_file():
            return p / name
    raise UserError(
        f"{p}: no results.csv or results.jsonl (a compare, sweep or suite folder has them; "
        "for a simulate run use rodctl.load_run)"
    )


def load_results(path: str | Path) -> Any:
    """One row per episode of a compare, sweep or suite, as a pandas DataFrame.

    Args:
        path: the run folder (what `rodctl compare` printed last), or its results.csv or
            results.jsonl.

    Returns:
        A DataFrame with results.csv's columns (for a compare: `rodctl.bench.compare.CSV_COLUMNS`);
        empty cells are NaN.

    Raises:
        ModuleNotFoundError: pandas is not installed (the message says how to install it).
        UserError: no results there, or a file that is not a results table.
    """
    pd = _pandas()
    file = results_file(path)
    if file.suffix.lower() == ".jsonl":
        rows = []
        for line in file.read_text(encoding="utf-8").splitlines():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                continue  # a line cut by a crash, as `ResultsLog.read` skips it
        frame = pd.DataFrame(rows)
        from rodctl.bench.compare import CSV_COLUMNS

        first = [c for c in CSV_COLUMNS if c in frame.columns]
        frame = frame[first + [c for c in frame.columns if c not in first]]
        if "error" in frame:  # as read from results.csv: no error is an empty cell
            frame["error"] = frame["error"].mask(frame["error"] == "")
        return frame
    try:
        return pd.read_csv(file)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise UserError(f"{file}: cannot be read as a results table: {exc}") from None


def load_run(path: str | Path, *, recover: bool = False, images: bool = True) -> Any:
    """A `rodctl simulate` run read back from its MCAP log (`rodctl.replay.read_run`).

    Returns:
        `ReadRun`: `.header` (run id, embedded config YAML, numeric environment), `.records`
        (one `StepRecord` a step: features, commands, pixel error, T1, images...), `.summary`
        (the logged summary dict), `.status`, `.complete`, `.warnings`.
    """
    from rodctl.replay import read_run

    return read_run(path, recover=recover, images=images)
