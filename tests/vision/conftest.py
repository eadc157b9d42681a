"""Shared fixtures for the vision tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest


def _distance_to_polyline(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """(M,) distance of each of (M, 2) points to the (K, 2) polyline `curve`."""
    a = curve[:-1][None]
    ab = (curve[1:] - curve[:-1])[None]
    ap = points[:, None] - a
    t = np.clip((ap * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    return np.linalg.norm(ap - t[..., None] * ab, axis=-1).min(axis=1)


@pytest.fixture
def dist_to_curve() -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """distance_to_polyline(points (M, 2), curve (K, 2)) -> (M,) distances."""
    return _distance_to_polyline
