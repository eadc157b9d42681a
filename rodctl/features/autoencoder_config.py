"""Config of the paper's feature (section VI-A), an autoencoder latent, and its registration.

Kept apart from `autoencoder.py`, which knows no config model: this module imports it (and
`auto.py`, the cache of `checkpoint: auto`), never the other way round, and neither imports torch
or the training code (`rodctl.training`). The autoencoder config also carries the settings of
`rodctl train-encoder`: how the training centerlines are collected through the simulator and
camera, and how the network is trained. Those settings never change what a trained checkpoint
*is* for (the fingerprint ignores them); the architecture settings do.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator

from rodctl.config.base import StrictModel
from rodctl.errors import UserError
from rodctl.features.auto import cached_checkpoint
from rodctl.features.autoencoder import (
    DEFAULT_CHECKPOINT,
    EncoderCheckpoint,
    architecture_of,
    encoder_fingerprint,
)
from rodctl.notices import say_once
from rodctl.registry import FEATURES, BuildContext


class EncoderDataConfig(StrictModel):
    """How `rodctl train-encoder` collects training centerlines (docs/method.md §7).

    The gripper walks, one control step (at most `rod.max_step` per axis) at a time, towards
    gripper poses drawn uniformly from the workspace (`rod.workspace`, reach and angle limits
    included), a new one each time it arrives. Every settled step is rendered and extracted by the
    camera pipeline; steps that do not settle, or whose extraction is not ok, are skipped. The
    dataset is made of independently seeded walks ("chunks") that start at the home pose, so it
    does not depend on the number of worker processes.
    """

    samples: int = Field(
        100_000, le=10_000_000, ge=2, description="Centerlines to collect (the paper used 100,000)."
    )
    chunk: int = Field(
        500,
        le=1_000_000,
        ge=1,
        description="Samples per independently seeded walk; also the train/validation split unit.",
    )
    workers: int = Field(2, le=256, ge=1, description="Collection processes (1 = in-process).")


class EncoderTrainingConfig(StrictModel):
    """How the autoencoder is trained (paper section VI-A: Adam, lr 1e-3, batch 10,000, MSE)."""

    epochs: int = Field(
        800,
        le=1_000_000,
        ge=1,
        description="Passes over the training set. The paper gives none; on 100k collected "
        "shapes 300 epochs (2,700 Adam steps at batch 10,000) left 1.05 px, 800 reach 0.62 px "
        "in 226 s on 2 cores.",
    )
    batch_size: int = Field(
        10_000, le=10_000_000, ge=1, description="Mini-batch size (the paper: 10,000)."
    )
    lr: float = Field(
        1e-3, le=10.0, gt=0.0, description="Initial Adam learning rate (the paper: 1e-3)."
    )
    lr_final: float = Field(
        1e-5,
        le=10.0,
        ge=0.0,
        description="Learning rate reached at the last epoch by cosine decay (ours; paper silent).",
    )
    validation_fraction: float = Field(
        0.1,
        gt=0.0,
        lt=1.0,
        description="Share of the collected walks held out for validation.",
    )
    threads: int = Field(
        1,
        le=256,
        ge=1,
        description="torch intra-op threads while training. 1 by measurement: the network is "
        "small, and a second thread was 14x slower per epoch on a busy 2-core machine "
        "(benchmarks/bench_training_threads.py, docs/install.md).",
    )


class AutoencoderFeatureConfig(StrictModel):
    """The paper's feature (section VI-A): an autoencoder latent of the N-point centerline."""

    type: Literal["autoencoder"] = "autoencoder"
    latent_dim: int = Field(6, le=1024, ge=1, description="Latent dimension p.")
    hidden: list[Annotated[int, Field(le=65_536)]] = Field(
        [128, 64],
        min_length=1,
        description="Encoder hidden layer widths (ReLU); the decoder mirrors them.",
    )
    checkpoint: str | None = Field(
        None,
        description="Trained encoder (encoder.npz, or encoder.pt which needs torch to load). "
        "None: the default packaged in rodctl/assets/ (the default rod and camera only). "
        "'auto': a quick encoder for this rod and camera (3,000 samples, 300 epochs, about 20 s), "
        "trained on first use and cached in $XDG_CACHE_HOME/rodctl/encoders.",
    )
    other_setup: Literal["refuse", "accept"] = Field(
        "refuse",
        description="A checkpoint trained for another rod or camera (its fingerprint differs "
        "from this config's): 'refuse' it, naming the config keys that differ (exit 2), or "
        "'accept' it for a transfer experiment (the differences are printed once on stderr).",
    )
    data: EncoderDataConfig = Field(
        EncoderDataConfig(),
        description="How `rodctl train-encoder` collects centerlines (ignored when encoding).",
    )
    training: EncoderTrainingConfig = Field(
        EncoderTrainingConfig(),
        description="How `rodctl train-encoder` trains the network (ignored when encoding).",
    )

    @field_validator("hidden")
    @classmethod
    def _positive_widths(cls, value: list[int]) -> list[int]:
        if any(w < 1 for w in value):
            raise ValueError(f"hidden layer widths must be >= 1, got {value}")
        return value


