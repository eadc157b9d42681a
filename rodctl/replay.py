"""Reading a run back from its MCAP log, and rebuilding its other outputs from it alone.

Why: the MCAP is the run's source of truth. `rodctl replay RUN_DIR|FILE.mcap` must work with no
simulator, no model and no config file at hand: it reads the step records back exactly
(`rodctl.logs.codec`), rewrites run.rrd and the figures from them, and prints the summary.
`replay --verify` re-runs the simulation and compares each fresh record with the logged one using
`compare_records` (bit for bit: float64 values and dtypes equal, NaN equal to NaN).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rodctl.config.loading import safe_load
from rodctl.config.logging import LoggingConfig
from rodctl.errors import UserError
from rodctl.logs.codec import ReadRun
from rodctl.records import RunSummary, StepRecord

__all__ = [
    "ReadRun",
    "Rebuilt",
    "compare_records",
    "mcap_path",
    "read_run",
    "rebuild",
    "summary_rows",
    "format_summary",
]


def mcap_path(path: str | Path) -> Path:
    """The MCAP file of a run directory, or `path` itself when it is a file."""
    p = Path(path)
    if p.is_dir():
        f = p / "run.mcap"
        if not f.is_file():
            raise UserError(f"{p}: no run.mcap in this run directory")
        return f
    if not p.exists():
        raise UserError(f"{p}: no such run directory or file")
    return p


def read_run(path: str | Path, *, recover: bool = False, images: bool = True) -> ReadRun:
    """Read a run back from RUN_DIR/run.mcap or an MCAP file.

    Args:
        path: a run directory or an MCAP file.
        recover: accept a file whose writer never finished (killed run) and return its complete
            steps, with `complete=False` and a warning; otherwise such a file raises UserError.
        images: decode logged camera frames into `StepRecord.image`.

    Returns:
        ReadRun(path, header, records, summary | None, status | None, complete, warnings).

    Raises:
        UserError: missing, not MCAP, not a rodctl log, damaged, or incomplete without
            `recover`.
    """
    from rodctl.logs.mcap import read_mcap

    return read_mcap(mcap_path(path), recover=recover, images=images)


def _logging_config(config_yaml: str) -> LoggingConfig:
    """The run's logging settings from its resolved config; defaults if they do not parse."""
    try:
        data = yaml.safe_load(config_yaml)
        return LoggingConfig.model_validate((data or {}).get("logging", {}))
    except Exception:  # noqa: BLE001 - a replay must not fail on an old or foreign config
        return LoggingConfig()


def summary_object(summary: dict[str, Any] | None) -> RunSummary | None:
    """The logged summary mapping as a RunSummary (None when absent or not a full summary)."""
    if not summary:
        return None
    keys = [f.name for f in fields(RunSummary) if f.name != "extra"]
    # Wall-clock figures are not logged (RunSummary.INVOCATION_KEYS): unknown from the log.
    values = {k: math.nan for k in RunSummary.INVOCATION_KEYS if k in keys} | dict(summary)
    if any(k not in values for k in keys):
        return None
    for k in ("final_T1", "final_pixel_error", "wall_time_s", "steps_per_s"):
        v = values[k]
        values[k] = math.nan if v is None else float(v)
    extra = {k: v for k, v in values.items() if k not in keys}
    return RunSummary(**{k: values[k] for k in keys}, extra=extra)


@dataclass
class Rebuilt:
    """What `rebuild` read and wrote."""

    run: ReadRun
    rrd: Path | None
    figures: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def rebuild(
    path: str | Path,
    out_dir: str | Path | None = None,
    *,
    recover: bool = False,
    rerun: bool = True,
    figures: bool = True,
) -> Rebuilt:
    """Rewrite run.rrd and figures/ from a run's MCAP alone (no simulation).

    Args:
        path: a run directory or an MCAP file.
        out_dir: where to write; default the run directory (the MCAP file's folder).
        recover: accept an unfinished MCAP (see `read_run`).
        rerun: write `out_dir/run.rrd`.
        figures: write `out_dir/figures/*.png` with `rodctl.plots.write_figures`.

    Returns:
        The records read and the paths written.
    """
    src = mcap_path(path)
    run = read_run(src, recover=recover)
    out = Path(out_dir) if out_dir is not None else src.parent
    out.mkdir(parents=True, exist_ok=True)
    result = Rebuilt(run=run, rrd=None)
    if rerun:
        from rodctl.logs.rerun import RerunSink

        result.rrd = out / "run.rrd"
        sink = RerunSink(result.rrd, _logging_config(run.header.config_yaml))
        status = run.status or "interrupted"
        try:
            sink.open(run.header)
            for rec in run.records:
                sink.write(rec)
        finally:
            sink.close(summary_object(run.summary), status)
    if figures:
        try:
            from rodctl.plots import write_figures
        except ImportError as exc:  # pragma: no cover - plots ships with rodctl
            result.notes.append(f"figures skipped: {exc}")
        else:
            if run.records:
                result.figures = list(write_figures(run.header, run.records, out / "figures"))
            else:
                result.notes.append("figures skipped: no complete step in the log")
    return result


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if v is None:
        return "—"
    return str(v)


def summary_rows(run: ReadRun) -> list[tuple[str, str]]:
    """The run's summary as (name, value) rows for a table.

    The logged summary when the run closed with one; otherwise what the records say.
    """
    rows: list[tuple[str, str]] = [
        ("run_id", run.header.run_id),
        ("method", run.header.method),
        ("status", run.status or "unknown (writer never closed)"),
        ("file complete", "yes" if run.complete else "no (recovered)"),
        ("steps logged", str(len(run.records))),
    ]
    if run.summary:
        for k, v in run.summary.items():
            if k in ("status", "method"):
                continue
            rows.append((k, _fmt(v)))
    elif run.records:
        last = run.records[-1]
        rows += [
            ("last step", str(last.step)),
            ("final_T1", _fmt(float(last.T1))),
            ("final_pixel_error", _fmt(float(last.pixel_error))),
        ]
    return rows


