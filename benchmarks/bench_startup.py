"""The whole `rodctl simulate` process with the quasi-static engine, and where its time goes
(issue 24).

Goal: `rodctl simulate configs/default.yaml --set rod.engine=quasistatic` <= 1.0 s for the whole
process on a quiet machine. On a loaded machine the wall time also counts waiting for a core, so
the CPU time (user + sys of the command and of its helper processes, the figure and Rerun
processes, which it waits for) is printed beside it, and:

- `--before REV`: the same command from the code of git revision REV (exported with `git
  archive` to a temporary folder and run from there), interleaved with this code's runs
  (before, after, after, before, ...), so that the load moves both alike: side-by-side figures
  from one script.
- The timeline of this code's median run (`RODCTL_TIMELINE`, rodctl/timeline.py): when each
  process (the command, the figure process, the Rerun process) reached each phase, seconds
  since the command was started, with the CPU time that process had used by then; and the
  critical path in brief: the command's imports, the episode, and what it then waits for.
- The same command with the figures and run.rrd off (the command alone), and the CPU time of
  importing the heavy modules, each in a fresh interpreter.

Bytecode: every side runs with its compiled modules cached (`PYTHONPYCACHEPREFIX`, a temporary
folder, filled by one untimed run of each side first), as an installed rodctl runs (pip compiles
on install). Before 2026-12-02 08:00 UTC this script set PYTHONDONTWRITEBYTECODE, so that every
timed run compiled rodctl's ~80 modules from source in each process (~0.2 s of CPU, ~0.4 s of
wall on 2 cores): the figures before then include that.

    python benchmarks/bench_startup.py [--repeat 2] [--before 6736bdb]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
GOAL_S = 1.0
COMMAND = ["simulate", "configs/default.yaml", "--set", "rod.engine=quasistatic", "-q"]
VARIANTS = {
    "as configured": [],
    "figures and run.rrd off": [
        *("--set", "logging.figures=false"),
        *("--set", "logging.rerun=false"),
    ],
}
#: Imports whose cost the command pays (rerun and matplotlib in the helper processes), and
#: torch for comparison (simulate does not import it).
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
#: Phases named in the critical-path summary: (label, from, to), each a (role, event) mark;
#: from None: the command's start.
SPANS = [
    ("command: start to its imports done", None, ("main", "cli")),
    ("command: config, env, method, run dir", ("main", "cli"), ("main", "episode start")),
    ("command: the episode, its sinks closed", ("main", "episode start"), ("main", "episode end")),
    ("  of it: waiting for the Rerun process", ("main", "rerun close sent"),
     ("main", "rerun closed")),
    ("command: episode end to the figures", ("main", "episode end"),
     ("main", "figures received")),
    ("figure process: launched to ready", ("main", "started rodctl.figure_worker"),
     ("figures", "ready")),
    ("Rerun process: launched to ready", ("main", "started rodctl.logs.rerun_process"),
     ("rerun", "ready")),
    ("figure process: ready to its reply", ("figures", "ready"), ("figures", "replied")),
]  # fmt: skip


def timed(argv: list[str], cwd: Path, env: dict[str, str]) -> tuple[float, float, float]:
    """(start monotonic s, wall s, CPU s of the child and its waited-for children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    subprocess.run(argv, check=True, capture_output=True, cwd=cwd, env=env)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return t0, wall, cpu


def read_timeline(path: Path, t0: float) -> list[tuple[str, str, float, float]]:
    """(role, event, s since t0, CPU s of that process) per line of a `RODCTL_TIMELINE` file."""
    out = []
    for line in path.read_text().splitlines():
        _pid, role, rest = line.split(" ", 2)
        event, mono, cpu = rest.rsplit(" ", 2)
        out.append((role, event, float(mono) - t0, float(cpu)))
    return out


def export(rev: str, into: Path) -> Path:
    """The package and configs of git revision `rev`, exported under `into`."""
    archive = subprocess.run(
        ["git", "archive", rev, "rodctl", "configs"], cwd=REPO, check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def compare(variant: str, extra: list[str], repeat: int, tmp: Path, before: Path | None) -> None:
    """Wall and CPU per run (interleaved with `before`), then this code's median timeline."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    base_env = {**env, "NO_COLOR": "1", "PYTHONPYCACHEPREFIX": str(tmp / "pycache")}
    sides = {"after": (REPO, base_env)}
    if before is not None:  # its own package first on the path (PYTHONPATH precedes the venv's)
        sides["before"] = (before, {**base_env, "PYTHONPATH": str(before)})
    order = ["before", "after", "after", "before"] if before is not None else ["after"]
    runs: dict[str, list[tuple[float, float, Path, float]]] = {side: [] for side in sides}
    argv = [sys.executable, "-m", "rodctl", *COMMAND, *extra, "-o", str(tmp / "runs")]
    for cwd, side_env in sides.values():  # untimed: the bytecode cache filled (module docstring)
        timed(argv, cwd, side_env)
    for _ in range(repeat):
        for side in order:
            cwd, env = sides[side]
            marks = tmp / f"{variant.replace(' ', '_')}-{side}-{len(runs[side])}.txt"
            env = {**env, "RODCTL_TIMELINE": str(marks)} if side == "after" else env
            t0, wall, cpu = timed(argv, cwd, env)
            runs[side].append((wall, cpu, marks, t0))
    print(f"\nrodctl {' '.join(COMMAND)} ({variant}), load now {os.getloadavg()[0]:.1f}:")
    for side, got in runs.items():
        walls = ", ".join(f"{w:.2f}" for w, *_ in got)
        cpus = ", ".join(f"{c:.2f}" for _, c, *_ in got)
        median = statistics.median(w for w, *_ in got)
        print(f"  {side:<6} wall {walls} s (median {median:.2f}); CPU, all processes {cpus} s")
    best = min(w for w, *_ in runs["after"])
    verdict = "met" if best <= GOAL_S else "NOT met"
    print(f"  goal <= {GOAL_S:.1f} s wall (quiet machine): {verdict} here (wall waits for cores)")
    wall, cpu, marks, t0 = sorted(runs["after"])[len(runs["after"]) // 2]
    print_timeline(read_timeline(marks, t0), wall, cpu)


def print_timeline(lines: list[tuple[str, str, float, float]], wall: float, cpu: float) -> None:
    """The median run's marks per process, and the critical path in brief."""
    print(f"  timeline of the median run (wall {wall:.2f} s, CPU {cpu:.2f} s), s since start:")
    print(f"    {'process':<8} {'event':<34} {'t':>6} {'CPU':>6}")
    for role, event, t, c in lines:
        print(f"    {role:<8} {event:<34} {t:6.2f} {c:6.2f}")
    at = {(role, event): t for role, event, t, _ in lines}
    print("  critical path:")
    for label, a, b in SPANS:
        start = 0.0 if a is None else at.get(a)
        end = at.get(b)
        if start is not None and end is not None:
            print(f"    {label:<44} {end - start:5.2f} s")
    last_cpu = {role: c for role, _e, _t, c in lines}
    cpus = ", ".join(f"{role} {c:.2f}" for role, c in last_cpu.items())
    print(f"  CPU by process at its last mark (s): {cpus} (sum {sum(last_cpu.values()):.2f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2, help="rounds of runs per variant")
    ap.add_argument("--before", metavar="REV", help="also run git revision REV, interleaved")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        before = export(args.before, Path(tempfile.mkdtemp(dir=tmp))) if args.before else None
        for variant, extra in VARIANTS.items():
            compare(variant, extra, args.repeat, tmp, before)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")  # the best of 3: with the cache
        base = min(timed([sys.executable, "-c", "pass"], REPO, env)[2] for _ in range(3))
        print(f"\nimports, CPU s in a fresh interpreter beyond its own start-up ({base:.3f} s):")
        for module in IMPORTS:
            argv = [sys.executable, "-c", f"import {module}"]
            cpu = min(timed(argv, REPO, env)[2] for _ in range(3)) - base
            print(f"  {module:<20} {cpu:6.3f}")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
