"""The FeatureMap protocol: centerline (pixels) -> low-dimensional shape feature s."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class FeatureMap(Protocol):
    """Maps an N-point pixel centerline to a feature s in R^p (method-notes: s = f_s(c)).

    Attributes:
        dim: the feature dimension p.
        points: the number N of centerline points it expects.
    """

    dim: int
    points: int

    def encode(self, centerline_px: np.ndarray) -> np.ndarray:
        """(N, 2) pixels, clamp end first -> (p,) float64 feature. Deterministic."""
        ...

    def encode_batch(self, centerlines_px: np.ndarray) -> np.ndarray:
        """(B, N, 2) -> (B, p)."""
        ...
