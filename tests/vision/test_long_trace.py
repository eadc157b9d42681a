"""The extractor's sampling of traces longer than OpenCV's map limit (met in a dual-arm walk)."""

import numpy as np

from rodctl.config import ExperimentConfig
from rodctl.vision import Camera, CenterlineExtractor


def test_the_extractor_samples_a_trace_longer_than_opencv_maps():
    """cv2.remap refuses maps of 32767 columns or more; a long trace is sampled in rows, with
    the values of short samplings."""
    cfg = ExperimentConfig()
    ex = CenterlineExtractor(cfg.camera, Camera(cfg.camera, None), np.zeros(3))
    gen = np.random.default_rng(0)
    image = gen.integers(0, 256, (cfg.camera.height, cfg.camera.width, 3), dtype=np.uint8)
    pts = gen.uniform(0.0, 600.0, (40_000, 2))
    parts = [ex._sample(image, pts[i : i + 10_000]) for i in range(0, 40_000, 10_000)]
    np.testing.assert_array_equal(ex._sample(image, pts), np.concatenate(parts))
