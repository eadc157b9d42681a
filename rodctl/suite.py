"""Benchmark suites: every method on every scenario, compared paired by target, with a report.

Why a suite: one scenario cannot tell methods apart. Under the nominal speed limit every working
adaptive method converges at the speed limit's bound, so "fastest" is decided by the limit, not
the method. A suite runs the same methods on scenarios that stress different parts of a method
(a loose speed limit, hard targets, a noisy camera, heavy and soft rods, friction, mid-run
changes) and compares each method with a reference *paired by target* (`rodctl.statistics`), so a
difference is reported with its confidence interval and p-value, or not at all.

A suite is a compare config with `scenarios`: each scenario is `base` with some dotted keys set
(as with `--set`) and optionally its own target set. Each scenario runs as an ordinary
`rodctl compare` into `scenarios/<name>/` (its own results, figures, resume), from a config file
written beside it (`scenarios/<name>.yaml`), so any one of them can be rerun alone. The suite
then writes `results.csv` (every episode, with a `scenario` column), `summary.md` (per-scenario
tables and paired statistics) and `report.html` (self-contained: figures embedded).
"""

from __future__ import annotations

import csv
import functools
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml

from rodctl.config.compare import CompareConfig
from rodctl.config.loading import ConfigError, apply_override, validate_config
from rodctl.errors import UserError
from rodctl.report import write_report_html
from rodctl.runs import RunDir, write_json_atomic
from rodctl.statistics import PairedDifference, paired_difference

#: Metrics compared paired by target: (column, label, unit, which episodes count).
PAIRED_METRICS = (
    ("steps_to_converge", "steps to converge", "steps"),
    ("excess_steps", "steps over the speed-limit bound", "steps"),
    ("near_origin_steps", "final approach (below 2x tolerance to converged)", "steps"),
    ("smoothness_translation", "smoothness, translation", "speed limits"),
    ("smoothness_rotation", "smoothness, rotation", "speed limits"),
    ("event_peak_error", "peak error after the event", "px"),
    ("event_steps_to_converge", "steps from the event to convergence", "steps"),
)


def present_metrics(rows: Sequence[dict[str, Any]]) -> tuple[tuple[str, str, str], ...]:
    """The paired metrics some episode of `rows` has a value for (the event metrics only
    where an event happened)."""
    return tuple(m for m in PAIRED_METRICS if any(r.get(m[0]) is not None for r in rows))


def scenario_configs(cfg: CompareConfig, config_dir: Path, source: str) -> dict[str, dict]:
    """Each scenario as a complete compare config (a mapping), validated.

    Raises:
        UserError: a scenario key that does not exist or a value out of range, named as
            `scenarios.<name>.set.<key>`.
    """
    from rodctl.compare import method_config

    out: dict[str, dict] = {}
    common = cfg.model_dump(mode="json", exclude={"scenarios"})
    for name, sc in (cfg.scenarios or {}).items():
        data = json.loads(json.dumps(common))
        # The base as written, not resolved: a scenario that sets `rod.material` must not meet
        # the EI and rho*A the default material resolved to.
        data["base"] = cfg.base.model_dump(mode="json", exclude_unset=True)
        data.update(name=f"{cfg.name}-{name}"[:64], scenario=name)
        if any(k.startswith("rod.material") for k in sc.set):
            # A new material sets EI and rho*A: the base's (resolved from its own material)
            # would contradict it, unless the scenario sets them too.
            rod = data["base"].get("rod", {})
            for derived in ("bending_stiffness", "mass_per_length"):
                if f"rod.{derived}" not in sc.set:
                    rod.pop(derived, None)
        for key, value in sc.set.items():
            apply_override(data["base"], key.split("."), value, f"scenarios.{name}.set.{key}")
        for key, value in sc.method_set.items():
            _set_in_methods(data["methods"], key, value, f"{source}: scenarios.{name}.method_set")
        if sc.targets is not None:
            data["targets"] = sc.targets.model_dump(mode="json")
        tfile = data["targets"].get("file")
        if tfile and not Path(tfile).is_absolute():
            data["targets"]["file"] = str((config_dir / tfile).resolve())
        where = f"{source}: scenarios.{name}"
        scfg = validate_config(data, where, CompareConfig)
        for method in scfg.methods:
            method_config(scfg, method, source=where)
        out[name] = data
    return out


def _set_in_methods(methods: dict[str, dict], key: str, value: Any, where: str) -> None:
    """Set `key` (`<stage>.<field>...`) in every method whose stage's type has that field.

    Raises:
        ConfigError: the key does not start with a stage, or no method's stage has the field.
    """
    from rodctl.registry import STAGES

    parts = key.split(".")
    if len(parts) < 2 or parts[0] not in STAGES:
        raise ConfigError(
            f"{where}.{key}: expected <stage>.<field> with stage one of {', '.join(STAGES)}"
        )
    registry = STAGES[parts[0]]
    hit = False
    for method in methods.values():
        section = method[parts[0]]
        fields = registry.get(section.get("type", registry.default)).config.model_fields
        if parts[1] in fields:
            apply_override(section, parts[1:], value, f"{where}.{key}")
            hit = True
    if not hit:
        raise ConfigError(f"{where}.{key}: no method's {parts[0]} has a field {parts[1]!r}")


