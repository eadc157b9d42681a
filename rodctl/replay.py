"""Reading a run back from its MCAP log, and rebuilding its other outputs from it alone.

Why: the MCAP is the run's source of truth. `rodctl replay RUN_DIR|FILE.mcap` must work with no
simulator, no model and no config file at hand: it reads the step records back exactly
(`rodctl.logs.codec`), rewrites run.rrd and the figures from them, and prints the summary.
`replay --verify` re-runs the simulation and compares each fresh record with the logged one
(`compare_runs`): bit for bit first (float64 values equal, NaN equal to NaN), then, for what is
not bit-identical, within `--tolerance`. The verdict is one of three (`VerifyResult`):
bit-identical; identical within the tolerance (the largest deviation of each field reported in
the field's units, beside the two numeric environments where they differ: a rerun on another
CPU or BLAS kernel may change the last bits, see `rodctl.numenv`); or a real mismatch (the first
step and field that differ beyond the tolerance, or a step count, flag or text that differs).
"""

from __future__ import annotations

import errno
import math
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import nullcontext, suppress
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from rodctl.config.loading import safe_load
from rodctl.config.logging import LoggingConfig
from rodctl.errors import RunFailed, UserError, make_out_folder
from rodctl.figure_worker import FiguresFailed, FigureWorker, save_figures
from rodctl.logs.codec import ReadRun
from rodctl.records import FIELD_UNITS as RECORD_UNITS
from rodctl.records import RunSummary, StepRecord, summary_text

__all__ = [
    "ReadRun",
    "Rebuilt",
    "VerifyResult",
    "compare_records",
    "compare_runs",
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
        try:
            p.stat()
        except OSError as exc:  # exists() says False for a link loop too: say which
            if exc.errno == errno.ELOOP:
                raise UserError(f"{p}: a loop of symbolic links, no run behind it") from None
        if p.is_symlink():
            raise UserError(f"{p}: a symbolic link to {os.readlink(p)}, which does not exist")
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
        data = safe_load(config_yaml)
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
    check: Callable[[ReadRun], None] | None = None,
) -> Rebuilt:
    """Rewrite run.rrd and figures/ from a run's MCAP alone (no simulation).

    Args:
        path: a run directory or an MCAP file.
        out_dir: where to write; default the run directory (the MCAP file's folder).
        recover: accept an unfinished MCAP (see `read_run`).
        rerun: write `out_dir/run.rrd`.
        figures: write `out_dir/figures/*.png`, drawn by a helper process
            (`rodctl.figure_worker`) while run.rrd is rewritten.
        check: called with the run as read, before anything is written (e.g.
            `check_verifiable` for `replay --verify`: its UserError leaves the folder as it was).

    Returns:
        The records read and the paths written.

    Raises:
        RunFailed: the figures could not be drawn (the reason; run.rrd is written).
    """
    src = mcap_path(path)
    with FigureWorker.start() if figures else nullcontext() as worker:
        run = read_run(src, recover=recover)
        if check is not None:
            check(run)
        if worker is not None and run.records:
            worker.submit(run.header, run.records)  # drawn while run.rrd is written
        out = make_out_folder(out_dir) if out_dir is not None else src.parent
        result = Rebuilt(run=run, rrd=None)
        if rerun:
            result.rrd = _write_rrd(run, out / "run.rrd")
        if worker is not None:
            if run.records:
                try:
                    pngs = worker.result()
                except FiguresFailed as exc:
                    raise RunFailed(f"figures not written: {exc}") from None
                result.figures = save_figures(pngs, out / "figures")
            else:
                result.notes.append("figures skipped: no complete step in the log")
    return result


def _write_rrd(run: ReadRun, final: Path) -> Path:
    """Write the run's Rerun recording to `final` through a temporary file renamed at the end:
    a replay cut short (Ctrl-C, a full disk) leaves the run.rrd that was there as it was."""
    from rodctl.logs.rerun import RerunSink

    tmp = final.with_name(f".{final.name}.rebuilding")
    sink = RerunSink(tmp, _logging_config(run.header.config_yaml))
    try:
        try:
            sink.open(run.header)
            for rec in run.records:
                sink.write(rec)
        finally:
            sink.close(summary_object(run.summary), run.status or "interrupted")
    except BaseException as exc:
        with suppress(OSError):  # a read-only disk refuses even this (EROFS)
            tmp.unlink(missing_ok=True)
        if isinstance(exc, RunFailed | OSError):  # named as the file the user knows
            raise _renamed(exc, tmp, final) from None
        raise
    os.replace(tmp, final)
    return final


