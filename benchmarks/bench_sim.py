"""Speed of the simulated rod: raw steps/s, real-time factor, wall time of one control step.

Prints figures; asserts nothing (speed goals are checked by reading these numbers, not by timed
tests). Goals from issue #3: >= 10x real time at N = 50, one control step (move + settle) <= 10 ms.
Issue #12: with gravity (a heavy rod in a vertical plane) and with table friction, steps/s and
one control step's wall time within 1.5x of the weightless rod at N = 25, 50, 100 (the "x"
columns: weightless / this for steps/s, this / weightless for the control step).

    .venv/bin/python benchmarks/bench_sim.py                 # N = 25, 50, 100
    .venv/bin/python benchmarks/bench_sim.py --segments 50 --commands 100

On a shared machine the wall times are noisy: each figure is the median of several repeats, and
the p90 is printed next to it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rodctl.config.rod import RodConfig
from rodctl.sim import RodSim
from rodctl.sim.elastica import cantilever_tip_load


def bench_steps(sim: RodSim, steps: int, repeats: int) -> float:
    """Median wall time (s) of one physics step with the gripper held still."""
    target = sim.gripper_pose
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim.chain.run(steps, target)
        times.append((time.perf_counter() - t0) / steps)
    return float(np.median(times))


def bench_readout(sim: RodSim, repeats: int = 2000) -> float:
    """Median wall time (s) of one `centerline()` call (batch read + joint points)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim.centerline()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def bench_control_steps(sim: RodSim, commands: int, seed: int = 0) -> dict[str, float]:
    """Random commands within `max_step` from home, as a servo loop would send them."""
    rng = np.random.default_rng(seed)
    limit = np.asarray(sim.cfg.max_step)
    walls, steps, settle_times, sims = [], [], [], []
    settled = 0
    for _ in range(commands):
        # Random walk that drifts back towards home so it stays in the workspace.
        u = rng.uniform(-1, 1, 3) * limit + 0.2 * (sim.home_pose - sim.gripper_pose)
        t_sim = sim.sim_time
        t0 = time.perf_counter()
        r = sim.apply(u)
        walls.append(time.perf_counter() - t0)
        steps.append(r.sim_steps)
        settle_times.append(r.settle_time)
        sims.append(sim.sim_time - t_sim)
        settled += r.settled
    walls_ms = 1e3 * np.array(walls)
    return {
        "median_ms": float(np.median(walls_ms)),
        "p90_ms": float(np.percentile(walls_ms, 90)),
        "mean_steps": float(np.mean(steps)),
        "settle_s": float(np.mean(settle_times)),
        "rtf": float(np.sum(sims) / np.sum(walls)),
        "settled": settled / commands,
    }


def cantilever_error(segments: int) -> float:
    """Relative tip-deflection error (%) of the chain at alpha = 1 (settled to 1e-9 m/s)."""
    from rodctl.sim import RodChain, first_mode_rate, stable_dt_limit

    cfg = RodConfig(segments=segments)
    args = (cfg.length, cfg.bending_stiffness, cfg.mass_per_length, segments, cfg.inertia_radius)
    chain = RodChain(
        *args[:4],
        clamp_pose=(0, 0, 0),
        dt=0.5 * stable_dt_limit(*args),
        iterations=cfg.iterations,
        damping_rate=2 * first_mode_rate(*args, free_end=True),
        inertia_radius=cfg.inertia_radius,
        gripped=False,
        tip_force=(0.0, cfg.bending_stiffness / cfg.length**2),
    )
    for _ in range(2000):
        chain.run(20)
        if chain.max_speed() < 1e-9:
            break
    ref = cantilever_tip_load(1.0).deflection
    return 100 * (chain.joint_points()[-1, 1] / cfg.length - ref) / ref


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, nargs="+", default=[25, 50, 100])
    parser.add_argument("--commands", type=int, default=40, help="control steps per N")
    parser.add_argument("--steps", type=int, default=2000, help="physics steps per timing")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    print(
        f"{'N':>4} {'physics':>9} {'iter':>4} {'dt ms':>6} {'steps/s':>8} {'x':>5} "
        f"{'RTF raw':>8} {'read us':>7} {'build s':>7} | {'ctrl ms':>7} {'x':>5} {'p90 ms':>7} "
        f"{'steps':>6} {'settle s':>8} {'RTF loop':>8} {'settled':>7} | {'cantilever err %':>16}"
    )
    for n in args.segments:
        base: dict[str, float] = {}
        for physics, extra in PHYSICS.items():
            t0 = time.perf_counter()
            sim = RodSim(RodConfig(segments=n, **extra))
            build = time.perf_counter() - t0
            per_step = bench_steps(sim, args.steps, args.repeats)
            read = bench_readout(sim)
            ctrl = bench_control_steps(sim, args.commands)
            if not base:
                base = {"per_step": per_step, "ctrl": ctrl["median_ms"]}
                err = f"{cantilever_error(n):>+16.4f}"
            else:
                err = f"{'':>16}"
            print(
                f"{n:>4} {physics:>9} {sim.cfg.iterations:>4} {1e3 * sim.dt:>6.2f} "
                f"{1 / per_step:>8.0f} {per_step / base['per_step']:>5.2f} "
                f"{sim.dt / per_step:>8.0f} {1e6 * read:>7.1f} {build:>7.2f} | "
                f"{ctrl['median_ms']:>7.1f} {ctrl['median_ms'] / base['ctrl']:>5.2f} "
                f"{ctrl['p90_ms']:>7.1f} {ctrl['mean_steps']:>6.0f} "
                f"{ctrl['settle_s']:>8.2f} {ctrl['rtf']:>8.0f} {ctrl['settled']:>7.0%} | {err}"
            )
    print(
        "steps/s: physics steps per wall second (gripper still); RTF raw = steps/s * dt; "
        "ctrl ms: wall time of one apply() = move over control_period + settle (median, p90); "
        "steps: physics steps per apply; settle s: simulated settle time; RTF loop: simulated "
        "/ wall time over the control steps. Rotary inertia is inflated (rod.inertia_radius), "
        "so simulated time is a quasi-static clock, not the physical rod's. "
        "x: cost relative to the weightless rod at the same N (goal <= 1.5). "
        "gravity: the default rod in a vertical plane, g = 9.81 (q L^3/EI = 19); heavy: "
        "q L^3/EI = 100; table: lying on a table, mu = 0.5."
    )


#: The physics compared, as RodConfig overrides; the first is the reference.
PHYSICS: dict[str, dict] = {
    "weightless": {},
    "gravity": {"gravity": (0.0, -9.81)},
    "heavy": {"gravity": (0.0, -9.81), "mass_per_length": 100 * 5e-3 / (9.81 * 0.5**3)},
    "table": {"table_friction": 0.5},
}


if __name__ == "__main__":
    main()
