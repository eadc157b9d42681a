"""The planner reference (rodctl/planner.py) on the targets of a compare or suite run: how often
does a method converge in fewer steps than the planner found?

    .venv/bin/python benchmarks/bench_planner.py                  # its own compare: 5 targets
    .venv/bin/python benchmarks/bench_planner.py RUN_FOLDER       # every event-free scenario
    .venv/bin/python benchmarks/bench_planner.py RUN_FOLDER --scenario nominal --limit 20
    .venv/bin/python benchmarks/bench_planner.py RUN_FOLDER --out planner.csv

RUN_FOLDER is a `rodctl compare` folder or a suite folder (its results.csv; docs/outputs.md). The
scenario's experiment config (rod, camera, run.pixel_tolerance) is the `base` of the compare run
that made the rows: RUN_FOLDER/results.json for a plain compare, or in a suite the results.json
under RUN_FOLDER/scenarios/ whose config names that scenario and seed; `--config FILE` (a
compare config, with `--set` overrides) replaces it for a plain compare. Scenarios with mid-run
events, dual-arm runs and table friction are skipped with the reason (the planner refuses them).

For each target (its pose from results.csv's target_x/y/theta, the target made again by the
scenario's rod and clean camera, as compare made it), the planner's verified step count
`planner_steps`; then per method, over its converged episodes on the planned targets: how many
beat the planner (steps < planner_steps), tie or lose, and the same with the probing steps taken
off (steps − probe_steps), which is what a method that did not have to probe would need. The
planner is not a proven lower bound (docs/statistics.md, "Planner reference"): a method beating it
means the search missed a pose, and every such case is listed.

Printed: per scenario, pose_steps against planner_steps (how much the tolerance shortens the
target pose's path), the per-method table, the beats, and the planner's CPU time per target.
Exit 2 with one message for a folder without results.csv, a missing column or config.

Without RUN_FOLDER (as `make bench` runs it) it first runs its own compare: the suite's nominal
scenario (configs/benchmarks/suite.yaml's base and methods) on `--targets` targets (default 5),
one worker, logging off, in a temporary folder.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rodctl.config import ExperimentConfig, load_config, validate_config  # noqa: E402
from rodctl.config.compare import CompareConfig  # noqa: E402
from rodctl.config.loading import apply_override, parse_override  # noqa: E402
from rodctl.errors import UserError  # noqa: E402
from rodctl.planner import (  # noqa: E402
    PlannerError,
    check_plannable,
    grid_min_error,
    make_target,
    plan,
)

NEEDED = (
    "scenario", "seed", "method", "target", "target_x", "target_y", "target_theta", "converged",
    "steps", "probe_steps", "pose_steps",
)  # fmt: skip

PLAN_COLUMNS = (
    "scenario", "seed", "target", "pose_steps", "planner_steps", "planner_x", "planner_y",
    "planner_theta", "planner_pixel_error", "best_error", "snaps", "evaluations", "cpu_s",
    "search_below", "grid_below",
)  # fmt: skip


def read_results(folder: Path) -> list[dict[str, str]]:
    """The rows of FOLDER/results.csv (or of FOLDER itself, a csv file)."""
    path = folder if folder.suffix == ".csv" else folder / "results.csv"
    if not path.is_file():
        raise UserError(f"{path}: no results.csv (give a compare or suite run folder)")
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        missing = [c for c in NEEDED if c not in (reader.fieldnames or ())]
        if missing:
            raise UserError(f"{path}: results.csv lacks the column(s) {', '.join(missing)}")
        return list(reader)


def _run_json(folder: Path, scenario: str, seed: str) -> Path | None:
    """The results.json of the compare run that made a scenario's rows at a seed: the folder's
    own (a plain compare), or the one under scenarios/ (a suite: one compare run folder per
    scenario and seed) whose config names that scenario and seed."""
    own = folder / "results.json"
    found = [own] if own.is_file() else []
    found += sorted((folder / "scenarios").glob("*/results.json"))
    for path in found:
        try:
            cfg = json.loads(path.read_text(encoding="utf-8")).get("config") or {}
        except (OSError, ValueError):
            continue
        if cfg.get("scenario", "nominal") == scenario and str(cfg.get("seed", 0)) == str(seed):
            return path
    return None


def scenario_config(
    folder: Path, scenario: str, seed: str, config: str | None, overrides: list[str]
) -> tuple[ExperimentConfig, dict[int, int]]:
    """(the base experiment config of the run that made the rows, target index -> its seed)."""
    if config is not None:
        return load_config(config, overrides, CompareConfig).base, {}
    path = _run_json(folder if folder.is_dir() else folder.parent, scenario, seed)
    if path is None:
        raise UserError(
            f"{folder}: no results.json of scenario {scenario!r} at seed {seed} (in the folder "
            "or under its scenarios/); give --config"
        )
    data = json.loads(path.read_text(encoding="utf-8"))
    try:
        base = data["config"]["base"]
    except (KeyError, TypeError):
        raise UserError(f"{path}: no config.base in results.json") from None
    cfg = ExperimentConfig.model_validate(base)
    if overrides:
        data = cfg.model_dump(mode="json")
        for text in overrides:
            parts, value = parse_override(text)
            apply_override(data, parts, value, text)
        cfg = validate_config(data, f"{path}: config.base with --set")
    seeds = {int(t["index"]): int(t["seed"]) for t in data.get("targets", []) if "seed" in t}
    return cfg, seeds


def _int(v: str) -> int | None:
    return int(float(v)) if v not in ("", None) else None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "run", type=Path, nargs="?", help="a compare or suite run folder (default: run one)"
    )
    ap.add_argument("--targets", type=int, default=5, help="targets of its own compare run")
    ap.add_argument("--scenario", action="append", help="only these scenarios (repeatable)")
    ap.add_argument("--limit", type=int, default=None, help="at most this many targets a scenario")
    ap.add_argument("--config", help="a compare config for a plain compare run (else results.json)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", type=Path, help="write the plans here (csv)")
    ap.add_argument(
        "--grid",
        type=int,
        default=0,
        metavar="N",
        help="also start fits from an N^3 grid over the poses one step short of each plan "
        "(a check of the local search; about N^3 times a plan's cost)",
    )
    args = ap.parse_args(argv)
    try:
        if args.run is None:
            with tempfile.TemporaryDirectory() as tmp:
                args.run = _own_compare(Path(tmp), args.targets)
                return _run(args)
        return _run(args)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _own_compare(tmp: Path, targets: int) -> Path:
    """Run the suite's nominal scenario on `targets` targets into `tmp`; its run folder."""
    suite = yaml.safe_load((REPO / "configs/benchmarks/suite.yaml").read_text(encoding="utf-8"))
    base = suite["base"]
    base["logging"] = {"mcap": False, "rerun": False, "figures": False}
    cfg = {
        "name": "planner-bench",
        "seed": 0,
        "scenario": "nominal",
        "reference": suite.get("reference"),
        "base": base,
        "methods": suite["methods"],
        "targets": {**suite["targets"], "count": targets},
        "workers": 1,
    }
    path = tmp / "compare.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "rodctl", "compare", str(path), "--out", str(tmp / "runs")]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, check=False)
    if done.returncode != 0:
        raise UserError(f"the compare run failed ({done.returncode}): {done.stderr[-2000:]}")
    folder = Path(done.stdout.strip().splitlines()[-1])
    wall = time.perf_counter() - t0
    print(f"compare: {targets} targets of the suite's nominal scenario, {wall:.0f} s")
    return folder


