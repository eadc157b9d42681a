"""Benchmark: reset without re-driving (issue 24). What an episode saves when its rod starts from
the stored settled home state (`RodSim.at_home`) instead of being driven home from the straight
rod, for the pymunk and the quasi-static engine.

    .venv/bin/python benchmarks/bench_reset.py            # configs/default.yaml, heavy-rod.yaml
    .venv/bin/python benchmarks/bench_reset.py --repeat 10

Printed per config and engine: the driven build (`RodSim(cfg)`), the restored one (`at_home`, the
home state already stored), and `ShapeServoEnv.reset` with a given target (as every compare
episode resets) both ways; the saving is per episode. The issue measured building a fresh rod and
driving it home at 35 % of an episode's cost; there is no numeric goal beyond "less".
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import rodctl.env as env_module  # noqa: E402
from rodctl.config import load_config  # noqa: E402
from rodctl.env import ShapeServoEnv  # noqa: E402
from rodctl.sim import RodSim  # noqa: E402


def _median_s(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument(
        "configs", nargs="*", default=["configs/default.yaml", "configs/heavy-rod.yaml"]
    )
    args = parser.parse_args()
    restored = env_module._home_sim
    print(f"{'config':<24} {'engine':<12} {'driven':>10} {'restored':>10} {'reset driven':>13} "
          f"{'reset restored':>15} {'saving/episode':>15}")  # fmt: skip
    for path in args.configs:
        for engine in ("pymunk", "quasistatic"):
            cfg = load_config(REPO / path, [f"rod.engine={engine}"])
            RodSim.at_home(cfg.rod)  # the home state, stored once per rod config
            driven = _median_s(lambda cfg=cfg: RodSim(cfg.rod), args.repeat)
            put = _median_s(lambda cfg=cfg: RodSim.at_home(cfg.rod), args.repeat)
            env = ShapeServoEnv(cfg)
            target = env.make_target()
            resets = {}
            for name, home in (("driven", RodSim), ("restored", restored)):
                env_module._home_sim = home
                try:
                    resets[name] = _median_s(
                        lambda env=env, t=target: env.reset(seed=0, options={"target": t}),
                        args.repeat,
                    )
                finally:
                    env_module._home_sim = restored
            saving = resets["driven"] - resets["restored"]
            print(
                f"{Path(path).stem:<24} {engine:<12} {1e3 * driven:>8.1f}ms {1e3 * put:>8.2f}ms "
                f"{1e3 * resets['driven']:>11.1f}ms {1e3 * resets['restored']:>13.1f}ms "
                f"{1e3 * saving:>13.1f}ms"
            )
    print("goal: the restored reset cheaper than the driven one (no numeric goal in issue 24)")


if __name__ == "__main__":
    main()