def load_autoencoder(cfg: AutoencoderFeatureConfig, *, points: int, experiment=None):
    """Load the checkpoint `cfg.checkpoint` (None: the packaged default) and check it fits.

    Args:
        cfg: the autoencoder feature config.
        points: N, the centerline points the experiment extracts.
        experiment: the whole config; when given, the checkpoint's fingerprint (rod, camera, N,
            architecture) must match it, otherwise only N and the architecture are checked.

    Returns:
        The `AutoencoderFeatureMap` of the checkpoint.

    Raises:
        UserError: the file is missing or corrupt, or was trained for another setup; the message
            names the file and each mismatch.
    """
    if cfg.checkpoint == "auto":
        if experiment is None:
            raise UserError("feature.checkpoint: 'auto' needs the whole experiment config")
        path = cached_checkpoint(experiment)  # trained before by the command (module doc)
    else:
        path = _resolve(cfg.checkpoint) if cfg.checkpoint is not None else DEFAULT_CHECKPOINT
    ckpt = EncoderCheckpoint.load(path)
    if experiment is not None:
        expected = encoder_fingerprint(experiment)
    else:
        expected = {
            **ckpt.fingerprint,
            "points": points,
            "architecture": architecture_of(cfg, points),
        }
    if cfg.other_setup == "accept":
        # Another rod or camera is a transfer experiment; another N or network cannot run.
        shape = {k: expected.get(k) for k in ("points", "architecture")}
        ckpt.check_compatible({**ckpt.fingerprint, **shape}, str(path), experiment)
        _say_transfer(path, ckpt.mismatches(expected, experiment))
    else:
        ckpt.check_compatible(expected, str(path), experiment)
    return ckpt.feature_map(source=str(path))


def _say_transfer(path: Path, lines: list[str]) -> None:
    """Say once per run that an encoder runs on a set-up it was not trained for
    (`rodctl.notices`: not again in each worker process of a compare)."""
    if not lines:
        return
    say_once(
        f"feature transfer {path}: {lines}",  # one checkpoint may go to several set-ups
        f"feature.other_setup=accept: {path} was trained for another set-up:\n  "
        + "\n  ".join(lines),
    )


def _resolve(checkpoint: str) -> Path:
    """A relative path is looked up from the working folder, then from the folder that holds
    the rodctl package (so `rodctl/assets/...` in a shipped config works from anywhere)."""
    path = Path(checkpoint)
    if path.is_absolute() or path.exists():
        return path
    packaged = Path(__file__).resolve().parents[2] / path
    return packaged if packaged.exists() else path


@FEATURES.register(AutoencoderFeatureConfig)
def _build(cfg: AutoencoderFeatureConfig, ctx: BuildContext):
    return load_autoencoder(cfg, points=ctx.points, experiment=ctx.experiment)
