"""`rodctl sweep`: a grid or seeded random search over config values, ranked by a metric.

A sweep is a compare with one more axis. Each *point* sets some dotted keys of the experiment
(`controller.weights`, `estimator.p0`, `rod.EI`, …: the keys `--set` takes) and runs every
method on the shared targets of every seed; so two points differ only by their swept values.
Every (point, method, seed, target) combination is validated before any work starts (a value a
key does not accept is exit 2 naming the key, the value and the method), and each episode runs
through the same study skeleton, worker and executors as `rodctl compare` (`rodctl.bench.runner`;
local pool or Ray), with its row
appended to results.jsonl the moment it finishes and `--resume` to finish an interrupted sweep.

Outputs, in one new folder: results.jsonl (the journal), results.csv (one row per episode, a
column per swept key), summary.json / summary.md (one line per point and method, ranked by
`rank_by`), sensitivity.json (how far each ranking metric moves across each knob's range,
`rodctl/sensitivity.py`, also a section of summary.md), figures/<metric>_vs_<key>.png (each
ranking metric against each swept key), targets_seed<S>.yaml.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError
from rich.table import Table

from rodctl.bench.compare import method_config
from rodctl.bench.runner import RunInterrupted, make_pool, run_study, run_tasks, with_workers
from rodctl.bench.stats import quantiles
from rodctl.bench.target_set import (
    CompareTarget,
    given_target_poses,
    make_targets,
    write_targets,
)
from rodctl.bench.tasks import EpisodeTask
from rodctl.config import ExperimentConfig
from rodctl.config.loading import (
    ConfigError,
    apply_override,
    config_source,
    format_validation_error,
    load_config,
)
from rodctl.config.sweep import MAX_POINTS, METRICS, ParameterConfig, SweepConfig
from rodctl.display import stderr
from rodctl.errors import UserError
from rodctl.executors.base import Executor
from rodctl.features import make_feature_map
from rodctl.report import markdown_table
from rodctl.runs import jsonable, rng, write_json_atomic
from rodctl.training import prepare_feature

#: Per-episode columns of results.csv after the swept keys.
EPISODE_COLUMNS = (
    "method",
    "target",
    "difficulty",
    "outcome",
    "converged",
    "steps",
    "steps_to_converge",
    "final_pixel_error",
    "final_T1",
    "smoothness",
    "path_length",
    "saturated_steps",
    "probe_steps",
    "wall_time_s",
    "error",
)


# --- config and points ------------------------------------------------------------------------


def sweep_points(cfg: SweepConfig) -> list[dict[str, Any]]:
    """The points of the search, in order: each maps every swept key to its value.

    Grid: the product of every key's `values`, first key slowest. Random: `samples` draws from
    the 'sweep' stream of the seed, each key independently (a choice among `values`, or uniform
    / log-uniform in [low, high], rounded when `integer`; a list drawn element by element when
    `elements`, divided by its sum when `normalize`).
    """
    keys = list(cfg.parameters)
    if cfg.search == "grid":
        # a grid parameter has its values (`SweepConfig` checks it)
        combos = itertools.product(*(cfg.parameters[k].values or [] for k in keys))
        return [dict(zip(keys, c, strict=True)) for c in combos]
    gen = rng(cfg.seed, "sweep")
    drawn = [{k: _draw(cfg.parameters[k], gen) for k in keys} for _ in range(cfg.samples or 0)]
    return [_base_point(cfg), *drawn] if cfg.include_base else drawn


def _base_point(cfg: SweepConfig) -> dict[str, Any]:
    """The current setting of every swept key (`include_base`): each method's own value (the
    base's, with no `methods`), which must be the same for all, since a point is one setting.

    Raises:
        ConfigError: a swept key a method does not set, or one the methods set differently
            (named).
    """
    methods = _method_data(cfg)
    point = {}
    for key in cfg.parameters:
        own = {name: _lookup(data, key) for name, data in methods.items()}
        lacking = [name for name, v in own.items() if v is _MISSING]
        if lacking:
            who = "the base has" if cfg.methods is None else f"method {lacking[0]} has"
            raise ConfigError(
                f"parameters.{key}: include_base takes the current value, but {who} no such key"
            )
        values = {json.dumps(jsonable(v), sort_keys=True) for v in own.values()}
        if len(values) > 1:
            said = ", ".join(f"{name} {json.dumps(jsonable(v))}" for name, v in own.items())
            raise ConfigError(
                f"parameters.{key}: include_base makes point 0 the current setting, one for "
                f"every method, but the methods set it differently ({said}); sweep them "
                "separately, or leave include_base out"
            )
        point[key] = next(iter(own.values()))
    return point


_MISSING = object()


def _lookup(data: Any, key: str) -> Any:
    """The value at a dotted `key` of plain config data (list items by index), or _MISSING."""
    node = data
    for part in key.split("."):
        if isinstance(node, dict) and part in node:
            node = node[part]
        elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        else:
            return _MISSING
    return node


def _draw(p: ParameterConfig, gen: np.random.Generator) -> Any:
    """One random-search value of a parameter: a choice, a (log-)uniform draw, or a list drawn
    element by element (then divided by its sum when `normalize`)."""
    if p.elements is not None:
        drawn = [_draw(e, gen) for e in p.elements]
        if p.normalize:
            total = float(sum(drawn))
            drawn = [float(v) / total for v in drawn]
        return drawn
    if p.values is not None:
        return p.values[int(gen.integers(len(p.values)))]
    assert p.low is not None and p.high is not None  # `ParameterConfig` checks it
    if p.log:
        v = float(math.exp(gen.uniform(math.log(p.low), math.log(p.high))))
    else:
        v = float(gen.uniform(p.low, p.high))
    return int(round(v)) if p.integer else v


def _method_data(cfg: SweepConfig) -> dict[str, dict[str, Any]]:
    """Each method's experiment (as plain data) before the swept values: base + its stages."""
    if cfg.methods is None:
        return {"base": cfg.base.model_dump(mode="json")}
    return {name: method_config(cfg, name).model_dump(mode="json") for name in cfg.methods}


