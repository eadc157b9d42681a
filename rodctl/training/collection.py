"""Collecting training centerlines by driving the simulated rod and looking at it.

The paper collects 100,000 centerlines "by controlling the robot to deform the object
continuously" (section VI-A). We do the same in simulation: the gripper walks, one control step at
a time (`rod.max_step` per axis at most), towards a gripper pose drawn uniformly from the
workspace, and draws a new goal when it gets there. The workspace is a box intersected with a
reach disc, which is convex, so the straight walk between two allowed poses stays allowed. Every
settled step goes through the camera pipeline (render, then extract), exactly as in an
experiment, and steps whose extraction is not ok are skipped, so the encoder learns the pixels it
will be given, noise and extractor quirks included.

The work is cut into chunks of `feature.data.chunk` samples. Each chunk is a fresh walk from the
home pose with its own seed (`SeedSequence.spawn` of the config's "data" stream), so the dataset
is the same whether one process or several collect it, and whole chunks serve as the validation
split (consecutive shapes of one walk are near-duplicates).
"""

from __future__ import annotations

import json
import multiprocessing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rodctl import signals
from rodctl.config import ExperimentConfig
from rodctl.display import task_progress
from rodctl.errors import UserError
from rodctl.features.autoencoder import fingerprint_differences, is_autoencoder
from rodctl.runs import seed_sequence

#: A walk gives up after this many control steps per wanted sample, plus `_MAX_ATTEMPTS_SLACK`
#: (a broken setup, not bad luck).
_MAX_ATTEMPTS_PER_SAMPLE = 20
_MAX_ATTEMPTS_SLACK = 100
#: The walk has arrived when every axis is within this fraction of `rod.max_step` of its goal
#: (the gripper pose is read back from the rod, so an exact match never comes).
_ARRIVED = 0.5
_MAX = np.maximum.reduce


class CollectionFailed(RuntimeError):
    """A collection walk gave up: too few of its control steps gave a usable centerline. The
    message says how many steps were skipped for each reason (the simulator diverged or did not
    settle, a move was refused, the extractor did not see the whole rod, with its most common
    note), so that a failure names what failed."""


