"""Training the centerline autoencoder, and `train_encoder`, the body of `rodctl train-encoder`.

(Moved from `rodctl/features/training.py`: the feature stage loads a trained encoder and never
imports its training.)

The paper (section VI-A) trains with Adam at an initial learning rate of 1e-3, batches of 10,000
and an MSE reconstruction loss. With batches that large one epoch over 100,000 shapes is only ten
optimiser steps, so the number of epochs decides the quality; "initial" learning rate suggests a
schedule, and ours is a cosine decay to `lr_final` (a config value), which lets the last epochs
settle the sub-pixel detail.

Reported errors are in pixels: the mean over shapes and points of the Euclidean distance between
each input point and its reconstruction ("mean px"), plus the RMS and the worst shape's mean. The
validation set is made of whole collection walks (chunks) held out from training, because
consecutive shapes of one walk are near-duplicates and would flatter a random split.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from rodctl.config import ExperimentConfig, dump_config
from rodctl.config.loading import apply_override, parse_override
from rodctl.display import task_progress
from rodctl.errors import RunFailed, UserError
from rodctl.features import auto as quick
from rodctl.features.autoencoder import (
    AutoencoderNet,
    EncoderCheckpoint,
    architecture_of,
    encoder_fingerprint,
    require_torch,
)
from rodctl.features.autoencoder_config import AutoencoderFeatureConfig, EncoderTrainingConfig
from rodctl.notices import say_once
from rodctl.runs import RunDir, rng, torch_seed, write_json_atomic
from rodctl.training.collection import CenterlineDataset, CollectionFailed, collect_dataset


@contextmanager
def private_compile_cache() -> Iterator[None]:
    """torch.optim imports torch._dynamo, which makes its compile cache folder
    (`torchinductor_<user>`) in the system temp folder at import, although nothing is compiled
    here: point it into a temporary folder of our own for the duration, and remove that.
    A `TORCHINDUCTOR_CACHE_DIR` the user set is left alone."""
    if "TORCHINDUCTOR_CACHE_DIR" in os.environ:
        yield
        return
    folder = tempfile.mkdtemp(prefix="rodctl-torch-")
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = folder
    try:
        yield
    finally:
        if os.environ.get("TORCHINDUCTOR_CACHE_DIR") == folder:
            del os.environ["TORCHINDUCTOR_CACHE_DIR"]
        shutil.rmtree(folder, ignore_errors=True)


def pixel_errors(recon: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Reconstruction figures in pixels.

    Args:
        recon: (B, N, 2) reconstructed centerlines.
        truth: (B, N, 2) input centerlines.

    Returns:
        {"mean_px", "rms_px", "p95_px" (95th percentile of point errors), "worst_shape_mean_px"}.
    """
    d = np.linalg.norm(recon - truth, axis=-1)  # (B, N)
    return {
        "mean_px": float(d.mean()),
        "rms_px": float(np.sqrt((d**2).mean())),
        "p95_px": float(np.percentile(d, 95)),
        "worst_shape_mean_px": float(d.mean(axis=1).max()),
    }


