"""Benchmark of `rodctl compare`: run the comparison and print its wall time and table.

    .venv/bin/python benchmarks/bench_compare.py                 # configs/compare.yaml, 2 workers
    .venv/bin/python benchmarks/bench_compare.py --tune          # the tuning grid (seed 1)
    .venv/bin/python benchmarks/bench_compare.py --set targets.count=20

The paper's feature is the autoencoder, whose packaged checkpoint (rodctl/assets/encoder.pt) may
not exist yet. Then the paper's pipeline and the two ablations run on a stand-in feature,
`--stand-in` (default: the Bézier feature Ma et al. use, so that the paper-vs-Ma difference is
estimation + control alone), and the script says so loudly.

`--tune` runs every candidate setting of every method on a tuning target set drawn from a
different seed (1) than the benchmark's (0), and prints the ranking (success rate, then median
steps). Each method gets a grid of 6-8 settings of its own knobs: the same effort for each.
The ablations are not tuned: they take their parts' settings from the tuned methods.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rodctl.bench.compare import run_compare  # noqa: E402
from rodctl.features.autoencoder import DEFAULT_CHECKPOINT  # noqa: E402

PAPER_STAGES = ("paper", "akf-pinv", "broyden-mfac")


def tuning_config(stand_in: str) -> dict:
    """One compare config holding every candidate setting as its own method."""
    methods: dict[str, dict] = {}
    for est, (gain, limit) in itertools.product(
        ("broyden", "windowed_ls"), itertools.product((0.3, 0.5, 0.8), (10.0, 50.0))
    ):
        methods[f"ma-{est}-g{gain}-l{limit:g}"] = {
            "feature": {"type": "bezier", "degree": 4},
            "estimator": {"type": est},
            "controller": {"type": "pinv", "gain": gain, "error_limit": limit},
        }
    for servoed, gain, rth in itertools.product(
        ([0.25, 0.5, 0.75], [0.3, 0.6, 0.9]), (0.3, 0.6), (1.0, 100.0)
    ):
        tag = "-".join(f"{s:g}" for s in servoed)
        methods[f"agh-s{tag}-g{gain}-r{rth:g}"] = {
            "feature": {"type": "nodes", "positions": servoed},
            "estimator": {"type": "offline", "servoed": servoed},
            "controller": {"type": "qp", "gain": gain, "r_weights": [1.0, 1.0, rth]},
        }
    weights = {
        "w0": [0.55, 1e-4, 0.2, 0.05, 1e-4, 0.0998, 0.1],  # the default
        "wfast": [0.7, 1e-4, 0.1, 0.05, 1e-4, 0.0498, 0.1],
        "wsmooth": [0.4, 1e-4, 0.3, 0.1, 1e-4, 0.0998, 0.1],
    }
    for (wname, w), p0 in itertools.product(weights.items(), (10.0, 1000.0)):
        methods[f"paper-{wname}-p{p0:g}"] = {
            "feature": {"type": stand_in},
            "estimator": {"type": "akf", "p0": p0},
            "controller": {"type": "mfac", "weights": w},
        }
    return {
        "name": "compare-tune",
        "seed": 1,
        "base": {"logging": {"mcap": False, "rerun": False, "figures": False}},
        "methods": methods,
        "targets": {"count": 12, "min_offset": 0.1, "max_offset": 1.0},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(REPO / "configs" / "compare.yaml"))
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--out", default=str(REPO / "runs"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--stand-in", default="bezier", help="feature used if encoder.pt is missing")
    ap.add_argument("--tune", action="store_true", help="run the tuning grid (seed 1)")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args()

    overrides = list(args.overrides)
    have_encoder = DEFAULT_CHECKPOINT.exists()
    if args.tune:
        tmp = Path(tempfile.mkdtemp()) / "compare-tune.yaml"
        tmp.write_text(yaml.safe_dump(tuning_config(args.stand_in), sort_keys=False))
        config = str(tmp)
    else:
        config = args.config
        if not have_encoder:
            cfg = yaml.safe_load(Path(config).read_text())
            for name in PAPER_STAGES:
                feat = cfg.get("methods", {}).get(name, {}).get("feature", {})
                if feat.get("type") == "autoencoder":
                    overrides.append(f"methods.{name}.feature={{type: {args.stand_in}}}")
    if not have_encoder:
        print(
            f"NOTE: {DEFAULT_CHECKPOINT} is missing: the paper's pipeline and its ablations run "
            f"on the stand-in feature '{args.stand_in}', not the autoencoder.",
            file=sys.stderr,
        )
    t0 = time.perf_counter()
    out = run_compare(config, overrides, args.out, progress=not args.quiet, workers=args.workers)
    wall = time.perf_counter() - t0
    data = json.loads((out / "results.json").read_text())
    print(
        f"wall time: {wall:.1f} s with {args.workers} workers "
        f"({len(data['episodes'])} episodes, {wall * args.workers / len(data['episodes']):.2f}"
        " worker-s per episode; shared 2-core machine, timings are noisy)"
    )
    ranking = sorted(
        data["summary"]["methods"].items(),
        key=lambda kv: (-kv[1]["success_rate"], kv[1]["steps_median"] or 1e9),
    )
    print(f"{'method':40s} success  steps(median)  paired  smoothness")
    for name, s in ranking:
        print(
            f"{name:40s} {100 * s['success_rate']:6.1f}%  {s['steps_median']!s:>12}  "
            f"{s['paired_steps_median']!s:>6}  {s['smoothness_median']}"
        )
    print(out)


if __name__ == "__main__":
    main()
