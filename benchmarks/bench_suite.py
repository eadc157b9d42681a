"""Where the benchmark suite's time goes, per scenario and per episode, and a projection of the
full one-seed suite on 2 cores against issue 24's goal (<= 5 minutes).

Runs the suite config (default configs/benchmarks/suite.yaml) on one target seed with a few
targets per scenario (`--targets`, default 5; a scenario's own `targets` block gets the same
count), in this process (`--workers 1`), and charges the CPU time (`time.process_time`) of every
call to one category, the innermost one that is timed (a call inside a timed call is charged to
its own category and taken off its caller's):

- engine: the rod simulator (`RodSim` / `QuasiStaticSim`: moves, settles, events, snapshots,
  the home state, the analytic centerline Jacobian);
- vision: rendering and centerline extraction (`ShapeServoEnv._see`);
- method: the method's start and every `act` (feature, estimator, controller);
- true J: the true Jacobian each step's Jacobian error is scored against, less its physics;
- records: the episode's step records, sinks and summary (`rodctl.episode._Loop`);
- build: what each episode builds before its first step (its config validated, the env, the
  method: feature map and checkpoint), less the physics and vision inside;
- diagnosis: why a stalled episode stalled (`rodctl.diagnosis`), physics included;
- rest: the episode's remainder (env.reset/step bookkeeping, the loop, the row).

and, per scenario (paid once, not per episode): `preflight` (every method built once, and a
`checkpoint: auto` encoder trained if not cached), `targets` (the shared targets driven and
seen, physics included), `report` (results, figures, statistics, report.html), `other` (the run
folder, the journal, the rest of `run_compare`). The suite's own aggregation is one more line.

The projection on 2 cores: per scenario, its per-episode CPU x (methods x the scenario's full
target count) and its per-target cost x the full target count run on the 2 workers (halved);
the parent's own work (preflight, report, the rest) is serial. A fresh spawn worker's warm-up
(`--probe`: a new interpreter's imports, then one target's episodes of every method run twice,
the first pass's excess counted) is paid by the 2 workers once for the suite (`--pool shared`,
rodctl's suite since 2026-12-02) or once per scenario (`--pool per-scenario`, before).

    nice -n 10 .venv/bin/python benchmarks/bench_suite.py --targets 5
    nice -n 10 .venv/bin/python benchmarks/bench_suite.py --scenarios nominal,table --profile 25

Prints the machine load (`os.getloadavg`) before and after: figures are CPU time, which the
load changes little, but a loaded machine's caches make everything somewhat slower.
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import io
import json
import os
import pickle
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

import rodctl.bench.compare as compare
import rodctl.bench.episodes as episodes
import rodctl.bench.runner as runner
import rodctl.bench.suite as suite
import rodctl.bench.target_set as target_set
import rodctl.diagnosis as diagnosis
import rodctl.episode as episode
import rodctl.sim.quasistatic as qs
from rodctl.env import ShapeServoEnv
from rodctl.executors.base import THREAD_ENV
from rodctl.method import Method
from rodctl.sim.rod import RodSim

ROOT = Path(__file__).resolve().parents[1]
GOAL_S = 300.0  # issue 24: the full suite, quasistatic, table included, <= 5 minutes on 2 cores
CORES = 2

EPISODE_CATEGORIES = (
    "engine",
    "vision",
    "method",
    "true J",
    "records",
    "build",
    "diagnosis",
    "rest",
)
SCENARIO_CATEGORIES = ("preflight", "targets", "report", "other")


def cpu_now() -> float:
    """CPU seconds of this process and of its children that have ended (a quick encoder's
    collection pool, the spawn-worker probe)."""
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


class Ledger:
    """CPU time per (scenario, category), charged to the innermost timed call."""

    def __init__(self) -> None:
        self.cpu: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
        self.episodes: dict[str, int] = defaultdict(int)
        self.targets: dict[str, int] = defaultdict(int)
        self.first_tasks: dict[str, list[Any]] = defaultdict(list)
        self.scenario = "(suite)"
        # frames: [charged name, absorbing, time of timed children, absorbing category]
        self.stack: list[list[Any]] = []

    def timed(self, fn: Callable, category: str, *, absorb: bool = False) -> Callable:
        """`fn` with its CPU time charged to `category` (`absorb`: and its callees' too)."""

        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            stack = self.stack
            # Inside an absorbing call the call is charged there, split by category as
            # "<absorbing>:<category>" (what a diagnosis spends on physics, on vision...).
            outer = next((f for f in reversed(stack) if f[1]), None)
            name = category if outer is None else f"{outer[3]}:{category}"
            frame = [name, absorb and outer is None, 0.0, category if outer is None else outer[3]]
            stack.append(frame)
            t0 = cpu_now()
            try:
                return fn(*args, **kwargs)
            finally:
                dt = cpu_now() - t0
                stack.pop()
                self.cpu[self.scenario][name] += dt - frame[2]
                if stack:
                    stack[-1][2] += dt

        wrapper.__wrapped_by_bench__ = True  # type: ignore[attr-defined]
        return wrapper

    def patch(self, owner: Any, name: str, category: str, *, absorb: bool = False) -> None:
        """Replace `owner.name` (a class attribute or a module function) by its timed version;
        class methods, static methods and properties are left alone unless plain functions."""
        raw = owner.__dict__.get(name) if isinstance(owner, type) else getattr(owner, name)
        if raw is None:
            return
        if isinstance(raw, classmethod):
            setattr(owner, name, classmethod(self.timed(raw.__func__, category, absorb=absorb)))
        elif callable(raw):
            setattr(owner, name, self.timed(raw, category, absorb=absorb))


ENGINE_METHODS = (
    "apply",
    "move_to",
    "move_clamp",
    "slip_grasp",
    "set_bending_stiffness",
    "set_mass_per_length",
    "set_table_friction",
    "snapshot",
    "restore",
    "at_home",
    "clip_pose",
    "centerline",
    "health",
    "centerline_jacobian",
    "take_snap_notes",
)


def install(ledger: Ledger) -> None:
    """Time the entry points of every category (see the module doc)."""

    for cls in (RodSim, qs.QuasiStaticSim):
        for name in ENGINE_METHODS:
            ledger.patch(cls, name, "engine")
    ledger.patch(ShapeServoEnv, "_see", "vision")
    for name in ("act", "start"):
        ledger.patch(Method, name, "method")
    for name in ("true_jacobian", "jacobian_error_reference"):
        ledger.patch(ShapeServoEnv, name, "true J")
    for name in ("open", "record", "emit", "close", "finish"):
        ledger.patch(episode._Loop, name, "records")  # noqa: SLF001
    ledger.patch(ShapeServoEnv, "__init__", "build")
    ledger.patch(Method, "from_config", "build")
    # The episode's config, validated from its task (the worker's one model_validate).
    validate = ledger.timed(episodes.ExperimentConfig.model_validate, "build")
    episodes.ExperimentConfig = type("TimedConfig", (), {"model_validate": staticmethod(validate)})
    diagnosis_fn = ledger.timed(diagnosis.diagnose, "diagnosis", absorb=True)
    diagnosis.diagnose = diagnosis_fn  # `_diagnose` imports it at call time

    # Episodes: counted per scenario; their untimed remainder is "rest".
    run_task = ledger.timed(episodes.run_episode_task, "rest")

    def counted(task: Any) -> Any:
        ledger.episodes[ledger.scenario] += 1
        if task.target == 0:  # the first target's episodes: the spawn-worker probe's tasks
            ledger.first_tasks[ledger.scenario].append(task)
        return run_task(task)

    runner.run_episode_task = counted  # what stream_episodes submits

    # Per scenario.
    compare.preflight = ledger.timed(compare.preflight, "preflight", absorb=True)
    make_targets = ledger.timed(target_set.make_targets, "targets", absorb=True)

    def counting_targets(cfg: Any, *args: Any, **kwargs: Any) -> Any:
        out = make_targets(cfg, *args, **kwargs)
        ledger.targets[ledger.scenario] += len(out)
        return out

    compare.make_targets = counting_targets
    compare.CompareStudy.report = ledger.timed(compare.CompareStudy.report, "report", absorb=True)
    run_compare = ledger.timed(compare.run_compare, "other")

    def per_scenario(config_path: str, *args: Any, **kwargs: Any) -> Any:
        ledger.scenario = Path(config_path).stem
        try:
            return run_compare(config_path, *args, **kwargs)
        finally:
            ledger.scenario = "(suite)"

    suite.run_compare = per_scenario
    suite.write_suite_outputs = ledger.timed(suite.write_suite_outputs, "report", absorb=True)
    # Quick encoders (`checkpoint: auto`) not cached yet, trained before the scenarios run.
    suite._prepare_features = ledger.timed(suite._prepare_features, "training", absorb=True)  # noqa: SLF001


def overrides_for(data: dict, targets: int, seed: int) -> tuple[list[str], dict[str, int]]:
    """The `--set` overrides of a suite config (`data`) for one seed and `targets` targets per
    scenario; and each scenario's full target count (its own `targets.count`, else the
    suite's)."""
    default = int((data.get("targets") or {}).get("count", 100))
    sets = [f"seeds=[{seed}]", f"targets.count={targets}", "workers=1"]
    full = {}
    for name, sc in (data.get("scenarios") or {}).items():
        own = (sc or {}).get("targets")
        full[name] = int(own.get("count", 100)) if own else default
        if own:
            sets.append(f"scenarios.{name}.targets.count={targets}")
    return sets, full


PROBE = """
import json, pickle, sys, time
t0 = time.process_time()
import rodctl.bench.episodes as episodes, rodctl.executors.base as base
base.init_worker()
t1 = time.process_time()
tasks = pickle.loads(sys.stdin.buffer.read())
for t in tasks:
    episodes.run_episode_task(t)
t2 = time.process_time()
for t in tasks:
    episodes.run_episode_task(t)
t3 = time.process_time()
print(json.dumps({"imports": t1 - t0, "first": t2 - t1, "again": t3 - t2}))
"""


def pool_worker_cpu(tasks: list[Any]) -> dict[str, float]:
    """What a fresh spawn pool worker pays before it runs at full speed: a new interpreter
    imports what `run_episode_task` needs and runs the pool's initialiser, then runs `tasks`
    (one target's episodes, every method) twice; the warm-up is the imports plus the first
    pass's excess over the second (lazy imports, the home state, checkpoints...)."""
    out = subprocess.run(
        [sys.executable, "-c", PROBE],
        input=pickle.dumps(tasks),
        capture_output=True,
        check=True,
        cwd=ROOT,
        env={**os.environ, **{k: "1" for k in THREAD_ENV}},
    )
    got = json.loads(out.stdout.decode().strip().splitlines()[-1])
    got["warm_up"] = got["imports"] + max(0.0, got["first"] - got["again"])
    return got


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(ROOT / "configs/benchmarks/suite.yaml"))
    ap.add_argument("--targets", type=int, default=5, help="targets per scenario (default 5)")
    ap.add_argument("--seed", type=int, default=0, help="the one target seed (default 0)")
    ap.add_argument("--scenarios", default="", help="comma-separated subset (default: all)")
    ap.add_argument("--out", default="", help="where the suite folder goes (default: a temp dir)")
    ap.add_argument("--profile", type=int, default=0, help="print the top N functions (cProfile)")
    ap.add_argument(
        "--probe",
        default="nominal",
        help="the scenario whose first target's episodes the spawn-worker probe runs ('' to skip)",
    )
    ap.add_argument(
        "--pool",
        choices=("shared", "per-scenario"),
        default="shared",
        help="project a pool started once for the suite (rodctl since 2026-12-02) or a new "
        "pool per scenario (before): each pool's 2 workers pay the warm-up",
    )
    ap.add_argument("--json", default="", help="also write the figures to this JSON file")
    args = ap.parse_args(argv)

    config = Path(args.config)
    data = yaml.safe_load(config.read_text(encoding="utf-8"))
    config_used = config
    if args.scenarios:
        keep = [s for s in args.scenarios.split(",") if s]
        unknown = sorted(set(keep) - set(data["scenarios"]))
        if unknown:
            print(f"bench_suite: unknown scenarios {unknown}", file=sys.stderr)
            return 2
        # The subset, written next to the original (its relative paths resolve from there).
        data["scenarios"] = {k: v for k, v in data["scenarios"].items() if k in keep}
        config_used = config.with_name(f".bench-suite-{os.getpid()}.yaml")
        config_used.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    sets, full = overrides_for(data, args.targets, args.seed)
    load0 = os.getloadavg()
    print(f"load average before: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}", flush=True)

    ledger = Ledger()
    install(ledger)
    out = args.out or tempfile.mkdtemp(prefix="bench-suite-")
    profiler = cProfile.Profile() if args.profile else None
    cpu0, wall0 = time.process_time(), time.perf_counter()
    try:
        if profiler:
            profiler.enable()
        timed_suite = ledger.timed(suite.run_suite, "other")  # the suite's own share: "(suite)"
        folder = timed_suite(str(config_used), sets, out, progress=False, workers=1)
    finally:
        if profiler:
            profiler.disable()
        if config_used is not config:
            config_used.unlink(missing_ok=True)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    load1 = os.getloadavg()
    probe = {"warm_up": 0.0}
    if args.probe and ledger.first_tasks.get(args.probe):
        probe = pool_worker_cpu(ledger.first_tasks[args.probe])

    report = summarise(ledger, full, args.targets, probe["warm_up"], args.pool == "shared")
    report["probe"] = probe
    report.update(
        cpu_s=cpu,
        wall_s=wall,
        load_before=load0,
        load_after=load1,
        folder=str(folder),
        targets_per_scenario=args.targets,
        seed=args.seed,
    )
    print_report(report)
    print(f"load average after: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    print(f"suite folder: {folder}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1), encoding="utf-8")
    if profiler:
        s = io.StringIO()
        pstats.Stats(profiler, stream=s).sort_stats("cumulative").print_stats(args.profile)
        print(s.getvalue())
        s = io.StringIO()
        pstats.Stats(profiler, stream=s).sort_stats("tottime").print_stats(args.profile)
        print(s.getvalue())
    return 0