@dataclass
class CenterlineDataset:
    """Collected centerlines and where they came from.

    Attributes:
        centerlines: (M, N, 2) float32 extracted centerlines, pixels, clamp end first.
        poses: (M, 3) gripper pose [x, y, theta] of each sample, world frame.
        chunk: (M,) index of the walk each sample belongs to.
        attempts: control steps taken in total (samples + skipped steps).
    """

    centerlines: np.ndarray
    poses: np.ndarray
    chunk: np.ndarray
    attempts: int = 0

    def __len__(self) -> int:
        return int(self.centerlines.shape[0])

    def save(self, path: str | Path, *, fingerprint: dict[str, Any]) -> None:
        """Write an .npz (no pickles) holding the arrays and the setup they were collected for."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(
            tmp,
            centerlines=self.centerlines.astype(np.float32),
            poses=self.poses.astype(np.float64),
            chunk=self.chunk.astype(np.int32),
            attempts=np.int64(self.attempts),
            setup=np.array(json.dumps(dataset_setup(fingerprint), sort_keys=True)),
        )
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path, *, expected: dict[str, Any] | None = None) -> CenterlineDataset:
        """Read a dataset written by `save`.

        Args:
            path: the .npz file.
            expected: an encoder fingerprint; when given, the dataset must have been collected
                for the same rod, camera and N.

        Raises:
            UserError: missing or unreadable file, missing arrays, or another setup; the message
                names the file.
        """
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path}: dataset not found")
        try:
            with open(path, "rb") as f:
                zipped = f.read(4) == b"PK\x03\x04"
        except OSError as exc:
            raise UserError(f"{path}: not a readable centerline dataset ({exc})") from None
        if not zipped:  # np.load would try it as a pickle and say so
            raise UserError(
                f"{path}: not a centerline dataset (not a NumPy .npz archive; expected the "
                "dataset.npz of a train-encoder run)"
            )
        try:
            with np.load(path, allow_pickle=False) as npz:
                data = {k: npz[k] for k in ("centerlines", "poses", "chunk", "attempts", "setup")}
            setup = json.loads(str(data["setup"]))
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise UserError(f"{path}: not a readable centerline dataset ({exc})") from None
        cl = data["centerlines"]
        if (
            cl.ndim != 3
            or cl.shape[2] != 2
            or len(data["poses"]) != len(cl)
            or len(data["chunk"]) != len(cl)
        ):
            raise UserError(f"{path}: inconsistent dataset arrays (centerlines {cl.shape})")
        if len(cl) < 2:
            raise UserError(
                f"{path}: the dataset holds {len(cl)} centerline(s); training needs more"
            )
        if expected is not None and cl.shape[1] != expected.get("points", cl.shape[1]):
            raise UserError(
                f"{path}: the dataset's centerlines have {cl.shape[1]} points, this config's "
                f"camera.points is {expected['points']}"
            )
        if expected is not None:
            diffs = fingerprint_differences(setup, dataset_setup(expected))
            if diffs:
                raise UserError(
                    f"{path}: this dataset was collected for a different setup:\n  "
                    + "\n  ".join(d.replace("checkpoint", "dataset") for d in diffs)
                )
        return cls(cl, data["poses"], data["chunk"], int(data["attempts"]))


def dataset_setup(fingerprint: dict[str, Any]) -> dict[str, Any]:
    """The part of an encoder fingerprint a dataset depends on (all but the architecture)."""
    return {k: v for k, v in fingerprint.items() if k != "architecture"}


def chunk_sizes(samples: int, chunk: int) -> list[int]:
    """Split `samples` into walks of `chunk` samples, the last one shorter."""
    full, rest = divmod(samples, chunk)
    return [chunk] * full + ([rest] if rest else [])


def sample_goal(gen: np.random.Generator, sim: Any, cfg: ExperimentConfig) -> np.ndarray:
    """A gripper pose uniform over the allowed workspace (box, angle limits and reach)."""
    ws = cfg.rod.workspace
    lo = np.array([ws.x_limits[0], ws.y_limits[0], ws.theta_limits[0]])
    hi = np.array([ws.x_limits[1], ws.y_limits[1], ws.theta_limits[1]])
    for _ in range(10_000):
        pose = gen.uniform(lo, hi)
        if not sim.clip_pose(pose)[1]:
            return pose
    raise UserError("rod.workspace: no gripper pose in the box is within reach of the clamp")


def sample_end_goals(
    gen: np.random.Generator, sim: Any, cfg: ExperimentConfig, grip: np.ndarray
) -> np.ndarray:
    """Dual-arm: a (6,) goal, the gripper's `grip` and an x0-end pose uniform over the second
    arm's workspace box, redrawn (both) until the pair is allowed (within reach)."""
    ws = cfg.rod.clamp_arm.workspace
    lo = np.array([ws.x_limits[0], ws.y_limits[0], ws.theta_limits[0]])
    hi = np.array([ws.x_limits[1], ws.y_limits[1], ws.theta_limits[1]])
    for _ in range(10_000):
        pose = np.concatenate([grip, gen.uniform(lo, hi)])
        if not sim.clip_pose(pose)[1]:
            return pose
        grip = sample_goal(gen, sim, cfg)
    raise UserError("rod.clamp_arm.workspace: no pair of end poses is within reach")


def random_walk_start(cfg_json: str, seed: np.random.SeedSequence) -> tuple:
    """What a random-motion walk through the camera starts from (encoder data and the learned
    model's walks alike): (config, the walk's generator, a camera with its own noise stream, the
    extractor, the speed limit, a rod at home, the first goal pose), all from `seed`."""
    # Lazy: the simulator (pymunk) and the camera (OpenCV) only to collect; `train-encoder`
    # imports this module to read a dataset file too.
    from rodctl.sim import RodSim  # noqa: PLC0415
    from rodctl.vision import Camera, CenterlineExtractor  # noqa: PLC0415

    cfg = ExperimentConfig.model_validate_json(cfg_json)
    walk_seed, camera_seed = seed.spawn(2)
    gen = np.random.Generator(np.random.PCG64(walk_seed))
    clamp = np.asarray(cfg.rod.clamp_pose, dtype=float)
    camera = Camera(cfg.camera, np.random.Generator(np.random.PCG64(camera_seed)))
    extractor = CenterlineExtractor(cfg.camera, camera, clamp)
    max_step = np.asarray(cfg.rod.max_step, dtype=float)
    sim = RodSim(cfg.rod)
    return cfg, gen, camera, extractor, max_step, sim, sample_goal(gen, sim, cfg)


