"""Time to draw a run's three figures (shapes.png, t1.png, commands.png) and a comparison's four.

Goal: the figures are part of `rodctl simulate configs/default.yaml`, which the performance issue
wants under 1 s in all; the three figures of a run should take at most ~0.3 s. Prints figures
(CPU and wall time, median over repeats, after one warm-up that loads fonts); asserts nothing.

The records are synthetic (`rodctl.logs.synthetic`), 17 steps like the default run, 4 of them
probing; the comparison has 6 methods.

`simulate` and `replay` draw the run figures in a helper process (`rodctl.figure_worker`) that
starts with the run, so what the command waits for is printed too: from handing the records over
to having the PNG bytes, with a helper that had time to import and warm up (the usual case: the
episode lasts longer than its ~0.6 s of imports), and with one started at that moment (the worst
case: an episode shorter than the helper's start-up).

Run: .venv/bin/python benchmarks/bench_plots.py [--repeats R]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from rodctl import plots
from rodctl.figure_worker import FigureWorker
from rodctl.logs.synthetic import SyntheticRun

GOAL_S = 0.3


def timed(fn) -> tuple[float, float]:
    c, t = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c, time.perf_counter() - t


def helper_wait(header, records, ready_after: float) -> float:
    """Wall time from handing the run to a helper started `ready_after` s before to its PNGs."""
    with FigureWorker.start() as worker:
        time.sleep(ready_after)
        t = time.perf_counter()
        worker.submit(header, records)
        worker.result()
        return time.perf_counter() - t


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
    ready = [helper_wait(run.header, records, 3.0) for _ in range(args.repeats)]
    cold = [helper_wait(run.header, records, 0.0) for _ in range(args.repeats)]
    cpu1, wall1 = (statistics.median(x) for x in zip(*one, strict=True))
    cpu6, wall6 = (statistics.median(x) for x in zip(*cmp, strict=True))
    print(f"machine: {platform.machine()}, {platform.processor() or platform.system()}")
    print(
        f"run figures (3):        cpu {cpu1:.3f} s, wall {wall1:.3f} s   goal <= {GOAL_S} s "
        f"-> {'met' if wall1 <= GOAL_S else 'NOT met'}"
    )
    print(f"comparison figures (4, 6 methods): cpu {cpu6:.3f} s, wall {wall6:.3f} s")
    print("the command's wait for the run figures from the figure process (wall):")
    print(f"  helper ready (imported, warmed up):  {statistics.median(ready):.3f} s")
    print(f"  helper started at that moment:       {statistics.median(cold):.3f} s")
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
