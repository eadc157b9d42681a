"""How well an encoder checkpoint reconstructs the shapes of another rod (issue #12).

Why: the encoder fingerprint decides whether a checkpoint may be used for a config. Gravity and
table friction change the shapes the camera sees; this measures by how much, so the rule
(`rodctl/features/autoencoder.py`, `_rod_fingerprint`) rests on numbers. It collects fresh
shapes of each scenario exactly as `rodctl train-encoder` does (seeded random gripper walks,
camera extraction) and prints the checkpoint's reconstruction error next to the goal of the
packaged encoder (<= 1 px mean).

    .venv/bin/python benchmarks/bench_encoder_fit.py [--samples 300] [--checkpoint FILE]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rodctl.config import load_config
from rodctl.features.autoencoder import DEFAULT_CHECKPOINT, AutoencoderFeatureMap, EncoderCheckpoint
from rodctl.training.collection import collect_chunk

SCENARIOS = {
    "weightless (default)": [],
    "table, mu = 0.5": ["rod.table_friction=0.5"],
    "gravity, default rod (qL^3/EI = 19)": ["rod.gravity=[0,-9.81]"],
    "heavy-rod.yaml silicone tube (85)": [
        "rod.gravity=[0,-9.81]",
        "rod.material.name=silicone_tube",
    ],
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--checkpoint", default=str(DEFAULT_CHECKPOINT))
    parser.add_argument("--seed", type=int, default=12)
    args = parser.parse_args()
    feature = AutoencoderFeatureMap(EncoderCheckpoint.load(args.checkpoint), args.checkpoint)
    print(f"checkpoint {args.checkpoint}; {args.samples} fresh shapes per scenario")
    print(f"{'scenario':<40} {'mean px':>8} {'p95 px':>7} {'worst shape':>11} {'s':>5}  goal")
    for name, overrides in SCENARIOS.items():
        cfg = load_config("configs/default.yaml", overrides)
        t0 = time.perf_counter()
        data = collect_chunk(cfg.model_dump_json(), args.samples, np.random.SeedSequence(args.seed))
        err = feature.reconstruction_error(np.asarray(data["centerlines"], dtype=float))
        print(
            f"{name:<40} {err.mean():>8.2f} {np.percentile(err, 95):>7.2f} "
            f"{err.mean(axis=1).max():>11.2f} {time.perf_counter() - t0:>5.0f}  <= 1 px mean"
        )


if __name__ == "__main__":
    main()