def _total(cpu: dict[str, float], category: str) -> float:
    """A category's CPU, its absorbed parts ("<category>:<inner>") included."""
    return cpu.get(category, 0.0) + sum(v for k, v in cpu.items() if k.startswith(category + ":"))


def summarise(
    ledger: Ledger, full: dict[str, int], targets: int, worker: float, shared: bool
) -> dict:
    """Per scenario: CPU s per episode by category, the per-scenario costs, the projection.

    The projection on 2 cores: the episodes and the targets run on the 2 workers (their CPU
    halved); the parent's own work (preflight, report, the rest of `run_compare`) and each
    scenario's pool start-up (the 2 workers import at once) are serial, the workers idle.
    `worker`: a fresh worker's warm-up, paid once per suite (`shared`) or once per scenario.
    """
    rows = {}
    cpu_total = wall_total = 0.0
    inner: dict[str, float] = defaultdict(float)
    for name, n_full in full.items():
        cpu = ledger.cpu.get(name, {})
        n = ledger.episodes.get(name, 0)
        n_targets = ledger.targets.get(name, 0) or targets
        methods = n // n_targets if n_targets else 0
        per_episode = {c: _total(cpu, c) / n if n else 0.0 for c in EPISODE_CATEGORIES}
        fixed = {c: _total(cpu, c) for c in SCENARIO_CATEGORIES}
        per_target = fixed["targets"] / n_targets if n_targets else 0.0
        episodes_full = methods * n_full
        parallel = sum(per_episode.values()) * episodes_full + per_target * n_full
        serial = fixed["preflight"] + fixed["report"] + fixed["other"]
        warm = 0.0 if shared else worker
        cpu_total += parallel + serial + CORES * warm
        wall_total += parallel / CORES + serial + warm
        for k, v in cpu.items():
            if k.startswith("diagnosis:") and n:
                inner[k] += v / n * episodes_full
        rows[name] = {
            "episodes": n,
            "targets": n_targets,
            "full_episodes": episodes_full,
            "per_episode": per_episode,
            "per_target": per_target,
            "fixed": fixed,
            "projected_cpu_s": parallel + serial + CORES * warm,
            "projected_wall_s": parallel / CORES + serial + warm,
        }
    suite_parts = {
        c: _total(ledger.cpu.get("(suite)", {}), c) for c in ("training", "report", "other")
    }
    suite_cpu = sum(suite_parts.values())
    cpu_total += suite_cpu + (CORES * worker if shared else 0.0)
    wall_total += suite_cpu + (worker if shared else 0.0)
    return {
        "scenarios": rows,
        "diagnosis_parts_cpu_s": dict(inner),
        "suite_cpu_s": suite_parts,
        "pool_worker_warm_up_cpu_s": worker,
        "pool": "shared" if shared else "per-scenario",
        "projected_cpu_s": cpu_total,
        "projected_wall_2_cores_s": wall_total,
        "goal_s": GOAL_S,
    }


