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

import csv
import functools
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from rodctl.config.compare import CompareConfig
from rodctl.config.loading import ConfigError, apply_override, validate_config
from rodctl.errors import UserError
from rodctl.journal import lock_run_folder
from rodctl.report import write_report_html
from rodctl.runs import RunDir, write_json_atomic
from rodctl.statistics import PairedDifference, adjust, paired_difference

#: Metrics compared paired by target: (column, label, unit, which episodes count).
#: `excess_steps` (steps − pose_steps) and `event_steps_to_converge` (steps − the event's step)
#: are not tested: pose_steps and the event's step are the same for every method on a target,
#: so their paired differences are those of `steps_to_converge`, the same test counted again
#: (it would inflate the Holm family and list one finding two or three times). results.csv
#: keeps both columns.
PAIRED_METRICS = (
    ("steps_to_converge", "steps to converge", "steps"),
    ("near_origin_steps", "final approach (below 2x tolerance to converged)", "steps"),
    ("smoothness_translation", "smoothness, translation", "speed limits"),
    ("smoothness_rotation", "smoothness, rotation", "speed limits"),
    ("event_peak_error", "peak error after the event", "px"),
)


def present_metrics(rows: Sequence[dict[str, Any]]) -> tuple[tuple[str, str, str], ...]:
    """The paired metrics some episode of `rows` has a value for (the event metrics only
    where an event happened)."""
    return tuple(m for m in PAIRED_METRICS if any(r.get(m[0]) is not None for r in rows))


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
    from rodctl.compare import method_config

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
        lock_run_folder(run.path, "compare (suite)")  # held until run.finish
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
    lock_run_folder(path, "compare (suite)")  # held until run.finish; refused if in use
    run = RunDir(path=path, meta=meta)
    run.meta.update(status="running", ended_at=None)
    run.write_meta()
    return run


# --- aggregation -------------------------------------------------------------------------------

#: Significance level of every claim, after Holm's correction (rodctl.statistics).
ALPHA = 0.05


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


def _seeds(rows: Sequence[dict[str, Any]]) -> list[Any]:
    """The target seeds of `rows`, in numeric order."""
    return sorted({r.get("seed") for r in rows}, key=lambda s: (s is None, s or 0))


def pair_key(row: dict[str, Any]) -> tuple[Any, int]:
    """What pairs two methods' episodes: the same target of the same target set (seed)."""
    return (row.get("seed"), row["target"])


def _usable(row: dict[str, Any] | None) -> bool:
    """An episode that counts in the paired comparisons: it exists and, in a scenario with a
    mid-run event, the event reached it (one that ended first is reported apart)."""
    return row is not None and not row.get("finished_before_event")


def _paired_raw(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    reference: str,
    metrics: Sequence[tuple[str, str, str]],
) -> dict[str, dict[str, PairedDifference]]:
    by = {(r["method"], pair_key(r)): r for r in rows}
    targets = sorted({pair_key(r) for r in rows}, key=lambda k: (k[0] is None, k[0] or 0, k[1]))

    def value(method: str, t: tuple, col: str) -> float | None:
        r = by.get((method, t))
        if not _usable(r) or r.get("outcome") != "converged":
            return None
        v = r.get(col)
        # A non-finite value carries no difference (inf - inf is NaN, which would make every
        # Holm-adjusted p of the family 1).
        return None if v is None or not math.isfinite(float(v)) else float(v)

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


def paired_table(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    reference: str,
    metrics: Sequence[tuple[str, str, str]] = PAIRED_METRICS,
) -> dict[str, dict[str, PairedDifference]]:
    """For each method but the reference and each paired metric: method - reference over the
    targets both converged on (smoothness and steps only mean something for a converged run),
    paired by (seed, target); episodes an event never reached are left out. The p-values are
    Holm-adjusted over this table's tests (a suite re-adjusts over all of its tests)."""
    raw = _paired_raw(rows, methods, reference, metrics)
    cells = [(m, col) for m, per in raw.items() for col in per]
    adjusted = adjust([raw[m][col] for m, col in cells])
    for (m, col), d in zip(cells, adjusted, strict=True):
        raw[m][col] = d
    return raw


