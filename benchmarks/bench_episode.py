"""Where a default-config episode's CPU time goes, stage by stage, on either engine (issue 24).

Wraps the functions of one episode (the env's render-and-extract, step and reset, the method's
act, the AKF update and its eigenvalue clip, the step record and its Jacobian error, the
engine's apply) with CPU-time counters, runs `--episodes` episodes of `configs/default.yaml`
with logging off on one env after a warm-up episode, and prints each function's CPU time per
episode (nested: a caller's time includes its callees'). `bench_engine.py` gives the goal's
ratio; this says what the ratio is made of.

    python benchmarks/bench_episode.py [--engine quasistatic] [--episodes 20]
"""

from __future__ import annotations

import argparse
import collections
import functools
import os
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

from rodctl import episode as episode_module  # noqa: E402
from rodctl import fixedla  # noqa: E402
from rodctl.config import load_config  # noqa: E402
from rodctl.env import ShapeServoEnv  # noqa: E402
from rodctl.episode import run_episode  # noqa: E402
from rodctl.estimation import akf  # noqa: E402
from rodctl.method import Method  # noqa: E402

TOTAL: collections.Counter = collections.Counter()
CALLS: collections.Counter = collections.Counter()
LABELS: list[str] = []  # in the order printed


def _wrap(owner: Any, name: str, label: str) -> None:
    """Count the CPU time of `owner.name` under `label`."""
    fn = getattr(owner, name)

    @functools.wraps(fn)
    def timed(*args: Any, **kwargs: Any) -> Any:
        t = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            TOTAL[label] += time.process_time() - t
            CALLS[label] += 1

    setattr(owner, name, timed)
    LABELS.append(label)


def instrument(sim_type: type) -> None:
    """The stages `docs/engines.md` ("Speed") breaks an episode into."""
    for owner, name, label in [
        (ShapeServoEnv, "_see", "env._see, every frame (render + extract: vision)"),
        (ShapeServoEnv, "reset", "env.reset"),
        (ShapeServoEnv, "_make_target", "  env._make_target (drive the rod, look)"),
        (ShapeServoEnv, "step", "env.step"),
        (sim_type, "apply", "  sim.apply (physics)"),
        (ShapeServoEnv, "_info", "  env._info"),
        (Method, "act", "method.act"),
        (Method, "_encode", "  feature encode"),
        (akf.AdaptiveKalmanJacobian, "update", "  AKF update"),
        (fixedla, "clip_eigenvalues", "    fixedla.clip_eigenvalues"),
        (Method, "_command", "  controller"),
        (episode_module._Loop, "record", "step record"),
        (episode_module._Loop, "_jacobian_error", "  Jacobian error"),
        (fixedla, "singular_values", "  singular values of J"),
    ]:
        _wrap(owner, name, label)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engine", choices=["pymunk", "quasistatic"], default="quasistatic")
    ap.add_argument("--episodes", type=int, default=20)
    args = ap.parse_args()
    cfg = load_config(
        "configs/default.yaml",
        [
            "logging.mcap=false",
            "logging.rerun=false",
            "logging.figures=false",
            f"rod.engine={args.engine}",
        ],
    )
    env, method = ShapeServoEnv(cfg), Method.from_config(cfg)
    run_episode(env, method, sinks=[], run_id="bench")  # the home state, the caches
    instrument(type(env.sim))
    TOTAL.clear()
    CALLS.clear()
    c0 = time.process_time()
    for _ in range(args.episodes):
        summary = run_episode(env, method, sinks=[], run_id="bench").summary
    per = (time.process_time() - c0) / args.episodes
    print(
        f"{args.engine}: {1e3 * per:.1f} ms of CPU an episode ({summary.steps} steps, "
        f"{summary.outcome}; the counters' own cost included)"
    )
    for label in LABELS:
        ms = 1e3 * TOTAL[label] / args.episodes
        print(
            f"  {label:<50} {ms:7.2f} ms  {100 * ms / (1e3 * per):5.1f} %"
            f"  ({CALLS[label] / args.episodes:.0f} calls)"
        )


if __name__ == "__main__":
    main()
