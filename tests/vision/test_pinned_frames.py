"""Pinned frames: the camera's images and the extracted centerlines of a few scenes are the exact
bits of the code before the speed work of issue 24 (2026-12-02), so that a faster render or
extraction cannot change a run's numbers unnoticed (a suite run's published figures depend on
them). Each scene is drawn three times by one camera: the first frame draws the noise pool and
the background, later ones reuse them (and the pre-drawn clamp).

If a change is meant to alter these numbers (a more accurate extractor), regenerate the digests
and say so in the CHANGELOG: every run's results change with them.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from rodctl.config.camera import CameraConfig
from rodctl.vision import Camera, CenterlineExtractor, resample_polyline
from rodctl.vision.shapes import rod_shape

CLAMP = np.zeros(3)
SCENES = {
    "plain-s_shape": ({}, "s_shape"),
    "checker-noise-blur-hook": (
        {"background": "checker", "noise_std": 4.0, "blur_sigma": 0.8},
        "hook",
    ),
    "occluded-arc": ({"occlusions": [(300.0, 100.0, 340.0, 400.0)]}, "arc"),
    "random-occluders-tight_tip": ({"random_occlusions": 2, "noise_std": 2.0}, "tight_tip"),
}
#: scene -> (ok, bridged, [(image sha256[:32], points sha256[:32]) per frame], points 0, 37
#: and 99 of the last frame as float.hex)
PINNED = {
    "plain-s_shape": (
        True,
        False,
        [
            ("6226ca68273943d8c336330c79486eee", "7447a9c9280a8a7c0dcf460be41c1bd6"),
            ("6226ca68273943d8c336330c79486eee", "7447a9c9280a8a7c0dcf460be41c1bd6"),
            ("6226ca68273943d8c336330c79486eee", "7447a9c9280a8a7c0dcf460be41c1bd6"),
        ],
        [
            "0x1.981b2da88cbd8p+7",
            "0x1.c5e381796d101p+7",
            "0x1.0790991e2c73fp+8",
            "0x1.60ce749bd2e7dp+7",
            "0x1.71da8fc1cb66bp+8",
            "0x1.c5b95eb044c5cp+7",
        ],
    ),
    "checker-noise-blur-hook": (
        True,
        False,
        [
            ("3160e4a86c50e392265e9b63db23fbcf", "abb6bc599e398a2b0cffc30cdcc4b8d4"),
            ("ef1aa0572cc1b6dd865a2c13e9f46b65", "497520f5cc8c769d850df8f31f4e152c"),
            ("7f30fd6055b13404c81edf225bbcb873", "3ed7c410e7ec2fbd9c17d8fe96b9d7bc"),
        ],
        [
            "0x1.981b2da88cbd8p+7",
            "0x1.c5e381796d101p+7",
            "0x1.220cbf99a279ep+8",
            "0x1.c2f926a99810dp+7",
            "0x1.c651edf15ce0ap+7",
            "0x1.79a700dd229c2p+7",
        ],
    ),
    "occluded-arc": (
        False,
        True,
        [
            ("2176c4e6be9d0264ba5979b68cabd2e1", "5254718ffe8605cee594fc573d520e78"),
            ("2176c4e6be9d0264ba5979b68cabd2e1", "5254718ffe8605cee594fc573d520e78"),
            ("2176c4e6be9d0264ba5979b68cabd2e1", "5254718ffe8605cee594fc573d520e78"),
        ],
        [
            "0x1.981b2da88cbd8p+7",
            "0x1.c5e381796d101p+7",
            "0x1.1dfddbd8c4925p+8",
            "0x1.9993f29d7f20cp+7",
            "0x1.5972c6a6f588ap+8",
            "0x1.ad9afd4e93319p+6",
        ],
    ),
    "random-occluders-tight_tip": (
        True,
        False,
        [
            ("bc10379e257910cdca5ba981d507c11b", "eeedc7d945e6e8ff30f5f243ff998d80"),
            ("34db6ecd9d0761c5cfbe3972c24c8fab", "a7f99a022ba2ba1e053a3b31ab54eed3"),
            ("4023ec548951ee9eb00475dc75aae317", "9aba73fbd46bf8ff170f70dbb3f6a86f"),
        ],
        [
            "0x1.981b2da88cbd8p+7",
            "0x1.c5e381796d101p+7",
            "0x1.223ecae71901ap+8",
            "0x1.c5dbcaee21664p+7",
            "0x1.91dc7aac57347p+8",
            "0x1.7a34de3540bcdp+7",
        ],
    ),
}


def _digest(a: np.ndarray) -> str:
    return hashlib.sha256(a.tobytes()).hexdigest()[:32]


@pytest.mark.parametrize("scene", list(SCENES))
def test_frames_and_centerlines_are_the_pinned_bits(scene: str) -> None:
    render, shape = SCENES[scene]
    ok, bridged, digests, points = PINNED[scene]
    cfg = CameraConfig(render=render)
    cam = Camera(cfg, np.random.default_rng(3))
    ext = CenterlineExtractor(cfg, cam, CLAMP, rod_length=0.5)
    line, grip = rod_shape(shape, points=101)
    got = []
    for _ in digests:
        img = cam.render(line, grip, CLAMP)
        res = ext.extract(img, grip)
        got.append((_digest(img), _digest(res.points)))
    assert (res.ok, res.bridged) == (ok, bridged)
    assert [float(v).hex() for v in res.points[[0, 37, 99]].ravel()] == points
    assert got == digests


def test_resample_polyline_is_numpy_linspace_and_interp_bit_for_bit() -> None:
    """`resample_polyline` skips `np.linspace`'s overhead; its points are those of the plain
    numpy formulation it replaced, to the last bit."""
    rng = np.random.default_rng(0)
    for n in (2, 3, 100, 257):
        for m in (2, 5, 51):
            pts = np.cumsum(rng.normal(0.0, 1.0, (m, 2)), axis=0)
            s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
            q = np.linspace(0.0, s[-1], n)
            old = np.column_stack([np.interp(q, s, pts[:, 0]), np.interp(q, s, pts[:, 1])])
            assert resample_polyline(pts, n).tobytes() == old.tobytes()
    assert (resample_polyline(np.ones((4, 2)), 5) == 1.0).all()