def success_pairs(
    rows: Sequence[dict[str, Any]], method: str, reference: str
) -> tuple[int, int, int]:
    """(targets only the method converged on, both, only the reference), over the targets
    whose episodes of both methods the event reached (all targets when there is no event)."""
    by = {(r["method"], pair_key(r)): r for r in rows}
    conv = {k for k, r in by.items() if r.get("outcome") == "converged"}
    targets = [
        t
        for t in {pair_key(r) for r in rows}
        if _usable(by.get((method, t))) and _usable(by.get((reference, t)))
    ]
    only_m = sum((method, t) in conv and (reference, t) not in conv for t in targets)
    both = sum((method, t) in conv and (reference, t) in conv for t in targets)
    only_r = sum((method, t) not in conv and (reference, t) in conv for t in targets)
    return only_m, both, only_r


@dataclass
class Comparison:
    """One test of a suite: method - reference on one metric in one scenario, pooled over the
    seeds and on each seed alone."""

    scenario: str
    method: str
    metric: str
    label: str
    unit: str
    pooled: PairedDifference
    per_seed: dict[int, PairedDifference]

    @property
    def significant(self) -> bool:
        return self.pooled.significant(ALPHA)

    @property
    def disagreeing_seeds(self) -> list[int]:
        """The seeds whose mean difference does not have the pooled one's sign (or none)."""
        want = self.pooled.direction
        return [s for s, d in self.per_seed.items() if d.direction != want]

    @property
    def replicated(self) -> bool:
        """Significant pooled, after correction, and every one of >= 2 seeds agrees in sign."""
        return self.significant and len(self.per_seed) >= 2 and not self.disagreeing_seeds

    @property
    def verdict(self) -> str:
        if not self.significant:
            return "not significant"
        if self.replicated:
            return "replicated"
        if len(self.per_seed) < 2:
            return "not replicated (one seed)"
        seeds = ", ".join(str(s) for s in self.disagreeing_seeds)
        return f"not replicated (seed {seeds} disagrees in direction)"


def suite_comparisons(
    rows: Sequence[dict[str, Any]], methods: Sequence[str], reference: str, scenarios: Sequence[str]
) -> list[Comparison]:
    """Every comparison of the suite, pooled and per seed, Holm-adjusted.

    Two kinds of family: the pooled tests of every scenario, method and metric (the ones a
    finding rests on) are one family; the tests of one seed alone are another (what a suite
    run on that seed only would report). One seed: the pooled test is that seed's.
    """
    seeds = _seeds(rows)
    out: list[Comparison] = []
    for name in scenarios:
        mine = [r for r in rows if r["scenario"] == name]
        metrics = present_metrics(mine)
        pooled = _paired_raw(mine, methods, reference, metrics)
        if len(seeds) > 1:
            per = {
                s: _paired_raw([r for r in mine if r.get("seed") == s], methods, reference, metrics)
                for s in seeds
            }
        else:
            per = {s: pooled for s in seeds}
        for m, cells in pooled.items():
            for col, label, unit in metrics:
                out.append(
                    Comparison(
                        name, m, col, label, unit, cells[col], {s: per[s][m][col] for s in seeds}
                    )
                )
    for d, c in zip(adjust([c.pooled for c in out]), out, strict=True):
        c.pooled = d
    for s in seeds:
        family = adjust([c.per_seed[s] for c in out])
        for d, c in zip(family, out, strict=True):
            c.per_seed[s] = c.pooled if len(seeds) == 1 else d
    return out


def _difference_json(d: PairedDifference) -> dict[str, Any]:
    return vars(d) | {"significant": d.significant(ALPHA)}


