"""`rodctl compare`: the paper's comparison (Chen, section VI) turned into a reproducible benchmark.

The paper claims that its framework (autoencoder + AKF + MFAC) converges fastest, Ma et al. 2022
second and Aghajanzadeh et al. 2022 slowest but smoothest, and shows only curves of one run. Here
every method runs the same K reachable targets from the same start, under the same speed limits,
step budget, probing budget and success criterion (the mean pixel distance to the target's
extracted 100-point centerline, the one measure every feature can be judged by), and the outcome
of every episode is written down: converged, stalled, step limit or diverged.

Fairness is structural: `CompareConfig` lets a method choose only its feature, estimator and
controller; everything else comes from one shared `base` experiment. Each target has its own
seed (camera noise), shared by all methods, so two methods on one target differ only by method.

Episodes are independent, so an executor (`rodctl.executors`: this process, a spawn pool, Ray)
runs them, one BLAS/torch thread each, through the study skeleton a sweep runs on too
(`rodctl.bench.runner`); results depend neither on the number of workers nor on the executor.
Each row is appended to results.jsonl the moment its episode finishes, so a run stopped by
SIGINT/SIGTERM (or killed) keeps them and `--resume` finishes it.
Outputs, in one new folder: results.csv / results.json (one row per episode), summary.md (the
table also printed to the terminal, and the paired comparison with the reference), targets.yaml
(the target poses, reusable as a `targets.file`), figures/ (the paper's three figures side by
side for one target, success rate and steps against target difficulty), statistics.json and
report.html (`rodctl.bench.comparisons`, `rodctl.report`) and, if asked, every episode's logs
under episodes/.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from pydantic import ValidationError
from rich import box
from rich.table import Table

from rodctl.bench.comparisons import write_compare_report
from rodctl.bench.episodes import METRIC_COLUMNS
from rodctl.bench.runner import make_pool, run_study, run_tasks, with_workers
from rodctl.bench.stats import band_names, fmt, fmt_steps, summarize, summary_rows
from rodctl.bench.target_set import (
    CompareTarget,
    given_target_poses,
    make_targets,
    write_targets,
)
from rodctl.bench.tasks import EpisodeTask
from rodctl.config import ExperimentConfig
from rodctl.config.compare import CompareConfig, MethodConfig
from rodctl.config.loading import (
    ConfigError,
    config_source,
    format_validation_error,
    load_config,
)
from rodctl.display import stderr
from rodctl.errors import UserError
from rodctl.executors.base import Executor
from rodctl.features import make_feature_map
from rodctl.report import markdown_table
from rodctl.runs import write_json_atomic
from rodctl.training import prepare_feature

#: Columns of results.csv, in order.
CSV_COLUMNS = (
    "scenario",
    "seed",
    "method",
    "target",
    "band",
    "difficulty",
    "target_x",
    "target_y",
    "target_theta",
    "outcome",
    "converged",
    "steps",
    "steps_to_converge",
    "final_pixel_error",
    "final_T1",
    "path_length",
    "rotation_length",
    "smoothness",
    "saturated_steps",
    "clipped_steps",
    "probe_steps",
    *METRIC_COLUMNS,
    "jacobian_error_median",
    "jacobian_error_final",
    "diagnosis",
    "wall_time_s",
    "error",
)


# --- config -----------------------------------------------------------------------------------


def load_compare_config(path: str | Path, overrides: Sequence[str] | None = None) -> CompareConfig:
    """Load a compare config: YAML -> `--set` overrides -> validation, every method checked.

    Each method is validated as the full `ExperimentConfig` it will run (base + its three
    stages), so a method that cannot run (e.g. an offline Jacobian on a feature that does not
    observe its nodes) fails here, named by its dotted path.

    Raises:
        ConfigError: (a `UserError`) naming the file and the offending dotted key.
    """
    cfg = load_config(path, overrides, model=CompareConfig)
    source = config_source(path, overrides)
    for name in cfg.methods:
        method_config(cfg, name, source=source)
    return cfg


class MethodsSpec(Protocol):
    """What `method_config` reads of a compare, sweep or suite config."""

    @property
    def base(self) -> ExperimentConfig: ...

    @property
    def methods(self) -> Mapping[str, MethodConfig] | None: ...


def method_config(
    cfg: MethodsSpec, name: str, *, source: str = "compare config"
) -> ExperimentConfig:
    """The `ExperimentConfig` of one method: the shared base with the method's three stages.

    Raises:
        ConfigError: the combination does not validate (names `methods.<name>`).
    """
    assert cfg.methods is not None, "method_config needs a config with methods"
    method = cfg.methods[name]
    data = cfg.base.model_dump(mode="json")
    data.update(
        name=name,
        feature=method.feature.model_dump(mode="json"),
        estimator=method.estimator.model_dump(mode="json"),
        controller=method.controller.model_dump(mode="json"),
    )
    try:
        return ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, data, f"{source}: methods.{name}")) from None


# --- the study ----------------------------------------------------------------------------------


def preflight(cfg: CompareConfig) -> dict[str, ExperimentConfig]:
    """Every method's config, each built once here so a missing checkpoint, or one trained for
    another rod or camera, fails before work (and `checkpoint: auto` trains here, once)."""
    configs = {name: method_config(cfg, name) for name in cfg.methods}
    for ecfg in configs.values():
        prepare_feature(ecfg)
        make_feature_map(ecfg.feature, points=ecfg.camera.points, experiment=ecfg)
    return configs


def target_columns(cfg: CompareConfig, t: CompareTarget) -> dict[str, Any]:
    """The columns of results.csv that the target and the study decide (not the episode)."""
    return {
        "scenario": cfg.scenario,
        "seed": cfg.seed,
        "band": t.band(cfg.targets.bands),
        "difficulty": round(t.difficulty, 6),
        "target_x": float(t.pose[0]),
        "target_y": float(t.pose[1]),
        "target_theta": float(t.pose[2]),
    }


def episode_tasks(
    cfg: CompareConfig,
    configs: dict[str, ExperimentConfig],
    targets: Sequence[CompareTarget],
    fig_target: int,
    folder: Path,
) -> list[EpisodeTask]:
    """One task per (target, method), target-major: partial progress covers every method."""
    tasks = []
    for t in targets:
        for name, ecfg in configs.items():
            log_dir = folder / "episodes" / name / f"t{t.index:03d}" if cfg.keep_logs else None
            tasks.append(
                EpisodeTask(
                    config=ecfg.model_dump(mode="json"),
                    method=name,
                    target=t.index,
                    pose=tuple(float(v) for v in t.pose),
                    # Every method shares the base's rod and camera: the target made once.
                    target_view=t.view,
                    target_difficulty=t.difficulty,
                    seed=t.seed,
                    want_records=t.index == fig_target,
                    log_dir=str(log_dir) if log_dir else None,
                    # A stalled or pinned episode is examined for why (rodctl.diagnosis).
                    diagnose=True,
                    # results.jsonl carries every column of results.csv (`label_rows` too)
                    columns={**target_columns(cfg, t), "converged": False},
                )
            )
    return tasks


class CompareStudy:
    """`rodctl compare` as a study of `rodctl.bench.runner`: the shared targets, one episode
    per (target, method), and the comparison's outputs."""

    command = "compare"

    def __init__(
        self,
        cfg: CompareConfig,
        configs: dict[str, ExperimentConfig],
        given: list[list[float]] | None,
        wall0: float,
    ) -> None:
        self.config = cfg
        self.configs = configs  # `preflight`
        self.given = given
        self.hashed = {"config": cfg.model_dump(mode="json", exclude={"workers"}), "targets": given}
        self.targets: list[CompareTarget] = []
        self.fig_target = -1
        self.wall0 = wall0

    def plan(self, pool: Executor, folder: Path, progress: bool) -> list[EpisodeTask]:
        """Make the shared targets (targets.yaml) and the episode tasks."""
        cfg = self.config
        self.targets = make_targets(
            cfg, self.given, lambda tasks, fn: run_tasks(pool, tasks, fn, "targets", progress)
        )
        write_targets(self.targets, folder / "targets.yaml")
        self.fig_target = figure_target(cfg, self.targets)
        return episode_tasks(cfg, self.configs, self.targets, self.fig_target, folder)

    def report(
        self, folder: Path, rows: list[dict[str, Any]], total: int, pool: Executor, progress: bool
    ) -> None:
        """results.csv/json, summary.md, figures, statistics.json and report.html, and the table
        on the terminal; a partial run (fewer rows than `total`) says so in each."""
        cfg = self.config
        partial = len(rows) < total
        bands = band_names(cfg.targets.bands)
        records = {r["method"]: r.pop("_records") for r in rows if "_records" in r}
        label_rows(cfg, self.targets, rows)
        summary = summarize(rows, list(cfg.methods), bands)
        wall = time.perf_counter() - self.wall0
        workers = min(pool.workers, max(total, 1))  # a pool starts no more than it has tasks
        write_results(
            folder,
            cfg,
            self.targets,
            rows,
            summary,
            wall,
            workers,
            partial=partial,
            executor=pool.name,
            figure_target=self.fig_target,
        )
        header, lines = summary_rows(summary, bands)
        md = folder / "summary.md"
        write_summary_md(
            md, cfg, header, lines, summary, wall, workers, self.fig_target, len(self.targets)
        )
        if partial:
            _mark_partial(md, len(rows), len(self.targets) * len(cfg.methods))
        if rows:
            _write_figures(folder / "figures", records, rows, list(cfg.methods))
        write_compare_report(folder, cfg, rows)
        if progress:
            title = f"{cfg.name}: {len(self.targets)} targets, {wall:.0f} s"
            _print_table(summary, title + (" (PARTIAL)" if partial else ""))


