"""What a stopped compare or sweep says: the signal once, and "partial results kept" only when
some episode finished."""

from __future__ import annotations

import pytest
from paths import REPO
from typer.testing import CliRunner

import rodctl.bench.runner as runner_module
from rodctl.bench.journal import ResultsLog
from rodctl.bench.runner import stream_episodes
from rodctl.bench.tasks import EpisodeTask
from rodctl.cli import app
from rodctl.executors.base import Done, clear_stop, stop_reason


@pytest.fixture(autouse=True)
def _no_stop_left():
    clear_stop()
    yield
    clear_stop()


class _OneRow:
    """An executor whose one task comes back as a worker's interrupted row."""

    def submit(self, fn, task, key):
        self.key = key

    def results(self):
        row = {"method": "m", "target": 0, "outcome": "interrupted",
               "error": "interrupted by SIGTERM"}  # fmt: skip
        yield Done(self.key, value=row)


def test_a_workers_signal_is_named_once(tmp_path):
    task = EpisodeTask(config={}, method="m", target=0, pose=(0.0, 0.0, 0.0), seed=0)
    stream_episodes(_OneRow(), [task], ResultsLog(tmp_path / "r.jsonl"), progress=False)
    assert stop_reason() == "SIGTERM"


@pytest.mark.slow
def test_a_stop_before_any_episode_finished_does_not_claim_results(tmp_path, monkeypatch):
    def stopped(*args, **kwargs):
        raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(runner_module, "stream_episodes", stopped)
    res = CliRunner().invoke(
        app, ["compare", str(REPO / "configs/compare-smoke.yaml"), "-q", "-o", str(tmp_path),
              "--workers", "1", "--set", "targets.count=1"],
    )  # fmt: skip
    assert res.exit_code == 1, res.output
    assert "interrupted by SIGTERM: 0 of 6 episodes finished; no episode had finished" in res.output
    assert "partial results kept" not in res.output
