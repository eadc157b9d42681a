"""The quasi-static engine against pymunk, side by side in one run (issue 24).

Goals: one control step's physics >= 50x faster at N = 50 (N = 25 and 100 shown too); one
default-config episode with logging off >= 8x faster (CPU time: the first episode of a fresh
env, and later ones on the same env; as configured, and with the same work on both engines,
the Jacobian error that only the quasi-static engine scores for free turned off); `rodctl
simulate configs/default.yaml --set rod.engine=quasistatic` <= 1.0 s for the whole process.

`--free-clip` is a what-if, not a goal figure: both engines' episodes run with the AKF's
eigenvalue clip of Q memoised (each distinct input clipped once, by the same code, so the
episodes are the same bits), which prints the episode ratios the goal would see if that clip
cost nothing.

    python benchmarks/bench_engine.py [--moves 30] [--repeats 9] [--step-only | --episode-only]
        [--free-clip]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rodctl.config import load_config  # noqa: E402
from rodctl.config.rod import RodConfig  # noqa: E402
from rodctl.sim import RodSim  # noqa: E402


def physics(n: int, moves: int, repeats: int = 1) -> tuple[float, float, float, float, float]:
    """ms per `apply` for pymunk and quasistatic on the same random moves (wall, then CPU time
    of this process: on a loaded machine the wall time also counts waiting for a core), and
    the largest centerline difference in % of L. The quasi-static engine's moves take ~3 ms
    in all, a few scheduler ticks: with `repeats` > 1 they are replayed on that many fresh
    rods and each figure is the median (the same shapes every time)."""
    rng = np.random.default_rng(0)
    cfg = RodConfig(segments=n)
    us = rng.uniform(-1, 1, (moves, 3)) * np.asarray(cfg.max_step)
    out, cpu, lines = [], [], []
    for engine in ("pymunk", "quasistatic"):
        walls, cpus = [], []
        for _ in range(1 if engine == "pymunk" else max(1, repeats)):
            sim = RodSim(cfg.model_copy(update={"engine": engine}))
            t0, c0 = time.perf_counter(), time.process_time()
            got = []
            for u in us:
                sim.apply(u)
                got.append(sim.centerline())
            walls.append(1e3 * (time.perf_counter() - t0) / moves)
            cpus.append(1e3 * (time.process_time() - c0) / moves)
        out.append(float(np.median(walls)))
        cpu.append(float(np.median(cpus)))
        lines.append(np.array(got))
    d = lines[0] - lines[1]
    err = float(np.max(np.hypot(d[..., 0], d[..., 1])))
    return out[0], out[1], cpu[0], cpu[1], 100 * err / cfg.length


def episode(
    engine: str, repeats: int = 5, sets: tuple[str, ...] = ()
) -> tuple[float, float, float]:
    """CPU seconds of one default-config episode with logging off (the figure of the goal):
    (the first episode of a fresh env and method, which also computes the rod's home state;
    the wall time of that one; the mean of `repeats` more on the same env, as a study runs
    them). The process-wide one-time costs (imports, the numeric-environment probe of the run
    header) are paid before either engine is timed (`warm_process`)."""
    from rodctl.env import ShapeServoEnv
    from rodctl.episode import run_episode
    from rodctl.method import Method

    cfg = load_config(
        "configs/default.yaml",
        [
            "logging.mcap=false",
            "logging.rerun=false",
            "logging.figures=false",
            f"rod.engine={engine}",
            *sets,
        ],
    )
    env, method = ShapeServoEnv(cfg), Method.from_config(cfg)
    t0, c0 = time.perf_counter(), time.process_time()
    summary = run_episode(env, method, sinks=[], run_id="bench").summary
    first_cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    c0 = time.process_time()
    for _ in range(repeats):
        run_episode(env, method, sinks=[], run_id="bench")
    steady = (time.process_time() - c0) / max(repeats, 1)
    print(
        f"  {engine:<12} first episode {1e3 * first_cpu:7.1f} ms CPU ({1e3 * wall:7.1f} ms wall),"
        f" then {1e3 * steady:7.1f} ms CPU each  ({summary.steps} steps, {summary.outcome})"
    )
    return first_cpu, wall, steady


def warm_process() -> None:
    """What any first episode of a process pays whatever the engine: the imports of both
    engines and the numeric-environment probe (`rodctl.numenv`, ~50 ms, cached)."""
    from rodctl.numenv import numeric_environment

    for engine in ("pymunk", "quasistatic"):
        RodSim(RodConfig(segments=10).model_copy(update={"engine": engine}))
    numeric_environment()


def process() -> tuple[float, float]:
    """(wall s, CPU s of the process and its children); benchmarks/bench_startup.py breaks it
    down."""
    with tempfile.TemporaryDirectory() as tmp:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "rodctl",
                "simulate",
                "configs/default.yaml",
                "--set",
                "rod.engine=quasistatic",
                "--out",
                tmp,
            ],
            check=True,
            capture_output=True,
        )
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
        return wall, cpu


def episodes() -> None:
    print("one default-config episode, logging off (CPU time of this process):")
    warm_process()
    a, b = episode("pymunk"), episode("quasistatic")
    print(
        f"  speed-up: first episode {a[0] / b[0]:.1f}x CPU ({a[1] / b[1]:.1f}x wall),"
        f" later episodes {a[2] / b[2]:.1f}x CPU   (goal >= 8x)"
    )
    # As configured (run.jacobian_error: auto) only the quasi-static episode scores each step's
    # Jacobian estimate (exact J, no settles); pymunk would need six settles a step for it.
    # The same work on both: the score off.
    print("  the same work on both engines (run.jacobian_error=never: no Jacobian error scored):")
    off = ("run.jacobian_error=never",)
    a, b = episode("pymunk", sets=off), episode("quasistatic", sets=off)
    print(
        f"  speed-up: first episode {a[0] / b[0]:.1f}x CPU ({a[1] / b[1]:.1f}x wall),"
        f" later episodes {a[2] / b[2]:.1f}x CPU   (goal >= 8x)"
    )


def free_q_clip() -> None:
    """Memoise the AKF's Q clip (`clip_psd(..., test_first=False)`): the same results, each
    distinct input computed once, so from the second episode on the clip costs a lookup."""
    from rodctl.estimation import akf

    clip = akf.clip_psd
    memo: dict[tuple[bytes, float], np.ndarray] = {}

    def memoised(a: np.ndarray, floor: float, test_first: bool = True) -> np.ndarray:
        if test_first:
            return clip(a, floor, test_first)
        key = (a.tobytes(), floor)
        if key not in memo:
            memo[key] = clip(a, floor, test_first)
        return memo[key].copy()

    akf.clip_psd = memoised


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", type=int, default=30)
    ap.add_argument(
        "--repeats", type=int, default=9, help="quasi-static replays of the moves (median)"
    )
    ap.add_argument("--step-only", action="store_true", help="only the control-step figures")
    ap.add_argument("--episode-only", action="store_true", help="only the episode figure")
    ap.add_argument(
        "--free-clip",
        action="store_true",
        help="what-if: the AKF's Q clip memoised on both engines (the episode figures only)",
    )
    args = ap.parse_args()
    if args.free_clip:
        free_q_clip()
        episodes()
        return
    if args.episode_only:
        episodes()
        return
    print("one control step's physics (RodSim.apply, same random moves):")
    for n in (25, 50, 100):
        p, q, pc, qc, err = physics(n, args.moves, args.repeats)
        goal = "   (goal >= 50x)" if n == 50 else ""
        print(
            f"  N = {n:3d}: wall pymunk {p:7.2f} ms, quasistatic {q:6.3f} ms: {p / q:6.1f}x;"
            f"  CPU {pc:7.2f} / {qc:6.3f} ms: {pc / qc:6.1f}x{goal}"
            f"   shapes within {err:.4f} % of L"
        )
    if args.step_only:
        return
    episodes()
    t, cpu = process()
    print(
        f"rodctl simulate configs/default.yaml --set rod.engine=quasistatic: {t:.2f} s wall,"
        f" {cpu:.2f} s CPU   (goal <= 1.0 s)"
    )


if __name__ == "__main__":
    main()
