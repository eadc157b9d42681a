"""`AutoencoderFeatureMap.encode_rows`: the shapes of a step's true Jacobian in one pass, with
exactly the bits of `encode` shape by shape (the Jacobian error in every record depends on it)."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.config import ExperimentConfig
from rodctl.env import _rows_of
from rodctl.features import make_feature_map
from rodctl.features.autoencoder import AutoencoderFeatureMap


@pytest.fixture(scope="module")
def default_map():
    cfg = ExperimentConfig()
    return make_feature_map(cfg.feature, points=cfg.camera.points, experiment=cfg)


@pytest.mark.parametrize("batch", [1, 2, 6, 12])
def test_rows_are_the_bits_of_encode(default_map, batch):
    rng = np.random.default_rng(batch)
    base = np.column_stack([np.linspace(300.0, 420.0, 100), np.linspace(200.0, 330.0, 100)])
    for scale in (1e-6, 1e-2, 5.0):
        shapes = base + scale * rng.normal(size=(batch, 100, 2))
        one_by_one = np.stack([default_map.encode(x) for x in shapes])
        rows = default_map.encode_rows(shapes)
        assert rows.shape == (batch, default_map.dim)
        assert rows.tobytes() == one_by_one.tobytes()


def test_rows_refuse_a_wrong_shape_as_encode_does(default_map):
    with pytest.raises(ValueError, match="N=100"):
        default_map.encode_rows(np.zeros((6, 99, 2)))
    with pytest.raises(ValueError, match="N=100"):
        default_map.encode_rows(np.zeros((100, 2)))


def test_the_env_uses_rows_only_for_the_encode_they_match(default_map):
    assert _rows_of(default_map.encode) is not None
    assert _rows_of(default_map.encode_batch) is None  # BLAS products: not the same bits

    class Shifted(AutoencoderFeatureMap):  # overrides encode but not encode_rows
        def encode(self, centerline_px):
            return super().encode(centerline_px) + 1.0

    other = Shifted.__new__(Shifted)
    other.__dict__.update(default_map.__dict__)
    assert _rows_of(other.encode) is None
