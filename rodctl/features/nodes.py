"""Node feature for the Aghajanzadeh et al. 2022 baseline: the pixels of a few rod points.

That method servos the positions of chosen nodes of a discretised rod (docs/baselines.md).
Nodes are placed by normalised arc length rather than by index, so the feature means the same
rod points whatever N the extractor uses. Interior points barely see the gripper angle
(docs/method.md §6 records a stall caused by exactly this), so the default includes the tip.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator

from rodctl.config.base import StrictModel
from rodctl.features.base import build_checked
from rodctl.features.geometry import check_centerlines, resample_uniform
from rodctl.registry import FEATURES, BuildContext


class NodesFeatureMap:
    """s = [u_1, v_1, u_2, v_2, ...] of the rod points at the given normalised arc lengths (px).

    Args:
        positions: normalised arc lengths in (0, 1] from the clamp (1 = gripper end).
        points: centerline points N.

    Attributes:
        dim: p = 2 * len(positions).
        points: N.
        positions: (k,) the normalised arc lengths.
        kind: "nodes".
        units: "px".
        scale: (p,) ones (pixel units).
    """

    kind = "nodes"
    units = "px"

    def __init__(self, positions: Sequence[float], points: int) -> None:
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 1 or pos.size == 0 or np.any(pos <= 0.0) or np.any(pos > 1.0):
            raise ValueError(f"positions must be a non-empty list in (0, 1], got {positions}")
        if points < 2:
            raise ValueError("a centerline needs at least 2 points")
        self.positions = pos
        self.points = points
        self.dim = 2 * pos.size
        self.scale = np.ones(self.dim)

    def encode(self, centerline_px: np.ndarray) -> np.ndarray:
        """(N, 2) pixels, clamp end first -> (p,) node pixels. Deterministic."""
        return self.encode_batch(check_centerlines(centerline_px, self.points, batch=False))[0]

    def encode_batch(self, centerlines_px: np.ndarray) -> np.ndarray:
        """(B, N, 2) pixels -> (B, p)."""
        arr = check_centerlines(centerlines_px, self.points, batch=True)
        return resample_uniform(arr, self.positions).reshape(arr.shape[0], self.dim)


# --- config and registration ------------------------------------------------------------


class NodesFeatureConfig(StrictModel):
    """Pixel positions of a few centerline points (the Aghajanzadeh et al. baseline)."""

    type: Literal["nodes"] = "nodes"
    positions: list[Annotated[float, Field(le=1.0)]] = Field(
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


@FEATURES.register(NodesFeatureConfig)
def _build(cfg: NodesFeatureConfig, ctx: BuildContext) -> NodesFeatureMap:
    return build_checked(cfg.type, ctx.points, lambda: NodesFeatureMap(cfg.positions, ctx.points))
