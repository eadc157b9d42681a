"""Logging overhead per control step (ms) and bytes per step of run.mcap and run.rrd.

Goal (performance issue): both sinks together <= 10 % of the loop, with camera frames at 5 Hz of
simulated time, and run.mcap still byte-identical on rerun. The sinks encode frames and send
Rerun batches on background threads, so what the loop pays depends on the loop having work of
its own to overlap with: between two steps this script spins the CPU for `--loop-ms` (default
4 ms, the closed loop's own cost per step without logging on this machine, benchmarks/bench_loop.py)
and reports the time spent inside the sinks' calls, and its share of loop + logging. Prints
figures; asserts nothing (timings on a shared machine are noisy).

The records are synthetic (`rodctl.logs.synthetic`: 51-point world and 100-point pixel
centerlines, p = 6, q = 3); the frames are rendered beforehand by rodctl's own camera
(`rodctl.vision.camera.Camera`, 640 x 480) from those centerlines, so image content — and hence
PNG cost — is that of a real run. Scenarios: the default plain background; a checkerboard
background; the plain one with Gaussian pixel noise (std 2 grey levels), the PNG worst case; and no
frames at all. Each figure is the median over repeats of (time in `write` + `close`) / steps;
`p95` is the 95th percentile of single `write` calls (chunk flushes and frames make the spikes).
The synthetic steps are 0.2 s of simulated time apart, so at 5 Hz every attached frame is logged.

Run: .venv/bin/python benchmarks/bench_logging.py [--steps N] [--repeats R] [--image-every K]
     [--loop-ms MS]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from rodctl.config.camera import CameraConfig
from rodctl.config.logging import LoggingConfig
from rodctl.logs import codec
from rodctl.logs.mcap import McapSink
from rodctl.logs.rerun import RerunSink
from rodctl.logs.synthetic import SyntheticRun
from rodctl.records import StepRecord
from rodctl.vision.camera import Camera


def frames(run: SyntheticRun, records: list[StepRecord], every: int, kind: str) -> None:
    """Attach rendered frames to every `every`-th record (in place)."""
    if kind == "none" or every <= 0:
        for r in records:
            r.image = None
        return
    render = {} if kind != "checker" else {"background": "checker"}
    cam = Camera(CameraConfig.model_validate({"render": render}))
    rng = np.random.default_rng(0)
    for r in records:
        if r.step % every:
            r.image = None
            continue
        img = cam.render(r.centerline, r.gripper, run.header.clamp_pose)
        if kind == "noisy":
            img = np.clip(img + rng.normal(0.0, 2.0, img.shape), 0, 255).round().astype(np.uint8)
        r.image = img


def spin(ms: float) -> None:
    """Busy CPU for `ms` milliseconds on this thread (the loop's own work)."""
    end = time.perf_counter() + ms / 1e3
    x = 0
    while time.perf_counter() < end:
        x += 1


def one_run(
    sinks: str, run: SyntheticRun, records: list[StepRecord], out: Path, loop_ms: float = 0.0
):
    """Write one run; returns (ms/step incl. close, p95 write ms, close ms, {file: bytes})."""
    cfg = LoggingConfig()
    made = []
    if "mcap" in sinks:
        made.append(McapSink(out / "run.mcap", cfg))
    if "rerun" in sinks:
        made.append(RerunSink(out / "run.rrd", cfg))
    codec.FRAMES.reset()  # no frame carried over from the previous run
    for s in made:
        s.open(run.header)
    per_write = []
    for r in records:
        spin(loop_ms)
        t0 = time.perf_counter()
        for s in made:
            s.write(r)
        per_write.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    for s in made:
        s.close(None, "completed")
    close = time.perf_counter() - t0
    total = (sum(per_write) + close) / len(records) * 1e3
    sizes = {p.name: p.stat().st_size for p in (out / "run.mcap", out / "run.rrd") if p.exists()}
    return total, float(np.percentile(per_write, 95)) * 1e3, close * 1e3, sizes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--image-every", type=int, default=2, help="frame every K steps (5 Hz at 0.1 s)"
    )
    ap.add_argument("--loop-ms", type=float, default=4.0, help="loop work between steps (ms)")
    ap.add_argument("--frames", default="plain,checker,noisy,none", help="frame kinds to run")
    ap.add_argument("--sinks", default="mcap+rerun,mcap,rerun", help="sink sets to run")
    args = ap.parse_args()

    run = SyntheticRun(seed=0, image_every=0)
    records = run.records(args.steps)
    print(
        f"{args.steps} steps, frames every {args.image_every} steps, {args.loop_ms} ms of loop "
        f"work a step, median of {args.repeats}; goal: logging <= 10 % of loop + logging"
    )
    print(
        f"{'frames':<8} {'sinks':<11} {'ms/step':>8} {'share':>6} {'p95 ms':>7} {'close ms':>9} "
        f"{'mcap B/step':>12} {'rrd B/step':>11}"
    )
    for kind in args.frames.split(","):
        frames(run, records, args.image_every, kind)
        for sinks in args.sinks.split(","):
            results = []
            for _ in range(args.repeats):
                with tempfile.TemporaryDirectory() as tmp:
                    results.append(one_run(sinks, run, records, Path(tmp), args.loop_ms))
            ms = float(np.median([r[0] for r in results]))
            p95 = float(np.median([r[1] for r in results]))
            close = float(np.median([r[2] for r in results]))
            sizes = results[-1][3]
            mcap_b = sizes.get("run.mcap", 0) / args.steps
            rrd_b = sizes.get("run.rrd", 0) / args.steps
            share = 100 * ms / (args.loop_ms + ms) if args.loop_ms + ms > 0 else 0.0
            print(
                f"{kind:<8} {sinks:<11} {ms:8.2f} {share:5.1f}% {p95:7.2f} {close:9.1f} "
                f"{mcap_b:12.0f} {rrd_b:11.0f}"
            )


if __name__ == "__main__":
    main()
