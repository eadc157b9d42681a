"""The shared targets of a study: given (a file, a list) or sampled in difficulty bands, each
checked reachable by driving a rod there once, and what the clean camera saw there kept, so every
method's episode on the target reuses it (issue #17).

Sampled targets spread evenly over [min_offset, max_offset]: target i is drawn in the i-th of K
equal sub-bands from its own child of the 'targets' seed stream, so the set depends neither on
the worker count nor on the executor. The pose sampler is the environment's own
(`rodctl.targets.target_candidates`, through `ShapeServoEnv.make_target`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from rodctl.bench.tasks import TargetTask
from rodctl.config import ExperimentConfig
from rodctl.config.compare import (
    MAX_TARGETS,
    CompareTargetsConfig,
    check_pose_lengths,
    pose_kind,
)
from rodctl.config.loading import ConfigError, parse_yaml, read_yaml_text
from rodctl.env import ShapeServoEnv
from rodctl.errors import UserError
from rodctl.runs import seed_sequence


class TargetSpec(Protocol):
    """What target making reads of a compare config (a sweep gives one per seed)."""

    @property
    def seed(self) -> int: ...

    @property
    def base(self) -> ExperimentConfig: ...

    @property
    def targets(self) -> CompareTargetsConfig: ...


@dataclass
class CompareTarget:
    """One shared target: the gripper pose that makes it and how hard it is.

    Attributes:
        index: position in the target set (targets are numbered easy to hard when sampled).
        pose: (3,) gripper pose [x, y, theta], world frame, as the rod settled there (rod.arms:
            2: (6,), the gripper's pose then the x0 end's).
        difficulty: normalised distance of `pose` from the home pose (`rodctl.targets`).
        seed: the experiment seed of every episode on this target (camera noise).
        view: what the clean camera saw there, {"centerline": (M, 2) m, "pixels": (N, 2) px}:
            every method's episode reuses it instead of driving a rod to the target again
            (the same rod and camera made it; `settle_target`). None: each episode makes it.
    """

    index: int
    pose: np.ndarray
    difficulty: float
    seed: int
    view: dict[str, Any] | None = None

    def band(self, edges: Sequence[float]) -> str:
        """The difficulty band's name: easy / medium / hard for two edges, else band0..bandN."""
        i = int(np.searchsorted(np.asarray(edges, dtype=float), self.difficulty, side="right"))
        names = ("easy", "medium", "hard") if len(edges) == 2 else None
        return names[i] if names else f"band{i}"


def target_seeds(seed: int, k: int) -> list[int]:
    """(k,) per-target experiment seeds from the 'compare' stream."""
    state = seed_sequence(seed, "compare").generate_state(k, dtype=np.uint32)
    return [int(v) for v in state]


def read_target_file(path: str | Path, arms: int = 1) -> list[list[float]]:
    """Gripper poses from a YAML/JSON file: a list of [x, y, theta], or {targets: [...]}.

    `arms`: the rod's `rod.arms`; with 2 every pose holds 6 values, both ends' poses (the
    gripper's, then the x0 end's), and 3-value poses are refused (`check_pose_lengths`).

    Raises:
        ConfigError: missing file, not YAML, or not a non-empty list of 3-number (rod.arms: 2:
            6-number) poses.
    """
    path = Path(path)
    # The rules of config files: size, nesting, duplicate keys and alias bombs refused.
    data = parse_yaml(read_yaml_text(path, f"targets.file {path}"), f"targets.file {path}")
    if isinstance(data, dict) and "targets" in data:
        data = data["targets"]
    kind = pose_kind(arms)
    if not isinstance(data, list) or not data:
        raise ConfigError(f"targets.file {path}: expected a non-empty list of {kind}")
    if len(data) > MAX_TARGETS:
        raise ConfigError(
            f"targets.file {path}: {len(data)} poses, more than the {MAX_TARGETS} a compare takes"
        )
    poses = []
    for i, item in enumerate(data):
        ok = isinstance(item, list | tuple) and len(item) in (3, 6)
        ok = ok and all(isinstance(v, int | float) and math.isfinite(v) for v in item)
        if not ok:
            want = "[x, y, theta] (three" if arms == 1 else "6 values (six"
            raise ConfigError(
                f"targets.file {path}: item {i} is {item!r}; expected {want} finite numbers: "
                "metres, metres, radians" + (")" if arms == 1 else " for each end)")
            )
        poses.append([float(v) for v in item])
    check_pose_lengths(poses, arms, f"targets.file {path}", ConfigError)
    return poses


