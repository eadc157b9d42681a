"""The tasks a study hands its executor: typed, frozen, and plain enough to pickle.

An `EpisodeTask` is one method on one target (in a sweep, at one point, on one target seed): it
says everything its worker (`rodctl.bench.episodes.run_episode_task`) needs, the method's whole
experiment config included, so the worker depends on nothing but the task and every executor
(this process, a spawn pool, Ray) runs it alike. A `TargetTask` is one target to find and settle
(`rodctl.bench.target_set`).

`row_key` is what identifies an episode across runs (a task, or the row its worker returned, or
a row read back from results.jsonl): the key `--resume` and the journal go by.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class EpisodeTask:
    """One episode of a study.

    Attributes:
        config: the method's `ExperimentConfig` as plain data (`model_dump(mode="json")`); the
            worker sets its `seed` and `run.target.pose` from this task.
        method: the method's name in the study.
        target: the target's index in its target set.
        pose: the target's gripper pose [x, y, theta] (rod.arms: 2: six values, both ends').
        seed: the episode's experiment seed (camera noise), shared by every method on the
            target.
        target_view: the target as the clean camera saw it, {"centerline": (M, 2) m, "pixels":
            (N, 2) px}, reused instead of driving a rod there again; None: the episode makes it.
        target_difficulty: the target's difficulty (with `target_view`).
        want_records: return the episode's header and step records in the row (`_records`,
            for the side-by-side figures; never written to the journal).
        log_dir: where the episode's own logs go (config.yaml, summary.json, its sinks'
            files), or None.
        run_id: the episode's run id in its logs; None: `<method>_t<target>`.
        diagnose: examine a stalled or pinned episode for why (`rodctl.diagnosis`).
        tags: a sweep's identifying columns of the row: `point`, `seed`, `difficulty` and the
            swept values.
        columns: a compare's target columns of the row (so results.jsonl carries every column
            of results.csv).
    """

    config: Mapping[str, Any]
    method: str
    target: int
    pose: tuple[float, ...]
    seed: int
    target_view: Mapping[str, Any] | None = None
    target_difficulty: float | None = None
    want_records: bool = False
    log_dir: str | None = None
    run_id: str | None = None
    diagnose: bool = False
    tags: Mapping[str, Any] = field(default_factory=dict)
    columns: Mapping[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> tuple:
        """The episode's key (`row_key` of its row)."""
        return row_key(self.row_tags())

    @property
    def name(self) -> str:
        """The episode's run id in its logs."""
        return self.run_id or f"{self.method}_t{self.target:03d}"

    def row_tags(self) -> dict[str, Any]:
        """The identifying columns of the task's row (method, target, and a sweep's tags), and
        a compare's target columns."""
        return {"method": self.method, "target": self.target, **self.tags, **self.columns}


@dataclass(frozen=True)
class TargetTask:
    """One target to find and settle: a given pose, or one sampled in a difficulty band.

    Attributes:
        config: the experiment (plain data) whose rod and camera make the target.
        pose: the given pose, or None to sample one.
        seed_seq: the sampled target's own seed stream (with `band`).
        band: the (low, high) normalised offset from home to sample in (with `seed_seq`).
    """

    config: Mapping[str, Any]
    pose: tuple[float, ...] | None = None
    seed_seq: np.random.SeedSequence | None = None
    band: tuple[float, float] | None = None


def row_key(row: Mapping[str, Any]) -> tuple:
    """What identifies an episode (its row, or a task's `row_tags`) across runs: method, target
    and, in a sweep, its point and seed."""
    sweep = (row["point"], row["seed"]) if "point" in row else (None, None)
    return (row["method"], row["target"], *sweep)
