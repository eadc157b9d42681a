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
then writes `results.csv` (every episode, with `scenario` and `seed` columns), `summary.md`
(per-scenario tables, paired statistics and the findings' verdicts), `statistics.json` and
`report.html` (self-contained: figures embedded). With `seeds: [...]` every scenario runs once
per target seed; p-values are Holm-adjusted over the suite and a finding is replicated only
when every seed agrees (docs/statistics.md).
"""

from __future__ import annotations

import contextlib
import functools
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml
from rich.console import Group

from rodctl.bench.compare import (
    load_compare_config,
    method_config,
    run_compare,
    terminal_table,
    write_results_csv,
)
from rodctl.bench.comparisons import (
    ALPHA,
    Comparison,
    difference_json,
    pair_key,
    paired_markdown,
    seeds_of,
    success_pairs,
    suite_comparisons,
)
from rodctl.bench.runner import RunInterrupted, make_pool, with_workers
from rodctl.bench.stats import band_names, summarize, summary_rows
from rodctl.bench.target_set import given_target_poses
from rodctl.config.compare import CompareConfig
from rodctl.config.loading import ConfigError, apply_override, config_source, validate_config
from rodctl.diagnosis import DIAGNOSES
from rodctl.display import stderr
from rodctl.errors import UserError
from rodctl.executors.base import SharedExecutor, stop_handlers, stop_reason
from rodctl.registry import STAGES
from rodctl.report import markdown_table, write_report_html
from rodctl.runlock import lock_run_folder
from rodctl.runs import RunDir, write_json_atomic
from rodctl.statistics import PairedDifference
from rodctl.training import prepare_feature


def run_keys(cfg: CompareConfig) -> list[tuple[str, str, int]]:
    """(run key, scenario, seed) of every compare run of a suite, scenario-major.

    One seed (no `seeds`, or a list of one): the key is the scenario's name, as before seeds
    existed (so an older suite folder still resumes); several: `<scenario>-seed<S>`.
    """
    seeds = cfg.seeds or [cfg.seed]
    out = []
    for name in cfg.scenarios or {}:
        for s in seeds:
            out.append((name if len(seeds) == 1 else f"{name}-seed{s}", name, s))
    return out


def scenario_configs(cfg: CompareConfig, config_dir: Path, source: str) -> dict[str, dict]:
    """Each compare run of the suite (a scenario on one seed) as a complete compare config (a
    mapping), validated, by run key (`run_keys`).

    Raises:
        UserError: a scenario key that does not exist or a value out of range, named as
            `scenarios.<name>.set.<key>`.
    """
    by_scenario: dict[str, dict] = {}
    common = cfg.model_dump(mode="json", exclude={"scenarios", "seeds"})
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
        given_target_poses(scfg, config_dir)  # a targets.file that does not fit, before any run
        by_scenario[name] = data
    out: dict[str, dict] = {}
    for key, name, seed in run_keys(cfg):
        out[key] = {**json.loads(json.dumps(by_scenario[name])), "seed": seed}
        if key != name:  # several seeds: the run folders' names say which
            out[key]["name"] = f"{cfg.name}-{key}"[:64]
    return out


def _set_in_methods(methods: dict[str, dict], key: str, value: Any, where: str) -> None:
    """Set `key` (`<stage>.<field>...`) in every method whose stage's type has that field.

    Raises:
        ConfigError: the key does not start with a stage, or no method's stage has the field.
    """
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
    wall0 = time.perf_counter()
    cfg = with_workers(load_compare_config(config_path, overrides), workers)
    source = config_source(config_path, overrides)
    scenarios = scenario_configs(cfg, Path(config_path).resolve().parent, source)
    # Made (not started) before the suite's folder: a bad --executor, --workers or a Ray not
    # installed is refused leaving nothing behind.
    made = make_pool(executor, workers, cfg.workers, address)
    run = _reopen(resume) if resume is not None else _create(out, cfg)
    folders = {k: str(_inside(run.path, v)) for k, v in run.meta.get("scenarios", {}).items()}
    before = float(run.meta.get("wall_s", 0.0))  # earlier invocations' share (--resume)

    def wall() -> float:
        return before + time.perf_counter() - wall0

    status = "failed"
    extra: dict[str, Any] = {}  # meta.json's why and how far, for an interrupted suite
    try:
        # Quick encoders (`checkpoint: auto`) are trained before the pool starts, so that the
        # training sees the environment it always saw (not the workers' one-thread settings).
        _prepare_features(scenarios, folders, source)
        # One pool for every scenario: a new one per scenario cost each of its workers the
        # imports again (spawn) and the caches warmed again, and a Ray its start (17-19 s).
        pending = [n for n in scenarios if not _completed(Path(folders.get(n) or "-"))]
        pool = made if pending else None
        # The handlers around the pool's start too, as `run_study` has them: a SIGTERM while a
        # pool (a Ray: 17-19 s) starts ends the suite as interrupted, not by the default action.
        with stop_handlers(), pool or contextlib.nullcontext(), stop_handlers():
            shared = SharedExecutor(pool) if pool is not None else None
            # executor and address too: each scenario's meta.json records where it ran.
            options = {"progress": progress, "workers": workers, "pool": shared}
            _run_scenarios(
                run, scenarios, folders, wall, executor=executor, address=address, **options
            )
        _suite_report(cfg, run.path, folders, wall(), progress)
        status = "completed"
        return run.path
    except (KeyboardInterrupt, RunInterrupted) as exc:
        # The suite's folder is what --resume takes, not the cut scenario's.
        status, extra = "interrupted", _stopped(exc, folders, len(scenarios))
        done = extra["scenarios_finished"]["finished"]
        raise RunInterrupted(run.path, extra["reason"], done, len(scenarios), "scenarios") from None
    finally:
        extra.pop("reason", None)
        run.finish(status, wall_s=wall(), **extra)


def _stopped(exc: BaseException, folders: dict[str, str], total: int) -> dict[str, Any]:
    """What meta.json says of an interrupted suite, as a compare's does: why (`error`) and how
    far it got; `reason` (the signal) for the caller."""
    reason = exc.reason if isinstance(exc, RunInterrupted) else str(exc) or "SIGINT"
    done = sum(_completed(Path(f)) for f in folders.values())
    return {
        "reason": reason,
        "error": f"interrupted by {reason}",
        "scenarios_finished": {"finished": done, "total": total},
    }


def _suite_report(
    cfg: CompareConfig, folder: Path, folders: dict[str, str], wall: float, progress: bool
) -> None:
    """The suite's own tables (`write_suite_outputs`), shown when `progress`. Every scenario
    is done: a stop meanwhile lets them finish (the suite stays completed, as a compare does)."""
    with stop_handlers():
        report = write_suite_outputs(cfg, folder, folders, wall)
    if progress:
        stderr.print(report)


def _create(out: str, cfg: CompareConfig) -> RunDir:
    """A new suite folder, its lock held until `run.finish`."""
    run = RunDir.create(out, cfg, command="compare (suite)")
    lock_run_folder(run.path, "compare (suite)")
    return run


def _run_scenarios(
    run: RunDir,
    scenarios: dict[str, dict],
    folders: dict[str, str],
    wall: Callable[[], float],
    **compare_options: Any,
) -> None:
    """Each scenario's compare run, from its config file under scenarios/, into a folder of
    its own there; a scenario whose folder completed before (`--resume`) is kept as it is."""
    (run.path / "scenarios").mkdir(exist_ok=True)
    for name, data in scenarios.items():
        path = run.path / "scenarios" / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
        earlier = folders.get(name)
        if earlier and _completed(Path(earlier)):
            continue
        reason = stop_reason()  # a signal between two scenarios
        if reason is not None:
            raise KeyboardInterrupt(reason)
        # The scenario's folder is recorded as soon as it exists, so --resume continues it
        # (keeping its finished episodes) after a stop, and after a kill or power cut too.
        run_compare(
            str(path),
            [],
            str(run.path / "scenarios"),
            resume=earlier,
            on_start=functools.partial(_record_scenario, run, folders, name, wall),
            **compare_options,
        )


def _prepare_features(scenarios: dict[str, dict], folders: dict[str, str], source: str) -> None:
    """Every quick encoder (`feature.checkpoint: auto`) the scenarios still to run need, trained
    and cached now unless cached (`rodctl.training.prepare_feature`); each scenario's own
    preflight then finds it."""
    for name, data in scenarios.items():
        earlier = folders.get(name)
        if earlier and _completed(Path(earlier)):
            continue
        scfg = validate_config(data, f"{source}: scenarios.{name}", CompareConfig)
        for method in scfg.methods:
            prepare_feature(method_config(scfg, method, source=source))


def _record_scenario(
    run: RunDir, folders: dict[str, str], name: str, wall: Callable[[], float], folder: Path
) -> None:
    folders[name] = str(folder)
    # relative to the suite's folder, so that a suite moved or copied elsewhere still resumes
    run.meta["scenarios"] = {k: _relative(run.path, v) for k, v in folders.items()}
    run.meta["wall_s"] = wall()  # what a killed suite's --resume adds to
    run.write_meta()


def _relative(suite: Path, folder: str) -> str:
    """`folder` as meta.json records it: relative to the suite's folder when inside it."""
    try:
        return str(Path(folder).resolve().relative_to(suite.resolve()))
    except ValueError:
        return folder


def _inside(suite: Path, folder: str) -> Path:
    """A scenario folder from meta.json: relative to the suite's folder; an absolute one (as
    suites before recorded them) found under the suite's scenarios/ when the suite moved."""
    path = Path(folder)
    if not path.is_absolute():
        return suite / path
    moved = suite / "scenarios" / path.name
    return moved if not path.exists() and moved.exists() else path


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
    lock_run_folder(path, "compare (suite)")  # held until run.finish; refused if in use
    run = RunDir(path=path, meta=meta)
    run.meta.update(status="running", ended_at=None)
    run.write_meta()
    return run


# --- aggregation -------------------------------------------------------------------------------


def read_rows(folders: dict[str, str]) -> list[dict[str, Any]]:
    """Every episode of every compare run (results.json of each), tagged with the run's
    scenario and seed (from that run's own config)."""
    rows: list[dict[str, Any]] = []
    for key, folder in folders.items():
        data = json.loads((Path(folder) / "results.json").read_text(encoding="utf-8"))
        scenario = data.get("config", {}).get("scenario", key)
        for r in data["episodes"]:
            r["scenario"] = scenario
            r["seed"] = data.get("seed", r.get("seed"))
            rows.append(r)
    return rows


def statistics_json(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    reference: str,
    scenarios: Sequence[str],
    comparisons: Sequence[Comparison],
) -> dict[str, Any]:
    """statistics.json: every comparison with raw and adjusted p, per seed and pooled, its
    verdict, and the findings (the pooled tests significant after correction)."""
    seeds = seeds_of(rows)
    out: dict[str, Any] = {
        "reference": reference,
        "seeds": seeds,
        "alpha": ALPHA,
        "correction": {
            "method": "holm",
            "pooled_tests": sum(c.pooled.p_value is not None for c in comparisons),
            "per_seed_tests": {
                str(s): sum(c.per_seed[s].p_value is not None for c in comparisons) for s in seeds
            },
            "families": "the pooled tests of every scenario, method and metric; separately, "
            "each seed's tests (docs/statistics.md)",
        },
        "findings": [_finding_json(c) for c in comparisons if c.significant],
        "scenarios": {},
    }
    for name in scenarios:
        mine = [r for r in rows if r["scenario"] == name]
        entry: dict[str, Any] = {
            "finished_before_event": _finished_before_event(mine, methods),
            "diagnosis": diagnosis_counts(mine, methods),
            "methods": {},
        }
        for m in methods:
            if m != reference:
                mc = [c for c in comparisons if c.scenario == name and c.method == m]
                entry["methods"][m] = _method_json(mine, m, reference, seeds, mc)
        out["scenarios"][name] = entry
    return out


def _finding_json(c: Comparison) -> dict[str, Any]:
    """A significant pooled comparison, as statistics.json lists it among the findings."""
    return {
        "scenario": c.scenario,
        "method": c.method,
        "metric": c.metric,
        "mean": c.pooled.mean,
        "ci_low": c.pooled.ci_low,
        "ci_high": c.pooled.ci_high,
        "p_value": c.pooled.p_value,
        "p_adjusted": c.pooled.p_adjusted,
        "per_seed_mean": {str(s): d.mean for s, d in c.per_seed.items()},
        "replicated": c.replicated,
        "verdict": c.verdict,
    }


def _finished_before_event(rows: Sequence[dict[str, Any]], methods: Sequence[str]) -> dict:
    """Per method, its episodes that ended before the scenario's event reached them."""
    return {
        m: sum(bool(r.get("finished_before_event")) for r in rows if r["method"] == m)
        for m in methods
    }


def _method_json(
    rows: Sequence[dict[str, Any]],
    method: str,
    reference: str,
    seeds: Sequence[Any],
    comparisons: Sequence[Comparison],
) -> dict[str, Any]:
    """One method against the reference in one scenario: who converged where (pooled and per
    seed) and each paired metric's difference, verdict and per-seed differences."""
    om, both, orf = success_pairs(rows, method, reference)
    per_seed = {}
    for s in seeds:
        sm, sb, sr = success_pairs([r for r in rows if r.get("seed") == s], method, reference)
        per_seed[str(s)] = {"only_method": sm, "both": sb, "only_reference": sr}
    return {
        "success": {"only_method": om, "both": both, "only_reference": orf},
        "success_per_seed": per_seed,
        "metrics": {
            c.metric: difference_json(c.pooled)
            | {
                "verdict": c.verdict,
                "replicated": c.replicated,
                "per_seed": {str(s): difference_json(d) for s, d in c.per_seed.items()},
            }
            for c in comparisons
        },
    }


def write_suite_outputs(
    cfg: CompareConfig, folder: Path, folders: dict[str, str], wall: float
) -> Any:
    """results.csv, summary.md, statistics.json and report.html of the suite; returns the
    terminal tables."""
    rows = read_rows(folders)
    write_results_csv(folder / "results.csv", rows)
    methods = list(cfg.methods)
    ref = cfg.reference_method
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    scenarios = [n for n in (cfg.scenarios or {}) if n in scenarios] or scenarios
    seeds = seeds_of(rows)
    comparisons = suite_comparisons(rows, methods, ref, scenarios)
    md = [
        f"# rodctl benchmark suite: {cfg.name}",
        "",
        f"{_count(len(scenarios), 'scenario')} x {_count(len(methods), 'method')} x "
        f"{_count(len(seeds), 'target seed')} "
        f"({', '.join(str(s) for s in seeds)}); reference method **{ref}**; wall time "
        f"{wall:.0f} s (summed over the runs a `--resume` continued). Every scenario on every "
        "seed is an ordinary compare run under `scenarios/` (its own results, figures and "
        "summary).",
        "",
        *_method_text(len(seeds), comparisons),
        "",
        *_findings_markdown(comparisons, seeds),
    ]
    tables = []
    for name in scenarios:
        mine = [r for r in rows if r["scenario"] == name]
        mine_c = [c for c in comparisons if c.scenario == name]
        lines, table = _scenario_section(cfg, name, mine, mine_c, seeds)
        md += lines
        tables.append(table)
    (folder / "summary.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    write_json_atomic(
        folder / "statistics.json", statistics_json(rows, methods, ref, scenarios, comparisons)
    )
    figure_sets = [(name, Path(f)) for name, f in folders.items()]
    write_report_html(
        folder / "report.html", f"rodctl suite {cfg.name}", "\n".join(md), figure_sets
    )
    return Group(*tables)


def _scenario_section(
    cfg: CompareConfig,
    name: str,
    rows: Sequence[dict[str, Any]],
    comparisons: Sequence[Comparison],
    seeds: Sequence[Any],
) -> tuple[list[str], Any]:
    """One scenario's part of summary.md (what it changed, its table, the episodes the event
    missed, the diagnoses, the paired comparisons) and its terminal table."""
    methods = list(cfg.methods)
    bands = band_names(cfg.targets.bands)
    # Targets are told apart by (seed, target) once several seeds are pooled.
    keyed = [{**r, "target": pair_key(r)} for r in rows]
    summary = summarize(keyed, methods, bands)
    header, lines = summary_rows(summary, bands)
    sc = (cfg.scenarios or {}).get(name)
    md = [f"## {name}", ""]
    if sc is not None and sc.description:
        md += [sc.description, ""]
    if sc is not None and (sc.set or sc.method_set):
        changed = [f"`{k}` = `{v}`" for k, v in sc.set.items()]
        changed += [f"methods' `{k}` = `{v}`" for k, v in sc.method_set.items()]
        md += ["Changed: " + ", ".join(changed), ""]
    md += [markdown_table(header, lines), ""]
    early = _finished_before_event(rows, methods)
    if any(early.values()):
        md += [
            "Finished before the event (the event never reached them; counted in the table "
            "above, left out of the paired comparisons below with their pairs): "
            + ", ".join(f"{m} {n}" for m, n in early.items())
            + " episodes.",
            "",
        ]
    md += _diagnosis_markdown(rows, methods)
    md += paired_markdown(rows, methods, cfg.reference_method, comparisons, seeds)
    return md, terminal_table(summary, f"{name}: {summary['common_targets']} paired")


def diagnosis_counts(rows: Sequence[dict[str, Any]], methods: Sequence[str]) -> dict[str, Any]:
    """Per method, how many of its stalled or pinned episodes got each diagnosis (and how many
    got none: an older run, or a diagnosis that failed)."""
    out = {}
    for m in methods:
        failed = [r for r in rows if r["method"] == m and r.get("outcome") in ("stalled", "pinned")]
        counts = {d: sum(r.get("diagnosis") == d for r in failed) for d in DIAGNOSES}
        counts["none"] = len(failed) - sum(counts.values())
        out[m] = counts
    return out


def _diagnosis_markdown(rows: Sequence[dict[str, Any]], methods: Sequence[str]) -> list[str]:
    counts = diagnosis_counts(rows, methods)
    if not any(sum(c.values()) for c in counts.values()):
        return []
    header = ["method", "stalled or pinned", *DIAGNOSES, "not diagnosed"]
    lines = [
        [m, str(sum(c.values())), *(str(c[d]) for d in DIAGNOSES), str(c["none"])]
        for m, c in counts.items()
    ]
    return [
        "Why episodes stalled or got pinned (`diagnosis`, rodctl/diagnosis.py): *workspace* "
        "pinned or walled in; *estimator* the true Jacobian converges from the same state; "
        "*unreachable* a pose search with the true model cannot meet the tolerance; *other* "
        "reachable, yet the true Jacobian does not help the method's law.",
        "",
        markdown_table(header, lines),
        "",
    ]


def _method_text(n_seeds: int, comparisons: Sequence[Comparison]) -> list[str]:
    tests = sum(c.pooled.p_value is not None for c in comparisons)
    return [
        "Paired differences are *method minus reference* over the targets both converged on "
        "(lower is better for every metric): the mean, its BCa bootstrap 95 % confidence "
        "interval, the raw Wilcoxon signed-rank p, the p adjusted by Holm's correction over all "
        f"{tests} pooled tests of this suite (*adj.*), and wins/ties/losses. **bold**: "
        f"significant after correction (adjusted p < {ALPHA} and the interval excludes 0). A "
        "significant difference is **replicated** only when its mean has the same sign on every "
        f"target seed ({n_seeds} here"
        + ("; one seed cannot replicate anything" if n_seeds < 2 else "")
        + "). Method: docs/statistics.md.",
    ]


def _findings_markdown(comparisons: Sequence[Comparison], seeds: Sequence[Any]) -> list[str]:
    found = [c for c in comparisons if c.significant]
    rep = sum(c.replicated for c in found)
    out = [
        "## Findings",
        "",
        f"{len(found)} of {sum(c.pooled.p_value is not None for c in comparisons)} pooled tests "
        f"are significant after Holm's correction; {rep} of them replicated on every seed.",
        "",
    ]
    if not found:
        return out

    header = ["scenario", "method − ref", "metric", "pooled", *[f"seed {s}" for s in seeds]]
    header.append("verdict")
    lines = []
    for c in found:
        per = [_fmt_mean(c.per_seed[s]) for s in seeds]
        verdict = f"**{c.verdict}**" if c.replicated else c.verdict
        lines.append([c.scenario, c.method, c.label, c.pooled.describe(c.unit), *per, verdict])
    return [*out, markdown_table(header, lines), ""]


def _fmt_mean(d: PairedDifference) -> str:
    return "–" if d.mean is None else f"{d.mean:+.2f} (n = {d.n})"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"