def _renamed(exc: RunFailed | OSError, tmp: Path, final: Path) -> RunFailed | OSError:
    """`exc` with the temporary file's path replaced by `final`'s."""
    if isinstance(exc, OSError):
        if exc.filename is not None:  # the path, or a text with it (Rerun's errors)
            exc.filename = str(exc.filename).replace(str(tmp), str(final))
        return exc
    return RunFailed(str(exc).replace(str(tmp), str(final)))


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
            rows.append((k, summary_text(v)))
    elif run.records:
        last = run.records[-1]
        rows += [
            ("last step", str(last.step)),
            ("final_T1", summary_text(float(last.T1))),
            ("final_pixel_error", summary_text(float(last.pixel_error))),
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
    logged = safe_load(run.header.config_yaml)
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


#: Units of the StepRecord fields in verify reports (`rodctl.records.FIELD_UNITS`, without the
#: MCAP metadata's detail).
FIELD_UNITS = {name: unit.symbol for name, unit in RECORD_UNITS.items()}


@dataclass
class Deviation:
    """The largest difference of one field between the log and the rerun.

    Attributes:
        field: the StepRecord field (estimator_info entries as `estimator_info.alpha`).
        unit: the field's unit.
        max_abs: largest |logged - fresh| over every value of every step, in `unit`.
        step: the step where it occurred.
        within: whether every value of the field agreed within the tolerance.
        max_scaled: largest |logged - fresh| / max(1, |logged|): the smallest tolerance that
            accepts this field.
    """

    field: str
    unit: str
    max_abs: float
    step: int
    within: bool
    max_scaled: float = 0.0


@dataclass
class VerifyResult:
    """What `replay --verify` found; `verdict` is one of three.

    Attributes:
        verdict: "identical" (every compared value bit for bit), "within_tolerance" (some values
            differ, all by at most the tolerance) or "mismatch".
        steps: records compared (the shorter of the two runs): the initial frame (k = 0) and the
            steps after it, so one more than the run's `steps` in summary.json.
        tolerance: the agreement rule: |logged - fresh| <= tolerance * max(1, |logged|), i.e.
            absolute for values up to 1 in magnitude and relative above.
        differences: every (step, field) that is not bit-identical, as "step k: FIELD differs".
        deviations: the fields that are not bit-identical, largest deviation first per field.
        mismatch: the first real mismatch as "step k: FIELD differs (...)", None if there is none.
        logged_env: the numeric environment recorded with the log (None in older logs).
        fresh_env: the numeric environment of the rerun.
        numbers_only: True when everything but numeric values agrees exactly (step count,
            flags, phases, texts, shapes).
    """

    verdict: Literal["identical", "within_tolerance", "mismatch"]
    steps: int
    tolerance: float
    differences: list[str] = field(default_factory=list)
    deviations: list[Deviation] = field(default_factory=list)
    mismatch: str | None = None
    logged_env: dict[str, Any] | None = None
    fresh_env: dict[str, Any] | None = None
    numbers_only: bool = True

    @property
    def exit_code(self) -> int:
        """0 when identical or within the tolerance, 1 on a real mismatch."""
        return 1 if self.verdict == "mismatch" else 0

    def records_phrase(self) -> str:
        """The records compared, e.g. "12 records (the initial frame and 11 steps)".

        Record 0 is the initial observation, so N records are the initial frame and N - 1
        control steps (the `steps` of summary.json).
        """
        n = self.steps
        if n == 0:
            return "0 records"
        after = n - 1
        return (
            f"{n} record{'s' if n != 1 else ''} (the initial frame and "
            f"{after} step{'s' if after != 1 else ''})"
        )

    def environment_rows(self) -> list[tuple[str, Any, Any]]:
        """(key, logged, rerun) where the two numeric environments differ."""
        from rodctl.numenv import environment_differences

        if self.logged_env is None and self.fresh_env is None:
            return []
        return environment_differences(self.logged_env, self.fresh_env)

    def report(self) -> list[str]:
        """The verdict as lines of text: first line the verdict, then the details."""
        if self.verdict == "identical":
            return [f"verify: OK, {self.records_phrase()} identical"]
        lines: list[str] = []
        if self.verdict == "mismatch":
            lines.append(
                f"verify: FAILED, first mismatch: {self.mismatch} "
                f"({len(self.differences)} differences in all)"
            )
        else:
            lines.append(
                f"verify: OK within tolerance {self.tolerance:g}: {self.records_phrase()}, "
                f"{len(self.differences)} (step, field) pairs not bit-identical"
            )
        if self.deviations:
            lines.append("largest deviation per field (logged vs rerun):")
            for d in self.deviations:
                mark = "" if d.within else "  > tolerance"
                lines.append(f"  {d.field:<26} {d.max_abs:.3g} {d.unit} (step {d.step}){mark}")
        if self.logged_env is None:
            lines.append("numeric environment of the log: not recorded (older log)")
            if self.fresh_env:
                lines.append(f"numeric environment of the rerun: {_env_summary(self.fresh_env)}")
        else:
            env = self.environment_rows()
            if env:
                width = max(len(k) for k, _, _ in env)
                lines.append("numeric environments differ (logged | rerun):")
                lines += [f"  {k.ljust(width)}  {a!s} | {b!s}" for k, a, b in env]
            else:
                lines.append("numeric environments: identical (the difference is not theirs)")
        if self.verdict == "mismatch" and self.numbers_only:
            need = max(d.max_scaled for d in self.deviations)
            lines.append(
                "only numbers differ (steps, flags and texts agree): if the rerun ran on another "
                "machine or BLAS kernel and the deviations above are acceptable, "
                f"--tolerance {need:.2g} accepts them"
            )
        return lines


def _env_summary(env: dict[str, Any]) -> str:
    """One line: CPU model, numpy version and SIMD, BLAS kernels and threads."""
    cpu = env.get("cpu", {})
    npy = env.get("numpy", {})
    blas = ", ".join(
        f"{b.get('internal_api')} {b.get('architecture')} x{b.get('num_threads')}"
        for b in env.get("blas", [])
        if b.get("user_api") == "blas"
    )
    simd = "+".join(npy.get("simd_dispatched", []) or npy.get("simd_baseline", []))
    return f"{cpu.get('model', '?')}; numpy {npy.get('version', '?')} ({simd}); BLAS {blas or '?'}"


def _deviation(a: Any, b: Any) -> tuple[float, float] | None:
    """(largest |a - b|, largest |a - b| / max(1, |a|)) of two numeric values or arrays;
    None when they are not comparable numbers (another shape, a flag, a text, NaN vs a number).

    Booleans count as non-numeric: a flipped flag is a real mismatch at any tolerance.
    """
    if isinstance(a, bool | np.bool_ | str) or isinstance(b, bool | np.bool_ | str):
        return None
    try:
        x = np.asarray(a)
        y = np.asarray(b)
    except Exception:  # noqa: BLE001 - anything that is not array-like is not numeric
        return None
    if x.shape != y.shape or x.dtype.kind not in "fiu" or y.dtype.kind not in "fiu":
        return None
    x = x.astype(np.float64)
    y = y.astype(np.float64)
    if x.size == 0:
        return 0.0, 0.0
    nan_x, nan_y = np.isnan(x), np.isnan(y)
    if np.any(nan_x != nan_y):
        return None
    keep = ~nan_x & ~(np.isinf(x) & (x == y))
    if np.any(np.isinf(x[keep]) | np.isinf(y[keep])):
        return None
    diff = np.abs(x[keep] - y[keep])
    if diff.size == 0:
        return 0.0, 0.0
    scaled = diff / np.maximum(1.0, np.abs(x[keep]))
    return float(diff.max()), float(scaled.max())


def compare_runs(
    logged: Sequence[StepRecord],
    fresh: Sequence[StepRecord],
    *,
    tolerance: float = 0.0,
    logged_env: dict[str, Any] | None = None,
    fresh_env: dict[str, Any] | None = None,
    images: bool = False,
) -> VerifyResult:
    """Compare a logged run with its rerun and give the three-way verdict (`VerifyResult`).

    Bit for bit first (`compare_records`); a value that is not bit-identical is then accepted
    when |logged - fresh| <= tolerance * max(1, |logged|). Step counts, flags (settled,
    saturated, clipped, extraction_ok), the phase and texts must agree exactly at any tolerance:
    a rerun that decides differently is a different run.

    Args:
        logged: the records read from the log.
        fresh: the records of the rerun.
        tolerance: >= 0; 0 accepts only bit-identical values.
        logged_env: the numeric environment recorded with the log, if any.
        fresh_env: the numeric environment of the rerun.
        images: compare camera frames too (when both records carry one).
    """
    if not tolerance >= 0.0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance}")
    differences = compare_records(logged, fresh, images=images)
    worst: dict[str, Deviation] = {}
    numbers_only = len(logged) == len(fresh)
    mismatch = None if numbers_only else _count_mismatch(logged, fresh)
    for a, b in zip(logged, fresh, strict=False):
        for name, xv, yv in _values(a, b, images):
            if _same(xv, yv):
                continue
            unit = FIELD_UNITS.get(name.split(".")[0], "")
            dev = _deviation(xv, yv)
            if dev is None:
                numbers_only = False
                mismatch = mismatch or f"step {a.step}: {name} differs"
                continue
            absdev, scaled = dev
            within = scaled <= tolerance
            _note_deviation(worst, Deviation(name, unit, absdev, a.step, within, scaled))
            if not within and mismatch is None:
                by = f"{absdev:.3g} {unit}".strip()
                mismatch = f"step {a.step}: {name} differs (by {by})"
    verdict: Literal["identical", "within_tolerance", "mismatch"] = (
        "mismatch" if mismatch is not None else "within_tolerance" if differences else "identical"
    )
    return VerifyResult(
        verdict=verdict,
        steps=min(len(logged), len(fresh)),
        tolerance=float(tolerance),
        differences=differences,
        deviations=sorted(worst.values(), key=lambda d: d.field),
        mismatch=mismatch,
        logged_env=logged_env,
        fresh_env=fresh_env,
        numbers_only=numbers_only,
    )


