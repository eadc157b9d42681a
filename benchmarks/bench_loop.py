"""Closed-loop throughput of the full pipeline: simulate, render, extract, encode, estimate,
control and log, per step, on one core.

Goal (issue #6): >= 50 control steps/s including render, extraction, encoding and logging.
The run is kept going for a fixed number of steps (a tolerance nobody reaches, no stall exit)
so the figure is a steady-state rate, not one dominated by setup.

    python benchmarks/bench_loop.py [--config configs/default.yaml] [--steps 200]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the goal states

import torch  # noqa: E402

from rodctl.config import load_config  # noqa: E402
from rodctl.env import ShapeServoEnv  # noqa: E402
from rodctl.episode import run_episode  # noqa: E402
from rodctl.method import Method  # noqa: E402
from rodctl.simulate import make_sinks  # noqa: E402


def run(config: str, steps: int, logging: bool) -> None:
    overrides = [
        f"run.max_steps={steps}",
        "run.pixel_tolerance=1e-9",
        f"run.stall_window={steps}",
        "logging.figures=false",
        f"logging.mcap={str(logging).lower()}",
        f"logging.rerun={str(logging).lower()}",
    ]
    cfg = load_config(config, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        env, method = ShapeServoEnv(cfg), Method.from_config(cfg)
        sinks = make_sinks(cfg, __import__("pathlib").Path(tmp)) if logging else []
        t0 = time.perf_counter()
        summary = run_episode(env, method, sinks=sinks, run_id="bench").summary
        wall = time.perf_counter() - t0
    ms = summary.extra["time_per_step_ms"]
    total = sum(ms.values())
    label = "with logging (MCAP + Rerun, images 5 Hz)" if logging else "without logging"
    print(f"\n{label}: {summary.steps} steps, method {summary.method}")
    print(f"  loop rate      {summary.steps_per_s:8.1f} steps/s   (goal >= 50)")
    print(f"  setup          {summary.extra['setup_time_s']:8.3f} s (target + rod brought home)")
    print(f"  wall, all      {wall:8.3f} s")
    for stage, v in ms.items():
        print(f"  {stage:<14} {v:8.3f} ms/step  ({100 * v / total:5.1f} %)")
    if logging:
        print(f"  logging share  {100 * ms['logging'] / total:8.1f} % of the loop (goal <= 15 %)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/default.yaml")
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args()
    torch.set_num_threads(1)
    print(f"bench_loop: {args.config}, {args.steps} steps, torch threads 1")
    run(args.config, args.steps, logging=False)
    run(args.config, args.steps, logging=True)


if __name__ == "__main__":
    main()