def check_config(cfg: TargetSpec) -> ExperimentConfig:
    """The base with cheap stages: target checks need the rod and camera, not a method."""
    data = cfg.base.model_dump(mode="json")
    data.update(feature={"type": "nodes"}, estimator={"type": "akf"}, controller={"type": "mfac"})
    return ExperimentConfig.model_validate(data)


def settle_target(task: TargetTask) -> dict[str, Any]:
    """Worker: find a usable target (the given pose, or one sampled in the task's band) and
    settle it: the rod settles there and the camera extracts its centerline
    (`ShapeServoEnv.make_target`, whose sampler draws the candidates).

    Returns:
        {"pose", "difficulty", "view"} or {"error"}.
    """
    env = ShapeServoEnv(ExperimentConfig.model_validate(task.config))
    try:
        if task.pose is not None:
            target = env.make_target(list(task.pose))
        else:
            assert task.seed_seq is not None and task.band is not None
            gen = np.random.Generator(np.random.PCG64(task.seed_seq))
            target = env.make_target(band=task.band, generator=gen)
    except UserError as exc:
        return {"error": str(exc)}
    return {
        "pose": [float(v) for v in target.pose],
        "difficulty": float(target.difficulty),
        "view": {"centerline": target.centerline, "pixels": target.pixels},
    }


def given_target_poses(cfg: TargetSpec, config_dir: Path) -> list[list[float]] | None:
    """The target poses from `targets.file` (relative to `config_dir`) or `targets.poses`."""
    tc = cfg.targets
    if tc.file is not None:
        path = Path(tc.file)
        return read_target_file(
            path if path.is_absolute() else config_dir / path, cfg.base.rod.arms
        )
    if tc.poses is not None:
        # A compare config checks this when it loads; a sweep's (same targets) here.
        check_pose_lengths(tc.poses, cfg.base.rod.arms, "targets.poses", ConfigError)
        return [list(p) for p in tc.poses]
    return None


def make_targets(
    cfg: TargetSpec,
    given: list[list[float]] | None,
    run_tasks: Callable[[list[TargetTask], Callable[[TargetTask], Any]], list[Any]],
) -> list[CompareTarget]:
    """The shared targets, checked reachable, numbered easy to hard when sampled.

    Sampled targets spread evenly over [min_offset, max_offset]: target i is drawn (uniform
    direction, `rodctl.targets.target_candidates`) in the i-th of K equal sub-bands, from its
    own child of the 'targets' seed stream, so the set does not depend on the worker count.

    Raises:
        UserError: a given target pose is unusable, or a sampled band has no usable pose.
    """
    tc = cfg.targets
    base = check_config(cfg).model_dump(mode="json")
    tasks: list[TargetTask]
    if given is not None:
        tasks = [TargetTask(base, pose=tuple(p)) for p in given]
    else:
        k = tc.count
        edges = np.linspace(tc.min_offset, tc.max_offset, k + 1)
        children = seed_sequence(cfg.seed, "targets").spawn(k)
        tasks = [
            TargetTask(base, seed_seq=children[i], band=(edges[i], edges[i + 1])) for i in range(k)
        ]
    results = run_tasks(tasks, settle_target)
    seeds = target_seeds(cfg.seed, len(tasks))
    targets = []
    for i, res in enumerate(results):
        if "error" in res:
            what = f"target {i} {given[i]}" if given is not None else f"sampled target {i}"
            raise UserError(f"{what} is unusable: {res['error']}")
        targets.append(
            CompareTarget(i, np.asarray(res["pose"]), res["difficulty"], seeds[i], res.get("view"))
        )
    return targets


def write_targets(targets: Sequence[CompareTarget], path: Path) -> None:
    """targets.yaml: the poses (reusable as `targets.file`) with their difficulty as comments."""
    arms = len(targets[0].pose) // 3 if targets else 1
    lines = [f"# rodctl compare targets: {pose_kind(arms)} (world, m, rad)", "targets:"]
    for t in targets:
        pose = ", ".join(repr(float(v)) for v in t.pose)
        lines.append(f"  - [{pose}]  # {t.index}: difficulty {t.difficulty:.3f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