def run_suite(
    config_path: str,
    overrides: list[str],
    out: str,
    *,
    progress: bool,
    workers: int | None,
    executor: str = "local",
    address: str | None = None,
    resume: str | None = None,
) -> Path:
    """Run every scenario of a suite config, then aggregate; return the suite's folder.

    `resume`: an earlier suite folder; scenarios that completed are kept, the others resumed.
    """
    from rodctl.compare import RunInterrupted, load_compare_config, run_compare

    wall0 = time.perf_counter()
    cfg = load_compare_config(config_path, overrides)
    source = config_path + (" with --set " + " ".join(overrides) if overrides else "")
    scenarios = scenario_configs(cfg, Path(config_path).resolve().parent, source)
    if resume is not None:
        run = _reopen(resume)
    else:
        run = RunDir.create(out, cfg, command="compare (suite)")
    folders: dict[str, str] = dict(run.meta.get("scenarios", {}))
    before = float(run.meta.get("wall_s", 0.0))  # earlier invocations' share (--resume)

    def wall() -> float:
        return before + time.perf_counter() - wall0

    status = "failed"
    try:
        (run.path / "scenarios").mkdir(exist_ok=True)
        for name, data in scenarios.items():
            path = run.path / "scenarios" / f"{name}.yaml"
            path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
            earlier = folders.get(name)
            if earlier and _completed(Path(earlier)):
                continue
            # The scenario's folder is recorded as soon as it exists, so --resume continues it
            # (keeping its finished episodes) after a stop, and after a kill or power cut too.
            run_compare(
                str(path),
                [],
                str(run.path / "scenarios"),
                progress=progress,
                workers=workers,
                executor=executor,
                address=address,
                resume=earlier,
                on_start=functools.partial(_record_scenario, run, folders, name, wall),
            )
        report = write_suite_outputs(cfg, run.path, folders, wall())
        if progress:
            from rodctl.display import stderr

            stderr.print(report)
        status = "completed"
        return run.path
    except (KeyboardInterrupt, RunInterrupted) as exc:
        # The suite's folder is what --resume takes, not the cut scenario's.
        status = "interrupted"
        reason = exc.reason if isinstance(exc, RunInterrupted) else str(exc) or "SIGINT"
        done = sum(_completed(Path(f)) for f in folders.values())
        raise RunInterrupted(run.path, reason, done, len(scenarios), "scenarios") from None
    finally:
        run.finish(status, wall_s=wall())


def _record_scenario(
    run: RunDir, folders: dict[str, str], name: str, wall: Callable[[], float], folder: Path
) -> None:
    folders[name] = str(folder)
    run.meta["scenarios"] = folders
    run.meta["wall_s"] = wall()  # what a killed suite's --resume adds to
    run.write_meta()


def _completed(folder: Path) -> bool:
    try:
        return json.loads((folder / "meta.json").read_text())["status"] == "completed"
    except (OSError, ValueError, KeyError):
        return False


def _reopen(folder: str) -> RunDir:
    path = Path(folder)
    try:
        meta = json.loads((path / "meta.json").read_text())
    except (OSError, ValueError) as exc:
        raise UserError(f"--resume {folder}: not a suite run folder ({exc})") from None
    if meta.get("command") != "compare (suite)":
        raise UserError(
            f"--resume {folder}: not a suite run folder (command {meta.get('command')})"
        )
    run = RunDir(path=path, meta=meta)
    run.meta.update(status="running", ended_at=None)
    run.write_meta()
    return run


# --- aggregation -------------------------------------------------------------------------------


def read_rows(folders: dict[str, str]) -> list[dict[str, Any]]:
    """Every episode of every scenario (results.json of each scenario's compare)."""
    rows: list[dict[str, Any]] = []
    for name, folder in folders.items():
        data = json.loads((Path(folder) / "results.json").read_text(encoding="utf-8"))
        for r in data["episodes"]:
            r["scenario"] = name
            rows.append(r)
    return rows


def paired_table(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    reference: str,
    metrics: Sequence[tuple[str, str, str]] = PAIRED_METRICS,
) -> dict[str, dict[str, PairedDifference]]:
    """For each method but the reference and each paired metric: method - reference over the
    targets both converged on (smoothness and steps only mean something for a converged run)."""
    by = {(r["method"], r["target"]): r for r in rows}
    targets = sorted({r["target"] for r in rows})

    def value(method: str, t: int, col: str) -> float | None:
        r = by.get((method, t))
        if r is None or r.get("outcome") != "converged":
            return None
        v = r.get(col)
        return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)

    out: dict[str, dict[str, PairedDifference]] = {}
    for m in methods:
        if m == reference:
            continue
        out[m] = {
            col: paired_difference(
                [value(m, t, col) for t in targets], [value(reference, t, col) for t in targets]
            )
            for col, _, _ in metrics
        }
    return out


