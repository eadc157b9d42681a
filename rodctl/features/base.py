"""The FeatureMap protocol: centerline (pixels) -> low-dimensional shape feature s.

Besides the map itself a controller needs to know how big s is and in what units, so that gains,
tolerances and dead zones can be set per feature without knowing which feature it is: `dim`,
`units` and `scale` carry that.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, TypeVar

import numpy as np

from rodctl.errors import UserError

T = TypeVar("T")


class FeatureMap(Protocol):
    """Maps an N-point pixel centerline to a feature s in R^p (docs/method.md §1: s = f_s(c)).

    Attributes:
        dim: the feature dimension p.
        points: the number N of centerline points it expects.
        kind: the config `type` that builds it ("autoencoder", "bezier", "fourier", "nodes").
        units: "px" when every component is in pixels, "latent" for a learned code.
        scale: (p,) typical size of each component's variation (the training-set standard
            deviation for a learned code; ones for pixel features). Dividing s by it makes the
            components comparable.
    """

    dim: int
    points: int
    kind: str
    units: str
    scale: np.ndarray

    def encode(self, centerline_px: np.ndarray) -> np.ndarray:
        """(N, 2) pixels, clamp end first -> (p,) float64 feature. Deterministic."""
        ...

    def encode_batch(self, centerlines_px: np.ndarray) -> np.ndarray:
        """(B, N, 2) -> (B, p)."""
        ...


def build_checked(kind: str, points: int, make: Callable[[], T]) -> T:
    """`make()`, with a ValueError (a combination one config model alone cannot check, such as
    a degree too high for N points) turned into a `UserError` naming the feature and N."""
    try:
        return make()
    except ValueError as exc:
        raise UserError(f"feature ({kind}) with camera.points={points}: {exc}") from None
