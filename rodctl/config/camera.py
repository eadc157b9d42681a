"""Config of the eye-to-hand camera, the renderer and the centerline extractor.

Owned by `rodctl/vision/`.
"""

from __future__ import annotations

from pydantic import Field

from rodctl.config.base import StrictModel


class CameraConfig(StrictModel):
    """A fixed pinhole camera looking at the rod's plane."""

    width: int = Field(640, ge=16, description="Image width (px).")
    height: int = Field(480, ge=16, description="Image height (px).")
    points: int = Field(100, ge=2, description="Centerline points N extracted per image.")
