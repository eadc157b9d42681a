"""Config of the eye-to-hand camera, the renderer and the centerline extractor.

Owned by `rodctl/vision/`. The defaults describe a 640x480 pinhole camera 1.2 m from the rod's
plane, tilted 25 degrees so that perspective is real (the far side of the workspace looks smaller
than the near side), seeing the whole region the rod can reach (world x in [-0.2, 0.7] m, y in
[-0.45, 0.45] m) with a margin. Rendering extras (texture, noise, blur, occluders) are off by
default: the closed loop should first be tested with a clean image, then with each nuisance alone.

Colours are RGB triples (0-255). The extractor separates rod from everything else by colour: by
default the rod is the only chromatic thing in the scene and everything else is grey, which makes
the per-pixel rod coverage an exact linear function of the colour (rodctl/vision/centerline.py).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, PositiveFloat, model_validator

from rodctl.config.base import Point2, StrictModel

#: One colour channel, 0-255.
Channel = Annotated[int, Field(ge=0, le=255)]
#: A pixel coordinate, generously outside any image.
Pixel = Annotated[float, Field(ge=-1e5, le=1e5)]

#: An RGB colour, each channel 0-255.
Rgb = tuple[Channel, Channel, Channel]


class RenderConfig(StrictModel):
    """How the camera image is drawn: rod, fixtures, background and optional nuisances."""

    rod_width_px: int = Field(
        6,
        ge=2,
        le=40,
        description=(
            "Rod line thickness (px) as OpenCV draws it (round caps, anti-aliased); the visible "
            "band is about 1-3 px wider. Constant across the image."
        ),
    )
    rod_color: Rgb = Field((200, 40, 40), description="Rod colour (RGB).")
    background: Literal["plain", "checker"] = Field(
        "plain", description="plain: one colour; checker: a checkerboard lying on the rod's plane."
    )
    background_color: Rgb = Field((235, 235, 235), description="Background colour (RGB).")
    checker_color: Rgb = Field((200, 200, 200), description="Second checkerboard colour (RGB).")
    checker_size: PositiveFloat = Field(0.05, le=100.0, description="Checkerboard square size (m).")
    draw_gripper: bool = Field(True, description="Draw the gripper (palm and two fingers).")
    draw_clamp: bool = Field(True, description="Draw the clamp block.")
    fixture_color: Rgb = Field((80, 80, 80), description="Colour of gripper and clamp (RGB).")
    noise_std: float = Field(
        0.0, ge=0.0, le=100.0, description="Std of Gaussian pixel noise (grey levels); 0 = off."
    )
    blur_sigma: float = Field(
        0.0,
        ge=0.0,
        le=10.0,
        description="Gaussian blur sigma (px), applied before the noise; 0 = off.",
    )
    occlusions: list[tuple[Pixel, Pixel, Pixel, Pixel]] = Field(
        default_factory=list,
        description="Fixed occluding rectangles [u0, v0, u1, v1] in pixels, drawn over the rod.",
    )
    random_occlusions: int = Field(
        0, ge=0, le=20, description="Number of square occluders placed at random each frame."
    )
    occlusion_size_px: float = Field(
        30.0, le=1e4, gt=0.0, description="Side (px) of each random occluding square."
    )
    occluder_color: Rgb = Field((150, 150, 150), description="Colour of occluders (RGB).")

    @model_validator(mode="after")
    def _colours_in_range(self) -> RenderConfig:
        for name in (
            "rod_color",
            "background_color",
            "checker_color",
            "fixture_color",
            "occluder_color",
        ):
            if any(not 0 <= c <= 255 for c in getattr(self, name)):
                raise ValueError(f"{name} channels must lie in 0..255, got {getattr(self, name)}")
        for box in self.occlusions:
            if not (box[0] < box[2] and box[1] < box[3]):
                raise ValueError(f"an occlusion [u0, v0, u1, v1] needs u0 < u1 and v0 < v1: {box}")
        return self


class ExtractConfig(StrictModel):
    """How the centerline is traced in the image (see `rodctl/vision/centerline.py`)."""

    step_px: float | None = Field(
        None,
        le=1000.0,
        gt=0.5,
        description="Tracking step along the rod (px); None = the rod width.",
    )
    arc_length: Literal["plane", "image"] = Field(
        "plane",
        description=(
            "Spacing of the N output points: 'plane' = equal arc length on the rod's plane (the "
            "calibrated camera maps pixels to the plane), so point i matches the simulator's point "
            "i; 'image' = equal arc length in pixels (no calibration used)."
        ),
    )
    max_gap_px: float = Field(
        80.0, le=1e4, ge=0.0, description="Longest occluded stretch (px) that may be bridged."
    )
    on_gap: Literal["bridge", "fail"] = Field(
        "bridge",
        description=(
            "When part of the rod is hidden: bridge the gap (points returned, ok=False, "
            "bridged=True) or fail (points NaN, ok=False)."
        ),
    )
    refine_passes: int = Field(
        2, ge=0, le=5, description="Cross-section refinement passes on the N output points."
    )


class CameraConfig(StrictModel):
    """A fixed pinhole camera looking at the rod's plane (world z = 0, y up) from above, tilted.

    The camera sits `distance` metres from `look_at` along a direction tilted `tilt_deg` from the
    plane's normal towards world -y (rotated by `azimuth_deg` about world z), with its optical
    axis through `look_at`. At tilt 0 and azimuth 0 image u grows with world x and image v grows
    with world -y, so the image is not mirrored.
    """

    width: int = Field(640, le=8192, ge=16, description="Image width (px).")
    height: int = Field(480, le=8192, ge=16, description="Image height (px).")
    points: int = Field(
        100, le=10_000, ge=2, description="Centerline points N extracted per image."
    )
    fx: PositiveFloat = Field(560.0, le=1e6, description="Focal length along u (px).")
    fy: PositiveFloat = Field(560.0, le=1e6, description="Focal length along v (px).")
    cx: float | None = Field(
        None, ge=-1e5, le=1e5, description="Principal point u (px); None = (width - 1) / 2."
    )
    cy: float | None = Field(
        None, ge=-1e5, le=1e5, description="Principal point v (px); None = (height - 1) / 2."
    )
    look_at: Point2 = Field(
        (0.25, -0.03), description="World point (m) on the plane the optical axis passes through."
    )
    distance: PositiveFloat = Field(
        1.2, le=100.0, description="Camera centre to `look_at` distance (m)."
    )
    tilt_deg: float = Field(
        25.0, ge=0.0, lt=80.0, description="Angle between optical axis and plane normal (deg)."
    )
    azimuth_deg: float = Field(
        0.0,
        ge=-360.0,
        le=360.0,
        description="Rotation of the whole camera about the world z axis (deg).",
    )
    render: RenderConfig = RenderConfig()
    extract: ExtractConfig = ExtractConfig()


#: How far in front of the camera (m) every point the rod can reach must stay: the renderer
#: cannot draw a point behind the camera, and one just in front of it projects to pixels of
#: ~1e9 that OpenCV's integer drawing cannot hold.
MIN_DEPTH_M = 0.01


def nearest_depth(
    look_at: tuple[float, float],
    distance: float,
    tilt_deg: float,
    azimuth_deg: float,
    centres: list[tuple[float, float]],
    radius: float,
) -> float:
    """The smallest depth (m, along the optical axis) of a plane point within `radius` of the
    convex hull of `centres`, for the camera pose given (`CameraConfig`'s geometry).

    A plane point X sits at depth distance - sin(tilt) (X - look_at) . w in front of the
    camera, w = (sin(azimuth), -cos(azimuth)) the direction the camera leans towards; over the
    hull grown by `radius` the smallest is at a centre (a vertex) plus radius along w.
    """
    tilt, az = math.radians(tilt_deg), math.radians(azimuth_deg)
    wx, wy = math.sin(az), -math.cos(az)
    lean = max((cx - look_at[0]) * wx + (cy - look_at[1]) * wy for cx, cy in centres)
    return distance - math.sin(tilt) * (lean + radius)