def format_summary(run: ReadRun) -> str:
    """`summary_rows` as aligned plain text, warnings last."""
    rows = summary_rows(run)
    width = max(len(k) for k, _ in rows)
    lines = [f"{k.ljust(width)}  {v}" for k, v in rows]
    lines += [f"warning: {w}" for w in run.warnings]
    return "\n".join(lines)


def _same(a: Any, b: Any) -> bool:
    """Exact equality of two record values; numbers compared as float64 (NaN == NaN).

    Widening to float64 is exact, so a float32 array in a live record equals its float64
    read-back only if every value is the same number.
    """
    if isinstance(a, np.ndarray | list | tuple) or isinstance(b, np.ndarray | list | tuple):
        x, y = np.asarray(a), np.asarray(b)
        if x.shape != y.shape:
            return False
        if x.dtype.kind in "fiu" and y.dtype.kind in "fiu":
            return bool(np.array_equal(x.astype(np.float64), y.astype(np.float64), equal_nan=True))
        return bool(np.array_equal(x, y))
    if isinstance(a, bool | np.bool_) or isinstance(b, bool | np.bool_):
        return isinstance(a, bool | np.bool_) and isinstance(b, bool | np.bool_) and a == b
    if isinstance(a, int | float | np.number) and isinstance(b, int | float | np.number):
        fa, fb = float(a), float(b)
        return fa == fb or (math.isnan(fa) and math.isnan(fb))
    return type(a) is type(b) and a == b


def compare_records(
    logged: Sequence[StepRecord], fresh: Sequence[StepRecord], *, images: bool = False
) -> list[str]:
    """Every difference between two record sequences, bit for bit (empty = identical).

    Numbers are compared exactly as float64 (NaN equals NaN), arrays by shape and values,
    dicts key by key. `image` is compared only when `images` is True and both records carry one.
    """
    out: list[str] = []
    if len(logged) != len(fresh):
        out.append(f"step count differs: logged {len(logged)}, fresh {len(fresh)}")
    for a, b in zip(logged, fresh, strict=False):
        for f in fields(StepRecord):
            if f.name == "image" and not (images and a.image is not None and b.image is not None):
                continue
            x, y = getattr(a, f.name), getattr(b, f.name)
            if isinstance(x, dict) and isinstance(y, dict):
                same = x.keys() == y.keys() and all(_same(x[k], y[k]) for k in x)
            else:
                same = _same(x, y)
            if not same:
                out.append(f"step {a.step}: {f.name} differs")
    return out


def config_file_differences(run: ReadRun) -> list[str]:
    """How the run directory's config.yaml differs from the config embedded in the log.

    The log is the source of truth; a config.yaml that was edited, replaced or deleted beside it
    no longer describes the run, and `--verify` says so (empty list: they agree, or the log was
    given as a bare MCAP file with no run directory around it).
    """
    folder = Path(run.path).parent
    path = folder / "config.yaml"
    if Path(run.path).name != "run.mcap" or not (folder / "meta.json").exists():
        return []
    if not path.is_file():
        return [f"{path}: missing (the log's embedded config is the run's)"]
    try:
        on_disk = safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        return [f"{path}: unreadable ({str(exc).splitlines()[0]})"]
    logged = yaml.safe_load(run.header.config_yaml)
    if not isinstance(on_disk, dict):
        return [f"{path}: not a config mapping"]
    return [f"{path}: {d}" for d in _dict_differences(logged, on_disk)]


def _dict_differences(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b), key=str):
            where = f"{prefix}.{key}" if prefix else str(key)
            if key not in b:
                out.append(f"{where} missing (logged {a[key]!r})")
            elif key not in a:
                out.append(f"{where} not in the logged config ({b[key]!r})")
            else:
                out += _dict_differences(a[key], b[key], where)
        return out
    return [] if a == b else [f"{prefix}: logged {a!r}, config.yaml {b!r}"]


def verify(run: ReadRun, *, progress: bool = False) -> list[str]:
    """Re-run the simulation from the log's embedded config; every difference from the log.

    The run is deterministic (one seed, rebuilt simulator, no wall clock in any record), so a
    rerun with the same code must reproduce every logged step bit for bit. An empty list means
    it did. The embedded config must still validate with this version of rodctl.
    """
    from rodctl.config import validate_config

    data = yaml.safe_load(run.header.config_yaml)
    logged = run.records
    ended = run.complete and run.status == "completed"
    if not ended and logged:
        # An interrupted, failed or unfinished run: replay only as far as it got.
        data.setdefault("run", {})["max_steps"] = max(1, int(logged[-1].step))
    cfg = validate_config(data, f"{run.path} (embedded config.yaml)")
    records = rerun_records(cfg, run.header.run_id)
    fresh = records if ended else records[: len(logged)]
    return compare_records(logged, fresh)


def rerun_records(cfg: Any, run_id: str) -> list[StepRecord]:
    """The records of a fresh run of `cfg` through the one episode loop (no sinks)."""
    from rodctl.env import ShapeServoEnv
    from rodctl.episode import EpisodeFailed, run_episode
    from rodctl.method import Method

    try:
        result = run_episode(ShapeServoEnv(cfg), Method.from_config(cfg), run_id=run_id)
    except EpisodeFailed as exc:
        result = exc.result
    return result.records
