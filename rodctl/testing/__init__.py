"""Checks for plug-in authors: does a registered type honour its kind's protocol?

`check_stage(kind, config)` is the counterpart of Gymnasium's `check_env` for a feature map, a
Jacobian estimator or a controller: it builds the stage from its config through the registry
(as a run would), runs it on a small synthetic case with known answers, and checks the shapes,
that every output is finite, and that two stages built from the same config give bit-identical
outputs on the same inputs (a run must be reproducible from its config and seed). It raises
`StageCheckFailed` naming the first problem and returns what it saw.

`check_event`, `check_sink` and `check_executor` do the same for the other three kinds: an
event's example applied to a small rod, a synthetic run fed through a sink, and a few tasks
mapped through an executor. rodctl's own meta-tests (tests/test_registry.py) run these on every
registered type, the plug-ins' included.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from rodctl.config import ExperimentConfig
from rodctl.config.camera import CameraConfig
from rodctl.config.logging import LoggingConfig
from rodctl.config.rod import RodConfig
from rodctl.executors.base import ExecutorContext
from rodctl.logs.sinks import SinkContext
from rodctl.logs.synthetic import SyntheticRun
from rodctl.records import RunSummary
from rodctl.registry import EVENTS, EXECUTORS, KINDS, SINKS, STAGES, BuildContext, load_plugins
from rodctl.sim import RodSim
from rodctl.vision.camera import Camera

__all__ = [
    "StageCheckFailed",
    "StageReport",
    "check_event",
    "check_executor",
    "check_sink",
    "check_stage",
    "synthetic_centerlines",
]


class StageCheckFailed(AssertionError):
    """A registered type does not honour its kind's protocol; the message says how."""