def collect_chunk(cfg_json: str, count: int, seed: np.random.SeedSequence) -> dict[str, Any]:
    """One seeded walk that yields `count` extracted centerlines (runs in a worker process).

    Args:
        cfg_json: the experiment config as JSON (cheap to send to a process).
        count: samples wanted.
        seed: this walk's seed; its children seed the goals and the camera noise.

    Returns:
        {"centerlines": (count, N, 2) float32, "poses": (count, 3), "attempts": int}.

    Raises:
        CollectionFailed: the walk needed more than 20 control steps per sample (plus 100); the
            message counts the skipped steps by reason.
    """
    walk = _Walk(cfg_json, seed)
    points = np.empty((count, walk.cfg.camera.points, 2), dtype=np.float32)
    poses = np.empty((count, 3))
    n = attempts = 0
    while n < count:
        attempts += 1
        if attempts > _MAX_ATTEMPTS_PER_SAMPLE * count + _MAX_ATTEMPTS_SLACK:
            raise CollectionFailed(_failure_message(attempts - 1, n, walk.skipped, walk.notes))
        sample = walk.step()
        if sample is not None:
            points[n], poses[n] = sample
            n += 1
    return {"centerlines": points, "poses": poses, "attempts": attempts}


class _Walk:
    """The random walk of `collect_chunk`: the rod, the camera, the goal, and why steps were
    skipped. Dual-arm (`rod.arms: 2`): both ends walk, each over its own workspace, and the
    extractor starts at the x0 end, wherever it is."""

    def __init__(self, cfg_json: str, seed: np.random.SeedSequence) -> None:
        from rodctl.sim import RodSim  # noqa: PLC0415 (lazily: `random_walk_start`)
        from rodctl.vision import CenterlineExtractor  # noqa: PLC0415 (lazily, as RodSim)

        self._sim_type, self._extractor_type = RodSim, CenterlineExtractor
        start = random_walk_start(cfg_json, seed)
        self.cfg, self.gen, self.camera, self.extractor, self.max_step, self.sim, goal = start
        self.clamp = np.asarray(self.cfg.rod.clamp_pose, dtype=float)
        self.dual = self.cfg.rod.arms == 2
        if self.dual:
            self.max_step = self.sim.max_steps
            goal = sample_end_goals(self.gen, self.sim, self.cfg, goal)
        self.goal = goal
        self.skipped = dict.fromkeys(
            ("goal reached", "diverged", "refused", "unsettled", "not extracted"), 0
        )
        self.notes: dict[str, int] = {}

    def new_goal(self) -> np.ndarray:
        grip = sample_goal(self.gen, self.sim, self.cfg)
        return sample_end_goals(self.gen, self.sim, self.cfg, grip) if self.dual else grip

    def _skip(self, why: str, goal: bool = False) -> None:
        self.skipped[why] += 1
        if goal:
            self.goal = self.new_goal()

    def step(self) -> tuple[np.ndarray, np.ndarray] | None:
        """One control step towards the goal: (extracted points, gripper pose), or None when
        the step is skipped (counted in `skipped`, the extractor's note in `notes`)."""
        sim = self.sim
        delta = self.goal - np.asarray(sim.end_poses if self.dual else sim.gripper_pose, float)
        # np.max and np.clip as their bare ufuncs (the same bits without their Python layers:
        # a walk's own overhead per shape, beside ~1 ms of physics, rendering and extraction).
        max_step = self.max_step
        if _MAX(np.abs(delta) / max_step) < _ARRIVED:
            self._skip("goal reached", goal=True)
            return None
        res = sim.apply(np.minimum(np.maximum(delta, -max_step), max_step))
        if res.diverged:
            self.sim = self._sim_type(self.cfg.rod)
            self._skip("diverged", goal=True)
            return None
        if res.refused:
            self._skip("refused", goal=True)
            return None
        if not res.settled:
            self._skip("unsettled")
            return None
        pose = np.asarray(sim.gripper_pose, dtype=float)
        if self.dual:  # the extractor starts at the x0 end, wherever it is now
            self.clamp = sim.clamp_pose
            self.extractor = self._extractor_type(self.cfg.camera, self.camera, self.clamp)
        frame = self.camera.render(sim.centerline(), pose, self.clamp, transient=True)
        ext = self.extractor.extract(frame, pose)
        if not ext.ok:
            note = ext.note or "no note"
            self.notes[note] = self.notes.get(note, 0) + 1
            self._skip("not extracted")
            return None
        return ext.points, pose


