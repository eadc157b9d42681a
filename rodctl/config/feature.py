"""Config of the shape feature s = f_s(c): one union member per FeatureMap, keyed by `type`.

Owned by `rodctl/features/`. The autoencoder (the paper's feature, section VI-A) also carries the
settings of `rodctl train-encoder`: how the training centerlines are collected through the
simulator and camera, and how the network is trained. Those settings never change what a trained
checkpoint *is* for (the fingerprint ignores them); the architecture settings do.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator

from rodctl.config.base import StrictModel


class EncoderDataConfig(StrictModel):
    """How `rodctl train-encoder` collects training centerlines (method-notes section 3).

    The gripper walks, one control step (at most `rod.max_step` per axis) at a time, towards
    gripper poses drawn uniformly from the workspace (`rod.workspace`, reach and angle limits
    included), a new one each time it arrives. Every settled step is rendered and extracted by the
    camera pipeline; steps that do not settle, or whose extraction is not ok, are skipped. The
    dataset is made of independently seeded walks ("chunks") that start at the home pose, so it
    does not depend on the number of worker processes.
    """

    samples: int = Field(
        100_000, ge=2, description="Centerlines to collect (the paper used 100,000)."
    )
    chunk: int = Field(
        500,
        ge=1,
        description="Samples per independently seeded walk; also the train/validation split unit.",
    )
    workers: int = Field(2, ge=1, description="Collection processes (1 = in-process).")


class EncoderTrainingConfig(StrictModel):
    """How the autoencoder is trained (paper section VI-A: Adam, lr 1e-3, batch 10,000, MSE)."""

    epochs: int = Field(
        800,
        ge=1,
        description="Passes over the training set. The paper gives none; on 100k collected "
        "shapes 300 epochs (2,700 Adam steps at batch 10,000) left 1.05 px, 800 reach 0.62 px "
        "in 226 s on 2 cores.",
    )
    batch_size: int = Field(10_000, ge=1, description="Mini-batch size (the paper: 10,000).")
    lr: float = Field(1e-3, gt=0.0, description="Initial Adam learning rate (the paper: 1e-3).")
    lr_final: float = Field(
        1e-5,
        ge=0.0,
        description="Learning rate reached at the last epoch by cosine decay (ours; paper silent).",
    )
    validation_fraction: float = Field(
        0.1,
        gt=0.0,
        lt=1.0,
        description="Share of the collected walks held out for validation.",
    )
    threads: int = Field(2, ge=1, description="torch intra-op threads while training.")


class AutoencoderFeatureConfig(StrictModel):
    """The paper's feature (section VI-A): an autoencoder latent of the N-point centerline."""

    type: Literal["autoencoder"] = "autoencoder"
    latent_dim: int = Field(6, ge=1, description="Latent dimension p.")
    hidden: list[int] = Field(
        [128, 64],
        min_length=1,
        description="Encoder hidden layer widths (ReLU); the decoder mirrors them.",
    )
    checkpoint: str | None = Field(
        None,
        description="Trained encoder (encoder.npz, or encoder.pt which needs torch to load). "
        "None: the default packaged in rodctl/assets/ (the default rod and camera only). "
        "'auto': a quick encoder for this rod and camera (3,000 samples, 300 epochs, about 30 s), "
        "trained on first use and cached in $XDG_CACHE_HOME/rodctl/encoders.",
    )
    data: EncoderDataConfig = EncoderDataConfig()
    training: EncoderTrainingConfig = EncoderTrainingConfig()

    @field_validator("hidden")
    @classmethod
    def _positive_widths(cls, value: list[int]) -> list[int]:
        if any(w < 1 for w in value):
            raise ValueError(f"hidden layer widths must be >= 1, got {value}")
        return value


class BezierFeatureConfig(StrictModel):
    """Least-squares Bézier control points in normalised arc length (the Ma et al. baseline)."""

    type: Literal["bezier"] = "bezier"
    degree: int = Field(
        4, ge=1, le=12, description="Curve degree d; the feature has 2(d+1) components."
    )


class FourierFeatureConfig(StrictModel):
    """Chord line plus truncated sine series of x(rho), y(rho), rho the normalised arc length."""

    type: Literal["fourier"] = "fourier"
    harmonics: int = Field(
        4, ge=1, le=40, description="Harmonics H; the feature has 2(H+2) components."
    )


class NodesFeatureConfig(StrictModel):
    """Pixel positions of a few centerline points (the Aghajanzadeh et al. baseline)."""

    type: Literal["nodes"] = "nodes"
    positions: list[float] = Field(
        [1 / 3, 2 / 3, 1.0],
        min_length=1,
        description="Servoed points as normalised arc length in (0, 1] from the clamp.",
    )

    @field_validator("positions")
    @classmethod
    def _in_range(cls, value: list[float]) -> list[float]:
        if any(not 0.0 < p <= 1.0 for p in value):
            raise ValueError(f"positions must lie in (0, 1], got {value}")
        if len(set(value)) != len(value):
            raise ValueError(f"positions must be distinct, got {value}")
        return value


FeatureConfig = Annotated[
    AutoencoderFeatureConfig | BezierFeatureConfig | FourierFeatureConfig | NodesFeatureConfig,
    Field(discriminator="type"),
]
