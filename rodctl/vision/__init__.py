"""Eye-to-hand camera: pinhole geometry, scene rendering and centerline extraction.

`Camera` maps the rod's plane to pixels and back and draws what it sees; `CenterlineExtractor`
turns such an image into N ordered pixel points (clamp end first), the `c_k` of the method notes.
"""

from rodctl.vision.camera import Camera
from rodctl.vision.centerline import (
    CenterlineExtractor,
    Extraction,
    polyline_length,
    resample_polyline,
)

__all__ = ["Camera", "CenterlineExtractor", "Extraction", "polyline_length", "resample_polyline"]