def run_compare(
    config_path: str,
    overrides: list[str],
    out: str,
    *,
    progress: bool,
    workers: int | None,
    executor: str = "local",
    address: str | None = None,
    resume: str | None = None,
    on_start: Callable[[Path], None] | None = None,
    pool: Executor | None = None,
) -> Path:
    """Run the benchmark of `config_path` into a new folder under `out`; return that folder.

    Args:
        config_path: the compare config (YAML).
        overrides: `--set a.b=v` overrides, applied to the compare config (e.g.
            `methods.ours.controller.weights=[...]`, `targets.count=10`, `base.run.max_steps=100`).
        out: parent folder of the output folder.
        progress: show progress bars and print the summary table (stderr).
        workers: worker processes (Ray: CPUs of a Ray started for the run); None: the config's
            `workers`, else one per CPU core.
        executor: "local" (this process or a spawn pool) or "ray".
        address: an existing Ray cluster to run on (executor "ray").
        resume: an earlier run folder of the same config: its finished episodes are kept and
            only the others run, into that folder.
        on_start: called with the run's folder as soon as it exists (a suite records it, so
            that `--resume` continues this folder even after the process was killed).
        pool: an executor started by the caller and left running (a suite's, shared by its
            scenarios: `rodctl.executors.base.SharedExecutor`); None: one made for this run
            from `executor`, `workers` and `address`.

    Returns:
        The output folder (holding results.jsonl/csv/json, summary.md, targets.yaml, figures/).

    Raises:
        UserError: bad config, target file or target; a method that cannot be built; a
            `resume` folder whose config differs.
        RunInterrupted: SIGINT/SIGTERM stopped the run; every finished episode is written
            (results marked partial) and meta.json says `interrupted`.
    """
    wall0 = time.perf_counter()
    cfg = with_workers(load_compare_config(config_path, overrides), workers)
    configs = preflight(cfg)
    given = given_target_poses(cfg, Path(config_path).resolve().parent)
    study = CompareStudy(cfg, configs, given, wall0)
    if pool is None:
        pool = make_pool(executor, workers, cfg.workers, address)
    return run_study(
        study, out, pool, progress=progress, resume=resume, on_start=on_start, executor=executor
    )


