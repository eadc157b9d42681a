"""Table friction: the quasi-static engine's incremental minimisation against the pymunk table.

Goal (issue 24): settled centerlines within 0.2 % of L of the pymunk table's on the same moves,
on configs/table.yaml's path (the home drive, the drive to its target, the episode's commands,
recorded from a pymunk run of the config) and on >= 50 random moves. Beside the shipped pymunk
table it runs a pymunk table driven `--slow` times slower with 80 solver iterations, which is
how far the pymunk table's own settled shapes move when its ramp speed and solver error go
towards the quasi-static limit; and the cost per control step, CPU time side by side.

    python benchmarks/bench_table_friction.py [--moves 50] [--segments 50] [--slow 16]

The quasi-static engine refuses `table_friction` at validation; this benchmark builds its rods
with `model_copy` (no validation) to measure the solver (`rodctl/sim/friction.py`).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rodctl.config import load_config  # noqa: E402
from rodctl.config.rod import RodConfig  # noqa: E402
from rodctl.sim import RodSim, friction  # noqa: E402

GOAL = 0.2  # % of L


def record_table_path(segments: int) -> tuple[RodConfig, np.ndarray, list[np.ndarray]]:
    """(rod, target pose, the episode's commands) of configs/table.yaml, run on pymunk with
    logging off; the commands are what the method passed to `RodSim.apply`."""
    from rodctl.env import ShapeServoEnv  # noqa: PLC0415
    from rodctl.episode import run_episode  # noqa: PLC0415
    from rodctl.method import Method  # noqa: PLC0415
    from rodctl.training.auto import prepare_feature  # noqa: PLC0415

    sets = ["logging.mcap=false", "logging.rerun=false", "logging.figures=false"]
    cfg = load_config("configs/table.yaml", [*sets, f"rod.segments={segments}"])
    commands: list[np.ndarray] = []
    apply = RodSim.apply

    def recording(self: RodSim, u: np.ndarray):  # noqa: ANN202
        commands.append(np.asarray(u, dtype=float).copy())
        return apply(self, u)

    RodSim.apply = recording  # type: ignore[method-assign]
    try:
        env = ShapeServoEnv(cfg)
        prepare_feature(cfg)
        result = run_episode(env, Method.from_config(cfg))
    finally:
        RodSim.apply = apply  # type: ignore[method-assign]
    print(f"configs/table.yaml on pymunk (N = {segments}): {result.status}, {len(commands)} moves")
    assert cfg.run.target.pose is not None
    return cfg.rod, np.asarray(cfg.run.target.pose, dtype=float), commands


def engines(rod: RodConfig, slow: float) -> dict[str, RodConfig]:
    return {
        "pymunk": rod.model_copy(update={"engine": "pymunk"}),
        f"pymunk {slow:g}x slower, 80 iterations": rod.model_copy(
            update={
                "engine": "pymunk",
                "control_period": rod.control_period * slow,
                "iterations": 80,
            }
        ),
        "quasistatic": rod.model_copy(update={"engine": "quasistatic"}),
        # The same with twice the sub-moves per control step: the path's discretisation error.
        f"quasistatic, {2 * friction.SUBSTEPS} sub-moves": rod.model_copy(
            update={"engine": "quasistatic"}
        ),
    }


class Runs:
    """The same moves on every engine; the largest centerline gaps per pair, CPU per step."""

    def __init__(self, cfgs: dict[str, RodConfig]) -> None:
        self.cfgs = cfgs
        self.names = list(cfgs)
        self.gaps: dict[tuple[str, str], list[float]] = {}
        self.cpu = dict.fromkeys(self.names, 0.0)
        self.steps = 0

    def fresh(self) -> dict[str, RodSim]:
        sims = {}
        default = friction.SUBSTEPS
        for name, cfg in self.cfgs.items():
            t = time.process_time()
            friction.SUBSTEPS = 2 * default if "sub-moves" in name else default
            try:
                sims[name] = (
                    friction.TableQuasiStaticSim(cfg)
                    if cfg.engine == "quasistatic"
                    else RodSim(cfg)
                )
            finally:
                friction.SUBSTEPS = default
            self.cpu[name] += time.process_time() - t
        return sims

    def record(self, sims: dict[str, RodSim]) -> None:
        length = self.cfgs[self.names[0]].length
        for i, a in enumerate(self.names):
            for b in self.names[i + 1 :]:
                d = sims[a].centerline() - sims[b].centerline()
                gap = 100 * float(np.max(np.hypot(d[:, 0], d[:, 1]))) / length
                self.gaps.setdefault((a, b), []).append(gap)

    def move(self, sims: dict[str, RodSim], how: str, arg: np.ndarray) -> None:
        for name, sim in sims.items():
            t = time.process_time()
            result = getattr(sim, how)(arg)
            self.cpu[name] += time.process_time() - t
            if not result.settled or result.diverged:
                raise RuntimeError(f"{name}: {how} {arg} did not settle")
        self.steps += 1
        self.record(sims)

    def report(self, title: str) -> None:
        print(f"\n{title}")
        for (a, b), g in self.gaps.items():
            goal = f"  (goal <= {GOAL} %)" if (a, b) == ("pymunk", "quasistatic") else ""
            print(
                f"  {a:>34s} vs {b:<34s} max {max(g):.4f} %  median {np.median(g):.4f} % "
                f"of L over {len(g)} shapes{goal}"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--moves", type=int, default=50)
    ap.add_argument("--segments", type=int, default=50)
    ap.add_argument("--slow", type=float, default=16.0)
    args = ap.parse_args()
    print(f"uptime: {open('/proc/loadavg').read().split()[:3]}")

    rod, target, commands = record_table_path(args.segments)
    cfgs = engines(rod, args.slow)

    path = Runs(cfgs)
    sims = path.fresh()  # the home drive (from the straight rod, move_to the home pose)
    path.record(sims)
    path.move(sims, "move_to", target)  # the drive to the target, from home
    sims = path.fresh()
    for u in commands:  # the episode, from home
        path.move(sims, "apply", u)
    path.report(f"configs/table.yaml's path (home, target drive, {len(commands)} episode moves)")

    rand = Runs(cfgs)
    sims = rand.fresh()
    rand.record(sims)
    build = dict(rand.cpu)
    rand.cpu = dict.fromkeys(rand.names, 0.0)
    rng = np.random.default_rng(0)
    step = np.asarray(rod.max_step)
    home = sims["pymunk"].home_pose
    for _ in range(args.moves):
        u = rng.uniform(-1, 1, 3) * step + 0.2 * (home - sims["pymunk"].gripper_pose)
        rand.move(sims, "apply", u)
    rand.report(f"{args.moves} random moves (N = {args.segments}, mu = {rod.table_friction})")

    print("\nCPU time per control step (random moves), side by side in this process:")
    base = rand.cpu["pymunk"] / args.moves
    for name in rand.names:
        per = rand.cpu[name] / args.moves
        print(
            f"  {name:>34s}: {1e3 * per:8.2f} ms  ({per / base:.2f}x pymunk's); "
            f"building + driving home {build[name]:.2f} s"
        )
    print(f"uptime: {open('/proc/loadavg').read().split()[:3]}")


if __name__ == "__main__":
    main()
