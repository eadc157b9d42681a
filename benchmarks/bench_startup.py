"""The whole `rodctl simulate` process with the quasi-static engine, and where its time goes
(issue 24).

Goal: `rodctl simulate configs/default.yaml --set rod.engine=quasistatic` <= 1.0 s for the whole
process on a quiet machine. On a loaded machine the wall time also counts waiting for a core, so
the CPU time (user + sys of the process and the children it waited for, the figure worker
included) is printed beside it. The breakdown: the same command with logging off, and the CPU
time of importing the heavy modules, each in a fresh interpreter.

    python benchmarks/bench_startup.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

GOAL_S = 1.0
COMMAND = ["simulate", "configs/default.yaml", "--set", "rod.engine=quasistatic"]
LOGGING_OFF = [
    *("--set", "logging.mcap=false"),
    *("--set", "logging.rerun=false"),
    *("--set", "logging.figures=false"),
]
#: Imports whose cost the command pays (rerun only with logging.rerun, matplotlib in the figure
#: worker), and torch for comparison (simulate does not import it).
IMPORTS = [
    "numpy",
    "scipy.linalg",
    "gymnasium",
    "pydantic",
    "cv2",
    "rodctl",
    "rodctl.cli",
    "rodctl.simulate",
    "rodctl.logs.mcap",
    "rerun",
    "matplotlib.pyplot",
    "torch",
]


def timed(argv: list[str]) -> tuple[float, float]:
    """(wall s, CPU s of the child and its waited-for children) of one run of `argv`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, capture_output=True, env={**os.environ, "NO_COLOR": "1"})
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def best(argv: list[str], repeat: int) -> tuple[float, float]:
    runs = [timed(argv) for _ in range(repeat)]
    return min(w for w, _ in runs), min(c for _, c in runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per figure (the best is shown)")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        for label, extra in (("as configured", []), ("logging off", LOGGING_OFF)):
            argv = [sys.executable, "-m", "rodctl", *COMMAND, *extra, "--out", tmp]
            wall, cpu = best(argv, args.repeat)
            verdict = "met" if wall <= GOAL_S else "NOT met"
            print(
                f"rodctl {' '.join(COMMAND)} ({label}): wall {wall:.2f} s, CPU {cpu:.2f} s"
                f"   (goal <= {GOAL_S:.1f} s wall on a quiet machine: {verdict} here)"
            )
    base = best([sys.executable, "-c", "pass"], args.repeat)[1]
    print(f"imports, CPU s in a fresh interpreter beyond its own start-up ({base:.3f} s):")
    for module in IMPORTS:
        cpu = best([sys.executable, "-c", f"import {module}"], args.repeat)[1] - base
        print(f"  {module:<20} {cpu:6.3f}")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
