"""Does a run made under one BLAS kernel verify under another? Every shipped config (issue #18).

Goal: every shipped config, run under one OpenBLAS kernel and re-run under another, verifies
bit-identically or within a stated tolerance (1e-9: |a - b| <= 1e-9 max(1, |a|)).

For each single-run config in configs/ (compare and sweep configs excluded) the run is made
twice in fresh processes, under `OPENBLAS_CORETYPE` = the CPU's own kernel and = another one
(Prescott: SSE3 kernels every x86-64 CPU runs), and the two record sequences are compared with
`rodctl.replay.compare_runs`, as `rodctl replay --verify` compares a log with its rerun. Prints
the verdict and the largest deviation per config next to the goal. Needs numpy's BLAS to be
OpenBLAS on x86-64.

Run: .venv/bin/python benchmarks/bench_kernels.py [--configs default hard-bend ...]
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TOLERANCE = 1e-9

_CHILD = """
import pickle, sys
from rodctl.config import load_config
from rodctl.replay import rerun_records
records = rerun_records(load_config(sys.argv[1], []), "kernels")
with open(sys.argv[2], "wb") as f:
    pickle.dump(records, f)
"""


def run_under(config: Path, kernel: str, out: Path) -> list:
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
    subprocess.run(
        [sys.executable, "-c", _CHILD, str(config), str(out)], check=True, env=env, timeout=900
    )
    with open(out, "rb") as f:
        return pickle.load(f)


def main() -> None:
    from threadpoolctl import threadpool_info

    from rodctl.replay import compare_runs

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="*", help="config names (default: every shipped one)")
    ap.add_argument("--other", default="Prescott", help="the other OpenBLAS kernel")
    args = ap.parse_args()
    kernels = [lib.get("architecture") for lib in threadpool_info() if lib["user_api"] == "blas"]
    if not kernels or any(k is None for k in kernels):
        sys.exit("numpy's BLAS is not OpenBLAS here: nothing to compare")
    mine = kernels[0]
    names = args.configs or sorted(
        p.stem
        for p in (REPO / "configs").glob("*.yaml")
        if not p.stem.startswith(("compare", "sweep"))  # not single-run configs
    )
    print(f"kernels: {mine} (this CPU's) vs {args.other}; goal: identical or within {TOLERANCE:g}")
    worst_all = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            cfg = REPO / "configs" / f"{name}.yaml"
            a = run_under(cfg, mine, Path(tmp) / "a.pkl")
            b = run_under(cfg, args.other, Path(tmp) / "b.pkl")
            res = compare_runs(a, b, tolerance=TOLERANCE)
            if res.deviations:
                worst = max(res.deviations, key=lambda d: d.max_scaled)
                need = worst.max_scaled
                dev = (
                    f"needs tolerance {need:.2g} ({worst.field}: {worst.max_abs:.2g} "
                    f"{worst.unit} at step {worst.step})"
                )
                worst_all = max(worst_all, need)
            else:
                dev = "bit-identical"
            fields = ", ".join(d.field for d in res.deviations) or "-"
            print(f"  {name:<18} {len(a):>3} steps  {res.verdict:<16} {dev}")
            print(f"    {'steps, flags, texts agree' if res.numbers_only else res.mismatch}")
            print(f"    fields not bit-identical: {fields}")
    print(
        f"smallest tolerance that verifies every config: {worst_all:.3g} "
        f"(goal: bit-identical or within {TOLERANCE:g}) -> "
        + ("met" if worst_all <= TOLERANCE else "NOT met")
    )


if __name__ == "__main__":
    main()