def point_config(
    data: dict[str, Any], point: dict[str, Any], method: str, source: str
) -> ExperimentConfig:
    """One method's experiment at one point, validated.

    Raises:
        ConfigError: a key the experiment does not have, or a value it refuses (named with the
            point's values and the method).
    """
    data = json.loads(json.dumps(data))  # a deep copy of plain data
    for key, value in point.items():
        apply_override(data, key.split("."), value, f"{key}={value!r}")
    try:
        return ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        where = ", ".join(f"{k}={v!r}" for k, v in point.items())
        raise ConfigError(
            format_validation_error(exc, data, f"{source}: parameters ({where}), method {method}")
        ) from None


def load_sweep_config(path: str | Path, overrides: list[str] | None = None) -> SweepConfig:
    """Load and validate a sweep config, and every (point, method) experiment it makes.

    Raises:
        ConfigError: naming the file and the dotted key (`parameters.<key>`, `methods.<name>`).
    """
    cfg = load_config(path, overrides, model=SweepConfig)
    source = config_source(path, overrides)
    try:
        points = sweep_points(cfg)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if len(points) > MAX_POINTS:
        raise ConfigError(f"{source}: {len(points)} points; at most {MAX_POINTS} (split it)")
    methods = _method_data(cfg)
    for point in points:
        for name, data in methods.items():
            point_config(data, point, name, source)
    return cfg


# --- statistics -------------------------------------------------------------------------------


