"""First result fast: `rodctl simulate configs/default.yaml` end to end (goal <= 1.0 s wall).

Prints the whole-process wall time (median of 5 fresh processes) of the default run, the same run
without the Rerun recording and the figures (what the core costs), the import time of the
heavy modules in one such process (`python -X importtime`, cumulative, as imported on the way;
matplotlib is imported by the figure process, `rodctl.figure_worker`, not by the command), and
where the time of one run goes (`--phases`, on by default: the median over the repeats of each
phase's end, wrapping rodctl's functions in a driver process). Prints figures next to the goal;
asserts nothing (timings on a shared machine are noisy).

Run: .venv/bin/python benchmarks/bench_startup.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
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
    "gymnasium",
    "rodctl.env",
    "rodctl.logs.mcap",
)

#: A driver that runs the CLI like `python -m rodctl` and prints, as JSON on its last line, the
#: time (s since the interpreter started running the driver) at which each phase ended.
_PHASES = r"""
import atexit, json, sys, time
t0, wall0 = time.perf_counter(), time.time()
marks = {}
def mark(name):
    marks.setdefault(name, time.perf_counter() - t0)
import rodctl.cli
mark("imports (cli, config, pydantic, typer)")
import rodctl.simulate as S, rodctl.episode as E, rodctl.runs as R
def around(obj, attr, before=None, after=None):
    fn = getattr(obj, attr)
    def wrapped(*a, **k):
        if before: mark(before)
        try:
            return fn(*a, **k)
        finally:
            if after: mark(after)
    setattr(obj, attr, wrapped)
around(S, "make_sinks", "config loaded; env, method, run dir made", "sinks made (rerun import)")
around(E._Loop, "close", "episode (reset, sinks open, the steps)", "sinks closed")
around(S, "write_json_best_effort", None, "summary.json")
around(S, "_figures", None, "figures waited for and written")
around(R.RunDir, "finish", None, "meta.json")
atexit.register(
    lambda: print(json.dumps({**marks, "exit": time.perf_counter() - t0, "wall0": wall0}))
)
sys.argv = ["rodctl", *sys.argv[1:]]
rodctl.cli.main()
"""


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


def phases(cmd: list[str], repeats: int) -> tuple[float, list[tuple[str, float]], float]:
    """Medians over `repeats` runs: (interpreter start-up s, [(phase, its end in s after the
    start-up)], interpreter tear-down s after the last phase)."""
    ends: dict[str, list[float]] = {}
    startup, teardown = [], []
    for _ in range(repeats):
        t0, wall0 = time.perf_counter(), time.time()
        res = subprocess.run(
            [cmd[0], "-c", _PHASES, *cmd[3:]], capture_output=True, text=True, cwd=REPO
        )
        wall_s = time.perf_counter() - t0
        marks = json.loads(res.stdout.strip().splitlines()[-1])
        startup.append(marks.pop("wall0") - wall0)
        teardown.append(wall_s - startup[-1] - marks["exit"])
        for name, t in marks.items():
            ends.setdefault(name, []).append(t)
    order = sorted(ends, key=lambda n: statistics.median(ends[n]))
    return (
        statistics.median(startup),
        [(n, statistics.median(ends[n])) for n in order],
        statistics.median(teardown),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-phases", dest="phases", action="store_false")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        full = _cmd(tmp)
        core = _cmd(tmp, "logging.rerun=false", "logging.figures=false")
        t_full = wall(full, args.repeats)
        t_core = wall(core, args.repeats)
        imports = import_times(full)
        steps = phases(full, args.repeats) if args.phases else None
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
    for name in ("torch", "scipy", "matplotlib"):
        if name not in imports:
            print(f"  {name:<30} not imported")
    if steps is not None:
        startup, ends, teardown = steps
        print(f"one run as shipped, phase by phase (median of {args.repeats}; s):")
        print(f"  {'python start-up':<48} {startup:6.2f}")
        prev = 0.0
        for name, end in ends:
            if name != "exit":
                print(f"  {name:<48} {end - prev:6.2f}   (ends at {startup + end:5.2f})")
                prev = end
        print(f"  {'python tear-down':<48} {teardown:6.2f}")
    print(f"load average during the run: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