def _run(args: argparse.Namespace) -> int:
    rows = read_results(args.run)
    groups: dict[tuple[str, str], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        if args.scenario is None or r["scenario"] in args.scenario:
            groups[(r["scenario"], r["seed"])].append(r)
    if not groups:
        raise UserError(f"{args.run}: no rows for scenario(s) {args.scenario}")
    plans: list[dict[str, Any]] = []
    wall0 = time.perf_counter()
    for (scenario, seed), group in groups.items():
        cfg, seeds = scenario_config(args.run, scenario, seed, args.config, args.overrides)
        try:
            check_plannable(cfg)
        except PlannerError as exc:
            print(f"\n## {scenario} (seed {seed}): skipped: {exc}")
            continue
        targets: dict[int, tuple[float, float, float]] = {}
        for r in group:
            targets.setdefault(
                int(r["target"]),
                (float(r["target_x"]), float(r["target_y"]), float(r["target_theta"])),
            )
        chosen = sorted(targets)[: args.limit] if args.limit else sorted(targets)
        by_target: dict[int, dict[str, Any]] = {}
        for i in chosen:
            try:
                target = make_target(cfg, targets[i])
            except UserError as exc:
                print(f"  target {i}: cannot be made again ({exc}); skipped")
                continue
            p = plan(cfg, target, seed=seeds.get(i))
            rec = {
                "scenario": scenario, "seed": seed, "target": i, "pose_steps": p.pose_steps,
                "planner_steps": p.steps,
                "planner_x": None if p.pose is None else float(p.pose[0]),
                "planner_y": None if p.pose is None else float(p.pose[1]),
                "planner_theta": None if p.pose is None else float(p.pose[2]),
                "planner_pixel_error": round(p.pixel_error, 4),
                "best_error": round(p.best_error, 4), "snaps": p.snaps,
                "evaluations": p.evaluations, "cpu_s": round(p.cpu_s, 3),
            }  # fmt: skip
            if p.steps is not None:  # what the search found one step short (projected)
                rec["search_below"] = round(dict(p.levels).get(p.steps - 1, math.nan), 4)
            if args.grid and p.steps is not None:
                below, pose = grid_min_error(cfg, target, p.steps - 1, args.grid)
                rec["grid_below"] = round(below, 4)
                if below < cfg.run.pixel_tolerance and not below >= rec["search_below"] - 1e-3:
                    print(
                        f"  target {i}: the grid found {below:.3f} px at {pose} in "
                        f"{p.steps - 1} steps, which the search missed (it found "
                        f"{rec['search_below']} px there)"
                    )
            by_target[i] = rec
            plans.append(rec)
        _report(scenario, seed, group, by_target, float(cfg.run.pixel_tolerance))
    if args.out and plans:
        with args.out.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=PLAN_COLUMNS)
            writer.writeheader()
            for rec in plans:
                writer.writerow({k: "" if rec.get(k) is None else rec[k] for k in PLAN_COLUMNS})
        print(f"\nplans written to {args.out}")
    print(f"\nwall time {time.perf_counter() - wall0:.1f} s")
    return 0