def statistics_json(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    reference: str,
    scenarios: Sequence[str],
    comparisons: Sequence[Comparison],
) -> dict[str, Any]:
    """statistics.json: every comparison with raw and adjusted p, per seed and pooled, its
    verdict, and the findings (the pooled tests significant after correction)."""
    seeds = _seeds(rows)
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
        "findings": [
            {
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
            for c in comparisons
            if c.significant
        ],
        "scenarios": {},
    }
    for name in scenarios:
        mine = [r for r in rows if r["scenario"] == name]
        entry: dict[str, Any] = {
            "finished_before_event": {
                m: sum(bool(r.get("finished_before_event")) for r in mine if r["method"] == m)
                for m in methods
            },
            "diagnosis": diagnosis_counts(mine, methods),
            "methods": {},
        }
        for m in methods:
            if m == reference:
                continue
            om, both, orf = success_pairs(mine, m, reference)
            per_seed = {}
            for s in seeds:
                sm, sb, sr = success_pairs([r for r in mine if r.get("seed") == s], m, reference)
                per_seed[str(s)] = {"only_method": sm, "both": sb, "only_reference": sr}
            entry["methods"][m] = {
                "success": {"only_method": om, "both": both, "only_reference": orf},
                "success_per_seed": per_seed,
                "metrics": {
                    c.metric: _difference_json(c.pooled)
                    | {
                        "verdict": c.verdict,
                        "replicated": c.replicated,
                        "per_seed": {str(s): _difference_json(d) for s, d in c.per_seed.items()},
                    }
                    for c in comparisons
                    if c.scenario == name and c.method == m
                },
            }
        out["scenarios"][name] = entry
    return out


def write_suite_outputs(
    cfg: CompareConfig, folder: Path, folders: dict[str, str], wall: float
) -> Any:
    """results.csv, summary.md, statistics.json and report.html of the suite; returns the
    terminal tables."""
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
    scenarios = list(dict.fromkeys(r["scenario"] for r in rows))
    scenarios = [n for n in (cfg.scenarios or {}) if n in scenarios] or scenarios
    seeds = _seeds(rows)
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
        # Targets are told apart by (seed, target) once several seeds are pooled.
        keyed = [{**r, "target": pair_key(r)} for r in mine]
        summary = summarize(keyed, methods, bands)
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
        early = {
            m: sum(bool(r.get("finished_before_event")) for r in mine if r["method"] == m)
            for m in methods
        }
        if any(early.values()):
            md += [
                "Finished before the event (the event never reached them; counted in the table "
                "above, left out of the paired comparisons below with their pairs): "
                + ", ".join(f"{m} {n}" for m, n in early.items())
                + " episodes.",
                "",
            ]
        md += _diagnosis_markdown(mine, methods)
        mine_c = [c for c in comparisons if c.scenario == name]
        md += _paired_markdown(mine, methods, ref, mine_c, seeds)
        tables.append(
            (name, terminal_table(summary, f"{name}: {summary['common_targets']} paired"))
        )
    (folder / "summary.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    write_json_atomic(
        folder / "statistics.json", statistics_json(rows, methods, ref, scenarios, comparisons)
    )
    figure_sets = [(name, Path(f)) for name, f in folders.items()]
    write_report_html(
        folder / "report.html", f"rodctl suite {cfg.name}", "\n".join(md), figure_sets
    )
    from rich.console import Group

    return Group(*(t for _, t in tables))


def diagnosis_counts(rows: Sequence[dict[str, Any]], methods: Sequence[str]) -> dict[str, Any]:
    """Per method, how many of its stalled or pinned episodes got each diagnosis (and how many
    got none: an older run, or a diagnosis that failed)."""
    from rodctl.diagnosis import DIAGNOSES

    out = {}
    for m in methods:
        failed = [r for r in rows if r["method"] == m and r.get("outcome") in ("stalled", "pinned")]
        counts = {d: sum(r.get("diagnosis") == d for r in failed) for d in DIAGNOSES}
        counts["none"] = len(failed) - sum(counts.values())
        out[m] = counts
    return out