def _count_mismatch(logged: Sequence[StepRecord], fresh: Sequence[StepRecord]) -> str:
    return f"step count differs: logged {len(logged)}, rerun {len(fresh)}"


def _values(a: StepRecord, b: StepRecord, images: bool) -> Iterator[tuple[str, Any, Any]]:
    """(field name, logged value, rerun value) of every field of two records; a dict field whose
    keys agree (`estimator_info`) gives one per key, as `field.key`. The camera image only with
    `images` and when both records carry one."""
    for f in fields(StepRecord):
        if f.name == "image" and not (images and a.image is not None and b.image is not None):
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, dict) and isinstance(y, dict) and x.keys() == y.keys():
            yield from ((f"{f.name}.{k}", x[k], y[k]) for k in x)
        else:
            yield f.name, x, y


def _note_deviation(worst: dict[str, Deviation], dev: Deviation) -> None:
    """Fold one step's deviation of a field into `worst`, the field's largest so far: its size
    and step are the largest's, `within` holds only if every step's was within the tolerance,
    `max_scaled` is the largest scaled deviation of any step."""
    prev = worst.get(dev.field)
    if prev is None or dev.max_abs > prev.max_abs:
        if prev is not None:
            dev.within = dev.within and prev.within
            dev.max_scaled = max(dev.max_scaled, prev.max_scaled)
        worst[dev.field] = dev
    else:
        prev.within = prev.within and dev.within
        prev.max_scaled = max(prev.max_scaled, dev.max_scaled)


