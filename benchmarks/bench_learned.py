"""One-step prediction of the learned Jacobian against the online estimators (issue 27).

Why: the learned prior (docs/learned.md) is only worth its training if it predicts the next
feature change better than what the online estimators learn on the way. This collects random
motion as `rodctl train-model` does (configs/yu2023.yaml: the default rod, 4 servoed nodes),
holds out whole walks, fits the model on the rest and scores every estimator on the held-out
walks as the loop would meet them (`rodctl.training.learned.one_step_errors`):
the estimate from what it has seen predicts the next move's feature change, then folds it in.
Prints the mean error per estimator beside the goal: the learned model below the AKF.

    .venv/bin/python benchmarks/bench_learned.py [--samples 3000] [--chunk 300] [--held-out 2]
        [--set KEY=VALUE] [--save model.npz]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rodctl.config import load_config
from rodctl.estimation import AdaptiveKalmanJacobian, BroydenJacobian
from rodctl.estimation.learned import LearnedJacobian
from rodctl.registry import FEATURES, BuildContext, load_plugins
from rodctl.training.learned import (
    collect_walks,
    one_step_errors,
    train_model_from_walks,
)
from rodctl.vision import Camera


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/yu2023.yaml")
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--chunk", type=int, default=300)
    parser.add_argument("--held-out", type=int, default=2, help="walks held out for scoring")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--save", help="also write the fitted model (.npz) here")
    args = parser.parse_args()
    load_plugins()
    sets = [
        "estimator.checkpoint=null",
        f"estimator.data.samples={args.samples}",
        f"estimator.data.chunk={args.chunk}",
        *args.set,
    ]
    cfg = load_config(args.config, sets)
    t0 = time.perf_counter()
    walks = collect_walks(cfg, progress=True)
    collect = time.perf_counter() - t0
    held, train = walks[: args.held_out], walks[args.held_out :]
    model = train_model_from_walks(cfg, train)
    if args.save:
        model.save(args.save)
    feature = FEATURES.build(cfg.feature, BuildContext(points=cfg.camera.points, experiment=cfg))
    camera = Camera(cfg.camera, None)
    est = cfg.estimator
    p, q = model.p, model.q

    def learned(walk, eta):
        return LearnedJacobian(
            p, q, model, camera=camera, home_pose=walk["poses"][0], learning_rate=eta,
            window=est.window,
        )  # fmt: skip

    rows = {
        "AKF (default settings)": lambda w: AdaptiveKalmanJacobian(p, q),
        "Broyden (gamma = 1)": lambda w: BroydenJacobian(p, q),
        "learned, offline only": lambda w: learned(w, 0.0),
        f"learned, eta = {est.learning_rate}, window {est.window}": lambda w: learned(
            w, est.learning_rate
        ),
    }
    ds = [np.diff(feature.encode_batch(w["pixels"]), axis=0) for w in held]
    mean_ds = float(np.mean(np.linalg.norm(np.concatenate(ds), axis=1)))
    print(
        f"{len(train)} training walks ({model.metrics['train_pairs']} moves), {len(held)} "
        f"held out; collected in {collect:.0f} s; mean |ds| {mean_ds:.2f} {feature.units}"
    )
    results = {}
    for name, make in rows.items():
        # the online estimators spend the first q + 1 moves on their probing fit (not scored);
        # the learned model is scored from the same move on
        skip = 0 if name.startswith(("AKF", "Broyden")) else q + 1
        errs = [one_step_errors(make(w), w, feature.encode_batch, skip=skip) for w in held]
        results[name] = float(np.concatenate(errs).mean())
        print(f"  {name:<32} mean one-step error {results[name]:.3f} {feature.units}")
    best = min(v for k, v in results.items() if k.startswith("learned"))
    akf = results["AKF (default settings)"]
    verdict = "met" if best < akf else "NOT met"
    print(f"goal: learned below the AKF: {best:.3f} vs {akf:.3f} -> {verdict}")


if __name__ == "__main__":
    main()
