"""The logging section of the config: defaults and validation."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from rodctl.config import ExperimentConfig
from rodctl.config.logging import LoggingConfig


def test_defaults():
    cfg = ExperimentConfig().logging
    assert (cfg.mcap, cfg.rerun, cfg.image_rate_hz, cfg.mcap_compression) == (
        True,
        True,
        5.0,
        "zstd",
    )
    assert cfg.flush_every_steps == 10


@pytest.mark.parametrize(
    "bad",
    [
        {"image_rate_hz": -1.0},
        {"mcap_compression": "gzip"},
        {"png_compression": 10},
        {"flush_every_steps": 0},
        {"mcap_chunk_size": 10},
        {"imagerate": 5},
    ],
)
def test_bad_values_are_rejected(bad):
    with pytest.raises(ValidationError):
        LoggingConfig(**bad)