def check_verifiable(run: ReadRun) -> None:
    """Refuse `--verify` of a run that has no simulation to re-run (an imported recording).

    Raises:
        UserError: naming the recording and what to use instead.
    """
    data = safe_load(run.header.config_yaml)
    source = data.get("source") if isinstance(data, dict) else None
    if isinstance(source, dict):  # written by `rodctl import` (rodctl.recordings)
        raise UserError(
            f"{run.path}: an imported recording ({source.get('kind', 'recording')} from "
            f"{source.get('file', '?')}): there is no simulation to re-run, so --verify does "
            "not apply (plain `rodctl replay` rebuilds its views; `rodctl estimate` reads it)"
        )


def verify(run: ReadRun, *, tolerance: float = 0.0, progress: bool = False) -> VerifyResult:
    """Re-run the simulation from the log's embedded config and compare it with the log.

    The run is deterministic (one seed, rebuilt simulator, no wall clock in any record), so a
    rerun with the same code in the same numeric environment reproduces every logged step bit
    for bit; elsewhere the per-step path is kernel-independent where that was cheap
    (docs/reproducibility.md) and `tolerance` accepts what remains. The embedded config must still
    validate with this version of rodctl.

    Returns:
        The three-way verdict (`compare_runs`), with the log's and the rerun's numeric
        environments.
    """
    from rodctl.config import validate_config

    check_verifiable(run)
    data = safe_load(run.header.config_yaml)
    logged = run.records
    ended = run.complete and run.status == "completed"
    if not ended and logged:
        # An interrupted, failed or unfinished run: replay only as far as it got.
        data.setdefault("run", {})["max_steps"] = max(1, int(logged[-1].step))
    from rodctl.portable import with_embedded_checkpoint

    # The encoder copied into the run folder, not whatever its original path holds here.
    data = with_embedded_checkpoint(data, Path(run.path).parent)
    cfg = validate_config(data, f"{run.path} (embedded config.yaml)")
    records = rerun_records(cfg, run.header.run_id)
    fresh = records if ended else records[: len(logged)]
    from rodctl.numenv import numeric_environment

    return compare_runs(
        logged,
        fresh,
        tolerance=tolerance,
        logged_env=getattr(run.header, "numeric_env", None),
        fresh_env=numeric_environment(),
    )


def rerun_records(cfg: Any, run_id: str) -> list[StepRecord]:
    """The records of a fresh run of `cfg` through the one episode loop (no sinks)."""
    from rodctl.env import ShapeServoEnv
    from rodctl.episode import EpisodeFailed, run_episode
    from rodctl.method import Method
    from rodctl.training import prepare_feature

    prepare_feature(cfg)
    try:
        result = run_episode(ShapeServoEnv(cfg), Method.from_config(cfg), run_id=run_id)
    except EpisodeFailed as exc:
        result = exc.result
    return result.records
