"""What of `rodctl train-encoder` reproduces bit for bit under another numeric kernel (issue #18).

Runs a small `train-encoder` (default 2,000 samples, 50 epochs, batch 500) in fresh processes:
1. as this machine runs it;
2. the same again (same machine, same kernels: must be bit-identical);
3. with OpenBLAS forced to another kernel (`OPENBLAS_CORETYPE=Prescott`: numpy/scipy's BLAS, as
   on an older CPU) and torch restricted to its baseline CPU kernels
   (`ATEN_CPU_CAPABILITY=default`: torch's non-AVX2 code, as on a CPU without AVX2).
For each it compares the collected dataset (dataset.npz centerlines), the trained weights
(encoder.npz) and the validation error with run 1, and prints whether each is bit-identical and
otherwise by how much it differs.

Run: .venv/bin/python benchmarks/bench_encoder_repro.py [--samples 2000] [--epochs 50]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def train(out: Path, samples: int, epochs: int, env: dict[str, str]) -> Path:
    cmd = [
        sys.executable,
        "-m",
        "rodctl",
        "train-encoder",
        str(REPO / "configs/default.yaml"),
        "-q",
        "--out",
        str(out),
        "--set",
        f"feature.data.samples={samples}",
        "--set",
        f"feature.data.chunk={max(1, samples // 8)}",
        "--set",
        f"feature.training.epochs={epochs}",
        "--set",
        "feature.training.batch_size=500",
    ]
    res = subprocess.run(
        cmd, capture_output=True, text=True, env={**os.environ, **env}, cwd=REPO, check=True
    )
    return Path(res.stdout.strip().splitlines()[-1])


def compare(a: Path, b: Path) -> dict[str, str]:
    with np.load(a / "dataset.npz") as x, np.load(b / "dataset.npz") as y:
        ca, cb = x["centerlines"], y["centerlines"]
    with np.load(a / "encoder.npz") as x, np.load(b / "encoder.npz") as y:
        wa = {k: x[k] for k in x.files if k.startswith("w/")}
        wb = {k: y[k] for k in y.files if k.startswith("w/")}
    ma = json.loads((a / "metrics.json").read_text())["validation"]["mean_px"]
    mb = json.loads((b / "metrics.json").read_text())["validation"]["mean_px"]

    def same(u: np.ndarray, v: np.ndarray) -> str:
        if u.shape == v.shape and np.array_equal(u, v):
            return "bit-identical"
        return f"differs by up to {np.abs(u.astype(float) - v.astype(float)).max():.3g}"

    weights = [same(wa[k], wb[k]) for k in sorted(wa)]
    wdiff = max(float(np.abs(wa[k].astype(float) - wb[k].astype(float)).max()) for k in wa)
    return {
        "dataset (px)": same(ca, cb),
        "weights": "bit-identical"
        if all(w == "bit-identical" for w in weights)
        else f"differ by up to {wdiff:.3g}",
        "validation mean px": f"{ma:.4f} vs {mb:.4f}",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--epochs", type=int, default=50)
    args = ap.parse_args()
    variants = {
        "same machine again": {},
        "OPENBLAS_CORETYPE=Prescott": {"OPENBLAS_CORETYPE": "Prescott"},
        "ATEN_CPU_CAPABILITY=default": {"ATEN_CPU_CAPABILITY": "default"},
    }
    with tempfile.TemporaryDirectory() as tmp:
        base = train(Path(tmp) / "base", args.samples, args.epochs, {})
        print(f"train-encoder, {args.samples} samples, {args.epochs} epochs, vs a first run:")
        for name, env in variants.items():
            other = train(Path(tmp) / name.replace(" ", "_"), args.samples, args.epochs, env)
            for key, verdict in compare(base, other).items():
                print(f"  {name:<30} {key:<20} {verdict}")


if __name__ == "__main__":
    main()