def _diagnosis_markdown(rows: Sequence[dict[str, Any]], methods: Sequence[str]) -> list[str]:
    from rodctl.compare import markdown_table
    from rodctl.diagnosis import DIAGNOSES

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
    from rodctl.compare import markdown_table

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


#: What the paired tables of a plain compare show (its summary.md).
PAIRED_NOTE = (
    "Paired differences are *method minus reference* over the targets both converged on: "
    "the mean, its BCa bootstrap 95 % confidence interval, the raw Wilcoxon signed-rank p, the "
    "p adjusted by Holm's correction over every test of this compare (*adj.*) and "
    "wins/ties/losses (lower is better for every metric). **bold**: significant after "
    f"correction (adjusted p < {ALPHA} and the interval excludes 0). Method: docs/statistics.md."
)


def paired_statistics(
    rows: Sequence[dict[str, Any]], methods: Sequence[str], ref: str
) -> tuple[list[str], dict[str, Any]]:
    """Every method against `ref` on the episodes of one plain compare: the summary.md lines (a
    verdict per method, then the paired table) and statistics.json (for every method but the
    reference, each paired metric's difference with raw and Holm-adjusted p, and `success`:
    `success_pairs`). The tests of the compare are one family, as a suite's pooled tests are."""
    from rodctl.report import verdict_lines

    name = "compare"
    tagged = [{**r, "scenario": name} for r in rows]
    comparisons = suite_comparisons(tagged, methods, ref, [name])
    paired = {
        m: {c.metric: c.pooled for c in comparisons if c.method == m} for m in methods if m != ref
    }
    md = verdict_lines(ref, paired) + _paired_markdown(
        tagged, methods, ref, comparisons, _seeds(tagged), family="this compare's tests"
    )
    stats = {
        m: {col: _difference_json(d) for col, d in per.items()}
        | {"success": success_pairs(tagged, m, ref)}
        for m, per in paired.items()
    }
    return md, stats


def _paired_markdown(
    rows: Sequence[dict[str, Any]],
    methods: Sequence[str],
    ref: str,
    comparisons: Sequence[Comparison],
    seeds: Sequence[Any],
    family: str = "the suite",
) -> list[str]:
    """The paired table; `family`: what the p-values were adjusted over ("the suite", or a plain
    compare's own tests, where replication across seeds does not apply)."""
    from rodctl.compare import markdown_table

    suite = family == "the suite"

    metrics = list(dict.fromkeys((c.metric, c.label) for c in comparisons))
    by = {(c.method, c.metric): c for c in comparisons}
    header = ["method", "converged only / both / only ref"] + [lbl for _, lbl in metrics]
    lines = []
    for m in methods:
        if m == ref:
            continue
        om, both, orf = success_pairs(rows, m, ref)
        cells = [m, f"{om} / {both} / {orf}"]
        for col, _ in metrics:
            c = by[(m, col)]
            text = c.pooled.describe(c.unit)
            verdict = f"; {c.verdict}" if suite else ""
            cells.append(f"**{text}**{verdict}" if c.significant else text)
        lines.append(cells)
    pooled = "pooled over the seeds, " if len(seeds) > 1 else ""
    out = [f"Paired against **{ref}** ({pooled}Holm-adjusted over {family}):", ""]
    out += [markdown_table(header, lines), ""]
    if len(seeds) < 2:
        return out
    header = ["method", "seed"] + [lbl for _, lbl in metrics]
    lines = []
    for m in methods:
        if m == ref:
            continue
        for s in seeds:
            cells = [m, str(s)]
            for col, _ in metrics:
                d = by[(m, col)].per_seed[s]
                text = d.describe(by[(m, col)].unit)
                cells.append(f"**{text}**" if d.significant(ALPHA) else text)
            lines.append(cells)
    out += ["Per seed (each seed's tests Holm-adjusted as one family):", ""]
    return [*out, markdown_table(header, lines), ""]