def group_stats(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The ranking metrics of one (point, method) group over its episodes (seeds x targets).

    Steps, smoothness and path length are over converged episodes (a run wandering to the
    step limit accumulates them without bound); the final pixel error over all episodes.
    """
    conv = [r for r in rows if r.get("outcome") == "converged"]

    def med(values: list[Any]) -> float | None:
        return quantiles([float(v) for v in values if v is not None])[1]

    return {
        "episodes": len(rows),
        "converged": len(conv),
        "errors": sum(r.get("outcome") == "error" for r in rows),
        "success_rate": len(conv) / len(rows) if rows else None,
        "steps_median": med([r.get("steps_to_converge") for r in conv]),
        "steps_mean": _mean([r.get("steps_to_converge") for r in conv]),
        "final_pixel_error_median": med([r.get("final_pixel_error") for r in rows]),
        "smoothness_median": med([r.get("smoothness") for r in conv]),
        "path_length_median": med([r.get("path_length") for r in conv]),
        "wall_time_median": med([r.get("wall_time_s") for r in rows]),
    }


def _mean(values: list[Any]) -> float | None:
    kept = [float(v) for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def rank_groups(groups: list[dict[str, Any]], rank_by: list[str]) -> list[dict[str, Any]]:
    """Groups sorted best first by `rank_by` (success rate descending, the others ascending);
    a metric with no value (nothing converged) ranks last. Adds `rank` (1 = best)."""

    def key(g: dict[str, Any]) -> tuple:
        out = []
        for m in rank_by:
            v = g.get(m)
            if v is None or (isinstance(v, float) and math.isnan(v)):
                out.append((True, 0.0))
            else:
                out.append((False, -v if METRICS[m] else v))
        return tuple(out)

    ranked = sorted(groups, key=key)
    for i, g in enumerate(ranked, 1):
        g["rank"] = i
    return ranked


# --- the command ------------------------------------------------------------------------------


class SweepStudy:
    """`rodctl sweep` as a study of `rodctl.bench.runner`: the shared targets of every seed, one
    episode per (seed, target, point, method), and the ranking."""

    command = "sweep"

    def __init__(self, cfg: SweepConfig, source: str, config_dir: Path, wall0: float) -> None:
        self.config = cfg
        self.source = source
        self.points = sweep_points(cfg)
        self.methods = _method_data(cfg)
        preflight(self.methods)
        given = given_target_poses(cfg, config_dir)
        self.given = given
        self.hashed = {"config": cfg.model_dump(mode="json", exclude={"workers"}), "targets": given}
        self.targets: dict[int, list[CompareTarget]] = {}
        self.wall0 = wall0

    def plan(self, pool: Executor, folder: Path, progress: bool) -> list[EpisodeTask]:
        """Make every seed's shared targets (targets_seed<S>.yaml) and the episode tasks."""
        cfg = self.config
        for s in cfg.seeds:
            spec = cfg.model_copy(update={"seed": s})  # what make_targets reads: this seed

            def fan_out(ts: list[Any], fn: Callable[[Any], Any], s: int = s) -> list[Any]:
                return run_tasks(pool, ts, fn, f"targets s{s}", progress)

            self.targets[s] = make_targets(spec, self.given, fan_out)
            write_targets(self.targets[s], folder / f"targets_seed{s}.yaml")
        return sweep_tasks(cfg, self.points, self.methods, self.targets, folder, self.source)

    def report(
        self, folder: Path, rows: list[dict[str, Any]], total: int, pool: Executor, progress: bool
    ) -> None:
        """results.csv, summary.json/md (ranked), figures; the ranked table on the terminal."""
        wall = time.perf_counter() - self.wall0
        _report(self.config, folder, self.points, self.targets, rows, total, wall, pool, progress)


def run_sweep(
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
    """Run the sweep of `config_path` into a new folder under `out` (or `resume`); return it.

    Raises:
        UserError: a bad config (any point or method), target or `resume` folder.
        RunInterrupted: SIGINT/SIGTERM stopped it; finished episodes are written, partial.
    """
    wall0 = time.perf_counter()
    cfg = with_workers(load_sweep_config(config_path, overrides), workers)
    source = config_source(config_path, overrides)
    study = SweepStudy(cfg, source, Path(config_path).resolve().parent, wall0)
    pool = make_pool(executor, workers, cfg.workers, address)
    return run_study(study, out, pool, progress=progress, resume=resume, executor=executor)


def preflight(methods: dict[str, dict[str, Any]]) -> None:
    """Build each method's feature once here, so a missing checkpoint fails before any work."""
    for data in methods.values():
        ecfg = ExperimentConfig.model_validate(data)
        prepare_feature(ecfg)
        make_feature_map(ecfg.feature, points=ecfg.camera.points, experiment=ecfg)


def sweep_tasks(
    cfg: SweepConfig,
    points: list[dict[str, Any]],
    methods: dict[str, dict[str, Any]],
    targets: dict[int, list[CompareTarget]],
    folder: Path,
    source: str,
) -> list[EpisodeTask]:
    """One task per (seed, target, point, method), target-major: a partial sweep has every
    point on its first targets, so its ranking already means something."""
    configs = {
        (i, name): point_config(data, point, name, source).model_dump(mode="json")
        for i, point in enumerate(points)
        for name, data in methods.items()
    }
    tasks = []
    for s in cfg.seeds:
        for t in targets[s]:
            for i, point in enumerate(points):
                for name in methods:
                    run_id = f"{name}_p{i:04d}_s{s}_t{t.index:03d}"
                    log_dir = folder / "episodes" / run_id if cfg.keep_logs else None
                    tasks.append(
                        EpisodeTask(
                            config=configs[(i, name)],
                            method=name,
                            target=t.index,
                            pose=tuple(float(v) for v in t.pose),
                            seed=t.seed,
                            log_dir=str(log_dir) if log_dir else None,
                            run_id=run_id,
                            tags={
                                "point": i,
                                "seed": s,
                                "difficulty": round(t.difficulty, 6),
                                **point,
                            },
                        )
                    )
    return tasks


def _cell(v: Any) -> Any:
    """A CSV cell: lists and mappings as JSON, None as empty."""
    if v is None:
        return ""
    if isinstance(v, list | tuple | dict):
        return json.dumps(jsonable(v))
    return v


def _report(
    cfg: SweepConfig,
    folder: Path,
    points: list[dict[str, Any]],
    targets: dict[int, list[CompareTarget]],
    rows: list[dict[str, Any]],
    total: int,
    wall: float,
    pool: Any,
    progress: bool,
) -> None:
    """results.csv, summary.json/md (ranked), figures; the ranked table on the terminal."""
    keys = list(cfg.parameters)
    for r in rows:
        r["converged"] = r.get("outcome") == "converged"
    write_results_csv(folder / "results.csv", rows, keys)
    method_names = list(cfg.methods) if cfg.methods is not None else ["base"]
    ranked = rank_groups(_groups(points, method_names, rows), cfg.rank_by)
    summary = {
        "name": cfg.name,
        "search": cfg.search,
        "rank_by": cfg.rank_by,
        "parameters": keys,
        "points": len(points),
        "seeds": cfg.seeds,
        "targets_per_seed": {str(s): len(t) for s, t in targets.items()},
        "episodes": {"finished": len(rows), "total": total},
        "partial": len(rows) < total,
        "executor": pool.name,
        "workers": min(pool.workers, max(total, 1)),  # a pool starts no more than it has tasks
        "wall_time_s": round(wall, 2),
        "ranking": ranked,
    }
    write_json_atomic(folder / "summary.json", summary)
    header, lines = _summary_table(ranked, keys, cfg.rank_by)
    table = markdown_table(header, lines)
    text = _summary_md(cfg, summary, table, len(method_names), targets, wall)
    # sensitivity.json + its summary section; lazy: it loads scipy, only a report needs it
    from rodctl.sensitivity import write_sensitivity  # noqa: PLC0415

    text += write_sensitivity(folder, ranked, keys, cfg.rank_by)
    (folder / "summary.md").write_text("\n".join(text), encoding="utf-8")
    if rows:
        for metric in cfg.rank_by:
            for key in keys:
                path = folder / "figures" / f"{metric}_vs_{key.replace('.', '_')}.png"
                metric_figure(rows, key, metric, method_names, path)
    if progress:
        _print_table(f"{cfg.name}: {len(rows)}/{total} episodes, {wall:.0f} s", header, lines)


def write_results_csv(path: Path, rows: list[dict[str, Any]], keys: list[str]) -> None:
    """results.csv: one row per episode, its point and seed, a column per swept key, then the
    episode's own columns (`EPISODE_COLUMNS`)."""
    columns = ["point", "seed", *keys, *EPISODE_COLUMNS]
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: _cell(r.get(k)) for k in columns})


