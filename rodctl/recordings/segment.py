"""Segmentation of real camera images: the rod by an HSV colour threshold, cleaned up by
morphology, handed to rodctl's centerline extractor as the two-colour image it expects.

Why this shape: `rodctl.vision.centerline.CenterlineExtractor` recovers each pixel's rod
coverage from the scene's known colours (exact for rodctl's renderer). A real scene has a
textured, unevenly lit background; thresholding the hue, saturation and value isolates the rod
instead, an opening (3 x 3) removes isolated pixels of rod colour in the background and a
closing (5 x 5) fills specks of glare on the rod. The mask, slightly blurred (sigma 0.8 px, so
its edges are 50 % crossings between pixels as an anti-aliased rod's are), is painted in the
extractor's rod and background colours, so the walk, its sub-pixel edges and the occlusion
logic run unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

#: Default HSV range (OpenCV: H in 0..180, S, V in 0..255) of a red rod; a low hue above the
#: high one wraps through 0 (red straddles it).
RED_LOW = (170, 120, 50)
RED_HIGH = (10, 255, 255)


def hsv_mask(rgb: np.ndarray, low: Sequence[int], high: Sequence[int]) -> np.ndarray:
    """uint8 mask (255 = rod) of the pixels whose HSV lies in [low, high], cleaned up."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    lo, hi = tuple(int(v) for v in low), tuple(int(v) for v in high)
    if lo[0] > hi[0]:  # the hue range wraps through 0
        m = np.bitwise_or(
            cv2.inRange(hsv, lo, (180, hi[1], hi[2])), cv2.inRange(hsv, (0, lo[1], lo[2]), hi)
        )
    else:
        m = cv2.inRange(hsv, lo, hi)
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    return cv2.morphologyEx(m, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))


def mask_image(
    mask: np.ndarray, rod_rgb: Sequence[int], background_rgb: Sequence[int]
) -> np.ndarray:
    """The mask painted as an (H, W, 3) uint8 image in the extractor's two colours."""
    a = cv2.GaussianBlur(mask.astype(np.float32) / 255.0, (0, 0), 0.8)[..., None]
    img = a * np.asarray(rod_rgb, np.float32) + (1.0 - a) * np.asarray(background_rgb, np.float32)
    return img.round().clip(0, 255).astype(np.uint8)
