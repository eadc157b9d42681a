"""How many torch threads train the centerline autoencoder fastest (issue #28).

Why: `feature.training.threads` sets torch's intra-op threads while training. The network is
small (200-128-64-6 and back), so each matrix product is short and threads mostly add
synchronisation; on a busy machine a second thread also waits for a core. This times a few
epochs of the quick encoder (`rodctl train-encoder --quick`: 2,700 training shapes, batches of
500) and of the paper's setup (90,000 shapes, batches of 10,000) with 1, 2, ... threads,
alternating the thread counts so that a change of machine load hits them alike, and prints the
median seconds per epoch beside the goal (the fastest count is the default).

    .venv/bin/python benchmarks/bench_training_threads.py [--threads 1 2] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from rodctl.config import ExperimentConfig
from rodctl.features.auto import QUICK_BATCH, QUICK_SAMPLES
from rodctl.features.synthetic import rod_like_centerlines
from rodctl.training.encoder import fit_autoencoder

SETUPS = {
    "quick (--quick)": (int(QUICK_SAMPLES * 0.9), QUICK_BATCH, 20),
    "paper (default)": (90_000, 10_000, 2),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"CPU cores visible: {os.cpu_count()}; load average {os.getloadavg()[0]:.1f}")
    base = ExperimentConfig().feature
    print(f"default feature.training.threads = {base.training.threads}")
    gen = np.random.default_rng(0)
    for name, (n_train, batch, epochs) in SETUPS.items():
        train = rod_like_centerlines(gen, n_train, 100)
        held = train[:50]
        times: dict[int, list[float]] = {t: [] for t in args.threads}
        for _ in range(args.repeats):
            for threads in args.threads:
                feature = base.model_copy(deep=True)
                feature.training.epochs = epochs
                feature.training.batch_size = batch
                feature.training.threads = threads
                ckpt = fit_autoencoder(train, held, feature, seed=0, fingerprint={}, progress=False)
                # the epochs alone, not the numpy figures computed after them
                times[threads].append(ckpt.metrics["train_time_s"] / epochs)
        medians = {t: float(np.median(v)) for t, v in times.items()}
        best = min(medians, key=medians.get)
        for t, m in medians.items():
            print(
                f"{name:<16} {n_train:>6} shapes, batch {batch:>6}: {t} thread(s) "
                f"{m * 1e3:8.1f} ms/epoch (median of {args.repeats}; "
                f"{'fastest' if t == best else f'{m / medians[best]:.2f}x the fastest'})"
            )
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
