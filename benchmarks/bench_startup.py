"""First result fast: `rodctl simulate configs/default.yaml` end to end (goal <= 1.0 s wall).

Prints the whole-process wall time (median of 5 fresh processes) of the default run, the same run
without the Rerun recording and the figures (what the core costs), and the import time of the
heavy modules in one such process (`python -X importtime`, cumulative, as imported on the way).
Prints figures next to the goal; asserts nothing (timings on a shared machine are noisy).

Run: .venv/bin/python benchmarks/bench_startup.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
GOAL_S = 1.0
#: Modules whose cumulative import time is reported (when the run imports them at all).
HEAVY = (
    "numpy",
    "cv2",
    "pymunk",
    "pydantic",
    "typer",
    "rich",
    "scipy",
    "torch",
    "matplotlib",
    "rerun",
    "mcap",
    "rodctl.config",
    "rodctl.features.autoencoder",
    "rodctl.logs.rerun",
    "rodctl.plots",
)


def _cmd(out: str, *sets: str) -> list[str]:
    args = ["simulate", str(REPO / "configs/default.yaml"), "-q", "--out", out]
    for s in sets:
        args += ["--set", s]
    return [sys.executable, "-m", "rodctl", *args]


def wall(cmd: list[str], repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, cwd=REPO, env=os.environ.copy())
        times.append(time.perf_counter() - t0)
    return times


def import_times(cmd: list[str]) -> dict[str, float]:
    """Cumulative import time (s) of the HEAVY modules in one run, from -X importtime."""
    res = subprocess.run(
        [cmd[0], "-X", "importtime", *cmd[1:]], capture_output=True, text=True, cwd=REPO
    )
    out: dict[str, float] = {}
    for line in res.stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cumulative, name = (p.strip() for p in line.split("|"))
        if name in HEAVY and cumulative.isdigit():
            out[name] = int(cumulative) / 1e6
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        full = _cmd(tmp)
        core = _cmd(tmp, "logging.rerun=false", "logging.figures=false")
        t_full = wall(full, args.repeats)
        t_core = wall(core, args.repeats)
        imports = import_times(full)
    med = statistics.median(t_full)
    verdict = "met" if med <= GOAL_S else "NOT met"
    print(f"rodctl simulate configs/default.yaml, median of {args.repeats} processes:")
    print(f"  as shipped                      {med:6.2f} s wall   goal <= {GOAL_S} s: {verdict}")
    print(
        f"  without run.rrd and figures     {statistics.median(t_core):6.2f} s wall   "
        "(logging.rerun=false, logging.figures=false)"
    )
    print("import time, cumulative, in one run as shipped:")
    for name in HEAVY:
        if name in imports:
            print(f"  {name:<30} {imports[name]:6.2f} s")
    for name in ("torch", "scipy"):
        if name not in imports:
            print(f"  {name:<30} not imported")
    print(f"load average during the run: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