def success_pairs(
    rows: Sequence[dict[str, Any]], method: str, reference: str
) -> tuple[int, int, int]:
    """(targets only the method converged on, both, only the reference)."""
    conv = {(r["method"], r["target"]) for r in rows if r.get("outcome") == "converged"}
    targets = {r["target"] for r in rows}
    only_m = sum((method, t) in conv and (reference, t) not in conv for t in targets)
    both = sum((method, t) in conv and (reference, t) in conv for t in targets)
    only_r = sum((method, t) not in conv and (reference, t) in conv for t in targets)
    return only_m, both, only_r


def write_suite_outputs(
    cfg: CompareConfig, folder: Path, folders: dict[str, str], wall: float
) -> Any:
    """results.csv, summary.md and report.html of the suite; returns the terminal table."""
    from rodctl.compare import (
        CSV_COLUMNS,
        _band_names,
        markdown_table,
        summarize,
        summary_rows,
        terminal_table,
    )

    rows = read_rows(folders)
    with (folder / "results.csv").open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_COLUMNS})
    methods = list(cfg.methods)
    ref = cfg.reference_method
    bands = _band_names(cfg)
    md = [
        f"# rodctl benchmark suite: {cfg.name}",
        "",
        f"{_count(len(folders), 'scenario')} x {_count(len(methods), 'method')}; reference "
        f"method **{ref}**; wall time {wall:.0f} s (summed over the runs a `--resume` "
        "continued). Every scenario is an ordinary compare run under `scenarios/<name>/` (its "
        "own results, figures, summary and report).",
        "",
        PAIRED_NOTE,
        "",
    ]
    stats: dict[str, Any] = {}
    tables = []
    for name in folders:
        mine = [r for r in rows if r["scenario"] == name]
        summary = summarize(mine, methods, bands)
        header, lines = summary_rows(summary, bands)
        sc = (cfg.scenarios or {}).get(name)
        md += [f"## {name}", ""]
        if sc is not None and sc.description:
            md += [sc.description, ""]
        if sc is not None and (sc.set or sc.method_set):
            changed = [f"`{k}` = `{v}`" for k, v in sc.set.items()]
            changed += [f"methods' `{k}` = `{v}`" for k, v in sc.method_set.items()]
            md += ["Changed: " + ", ".join(changed), ""]
        md += [markdown_table(header, lines), ""]
        paired_md, stats[name] = paired_statistics(mine, methods, ref)
        md += paired_md
        tables.append(
            (name, terminal_table(summary, f"{name}: {summary['common_targets']} paired"))
        )
    (folder / "summary.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    write_json_atomic(folder / "statistics.json", stats)
    figure_sets = [(name, Path(f)) for name, f in folders.items()]
    write_report_html(
        folder / "report.html", f"rodctl suite {cfg.name}", "\n".join(md), figure_sets
    )
    from rich.console import Group

    return Group(*(t for _, t in tables))


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


#: What the paired tables show (summary.md of a suite, and of a plain compare).
PAIRED_NOTE = (
    "Paired differences are *method minus reference* over the targets both converged on: "
    "the mean, its bootstrap 95 % confidence interval, the Wilcoxon signed-rank p-value and "
    "wins/ties/losses (lower is better for every metric). **bold**: significant (p < 0.05 and "
    "the interval excludes 0)."
)


def paired_statistics(
    rows: Sequence[dict[str, Any]], methods: Sequence[str], ref: str
) -> tuple[list[str], dict[str, Any]]:
    """Every method against `ref` on the episodes of one compare (or one scenario): the
    summary.md lines (a verdict per method, then the paired table) and the statistics.json
    entry (each paired metric's difference, and `success`: `success_pairs`)."""
    from rodctl.report import verdict_lines

    metrics = present_metrics(rows)
    paired = paired_table(rows, methods, ref, metrics)
    md = verdict_lines(ref, paired) + _paired_markdown(rows, methods, ref, paired, metrics)
    stats = {
        m: {col: vars(d) for col, d in per.items()} | {"success": success_pairs(rows, m, ref)}
        for m, per in paired.items()
    }
    return md, stats


def _paired_markdown(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    ref: str,
    paired: dict[str, dict[str, PairedDifference]],
    metrics: Sequence[tuple[str, str, str]],
) -> list[str]:
    header = ["method", "converged only / both / only ref"] + [lbl for _, lbl, _ in metrics]
    lines = []
    for m, per in paired.items():
        om, both, orf = success_pairs(rows, m, ref)
        cells = [m, f"{om} / {both} / {orf}"]
        for col, _, unit in metrics:
            d = per[col]
            text = d.describe(unit)
            cells.append(f"**{text}**" if d.significant() else text)
        lines.append(cells)
    from rodctl.compare import markdown_table

    return [f"Paired against **{ref}**:", "", markdown_table(header, lines), ""]
