"""Shared fixtures: a tiny autoencoder trained on synthetic rod shapes (seconds, not minutes)."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.config import ExperimentConfig
from rodctl.features.autoencoder import EncoderCheckpoint, encoder_fingerprint
from rodctl.features.synthetic import rod_like_centerlines
from rodctl.training.encoder import fit_autoencoder

#: A small but real training run: enough steps to learn the 3-parameter family well.
TINY = {
    "feature": {
        "type": "autoencoder",
        "hidden": [64, 32],
        "training": {"epochs": 60, "batch_size": 250, "lr": 3e-3, "threads": 1},
    }
}


@pytest.fixture(scope="session")
def tiny_cfg() -> ExperimentConfig:
    return ExperimentConfig.model_validate(TINY)


@pytest.fixture(scope="session")
def synthetic_split() -> tuple[np.ndarray, np.ndarray]:
    """(train (2000, 100, 2), held-out (300, 100, 2)) synthetic centerlines in pixels."""
    return (
        rod_like_centerlines(np.random.default_rng(1), 2000, 100),
        rod_like_centerlines(np.random.default_rng(2), 300, 100),
    )


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_cfg, synthetic_split) -> EncoderCheckpoint:
    train, held = synthetic_split
    return fit_autoencoder(
        train,
        held,
        tiny_cfg.feature,
        seed=tiny_cfg.seed,
        fingerprint=encoder_fingerprint(tiny_cfg),
        progress=False,
    )
