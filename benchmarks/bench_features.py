"""Benchmark of the feature stage: data-collection rate, autoencoder training time, encode latency.

Prints figures; asserts nothing (speed goals are read by people, not by tests). Goals from the
issue: train the full 100k-sample setup in <= 5 minutes on 2 CPU cores; encode one centerline in
<= 100 us.

    .venv/bin/python benchmarks/bench_features.py                 # quick: ~1-2 minutes
    .venv/bin/python benchmarks/bench_features.py --full-training # also trains the default setup
                                                                  # end to end (minutes)

Training time is measured on synthetic rod shapes of the right size (the cost of an epoch does
not depend on what the shapes look like). Without --full-training it times a few epochs over the
default 100k samples and extrapolates to the default epoch count, and says so.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from rodctl.config import ExperimentConfig
from rodctl.features import BezierFeatureMap, FourierFeatureMap, NodesFeatureMap
from rodctl.features.autoencoder import torch_encode
from rodctl.features.synthetic import rod_like_centerlines
from rodctl.training.collection import collect_dataset
from rodctl.training.encoder import fit_autoencoder


def per_call_us(fn, arg, repeat: int = 2000) -> tuple[float, float]:
    """(median, 10th percentile) wall time of fn(arg) in microseconds, over batches of 50."""
    for _ in range(50):
        fn(arg)
    times = []
    for _ in range(repeat // 50):
        t = time.perf_counter()
        for _ in range(50):
            fn(arg)
        times.append((time.perf_counter() - t) / 50 * 1e6)
    return float(np.median(times)), float(np.percentile(times, 10))


def bench_collection(samples: int, workers: int) -> None:
    cfg = ExperimentConfig.model_validate(
        {
            "feature": {
                "data": {
                    "samples": samples,
                    "chunk": max(1, samples // (2 * workers)),
                    "workers": workers,
                }
            }
        }
    )
    t = time.perf_counter()
    data = collect_dataset(cfg, progress=False)
    dt = time.perf_counter() - t
    print(
        f"collection  workers={workers}: {len(data)} shapes in {dt:.1f} s = "
        f"{len(data) / dt:.1f} shapes/s ({data.attempts} control steps; process start included)"
    )


def bench_training(full: bool, epochs_probe: int) -> None:
    cfg = ExperimentConfig()
    feature = cfg.feature
    n = feature.data.samples
    n_train = int(round(n * (1 - feature.training.validation_fraction)))
    gen = np.random.default_rng(0)
    train = rod_like_centerlines(gen, n_train, cfg.camera.points)
    held = rod_like_centerlines(gen, n - n_train, cfg.camera.points)
    if full:
        t = time.perf_counter()
        ckpt = fit_autoencoder(train, held, feature, seed=0, fingerprint={}, progress=True)
        dt = time.perf_counter() - t
        print(
            f"training    default setup ({n_train} train shapes, {feature.training.epochs} epochs,"
            f" batch {feature.training.batch_size}, {feature.training.threads} threads): "
            f"{dt:.0f} s measured; validation mean {ckpt.metrics['validation']['mean_px']:.3f} px "
            "(synthetic shapes)"
        )
        return
    probe = feature.model_copy(deep=True)
    probe.training.epochs = epochs_probe
    t = time.perf_counter()
    fit_autoencoder(train, held[:100], probe, seed=0, fingerprint={}, progress=False)
    dt = time.perf_counter() - t
    per_epoch = dt / epochs_probe
    print(
        f"training    {per_epoch:.2f} s/epoch over {n_train} shapes (batch "
        f"{feature.training.batch_size}, {feature.training.threads} threads) -> default "
        f"{feature.training.epochs} epochs ~ {per_epoch * feature.training.epochs:.0f} s "
        f"(EXTRAPOLATED from {epochs_probe} epochs; run --full-training to measure)"
    )


def bench_encode() -> None:
    from rodctl.features import make_feature_map

    cfg = ExperimentConfig()
    c = rod_like_centerlines(np.random.default_rng(3), 1, cfg.camera.points)[0]
    ae = make_feature_map(cfg.feature, points=cfg.camera.points)
    med, p10 = per_call_us(ae.encode, c)
    print(f"encode      autoencoder numpy (packaged): median {med:.1f} us, p10 {p10:.1f} us")
    ckpt = ae.checkpoint  # type: ignore[attr-defined]
    net = ckpt.network()
    import torch

    x = torch.as_tensor(
        ((c.reshape(-1) - ckpt.input_mean) / ckpt.input_scale)[None], dtype=torch.float32
    )

    def torch_call(arg):
        with torch.no_grad():
            return net.encoder(arg)

    med_t, p10_t = per_call_us(torch_call, x, repeat=1000)
    print(
        f"encode      autoencoder torch (encoder only, no conversion): median {med_t:.1f} us, "
        f"p10 {p10_t:.1f} us"
    )
    gap = np.abs(ae.encode(c) - torch_encode(ckpt, c[None])[0]).max()
    print(f"            numpy vs torch latent max difference: {gap:.2e}")
    for fmap in (
        BezierFeatureMap(4, 100),
        FourierFeatureMap(4, 100),
        NodesFeatureMap([1 / 3, 2 / 3, 1.0], 100),
    ):
        med, p10 = per_call_us(fmap.encode, c)
        print(f"encode      {fmap.kind:<11}: median {med:.1f} us, p10 {p10:.1f} us")
    batch = rod_like_centerlines(np.random.default_rng(4), 10_000, cfg.camera.points)
    t = time.perf_counter()
    ae.encode_batch(batch)
    print(f"encode      autoencoder batch of 10,000: {(time.perf_counter() - t) * 1e3:.0f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--collect", type=int, default=200, help="shapes to collect (0: skip)")
    parser.add_argument("--workers", type=int, default=2, help="collection processes")
    parser.add_argument("--epochs-probe", type=int, default=5)
    parser.add_argument("--full-training", action="store_true")
    parser.add_argument("--skip-training", action="store_true")
    args = parser.parse_args()
    print(
        f"CPU cores visible: {os.cpu_count()}; timings are wall clock and noisy on a shared machine"
    )
    bench_encode()
    if args.collect:
        bench_collection(args.collect, 1)
        if args.workers > 1:
            bench_collection(args.collect, args.workers)
    if not args.skip_training:
        bench_training(args.full_training, args.epochs_probe)


if __name__ == "__main__":
    main()
