"""The extractor's output, byte for byte, on many scenes: the digests below were made by the code
of `main` before the extraction speed work of issue 24 (commit 6736bdb, 2026-12-02), so a faster
walk, refinement or sampling cannot change a run's numbers unnoticed (published benchmark results
depend on them; `test_pinned_frames.py` pins a few scenes' frames and points in detail).

Per render setting of `benchmarks/bench_vision.py` (plain; checker; checker + noise + blur): the
bench's eight reference shapes and twelve random ones, each drawn three times by one camera, and
extracted with and without the gripper hint and with and without the rod's length (the length
check): one digest of all the frames and one of all the extractions (points, ok, note, bridged).

If a change is meant to alter these numbers (a more accurate extractor), regenerate the digests
and say so in the CHANGELOG: every run's results change with them.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from rodctl.config.camera import CameraConfig
from rodctl.vision import Camera, CenterlineExtractor
from rodctl.vision.shapes import SHAPES, random_shape, rod_shape

CLAMP = np.zeros(3)
SETTINGS = {
    "plain": {},
    "checker": {"background": "checker"},
    "checker-noise-blur": {"background": "checker", "noise_std": 4.0, "blur_sigma": 0.8},
}
#: setting -> (sha256[:32] of the frames, sha256[:32] of the extractions), made on main (6736bdb)
PINNED = {
    "plain": ("5ee18e214434964997e33af8b934f082", "914a93427cf3d8930c1f96f650911b27"),
    "checker": ("3996957088efa79ad1c7ca6291c04f6f", "5c30a908c014586a900db1af1c790559"),
    "checker-noise-blur": ("8f45c1a59e4d5eb9fc663d99cab20b05", "035117c4f211a300cc08c3d9a38cd4af"),
}


def _shapes() -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(24)
    shapes = [rod_shape(name, points=101) for name in SHAPES]
    for _ in range(12):
        length = float(rng.uniform(0.3, 0.65))
        shapes.append(random_shape(rng, length, points=101, max_turn=float(rng.uniform(0.5, 3.5))))
    return shapes


def digests(setting: str) -> tuple[str, str]:
    """(frames digest, extractions digest) of one render setting."""
    cfg = CameraConfig(render=SETTINGS[setting])
    cam = Camera(cfg, np.random.default_rng(0))
    extractors = [
        CenterlineExtractor(cfg, cam, CLAMP, rod_length=0.5),
        CenterlineExtractor(cfg, cam, CLAMP),
    ]
    frames, results = hashlib.sha256(), hashlib.sha256()
    for line, grip in _shapes():
        for _ in range(3):
            img = cam.render(line, grip, CLAMP)
            frames.update(img.tobytes())
            for ext in extractors:
                for hint in (grip, None):
                    res = ext.extract(img, hint)
                    results.update(res.points.tobytes())
                    results.update(repr((res.ok, res.note, res.bridged)).encode())
    return frames.hexdigest()[:32], results.hexdigest()[:32]


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_frames_and_extractions_are_the_bits_of_main(setting: str) -> None:
    assert digests(setting) == PINNED[setting]


if __name__ == "__main__":  # print the digests (to regenerate PINNED, on purpose only)
    for name in SETTINGS:
        print(f'    "{name}": {digests(name)},')
