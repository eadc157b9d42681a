"""`rodctl train-model`: collects random motion, fits the learned Jacobian, writes the model."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.estimation.learned import RbfJacobianModel

TINY = [
    "--set", "rod.segments=12", "--set", "camera.points=20",
    "--set", "estimator.data.samples=40", "--set", "estimator.data.chunk=20",
    "--set", "estimator.data.workers=1", "--set", "estimator.training.centres=4",
]  # fmt: skip


@pytest.mark.slow
def test_train_model_writes_a_model_the_config_then_accepts(tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    runner = CliRunner()
    res = runner.invoke(
        app, ["train-model", "configs/yu2023.yaml", "-q", "-o", str(tmp_path), *TINY]
    )
    assert res.exit_code == 0, res.output
    run = Path(res.output.strip().splitlines()[-1])
    metrics = json.loads((run / "metrics.json").read_text())
    model = RbfJacobianModel.load(run / "model.npz")
    assert metrics["sha256"] == model.digest()
    assert metrics["train_pairs"] > 0 and metrics["fingerprint"]["rod"]["length"] == 0.5
    # The model fits the config it was trained with, and is refused for another rod.
    from rodctl.config import load_config
    from rodctl.errors import UserError

    sets = [a for a in TINY if a != "--set"] + [f"estimator.checkpoint={run / 'model.npz'}"]
    load_config("configs/yu2023.yaml", sets)
    try:
        load_config("configs/yu2023.yaml", [*sets, "rod.length=0.4"])
    except UserError as exc:
        assert "rod.length" in str(exc) and "other_setup=accept" in str(exc)
    else:
        raise AssertionError("a model trained for another rod length was accepted")
    load_config("configs/yu2023.yaml", [*sets, "rod.length=0.4", "estimator.other_setup=accept"])


def test_train_model_refuses_a_config_without_the_learned_estimator(tmp_path):
    res = CliRunner().invoke(
        app, ["train-model", str(REPO / "configs/default.yaml"), "-o", str(tmp_path)]
    )
    assert res.exit_code == 2
    assert "estimator.type=learned" in res.output
    assert not list(tmp_path.iterdir())  # no run directory for bad input


def test_a_small_collection_says_what_it_changed(tmp_path, monkeypatch):
    """Found by a new-user trial: 10 samples trained without a word a model with no
    validation and 10 centres instead of the configured ones."""
    monkeypatch.chdir(REPO)
    small = [*TINY, "--set", "estimator.data.samples=10"]
    res = CliRunner().invoke(
        app, ["train-model", "configs/yu2023.yaml", "-q", "-o", str(tmp_path), *small]
    )
    assert res.exit_code == 0, res.output
    assert (
        "warning: 10 samples in 1 walk(s) of estimator.data.chunk = 20: no walk is held out: "
        "metrics.json's validation is null" in res.output
    )
    assert "the model has 4 centres" not in res.output  # 4 asked for, 10 distinct states
    run = Path(res.output.strip().splitlines()[-1])
    assert json.loads((run / "metrics.json").read_text())["validation"] is None
    again = [*TINY, "--set", "estimator.data.samples=10", "--set", "estimator.training.centres=50"]
    res = CliRunner().invoke(
        app, ["train-model", "configs/yu2023.yaml", "-q", "-o", str(tmp_path), *again]
    )
    assert "the model has 10 centres, not the 50 of estimator.training.centres" in res.output