# --- outputs ------------------------------------------------------------------------------------


def label_rows(
    cfg: CompareConfig, targets: Sequence[CompareTarget], rows: list[dict[str, Any]]
) -> None:
    """Give every row the columns its target and the study decide (`target_columns`), and
    `converged`, in place (a row kept from an older journal may lack them)."""
    by_index = {t.index: t for t in targets}
    for r in rows:
        r.update(target_columns(cfg, by_index[r["target"]]), converged=r["outcome"] == "converged")


def _mark_partial(md: Path, finished: int, expected: int) -> None:
    """Put the PARTIAL note at the top of summary.md."""
    note = (
        f"**PARTIAL**: the run was interrupted; {finished} of {expected} episodes finished "
        "and are counted here. `rodctl compare CONFIG --resume FOLDER` finishes it.\n\n"
    )
    md.write_text(note + md.read_text(encoding="utf-8"), encoding="utf-8")


def figure_target(cfg: CompareConfig, targets: Sequence[CompareTarget]) -> int:
    """The target drawn side by side: the configured one, else the one of median difficulty."""
    if cfg.figure_target is not None:
        if cfg.figure_target >= len(targets):
            raise UserError(
                f"figure_target={cfg.figure_target}, but there are only {len(targets)} targets"
            )
        return cfg.figure_target
    order = sorted(targets, key=lambda t: t.difficulty)
    return order[(len(order) - 1) // 2].index


def write_results(
    folder: Path,
    cfg: CompareConfig,
    targets: Sequence[CompareTarget],
    rows: Sequence[dict],
    summary: dict,
    wall: float,
    workers: int,
    *,
    partial: bool = False,
    executor: str = "local",
    figure_target: int | None = None,
) -> None:
    """results.csv (one row per episode) and results.json (rows, summary, targets, config).

    `partial`: an interrupted run; results.json says so (`"partial": true`).
    `figure_target`: the target the side-by-side figures show (their captions name it).
    """
    write_results_csv(folder / "results.csv", rows)
    data = {
        "name": cfg.name,
        "seed": cfg.seed,
        "wall_time_s": round(wall, 2),
        "workers": workers,
        "executor": executor,
        "partial": partial,
        "figure_target": figure_target,
        "targets": [
            {
                "index": t.index,
                "pose": [float(v) for v in t.pose],
                "difficulty": t.difficulty,
                "seed": t.seed,
            }
            for t in targets
        ],
        "summary": summary,
        "episodes": [{k: r.get(k) for k in CSV_COLUMNS} for r in rows],
        "config": cfg.model_dump(mode="json"),
    }
    write_json_atomic(folder / "results.json", data)


def write_results_csv(path: Path, rows: Sequence[dict]) -> None:
    """results.csv: one row per episode, the columns `CSV_COLUMNS` (None as empty)."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_COLUMNS})


def write_summary_md(
    path: Path,
    cfg: CompareConfig,
    header: Sequence[str],
    lines: Sequence[Sequence[str]],
    summary: dict,
    wall: float,
    workers: int,
    fig_target: int,
    targets: int,
) -> None:
    """summary.md: the table, what each method is, and how the benchmark was run (`targets`:
    the study's, whatever a partial run finished of them)."""
    run = cfg.base.run
    text = [
        f"# rodctl compare: {cfg.name}",
        "",
        f"{targets} targets per method, seed "
        f"{cfg.seed}; step budget {run.max_steps} (probing included), success = mean pixel "
        f"error < {run.pixel_tolerance} px on the {cfg.base.camera.points}-point centerline; "
        f"speed limit {list(cfg.base.rod.max_step)} per step. Wall time {wall:.0f} s to this "
        f"summary on {workers} worker(s) (a resumed run's earlier invocations included; "
        "meta.json's wall_s counts the figures too).",
        "",
        "Steps: steps to converge over converged episodes, median [IQR]; *paired*: only the "
        f"{summary['common_targets']} targets every method converged on. Smoothness: summed "
        "||u_k - u_{k-1}|| and path: summed ||(dx, dy)||, medians over converged episodes. "
        f"Band columns (difficulty edges {cfg.targets.bands}): success % / median steps. Last "
        "column: stalled / pinned / step limit / failed (diverged, lost the rod, error) episodes.",
        "",
        markdown_table(header, lines),
        "",
        "## Methods",
        "",
    ]
    for name, m in cfg.methods.items():
        text.append(
            f"- **{name}** ({m.feature.type} / {m.estimator.type} / {m.controller.type}): "
            f"{m.description}"
        )
    text += ["", f"Figures: figures/ (side-by-side figures for target {fig_target})."]
    path.write_text("\n".join(text) + "\n", encoding="utf-8")


def _write_figures(folder: Path, records: dict, rows: Sequence[dict], methods: list[str]) -> None:
    from rodctl.plots import write_comparison_figures  # noqa: PLC0415 - matplotlib, to draw

    ordered = {m: records[m] for m in methods if m in records}
    if ordered:
        write_comparison_figures(ordered, folder)
    success_figure(rows, methods, folder / "success_vs_difficulty.png")


def terminal_table(summary: dict, title: str) -> Any:
    """The summary as a rich table that fits 80 columns (the full table is in summary.md).

    Columns: success rate; median [IQR] steps to converge; paired median (targets every
    method converged on); median smoothness; median final pixel error; stalled / pinned /
    step-limit / failed episodes.
    """
    table = Table(title=title, box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True)
    justifications: tuple[tuple[str, Literal["left", "right"]], ...] = (
        ("method", "left"),
        ("success", "right"),
        ("steps [IQR]", "right"),
        ("paired", "right"),
        ("smooth", "right"),
        ("px", "right"),
        ("st/pin/lim/fail", "right"),
    )
    for name, justify in justifications:
        table.add_column(name, justify=justify, no_wrap=True, min_width=len(name))
    for m, st in summary["methods"].items():
        rate = st["success_rate"]
        o = st["outcomes"]
        fails = o["diverged"] + o["lost_tracking"] + o["error"]
        table.add_row(
            m,
            f"{fmt(None if rate is None else 100 * rate)}%",
            f"{fmt_steps(st['steps_median'])} [{fmt_steps(st['steps_q25'])}-"
            f"{fmt_steps(st['steps_q75'])}]",
            fmt_steps(st["paired_steps_median"]),
            fmt(st["smoothness_median"], ".3f"),
            fmt(st["final_pixel_error_median"], ".2f"),
            f"{o['stalled']}/{o.get('pinned', 0)}/{o['step_limit']}/{fails}",
        )
    return table


def _print_table(summary: dict, title: str) -> None:
    stderr.print(terminal_table(summary, title))


def success_figure(rows: Sequence[dict], methods: Sequence[str], path: Path, bins: int = 5) -> Path:
    """Success rate and median steps to converge against target difficulty, one line per method.

    Methods differ by colour, line style and marker (`rodctl.plots.style`), and each method's
    points are shifted sideways by a small, fixed amount, so two methods with the same value
    (every method at 100 %) stay visible side by side instead of hiding each other."""
    from rodctl.plots import DPI  # noqa: PLC0415 - matplotlib, only to draw

    fig = success_axes(rows, methods, bins)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    return path


def success_axes(rows: Sequence[dict], methods: Sequence[str], bins: int = 5) -> Any:
    """The matplotlib Figure of `success_figure`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from rodctl.plots import style  # noqa: PLC0415 - matplotlib, only to draw

    d = np.array([r["difficulty"] for r in rows], dtype=float)
    edges = np.linspace(d.min(), d.max() + 1e-9, bins + 1)
    mid = 0.5 * (edges[:-1] + edges[1:])
    span = float(d.max() - d.min()) or 0.1
    fig = Figure(figsize=(6.4, 5.6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for i, m in enumerate(methods):
        rate, steps = [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            rb = [r for r in rows if r["method"] == m and lo <= r["difficulty"] < hi]
            cb = [r["steps_to_converge"] for r in rb if r["outcome"] == "converged"]
            rate.append(100 * len(cb) / len(rb) if rb else np.nan)
            steps.append(np.median(cb) if cb else np.nan)
        x = mid + (i - (len(methods) - 1) / 2) * 0.012 * span
        st = style(i) | {"markersize": 6}
        ax1.plot(x, rate, label=m, **st)
        ax2.plot(x, steps, label=m, **st)
    ax1.set_ylabel("success rate (%)")
    ax1.set_ylim(-5, 105)
    ax2.set_ylabel("median steps to converge")
    ax2.set_xlabel("target difficulty (normalised offset from home)")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    ax1.legend(fontsize=8)
    fig.suptitle("Success and speed against target difficulty")
    FigureCanvasAgg(fig)
    return fig