def _groups(
    points: list[dict[str, Any]], methods: list[str], rows: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """One group per (point, method), point-major, with its swept values and `group_stats`."""
    groups = []
    for i, point in enumerate(points):
        for m in methods:
            mine = [r for r in rows if r.get("point") == i and r["method"] == m]
            groups.append({"point": i, "method": m, **point, **group_stats(mine)})
    return groups


def _summary_md(
    cfg: SweepConfig,
    summary: dict[str, Any],
    table: str,
    n_methods: int,
    targets: dict[int, list[CompareTarget]],
    wall: float,
) -> list[str]:
    """summary.md's lines: the title, the PARTIAL note of a stopped sweep, how it ran, the
    ranked table."""
    finished, total = summary["episodes"]["finished"], summary["episodes"]["total"]
    text = [f"# rodctl sweep: {cfg.name}", ""]
    if summary["partial"]:
        counts = sorted({g["episodes"] for g in summary["ranking"]})
        uneven = (
            f" The points finished different numbers of episodes ({', '.join(map(str, counts))})"
            ", so their ranks compare partly different targets."
            if len(counts) > 1
            else ""
        )
        text += [
            f"**PARTIAL**: interrupted; {finished} of {total} episodes finished and are "
            f"counted here.{uneven} `rodctl sweep CONFIG --resume FOLDER` finishes it.",
            "",
        ]
    return text + [
        f"{cfg.search} search, {summary['points']} points x {n_methods} method(s) x "
        f"{sum(len(t) for t in targets.values())} targets in all (seeds {cfg.seeds}, each its "
        "own target set); ranked by "
        f"{', '.join(cfg.rank_by)} (success rate: higher is better; others lower). Steps: "
        f"median steps to converge over converged episodes. Wall time {wall:.0f} s to this "
        f"summary on {summary['workers']} {summary['executor']} worker(s) (a resumed run's "
        "earlier invocations included; meta.json's wall_s counts the figures too).",
        "",
        table,
        "",
    ]


def _print_table(title: str, header: list[str], lines: list[list[str]]) -> None:
    """The ranked table (its first 20 lines) on the terminal."""
    table = Table(title=title)
    for h in header:
        table.add_column(h)
    for line in lines[:20]:
        table.add_row(*line)
    stderr.print(table)


def _fmt(v: Any, spec: str) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    return format(v, spec)


def _summary_table(
    ranked: list[dict[str, Any]], keys: list[str], rank_by: list[str]
) -> tuple[list[str], list[list[str]]]:
    # A ranking metric the fixed columns do not show gets its own, after success: ranked by
    # steps_mean, a table of medians only looked out of order
    shown = {"success_rate", "steps_median", "final_pixel_error_median", "smoothness_median"}
    extra = [m for m in rank_by if m not in shown]
    header = ["rank", "point", "method", *keys, "success", *extra, "steps", "final px"]
    header += ["smooth.", "errors"]
    lines = []
    for g in ranked:
        rate = g["success_rate"]
        pct = _fmt(None if rate is None else 100 * rate, ".0f")
        lines.append(
            [
                str(g["rank"]),
                str(g["point"]),
                g["method"],
                *[json.dumps(jsonable(g[k])) for k in keys],
                f"{g['converged']}/{g['episodes']} ({pct}%)",
                *[_fmt(g[m], ".4g") for m in extra],
                _fmt(g["steps_median"], ".1f"),
                _fmt(g["final_pixel_error_median"], ".2f"),
                _fmt(g["smoothness_median"], ".3f"),
                str(g["errors"]),
            ]
        )
    return header, lines


def metric_figure(
    rows: list[dict[str, Any]], key: str, metric: str, methods: list[str], path: Path
) -> Path:
    """`metric` against the values of one swept key (pooled over the other keys), per method.

    Numeric values get a numeric axis (log when they span more than two decades); any other
    value (a list of weights) is a category labelled by its value.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    values: list[Any] = []
    for r in rows:
        v = r.get(key)
        if v not in values:
            values.append(v)
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
    if numeric:
        values = sorted(values)
    if _numeric_lists(values):
        return _elements_figure(rows, key, metric, methods, values, path)
    fig = Figure(figsize=(6.4, 4.2), layout="constrained")
    ax = fig.subplots()
    for m in methods:
        ys = [
            group_stats([r for r in rows if r["method"] == m and r.get(key) == v])[metric]
            for v in values
        ]
        xs = values if numeric else list(range(len(values)))
        ax.plot(xs, [np.nan if y is None else y for y in ys], marker="o", label=m)
    if numeric:
        positive = [v for v in values if v > 0]
        if len(positive) == len(values) and max(values) / min(values) > 100:
            ax.set_xscale("log")
    else:
        ax.set_xticks(range(len(values)))
        ax.set_xticklabels([json.dumps(jsonable(v)) for v in values], rotation=20, fontsize=7)
    ax.set_xlabel(key)
    ax.set_ylabel(metric.replace("_", " "))
    if metric == "success_rate":
        ax.set_ylim(-0.05, 1.05)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{metric} against {key}")
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)
    return path


def _numeric_lists(values: list[Any]) -> bool:
    """Whether every value is a list of numbers, all of one length (a weight vector)."""
    return bool(values) and all(
        isinstance(v, list)
        and len(v) == len(values[0]) > 0
        and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        for v in values
    )


def _elements_figure(
    rows: list[dict[str, Any]],
    key: str,
    metric: str,
    methods: list[str],
    values: list[list[float]],
    path: Path,
) -> Path:
    """`metric` of each (point, method) group against each element of a list-valued key, one
    panel per element, as points (a list drawn element by element has no order to join them
    in; its values as tick labels did not fit)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = len(values[0])
    cols = min(n, 4)
    fig = Figure(figsize=(3.2 * cols, 2.6 * math.ceil(n / cols) + 0.4), layout="constrained")
    axes = np.atleast_1d(fig.subplots(math.ceil(n / cols), cols, squeeze=False)).ravel()
    for m_i, m in enumerate(methods):
        ys = [
            group_stats([r for r in rows if r["method"] == m and r.get(key) == v])[metric]
            for v in values
        ]
        y = [np.nan if v is None else v for v in ys]
        for j in range(n):
            axes[j].scatter([v[j] for v in values], y, s=14, color=f"C{m_i}", label=m)
    for j, ax in enumerate(axes):
        if j >= n:
            ax.set_visible(False)
            continue
        ax.set_xlabel(f"{key}[{j}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
        if metric == "success_rate":
            ax.set_ylim(-0.05, 1.05)
    axes[0].set_ylabel(metric.replace("_", " "))
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{metric} against each element of {key}", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)
    return path


def read_results(folder: str | Path) -> list[dict[str, Any]]:
    """The rows of a sweep's results.csv (strings, as written)."""
    with (Path(folder) / "results.csv").open(encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


__all__ = [
    "RunInterrupted",
    "UserError",
    "load_sweep_config",
    "metric_figure",
    "rank_groups",
    "read_results",
    "run_sweep",
    "sweep_points",
]
