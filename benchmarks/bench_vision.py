"""Render and extraction time per frame at 640x480, and accuracy, for the reference shapes.

Prints figures beside their goals; asserts nothing (speed goals are read, not tested). Goals
(issue 24): render + extract <= 1 ms per frame plain, <= 3 ms with checker, noise and blur; mean
distance to the projected centreline <= 0.5 px. Run:
``.venv/bin/python benchmarks/bench_vision.py [--repeats 200]``. Timings on a shared machine are
noisy: the median of many repeats is reported, wall time and the thread's CPU time (which leaves
out the time the process waited for a core).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rodctl.config.camera import CameraConfig
from rodctl.vision import Camera, CenterlineExtractor
from rodctl.vision.shapes import SHAPES, rod_shape


def _median_ms(fn, repeats: int) -> tuple[float, float]:
    """(wall, thread CPU) median milliseconds of `fn()`."""
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))


def _dist_to_curve(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    a, ab = curve[:-1][None], np.diff(curve, axis=0)[None]
    ap = points[:, None] - a
    t = np.clip((ap * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    return np.linalg.norm(ap - t[..., None] * ab, axis=-1).min(axis=1)


def main() -> None:
    """Print one table per render setting."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    settings = {
        "default (plain)": ({}, 1.0),
        "checker": ({"background": "checker"}, 1.0),
        "checker+noise+blur": (
            {"background": "checker", "noise_std": 4.0, "blur_sigma": 0.8},
            3.0,
        ),
    }
    clamp = np.zeros(3)
    for label, (render, goal_ms) in settings.items():
        cfg = CameraConfig(render=render)
        cam = Camera(cfg, np.random.default_rng(0))
        ext = CenterlineExtractor(cfg, cam, clamp, rod_length=0.5)
        print(f"\n== {label}  ({cfg.width}x{cfg.height}, N = {cfg.points})")
        print(
            f"{'shape':16s} {'render ms':>9s} {'extract ms':>10s} {'total':>6s} {'cpu':>6s} "
            f"{'ok':>3s} {'mean px':>8s} {'max px':>7s} {'idx max px':>10s}"
        )
        totals, cpus, means = [], [], []
        for name in SHAPES:
            fine, grip = rod_shape(name, points=2001)
            line = fine[::20]
            img = cam.render(line, grip, clamp)
            r_ms, r_cpu = _median_ms(lambda: cam.render(line, grip, clamp), args.repeats)  # noqa: B023
            e_ms, e_cpu = _median_ms(lambda: ext.extract(img, grip), args.repeats)  # noqa: B023
            res = ext.extract(img, grip)
            if np.isfinite(res.points).all():
                d = _dist_to_curve(res.points, cam.project(fine))
                idx = np.linalg.norm(res.points - cam.project(rod_shape(name)[0]), axis=1)
                acc = f"{d.mean():8.3f} {d.max():7.3f} {idx.max():10.3f}"
            else:
                acc = f"{'-':>8s} {'-':>7s} {'-':>10s}"
            print(
                f"{name:16s} {r_ms:9.3f} {e_ms:10.3f} {r_ms + e_ms:6.2f} {r_cpu + e_cpu:6.2f} "
                f"{'yes' if res.ok else 'NO':>3s} {acc}  {res.note}"
            )
            if res.ok:  # the loop is a known limit (reported, not traced): not in the goals
                totals.append(r_ms + e_ms)
                cpus.append(r_cpu + e_cpu)
                means.append(float(d.mean()))
        worst, worst_cpu, worst_mean = max(totals), max(cpus), max(means)
        print(
            f"-- slowest traced shape: {worst:.2f} ms wall, {worst_cpu:.2f} ms CPU "
            f"(goal <= {goal_ms:g} ms: {'met' if worst <= goal_ms else 'NOT met'} on wall, "
            f"{'met' if worst_cpu <= goal_ms else 'NOT met'} on CPU); "
            f"worst mean error {worst_mean:.3f} px (goal <= 0.5 px: "
            f"{'met' if worst_mean <= 0.5 else 'NOT met'})"
        )


if __name__ == "__main__":
    main()