@dataclass
class StageReport:
    """What `check_stage` saw: the kind, the type, and the shapes of its outputs."""

    kind: str
    type: str
    shapes: dict[str, tuple[int, ...]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _fail(kind: str, name: str, what: str) -> StageCheckFailed:
    return StageCheckFailed(f"{kind} type {name!r}: {what}")


def _config(kind: str, config: Any) -> BaseModel:
    """A config instance of `kind` from an instance, a dict with `type`, or a type name."""
    load_plugins()
    registry = KINDS[kind]
    if isinstance(config, BaseModel):
        return config
    if isinstance(config, str):
        config = {"type": config}
    if not isinstance(config, dict) or "type" not in config:
        raise TypeError(f"config: a {kind} config model, a dict with `type`, or a type name")
    return registry.get(config["type"]).config.model_validate(config)


def synthetic_centerlines(points: int, count: int, seed: int = 0) -> np.ndarray:
    """(count, points, 2) smooth rod-like centerlines in pixels of a 640 x 480 view: a clamp at
    the left, the far end moving about, arc-length resampled. Deterministic for `seed`."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, points)
    out = np.empty((count, points, 2))
    for i in range(count):
        bend, tip, twist = rng.uniform(-1.0, 1.0, 3)
        x = 160.0 + (300.0 + 20.0 * tip) * t
        y = 240.0 + 60.0 * bend * np.sin(np.pi * t / 2) + 25.0 * twist * t**2
        out[i] = np.column_stack([x, y])
    return out


def _finite(
    kind: str, name: str, what: str, value: Any, shape: tuple[int | np.integer, ...]
) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise _fail(kind, name, f"{what} has shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise _fail(kind, name, f"{what} is not finite: {arr}")
    return arr


def check_stage(
    kind: str,
    config: Any,
    *,
    points: int = 100,
    p: int = 6,
    q: int = 3,
    steps: int = 8,
    experiment: Any = None,
    seed: int = 0,
) -> StageReport:
    """Build a stage from `config` through its registry, run it on a small case, check it.

    Args:
        kind: "feature", "estimator" or "controller".
        config: the stage's config model instance, a dict with `type`, or a type name (its
            defaults).
        points: N, centerline points given to a feature map.
        p, q: feature and command dimensions for an estimator or a controller.
        steps: updates (estimator) or commands (controller) run.
        experiment: the experiment config a factory may read (`BuildContext.experiment`;
            None: the defaults).
        seed: of the synthetic case.

    Checks, by kind:
        feature: `encode` gives (dim,) finite values for several centerlines, `encode_batch`
            (when present) gives the same rows; `dim` and `units` are declared.
        estimator: `info()` gives a dict before `reset` too (the loop logs it during probing);
            after `reset(J0)`, `update(ds, dr)` on moves of a known linear map gives a (p, q)
            finite estimate each step and `info()` a dict.
        controller: after `reset()`, `command(s, s*, J, r)` gives a (q,) finite command.
        all: a second stage built from the same config gives bit-identical outputs.
    `report.notes` (not failures: a stage may have reasons) says when an estimate moved away
    from the true map, or when a controller's first command points away from a reachable
    target s* = s + J du (J u · (s* - s) < 0).

    Raises:
        StageCheckFailed: the first problem found, naming the type.
    """
    if kind not in STAGES:
        raise ValueError(f"kind must be one of {', '.join(STAGES)}, got {kind!r}")
    cfg = _config(kind, config)
    name = str(cfg.type)  # type: ignore[attr-defined]
    if experiment is None:
        experiment = ExperimentConfig()
    ctx = _context(points, p, q, experiment, seed)
    run = {"feature": _run_feature, "estimator": _run_estimator, "controller": _run_controller}
    report = StageReport(kind, name)
    first = run[kind](cfg, ctx, report, steps, seed)
    again = run[kind](cfg, ctx, StageReport(kind, name), steps, seed)
    for key, value in first.items():
        if not np.array_equal(value, again[key]):
            raise _fail(kind, name, f"not deterministic: {key} differs between two builds")
    return report


def _context(points: int, p: int, q: int, experiment: Any, seed: int) -> BuildContext:
    """The synthetic case's build context: a fixed home pose and step size, and an oracle that
    gives a true map J drawn from `seed`."""
    rng = np.random.default_rng(seed)
    j_true = rng.normal(0.0, 30.0, (p, q))
    return BuildContext(
        points=points,
        p=p,
        q=q,
        home_pose=np.array([0.4, 0.2, 0.0]),
        max_step=np.array([0.01, 0.01, 0.05]),
        oracle=lambda: j_true,
        experiment=experiment,
    )


def _build(kind: str, cfg: BaseModel, ctx: BuildContext) -> Any:
    try:
        return STAGES[kind].build(cfg, ctx)
    except Exception as exc:
        raise _fail(kind, str(cfg.type), f"its factory raised {exc!r}") from exc  # type: ignore[attr-defined]


def _run_feature(cfg: Any, ctx: BuildContext, report: StageReport, steps: int, seed: int) -> dict:
    obj = _build("feature", cfg, ctx)
    name = cfg.type
    dim = getattr(obj, "dim", None)
    if not isinstance(dim, int | np.integer) or dim < 1:
        raise _fail("feature", name, f"`dim` must be a positive int, got {dim!r}")
    if not isinstance(getattr(obj, "units", None), str):
        raise _fail("feature", name, "`units` must be a string ('px', 'latent', ...)")
    curves = synthetic_centerlines(ctx.points, max(2, min(steps, 4)), seed)
    s = np.stack([_finite("feature", name, "encode(c)", obj.encode(c), (dim,)) for c in curves])
    batch = getattr(obj, "encode_batch", None)
    if batch is not None:
        b = _finite("feature", name, "encode_batch(cs)", batch(curves), (len(curves), dim))
        if not np.allclose(b, s, rtol=1e-6, atol=1e-9 * (1 + np.abs(s).max())):
            raise _fail("feature", name, "encode_batch differs from encode row by row")
    report.shapes["s"] = (int(dim),)
    return {"s": s}


def _run_estimator(cfg: Any, ctx: BuildContext, report: StageReport, steps: int, seed: int):
    obj = _build("estimator", cfg, ctx)
    name, shape = cfg.type, (ctx.p, ctx.q)
    assert ctx.max_step is not None  # `check_stage` gives one
    rng = np.random.default_rng(seed + 1)
    j_true = np.asarray(ctx.oracle(), dtype=float)
    j0 = j_true + rng.normal(0.0, 10.0, shape)
    # The loop logs info() from the first frame on, through the probing moves, before reset
    try:
        early = obj.info()
    except Exception as exc:
        raise _fail(
            "estimator",
            name,
            f"info() before reset() raised {exc!r}; the loop logs it from the first frame, "
            "during the probing moves that give J0 (return {} until reset)",
        ) from exc
    if not isinstance(early, dict):
        raise _fail("estimator", name, "info() before reset() must return a dict")
    obj.reset(j0)
    out = []
    for _ in range(steps):
        dr = rng.uniform(-1.0, 1.0, ctx.q) * ctx.max_step
        est = obj.update(j_true @ dr, dr)
        out.append(_finite("estimator", name, "update(ds, dr)", est, shape))
    if not isinstance(obj.info(), dict):
        raise _fail("estimator", name, "info() must return a dict")
    before, after = np.linalg.norm(j0 - j_true), np.linalg.norm(out[-1] - j_true)
    if not after <= before * (1 + 1e-9):
        report.notes.append(
            f"the estimate moved away from the true map ({before:.3g} -> {after:.3g})"
        )
    report.shapes["J"] = shape
    return {"J": np.stack(out)}


def _run_controller(cfg: Any, ctx: BuildContext, report: StageReport, steps: int, seed: int):
    obj = _build("controller", cfg, ctx)
    name = cfg.type
    assert ctx.max_step is not None  # `check_stage` gives one
    rng = np.random.default_rng(seed + 2)
    j = rng.normal(0.0, 30.0, (ctx.p, ctx.q))
    obj.reset()
    s = rng.normal(0.0, 5.0, ctx.p)
    target = s + j @ (0.3 * ctx.max_step * rng.uniform(-1.0, 1.0, ctx.q))
    r = np.array(ctx.home_pose, dtype=float)
    out = []
    for k in range(steps):
        u = _finite(
            "controller", name, "command(s, s*, J, r)", obj.command(s, target, j, r), (ctx.q,)
        )
        if k == 0 and float((j @ u) @ (target - s)) < -1e-12 * (1 + np.abs(u).max()):
            report.notes.append("the first command points away from a reachable target")
        out.append(u)
        s, r = s + j @ u, r + u
    report.shapes["u"] = (ctx.q,)
    return {"u": np.stack(out)}


def check_event(config: Any, *, segments: int = 20) -> str:
    """Apply one event (a config instance, or a dict with `type`) to a small rod and camera,
    through the registry as the environment does; check the log line and that the rod stays
    finite. Returns the log line.

    Raises:
        StageCheckFailed: the apply function raised, returned no line, or broke the rod.
    """
    cfg = _config("event", config)
    name = str(cfg.type)  # type: ignore[attr-defined]
    sim = RodSim(RodConfig(segments=segments))
    camera = Camera(CameraConfig())
    try:
        line = EVENTS.build(cfg, sim, camera)
    except Exception as exc:
        raise _fail("event", name, f"its apply function raised {exc!r}") from exc
    if not isinstance(line, str) or not line.strip():
        raise _fail("event", name, f"apply must return one log line, got {line!r}")
    centerline = sim.centerline()
    if not np.all(np.isfinite(centerline)):
        raise _fail("event", name, "the rod's centerline is not finite after the event")
    return line


def check_sink(config: Any, folder: str | Path, *, steps: int = 6) -> list[Path]:
    """Feed a small synthetic run through one sink (built by its factory into `folder`) and
    close it as completed; check that it wrote something there. Returns the files written.

    Raises:
        StageCheckFailed: the sink raised, or left no file in `folder`.
    """
    cfg = _config("sink", config)
    name = str(cfg.type)  # type: ignore[attr-defined]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    before = set(folder.rglob("*"))
    run = SyntheticRun(seed=1, image_every=3)
    records = run.records(steps)
    last = records[-1]
    summary = RunSummary(
        status="completed",
        outcome="converged",
        method="synthetic",
        steps=int(last.step),
        converged=True,
        steps_to_converge=int(last.step),
        final_T1=float(last.T1),
        final_pixel_error=float(last.pixel_error),
        wall_time_s=1.0,
        steps_per_s=float(steps),
    )
    try:
        sink = SINKS.build(cfg, SinkContext(folder, LoggingConfig()))
        sink.open(run.header)
        for record in records:
            sink.write(record)
        sink.close(summary, "completed")
    except Exception as exc:
        raise _fail("sink", name, f"raised {exc!r}") from exc
    written = sorted(p for p in set(folder.rglob("*")) - before if p.is_file())
    if not written or all(p.stat().st_size == 0 for p in written):
        raise _fail("sink", name, f"wrote nothing into {folder}")
    return written


def _square(x: float) -> float:
    return x * x


def check_executor(config: Any, *, workers: int = 1, tasks: int = 3) -> None:
    """Map a few tasks through an executor built by its factory; check every result comes
    back, in task order, with its key.

    Raises:
        StageCheckFailed: a result is missing, wrong, or the executor raised.
    """
    cfg = _config("executor", config)
    name = str(cfg.type)  # type: ignore[attr-defined]
    values = [float(i) + 0.5 for i in range(tasks)]
    try:
        with EXECUTORS.build(cfg, ExecutorContext(workers=workers)) as ex:
            done = ex.map(_square, values)
    except Exception as exc:
        raise _fail("executor", name, f"raised {exc!r}") from exc
    for i, d in enumerate(done):
        if d.key != i or d.error is not None or not math.isclose(d.value, values[i] ** 2):
            raise _fail("executor", name, f"task {i} came back as {d!r}")
