"""Time to draw a run's three figures (shapes.png, t1.png, commands.png) and a comparison's four.

Goal: the figures are part of `rodctl simulate configs/default.yaml`, which the performance issue
wants under 1 s in all; the three figures of a run should take at most ~0.3 s. Prints figures
(CPU and wall time, median over repeats, after one warm-up that loads fonts); asserts nothing.

The records are synthetic (`rodctl.logs.synthetic`), 17 steps like the default run, 4 of them
probing; the comparison has 6 methods.

Run: .venv/bin/python benchmarks/bench_plots.py [--repeats R]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import tempfile
import time
from pathlib import Path

from rodctl import plots
from rodctl.logs.synthetic import SyntheticRun

GOAL_S = 0.3


def timed(fn) -> tuple[float, float]:
    c, t = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    run = SyntheticRun(seed=0, image_every=0)
    records = run.records(17)
    methods = ("paper", "ma2022", "ma2022-wls", "aghajanzadeh2022", "akf-pinv", "broyden-mfac")
    runs = {
        m: (SyntheticRun(seed=i).header, SyntheticRun(seed=i).records(17))
        for i, m in enumerate(methods)
    }
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        plots.write_figures(run.header, records, out / "warm")
        one = [
            timed(lambda: plots.write_figures(run.header, records, out / "one"))
            for _ in range(args.repeats)
        ]
        cmp = [
            timed(lambda: plots.write_comparison_figures(runs, out / "cmp"))
            for _ in range(max(1, args.repeats // 2))
        ]
    cpu1, wall1 = (statistics.median(x) for x in zip(*one, strict=True))
    cpu6, wall6 = (statistics.median(x) for x in zip(*cmp, strict=True))
    print(f"machine: {platform.machine()}, {platform.processor() or platform.system()}")
    print(
        f"run figures (3):        cpu {cpu1:.3f} s, wall {wall1:.3f} s   goal <= {GOAL_S} s "
        f"-> {'met' if wall1 <= GOAL_S else 'NOT met'}"
    )
    print(f"comparison figures (4, 6 methods): cpu {cpu6:.3f} s, wall {wall6:.3f} s")


if __name__ == "__main__":
    main()