def _failure_message(steps: int, n: int, skipped: dict[str, int], notes: dict[str, int]) -> str:
    """One line: how many steps gave how few centerlines, and why the others were skipped."""
    why = ", ".join(f"{k} {v}" for k, v in skipped.items() if v)
    if notes:
        note, times = max(notes.items(), key=lambda kv: kv[1])
        why += f" (the extractor's most common note, {times} times: {note!r})"
    return (
        f"data collection: {steps} control steps of a walk gave only {n} usable centerlines "
        f"(skipped: {why or 'none'}); the simulator or the extractor fails on most shapes"
    )


def _collect_task(args: tuple[str, int, np.random.SeedSequence]) -> dict[str, Any]:
    return collect_chunk(*args)


def _start_method() -> str:
    """The multiprocessing start method for collection workers.

    "spawn" (a clean interpreter: no torch or OpenMP state inherited) when the main module can be
    re-imported by the workers, as for the CLI, pytest or a script; "fork" otherwise (code fed on
    stdin or typed interactively), where spawned workers would fail to start.
    """
    # The main module of the moment, read at the call (runpy swaps it in `python -m`).
    import __main__  # noqa: PLC0415

    main_file = getattr(__main__, "__file__", None)
    if main_file is None or not Path(main_file).is_file():
        if "fork" in multiprocessing.get_all_start_methods():
            return "fork"
    return "spawn"


def map_chunks(fn: Any, tasks: list[Any], workers: int) -> Any:
    """(task, fn(task)) for every task, in order: in this process for one worker or one task,
    else in a pool of `workers` processes (the start method of `_start_method`). `fn` must be a
    module-level function (it is pickled to the workers)."""
    if workers == 1 or len(tasks) == 1:
        for task in tasks:
            yield task, fn(task)
        return
    ctx = multiprocessing.get_context(_start_method())
    # The workers keep SIGINT blocked for good: a Ctrl-C (sent to the whole process group) is
    # this process's to handle; leaving the `with` terminates them (no traceback from each).
    with signals.held_from_children():
        pool = ctx.Pool(min(workers, len(tasks)))
    with pool:
        yield from zip(tasks, pool.imap(fn, tasks), strict=True)


def collect_dataset(
    cfg: ExperimentConfig,
    *,
    progress: bool = True,
    keep_partial: Path | None = None,
    fingerprint: dict[str, Any] | None = None,
) -> CenterlineDataset:
    """Collect `cfg.feature.data.samples` centerlines through the simulator and the camera.

    Uses `cfg.feature.data.workers` processes (see `_start_method`); the result does not depend
    on that number.

    Args:
        cfg: the experiment config; `cfg.feature` must be an autoencoder.
        progress: show a rich progress bar.
        keep_partial: where to save the chunks collected so far if the collection is
            interrupted (SIGINT/SIGTERM), so that `train-encoder --dataset` can reuse them;
            needs `fingerprint`.
        fingerprint: the encoder fingerprint the dataset is saved with.

    Returns:
        The dataset, chunks in order.
    """
    feature = cfg.feature
    assert is_autoencoder(feature), "the training data of an autoencoder feature"
    data_cfg = feature.data
    sizes = chunk_sizes(data_cfg.samples, data_cfg.chunk)
    seeds = seed_sequence(cfg.seed, "data").spawn(len(sizes))
    cfg_json = cfg.model_dump_json()
    tasks = [(cfg_json, size, s) for size, s in zip(sizes, seeds, strict=True)]
    results: list[dict[str, Any]] = []
    try:
        with task_progress(
            "collecting", data_cfg.samples, progress, lines_unit="samples"
        ) as advance:
            for task, res in map_chunks(_collect_task, tasks, data_cfg.workers):
                results.append(res)
                advance(n=task[1])
    except KeyboardInterrupt:
        # Chunks finish in order (imap), so the first len(results) chunks are whole: keep them.
        if keep_partial is not None and len(results) >= 1 and fingerprint is not None:
            _assemble(results).save(keep_partial, fingerprint=fingerprint)
        raise
    return _assemble(results)


def _assemble(results: list[dict[str, Any]]) -> CenterlineDataset:
    """The dataset of the first len(results) chunks."""
    return CenterlineDataset(
        centerlines=np.concatenate([r["centerlines"] for r in results]),
        poses=np.concatenate([r["poses"] for r in results]),
        chunk=np.concatenate(
            [np.full(len(r["centerlines"]), i, dtype=np.int32) for i, r in enumerate(results)]
        ),
        attempts=int(sum(r["attempts"] for r in results)),
    )
