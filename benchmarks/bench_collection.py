"""Data collection for `train-encoder` with each rod engine: shapes per second, and where a
shape's time goes (issue 24).

Goal: >= 2,000 shapes/s on 2 cores with `rod.engine=quasistatic` (`rodctl/training/collection.py`:
a random walk of settled control steps, each shape rendered and extracted by the camera pipeline).

Figures per engine: the throughput of `collect_dataset` with 2 worker processes (wall time:
on a loaded machine it also counts waiting for a core), as measured on 2 x `--samples` shapes and
with the pool's start-up amortised (from a second run of three times as many), the workers' CPU
time per shape between the two runs, and the CPU time per shape of one walk in this process,
split into the physics (`RodSim.apply`), the rendering (`Camera.render`), the extraction
(`CenterlineExtractor.extract`) and the rest of the walk; 2 / (CPU per shape) is what 2 free
cores would give.

    python benchmarks/bench_collection.py [--samples 600] [--engines quasistatic pymunk]
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from collections import defaultdict

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rodctl.config import load_config  # noqa: E402
from rodctl.sim import RodSim  # noqa: E402
from rodctl.training import collection  # noqa: E402
from rodctl.vision import Camera, CenterlineExtractor  # noqa: E402

GOAL = 2000.0


def config(engine: str, samples: int, workers: int):
    return load_config(
        "configs/default.yaml",
        [
            f"rod.engine={engine}",
            f"feature.data.samples={samples}",
            f"feature.data.chunk={max(1, samples // 2)}",
            f"feature.data.workers={workers}",
        ],
    )


def warm_up(engine: str) -> float:
    """CPU s of a 5-shape walk: what a process pays once (the lazy imports of scipy.linalg for
    the quasi-static solve and of the camera stack, first calls), so that `breakdown` measures
    the steady state a long collection runs at."""
    cfg = config(engine, 5, 1)
    c0 = time.process_time()
    collection.collect_chunk(cfg.model_dump_json(), 5, np.random.SeedSequence(1))
    return time.process_time() - c0


def breakdown(engine: str, samples: int) -> tuple[float, dict[str, float]]:
    """(CPU s per shape, {part: CPU s per shape}) of one walk in this process."""
    spent: dict[str, float] = defaultdict(float)
    patched = []
    for cls, name, part in (
        (RodSim, "apply", "physics"),
        (Camera, "render", "render"),
        (CenterlineExtractor, "extract", "extract"),
    ):
        original = getattr(cls, name)

        def timed(*args, _original=original, _part=part, **kwargs):
            t0 = time.process_time()
            try:
                return _original(*args, **kwargs)
            finally:
                spent[_part] += time.process_time() - t0

        setattr(cls, name, timed)
        patched.append((cls, name, original))
    try:
        cfg = config(engine, samples, 1)
        c0 = time.process_time()
        out = collection.collect_chunk(cfg.model_dump_json(), samples, np.random.SeedSequence(7))
        total = time.process_time() - c0
    finally:
        for cls, name, original in patched:
            setattr(cls, name, original)
    n = len(out["centerlines"])
    parts = {k: v / n for k, v in spent.items()}
    parts["rest of the walk (incl. building the rod)"] = (total - sum(spent.values())) / n
    return total / n, parts


def throughput(engine: str, samples: int) -> tuple[float, float, float, float]:
    """(shapes/s of `collect_dataset` with 2 workers, pool start included; the same without
    it; the start-up in s; the workers' CPU ms a shape beyond the first `samples`), from two
    runs of `samples` and 3 x `samples` shapes (wall time; the CPU time of the finished worker
    processes, `RUSAGE_CHILDREN`).

    A pool's start-up (two spawned interpreters importing numpy, scipy, OpenCV and rodctl) is
    paid once per collection, however many shapes it collects; `train-encoder` collects 100,000.
    The marginal rate 2 `samples` / (t(3 `samples`) - t(`samples`)) is the rate with it
    amortised, and t(`samples`) - `samples` / rate is the start-up. On a loaded machine the
    wall figures count waiting for a core; the workers' CPU time does not (the same walks:
    each run's two walks have the same seeds, the longer ones going on from where the shorter
    ones stop)."""
    times, cpus = [], []
    for n in (samples, 3 * samples):
        cfg = config(engine, n, 2)
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        data = collection.collect_dataset(cfg, progress=False)
        times.append(time.perf_counter() - t0)
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime)
        assert len(data) == n
    marginal = 2 * samples / max(times[1] - times[0], 1e-9)
    cpu_shape = (cpus[1] - cpus[0]) / (2 * samples)
    return samples / times[0], marginal, times[0] - samples / marginal, cpu_shape


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=600)
    ap.add_argument("--engines", nargs="+", default=["quasistatic", "pymunk"])
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()}")
    for engine in args.engines:
        first = warm_up(engine)
        per_shape, parts = breakdown(engine, args.samples)
        rate, marginal, startup, cpu_shape = throughput(engine, 2 * args.samples)
        goal = f"   (goal >= {GOAL:.0f} shapes/s on 2 cores)" if engine == "quasistatic" else ""
        print(
            f"{engine}: collect_dataset, 2 workers: {rate:7.1f} shapes/s (wall, "
            f"{2 * args.samples} shapes, pool start-up included); {marginal:7.1f} shapes/s with "
            f"the start-up ({startup:.2f} s) amortised{goal}; one walk: {1e3 * per_shape:.3f} ms "
            f"CPU per shape = {2 / per_shape:7.1f} shapes/s on 2 free cores; the workers beyond "
            f"the first {2 * args.samples} shapes: {1e3 * cpu_shape:.3f} ms CPU per shape = "
            f"{2 / max(cpu_shape, 1e-12):7.1f} shapes/s on 2 free cores"
        )
        for part, cpu in parts.items():
            print(f"    {part:<42} {1e3 * cpu:7.3f} ms  {100 * cpu / per_shape:5.1f} %")
        print(f"    (once per process, before it: a 5-shape walk, imports included: {first:.2f} s)")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