def print_report(r: dict) -> None:
    cols = [*EPISODE_CATEGORIES]
    head = f"{'scenario':18s} {'ep':>4s} {'ms/ep':>7s} " + " ".join(f"{c[:7]:>7s}" for c in cols)
    head += f" {'tgt ms':>7s} {'prefl s':>7s} {'rep s':>6s} {'oth s':>6s} {'wall s':>7s}"
    print(
        "\nCPU ms per episode by category; per-scenario costs (CPU s); the full scenario's "
        "projected wall s on 2 cores (one seed)"
    )
    print(head)
    tot_cat: dict[str, float] = defaultdict(float)
    tot_ep = 0
    for name, row in r["scenarios"].items():
        pe = row["per_episode"]
        fx = row["fixed"]
        for c in cols:
            tot_cat[c] += pe[c] * row["full_episodes"]
        tot_ep += row["full_episodes"]
        print(
            f"{name:18s} {row['episodes']:4d} {1e3 * sum(pe.values()):7.1f} "
            + " ".join(f"{1e3 * pe[c]:7.1f}" for c in cols)
            + f" {1e3 * row['per_target']:7.1f} {fx['preflight']:7.2f} {fx['report']:6.2f}"
            f" {fx['other']:6.2f} {row['projected_wall_s']:7.1f}"
        )
    if tot_ep:
        print(
            f"{'(mean, weighted)':18s} {'':4s} {1e3 * sum(tot_cat.values()) / tot_ep:7.1f} "
            + " ".join(f"{1e3 * tot_cat[c] / tot_ep:7.1f}" for c in cols)
        )
        print(
            f"full suite, one seed ({tot_ep} episodes), episodes' CPU s: "
            + ", ".join(f"{c} {tot_cat[c]:.0f}" for c in cols)
        )
    parts = r["diagnosis_parts_cpu_s"]
    if parts:
        print(
            "  of which the diagnosis: "
            + ", ".join(f"{k.split(':', 1)[1]} {v:.0f}" for k, v in sorted(parts.items()))
        )
    fixed = defaultdict(float)
    for row in r["scenarios"].values():
        for k, v in row["fixed"].items():
            fixed[k] += v
    print(
        "per-scenario costs summed (CPU s): "
        + ", ".join(f"{k} {v:.1f}" for k, v in fixed.items())
        + "; the suite's own: "
        + ", ".join(f"{k} {v:.1f}" for k, v in r["suite_cpu_s"].items())
        + "; a fresh spawn worker's "
        f"warm-up {r['pool_worker_warm_up_cpu_s']:.2f} (imports "
        f"{r['probe'].get('imports', 0.0):.2f}), x {CORES} workers "
        + ("once (one pool for the suite)" if r["pool"] == "shared" else "per scenario")
    )
    print(f"this run: {r['cpu_s']:.1f} s CPU, {r['wall_s']:.1f} s wall")
    proj = r["projected_wall_2_cores_s"]
    verdict = "met" if proj <= r["goal_s"] else "NOT met"
    print(
        f"projection, the full suite on one seed: {r['projected_cpu_s']:.0f} s CPU; "
        f"{proj:.0f} s = {proj / 60:.1f} min on {CORES} free cores (the parent's work serial); "
        f"goal <= {r['goal_s'] / 60:.0f} min: {verdict}"
    )


if __name__ == "__main__":
    sys.exit(main())