def _report(
    scenario: str,
    seed: str,
    group: list[dict[str, str]],
    by_target: dict[int, dict[str, Any]],
    tol: float,
) -> None:
    print(f"\n## {scenario} (seed {seed}): {len(by_target)} targets planned")
    if not by_target:
        return
    planned = [t for t in by_target.values() if t["planner_steps"] is not None]
    cpu = [t["cpu_s"] for t in by_target.values()]
    print(
        f"planner: {len(planned)} of {len(by_target)} targets have a plan; CPU per target "
        f"median {np.median(cpu):.2f} s, max {max(cpu):.2f} s"
    )
    if planned:
        short = [t["pose_steps"] - t["planner_steps"] for t in planned]
        print(
            f"pose_steps - planner_steps: mean {np.mean(short):.2f}, max {max(short)}, "
            f"min {min(short)}; planner below pose_steps on {sum(s > 0 for s in short)} of "
            f"{len(planned)}"
        )
        grid = [t for t in planned if t.get("grid_below") is not None]
        if grid:
            missed = [t for t in grid if t["grid_below"] < t["search_below"] - 1e-3]
            print(
                f"grid check (fits from an N^3 grid one step short of each plan, projected "
                f"error): smallest {min(t['grid_below'] for t in grid):.3f} px over {len(grid)} "
                f"targets; below the search's own there on {len(missed)}"
            )
        near = [t for t in planned if t.get("search_below", math.inf) < tol]
        if near:
            print(
                f"{len(near)} plan(s) one step longer than a pose the search found within the "
                "tolerance by the projected error, whose straight path the render and "
                "extraction did not accept"
            )
    print(
        "| method | converged on planned | beats (steps) | ties | mean steps - planner | "
        "beats (steps - probing) | ties | mean (steps - probing) - planner |"
    )
    print("|---|---|---|---|---|---|---|---|")
    beaten: list[str] = []
    for method in dict.fromkeys(r["method"] for r in group):
        d_all, d_np = [], []
        for r in group:
            t = by_target.get(int(r["target"]))
            if r["method"] != method or t is None or t["planner_steps"] is None:
                continue
            if r["converged"] not in ("True", "true", "1"):
                continue
            steps, probe = _int(r["steps"]), _int(r["probe_steps"]) or 0
            if steps is None:
                continue
            d_all.append(steps - t["planner_steps"])
            d_np.append(steps - probe - t["planner_steps"])
            if steps - probe < t["planner_steps"]:
                beaten.append(
                    f"  {method} target {t['target']}: {steps} steps ({probe} probing) against "
                    f"planner {t['planner_steps']} (pose_steps {t['pose_steps']})"
                )
        print(
            f"| {method} | {len(d_all)} | {sum(d < 0 for d in d_all)} | "
            f"{sum(d == 0 for d in d_all)} | {_mean(d_all)} | {sum(d < 0 for d in d_np)} | "
            f"{sum(d == 0 for d in d_np)} | {_mean(d_np)} |"
        )
    if beaten:
        print("beaten (steps - probing < planner_steps):")
        print("\n".join(beaten))
    else:
        print("no converged episode beat the planner, probing steps taken off or not")


def _mean(values: list[int]) -> str:
    return f"{np.mean(values):+.2f}" if values else "-"


if __name__ == "__main__":
    sys.exit(main())