def fit_autoencoder(
    train: np.ndarray,
    validation: np.ndarray,
    feature: AutoencoderFeatureConfig,
    *,
    seed: int,
    fingerprint: dict[str, Any],
    config_yaml: str = "",
    progress: bool = True,
) -> EncoderCheckpoint:
    """Train the autoencoder of `feature` on pixel centerlines.

    Args:
        train: (B, N, 2) training centerlines, pixels.
        validation: (V, N, 2) held-out centerlines, pixels (V may be 0).
        feature: architecture and training settings.
        seed: the experiment seed; torch is seeded with `rodctl.runs.torch_seed(seed)`.
        fingerprint: recorded in the checkpoint (see `encoder_fingerprint`).
        config_yaml: the resolved config, recorded in the checkpoint.
        progress: show a rich progress bar.

    Returns:
        The trained checkpoint; `metrics` holds train/validation pixel errors, the loss curve
        (every epoch) and the training time.
    """
    tcfg: EncoderTrainingConfig = feature.training
    n_train, points = train.shape[0], train.shape[1]
    if n_train < 2:
        raise UserError(f"training needs at least 2 centerlines, got {n_train}")
    flat = train.reshape(n_train, -1).astype(np.float64)
    mean = flat.mean(axis=0)  # (2N,)
    scale = float(np.sqrt(((flat - mean) ** 2).mean()))  # pooled std, one number (module doc)
    if not scale > 0.0:
        raise UserError("training centerlines are all identical; nothing to learn")

    torch = require_torch("training an encoder")
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(tcfg.threads)
    try:
        gen = torch.Generator().manual_seed(torch_seed(seed))
        torch.manual_seed(torch_seed(seed))  # nn.Linear init draws from the default generator
        net = AutoencoderNet(2 * points, list(feature.hidden), feature.latent_dim)
        x = torch.as_tensor((flat - mean) / scale, dtype=torch.float32)
        with private_compile_cache():
            opt = torch.optim.Adam(net.parameters(), lr=tcfg.lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(
            opt, T_max=tcfg.epochs, eta_min=tcfg.lr_final
        )
        batch = min(tcfg.batch_size, n_train)
        losses: list[float] = []
        t0 = time.perf_counter()
        with task_progress("training", tcfg.epochs, progress, lines_unit="epochs") as advance:
            for _epoch in range(tcfg.epochs):
                order = torch.randperm(n_train, generator=gen)
                total = 0.0
                for start in range(0, n_train, batch):
                    xb = x[order[start : start + batch]]
                    loss = torch.mean((net(xb) - xb) ** 2)
                    opt.zero_grad(set_to_none=True)
                    loss.backward()
                    opt.step()
                    total += float(loss.detach()) * xb.shape[0]
                sched.step()
                # per-coordinate MSE in normalised units -> RMS point error in pixels
                losses.append(float(np.sqrt(2.0 * total / n_train) * scale))
                advance(f"rms {losses[-1]:.3f} px")
        train_time = time.perf_counter() - t0
        net.eval()
        state = {k: v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()}
    finally:
        torch.set_num_threads(previous_threads)

    ckpt = EncoderCheckpoint(
        state_dict=state,
        architecture=architecture_of(feature, points),
        input_mean=mean,
        input_scale=scale,
        latent_scale=np.ones(feature.latent_dim),
        fingerprint=fingerprint,
        config_yaml=config_yaml,
    )
    fmap = ckpt.feature_map()
    z = fmap.encode_batch(train)
    ckpt.latent_scale = np.maximum(z.std(axis=0), 1e-12)
    metrics: dict[str, Any] = {
        "train": pixel_errors(fmap.decode(z), train),
        "validation": (
            pixel_errors(fmap.decode(fmap.encode_batch(validation)), validation)
            if len(validation)
            else None
        ),
        "train_samples": int(n_train),
        "validation_samples": int(len(validation)),
        "epochs": tcfg.epochs,
        "batch_size": batch,
        "train_time_s": train_time,
        "threads": tcfg.threads,
        "loss_rms_px": losses,
    }
    ckpt.metrics = metrics
    return ckpt


def split_by_chunk(
    dataset: CenterlineDataset, fraction: float, gen: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Hold out whole collection walks: (train_indices, validation_indices).

    At least one chunk is held out when there are two or more.
    """
    chunks = np.unique(dataset.chunk)
    n_val = int(round(fraction * len(chunks)))
    n_val = min(max(n_val, 1 if len(chunks) > 1 else 0), len(chunks) - 1)
    held = gen.choice(chunks, size=n_val, replace=False) if n_val else np.empty(0, dtype=int)
    is_val = np.isin(dataset.chunk, held)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


def train_encoder(
    cfg: ExperimentConfig,
    run: RunDir,
    *,
    dataset: Path | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Collect (or load) centerlines, train the autoencoder, write its checkpoint and metrics.

    Writes into `run.path`: `dataset.npz` (the collected centerlines, unless `dataset` names an
    existing one), `encoder.npz` and `encoder.pt` (the same checkpoint for numpy and for torch)
    and `metrics.json`.

    Args:
        cfg: the experiment config; `cfg.feature` must be an autoencoder.
        run: the run directory.
        dataset: a `dataset.npz` from an earlier run to train on instead of collecting; it must
            have been collected for the same rod, camera and N.
        progress: show progress bars.

    Returns:
        The metrics written to metrics.json (pixel errors, sizes, times, file paths).

    Raises:
        UserError: the feature is not an autoencoder, or `dataset` is unreadable or was collected
            for another setup.
        RunFailed: a collection walk gave too few usable centerlines (`CollectionFailed`).
    """
    if not isinstance(cfg.feature, AutoencoderFeatureConfig):
        raise UserError(
            f"train-encoder trains the autoencoder feature, but feature.type is "
            f"{cfg.feature.type!r}; set feature.type=autoencoder"
        )
    fingerprint = encoder_fingerprint(cfg)
    data, dataset_path, collect_time = _dataset(cfg, run, dataset, fingerprint, progress)
    collected = dataset is None
    train_idx, val_idx = split_by_chunk(
        data, cfg.feature.training.validation_fraction, rng(cfg.seed, "data")
    )
    if len(val_idx) == 0:
        _warn_no_validation(len(data))
    ckpt = fit_autoencoder(
        data.centerlines[train_idx].astype(np.float64),
        data.centerlines[val_idx].astype(np.float64),
        cfg.feature,
        seed=cfg.seed,
        fingerprint=fingerprint,
        config_yaml=dump_config(cfg),
        progress=progress,
    )
    ckpt.metrics.update(
        dataset=str(dataset_path),
        dataset_collected=collected,
        collection_time_s=collect_time if collected else None,
        collection_rate_per_s=(len(data) / collect_time) if collected and collect_time else None,
        collection_attempts=data.attempts if collected else None,
    )
    return _write_checkpoint(ckpt, run)


def _warn_no_validation(samples: int) -> None:
    """A dataset of one collection walk: nothing whole to hold out (`split_by_chunk`)."""
    say_once(
        "encoder-no-validation",
        f"warning: the dataset holds {samples} centerlines from one collection walk, so no "
        "walk is held out: metrics.json's validation errors are null. Collect more "
        "(feature.data.samples above feature.data.chunk) for a held-out error.",
    )


def _dataset(
    cfg: ExperimentConfig,
    run: RunDir,
    dataset: Path | None,
    fingerprint: dict[str, Any],
    progress: bool,
) -> tuple[CenterlineDataset, Path, float]:
    """(the centerlines, where they are, the seconds it took): collected into the run's
    `dataset.npz` when `dataset` is None, else loaded from it (checked against `fingerprint`)."""
    t0 = time.perf_counter()
    if dataset is None:
        dataset_path = run.path / "dataset.npz"
        # Interrupted, the chunks collected so far are kept there (reuse with --dataset).
        try:
            data = collect_dataset(
                cfg, progress=progress, keep_partial=dataset_path, fingerprint=fingerprint
            )
        except CollectionFailed as exc:  # the system failed: one line, exit 1, the run kept
            raise RunFailed(f"train-encoder ({run.path}): {exc}") from None
        data.save(dataset_path, fingerprint=fingerprint)
    else:
        dataset_path = Path(dataset)
        data = CenterlineDataset.load(dataset_path, expected=fingerprint)
    return data, dataset_path, time.perf_counter() - t0


def _write_checkpoint(ckpt: EncoderCheckpoint, run: RunDir) -> dict[str, Any]:
    """Write the checkpoint and metrics.json into the run folder; the metrics written."""
    # The same checkpoint twice: encoder.npz for experiments (loads without torch) and
    # encoder.pt for torch tools (module doc of rodctl.features.autoencoder).
    checkpoint_path = run.path / "encoder.npz"
    ckpt.save(checkpoint_path)
    ckpt.save(run.path / "encoder.pt")
    metrics = {k: v for k, v in ckpt.metrics.items() if k != "loss_rms_px"}
    metrics["final_loss_rms_px"] = ckpt.metrics["loss_rms_px"][-1]
    metrics["checkpoint"] = str(checkpoint_path)
    metrics["checkpoint_torch"] = str(run.path / "encoder.pt")
    write_json_atomic(run.path / "metrics.json", metrics)
    return metrics


def quick_overrides(cfg: ExperimentConfig, keep: frozenset[str] = frozenset()) -> list[str]:
    """The quick encoder's data and training sizes as `--set` overrides for `cfg`
    (`rodctl.features.auto`: QUICK_SAMPLES, QUICK_EPOCHS, batches of at most QUICK_BATCH; they
    also name its cache file), but for the keys in `keep` (the user's own `--set`s, whose
    values `cfg` holds); none when the feature is not an autoencoder."""
    if not isinstance(cfg.feature, AutoencoderFeatureConfig):
        return []  # nothing to shrink; train_encoder says what is wrong
    data, training = cfg.feature.data, cfg.feature.training
    samples = data.samples if "feature.data.samples" in keep else quick.QUICK_SAMPLES
    sizes = {
        "feature.data.samples": samples,
        "feature.data.chunk": min(data.chunk, max(1, samples // 6)),  # six walks or more
        "feature.training.epochs": quick.QUICK_EPOCHS,
        "feature.training.batch_size": min(training.batch_size, quick.QUICK_BATCH),
    }
    return [f"{key}={value}" for key, value in sizes.items() if key not in keep]


def quick_config(cfg: ExperimentConfig) -> ExperimentConfig:
    """`cfg` with the quick encoder's data and training sizes (`quick_overrides`)."""
    data = cfg.model_dump(mode="json")
    for item in quick_overrides(cfg):
        apply_override(data, *parse_override(item), item)
    return ExperimentConfig.model_validate(data)


def train_checkpoint(cfg: ExperimentConfig, *, progress: bool = False) -> EncoderCheckpoint:
    """Collect `cfg.feature.data.samples` centerlines and train on them; nothing is written.

    The same steps as `train_encoder` (chunk-wise validation split, the config's seed), for
    callers that keep the checkpoint themselves (`feature.checkpoint: auto`).
    """
    if not isinstance(cfg.feature, AutoencoderFeatureConfig):
        raise UserError(f"feature.type is {cfg.feature.type!r}, not 'autoencoder'")
    data = collect_dataset(cfg, progress=progress)
    train_idx, val_idx = split_by_chunk(
        data, cfg.feature.training.validation_fraction, rng(cfg.seed, "data")
    )
    return fit_autoencoder(
        data.centerlines[train_idx].astype(np.float64),
        data.centerlines[val_idx].astype(np.float64),
        cfg.feature,
        seed=cfg.seed,
        fingerprint=encoder_fingerprint(cfg),
        config_yaml=dump_config(cfg),
        progress=progress,
    )
