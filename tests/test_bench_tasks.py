"""The typed episode tasks of the batch layer: what `--resume` keeps is decided by their keys,
and a task crosses to a spawn worker or Ray by pickling."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from rodctl.bench import episodes
from rodctl.bench.journal import ResultsLog, finished_rows
from rodctl.bench.tasks import EpisodeTask, TargetTask, row_key
from rodctl.config import ExperimentConfig
from rodctl.env import ShapeServoEnv


def _compare_task(method: str, target: int, **kw) -> EpisodeTask:
    return EpisodeTask(
        config={"name": "x"},
        method=method,
        target=target,
        pose=(0.5, 0.0, 0.0),
        seed=7,
        columns={"scenario": None, "seed": 0, "band": "easy", "converged": False},
        **kw,
    )


def _sweep_task(method: str, target: int, point: int, seed: int) -> EpisodeTask:
    return EpisodeTask(
        config={"name": "x"},
        method=method,
        target=target,
        pose=(0.5, 0.0, 0.0),
        seed=11,
        tags={"point": point, "seed": seed, "difficulty": 0.2, "estimator.p0": 10.0},
    )


def test_a_resumed_run_keeps_the_final_rows_of_its_own_episodes(tmp_path):
    """The journal's rows are matched to tasks by key: a sweep's point and seed tell two
    episodes of one method on one target apart; an interrupted row is run again, and so is a
    task that wants its records (they are not in the journal)."""
    log = ResultsLog(tmp_path / "results.jsonl")
    tasks = [_sweep_task("m", 0, p, s) for p in (0, 1) for s in (0, 1)]
    for t, outcome in zip(tasks, ["converged", "stalled", "interrupted", "converged"], strict=True):
        log.append({**t.row_tags(), "outcome": outcome, "steps": 3})
    kept = finished_rows(log, tasks)
    assert set(kept) == {tasks[0].key, tasks[1].key, tasks[3].key}
    assert kept[tasks[1].key]["outcome"] == "stalled"

    log = ResultsLog(tmp_path / "compare.jsonl")
    a, b = _compare_task("a", 0), _compare_task("a", 1, want_records=True)
    for t in (a, b):
        log.append({**t.row_tags(), "outcome": "converged"})
    assert set(finished_rows(log, [a, b])) == {a.key}


def test_a_tasks_key_is_its_rows_key_and_a_compare_row_has_no_sweep_point():
    t = _compare_task("a", 3)
    row = {**t.row_tags(), "outcome": "converged"}
    assert t.key == row_key(row) == ("a", 3, None, None)
    s = _sweep_task("a", 3, point=2, seed=5)
    assert s.key == row_key({**s.row_tags(), "outcome": "error"}) == ("a", 3, 2, 5)


def test_tasks_pickle_for_the_spawn_pool_and_ray_and_are_frozen():
    t = _compare_task("a", 0, target_view={"pixels": np.zeros((4, 2))}, target_difficulty=0.3)
    back = pickle.loads(pickle.dumps(t))
    assert (back.method, back.target, back.pose, back.columns) == (
        t.method,
        t.target,
        t.pose,
        t.columns,
    )
    np.testing.assert_array_equal(back.target_view["pixels"], np.zeros((4, 2)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.seed = 1  # type: ignore[misc]
    seq = np.random.SeedSequence(3).spawn(1)[0]
    target = pickle.loads(pickle.dumps(TargetTask({"x": 1}, seed_seq=seq, band=(0.1, 0.2))))
    assert target.seed_seq is not None
    assert target.seed_seq.generate_state(2).tolist() == seq.generate_state(2).tolist()


def test_an_autoencoder_method_reused_by_a_worker_runs_as_one_built_for_the_episode():
    """A worker builds an autoencoder method once per config and reuses it (its checkpoint is
    loaded once): the next episode's row is the one a freshly built method gives."""
    cfg = ExperimentConfig.model_validate(
        {
            "rod": {"engine": "quasistatic"},
            "run": {"max_steps": 12},
            "feature": {"type": "autoencoder"},
        }
    )
    env = ShapeServoEnv(cfg)

    def task(seed: int) -> EpisodeTask:
        t = env.make_target(seed=seed)
        view = {"centerline": t.centerline, "pixels": t.pixels}
        return EpisodeTask(
            config=cfg.model_dump(mode="json"),
            method="paper",
            target=seed,
            pose=tuple(float(v) for v in t.pose),
            seed=seed,
            target_view=view,
            target_difficulty=t.difficulty,
        )

    def row(t: EpisodeTask) -> dict:
        r = episodes.run_episode_task(t)
        r.pop("wall_time_s")
        return r

    episodes._METHODS.clear()
    first, second = task(3), task(4)
    row(first)
    reused = row(second)
    assert len(episodes._METHODS) == 1  # built once, used twice
    episodes._METHODS.clear()
    assert row(second) == reused  # a method built for this episode
    assert reused["outcome"] != "error" and reused["steps"] > 4
