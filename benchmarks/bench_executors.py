"""Episodes/s of the executors on the same episodes: the local pool with 1 and 2 workers, and
Ray with 2 CPUs (a local Ray started for the run), printed next to the goals.

    .venv/bin/python benchmarks/bench_executors.py                   # smoke methods, 4 targets
    .venv/bin/python benchmarks/bench_executors.py --targets 8 --skip-ray

Goals (issue #16): Ray's wall time within 1.2x of the local pool's on 2 cores; the local pool's
2-worker speed-up over 1 worker >= 1.7x. Each executor runs the same task list (the episodes of
configs/compare-smoke.yaml on `--targets` sampled targets, targets settled once beforehand) and
the results are checked identical (timing columns aside). Two walls are reported: *total*
(start-up included: spawning workers and importing torch, or starting Ray) and *episodes*
(from the first episode submitted, after every worker has started and imported rodctl). The
machine's load is printed too: on a shared machine the figures are only comparable within one
run of this script.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rodctl.bench import compare  # noqa: E402
from rodctl.bench.episodes import run_episode_task  # noqa: E402
from rodctl.bench.runner import run_tasks  # noqa: E402
from rodctl.bench.target_set import make_targets  # noqa: E402
from rodctl.bench.tasks import EpisodeTask  # noqa: E402
from rodctl.executors import make_executor  # noqa: E402


def episode_tasks(targets: int) -> list[EpisodeTask]:
    """The smoke benchmark's episodes on `targets` targets (no logs, no records)."""
    cfg = compare.load_compare_config(
        REPO / "configs" / "compare-smoke.yaml", [f"targets.count={targets}"]
    )
    configs = compare.preflight(cfg)
    with make_executor("local", 1) as ex:
        tgts = make_targets(cfg, None, lambda ts, fn: run_tasks(ex, ts, fn, "targets", False))
    return compare.episode_tasks(cfg, configs, tgts, fig_target=-1, folder=Path("."))


def warm(_task: int) -> int:
    """Start-up of a worker: what every episode process imports before its first step."""
    import rodctl.env
    import rodctl.episode
    import rodctl.method  # noqa: F401

    time.sleep(0.5)  # keep this worker busy so the next warm-up task goes to another
    return os.getpid()


def busy(_task: int) -> int:
    """1 s of pure CPU: what a core gives when nothing else competes for it."""
    t = time.process_time()
    while time.process_time() - t < 1.0:
        pass
    return os.getpid()


def cores_available() -> float:
    """The local pool's 2-worker speed-up on pure CPU work (6 x 1 s): ~2 on an idle 2-core
    machine, ~1 when other jobs hold a core. It bounds what the episode speed-up can show."""
    walls = []
    for w in (1, 2):
        with make_executor("local", w) as ex:
            ex.map(warm, list(range(w)))
            t = time.perf_counter()
            ex.map(busy, list(range(6)))
            walls.append(time.perf_counter() - t)
    return walls[0] / walls[1]


def run(kind: str, workers: int, tasks: list[dict]) -> dict:
    """Wall times of one executor on the tasks, and its rows (timing removed)."""
    t0 = time.perf_counter()
    with make_executor(kind, workers) as ex:
        ex.map(warm, list(range(workers)))  # workers started and imported: not episode time
        t1 = time.perf_counter()
        done = ex.map(run_episode_task, tasks)
        t2 = time.perf_counter()
    t3 = time.perf_counter()
    errors = [d.error for d in done if d.error]
    if errors:
        raise SystemExit(f"{kind} x{workers}: {errors[:3]}")
    rows = [{k: v for k, v in d.value.items() if k != "wall_time_s"} for d in done]
    return {"total": t3 - t0, "episodes": t2 - t1, "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=4, help="targets (x 6 methods = episodes)")
    ap.add_argument("--skip-ray", action="store_true", help="local pool only")
    args = ap.parse_args()
    tasks = episode_tasks(args.targets)
    n = len(tasks)
    print(
        f"{n} episodes (compare-smoke methods x {args.targets} targets); "
        f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )
    calib = cores_available()
    print(f"pure-CPU 2-worker speed-up right now: {calib:.2f}x (cores this job really gets)")
    modes = [("local", 1), ("local", 2)] + ([] if args.skip_ray else [("ray", 2)])
    res = {}
    for kind, w in modes:
        res[(kind, w)] = r = run(kind, w, tasks)
        print(
            f"  {kind:<5} x{w}: total {r['total']:6.1f} s ({n / r['total']:5.2f} episodes/s), "
            f"episodes {r['episodes']:6.1f} s ({n / r['episodes']:5.2f} episodes/s)"
        )
    base = res[("local", 1)]["rows"]
    same = all(r["rows"] == base for r in res.values())
    print(f"results identical across executors (timing aside): {same}")
    l1, l2 = res[("local", 1)], res[("local", 2)]
    speedup = l1["episodes"] / l2["episodes"]
    speedup_total = l1["total"] / l2["total"]
    print(
        f"local 2-worker speed-up: {speedup:.2f}x on episodes, {speedup_total:.2f}x total "
        f"(goal >= 1.7x): {'MET' if speedup >= 1.7 else 'NOT MET'}"
    )
    if ("ray", 2) in res:
        ray = res[("ray", 2)]
        ratio, ratio_total = ray["episodes"] / l2["episodes"], ray["total"] / l2["total"]
        print(
            f"Ray / local pool wall, 2 CPUs: {ratio:.2f}x on episodes, {ratio_total:.2f}x total "
            f"(goal <= 1.2x): {'MET' if ratio <= 1.2 else 'NOT MET'} on episodes, "
            f"{'MET' if ratio_total <= 1.2 else 'NOT MET'} total"
        )
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    if not same:
        raise SystemExit("results differ between executors")


if __name__ == "__main__":
    main()
