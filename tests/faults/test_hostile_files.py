"""Hostile checkpoints, datasets and run directories: each refused with one message naming the
file, never a traceback or a run that fails later."""

from __future__ import annotations

import numpy as np
import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config import load_config
from rodctl.features.autoencoder import EncoderCheckpoint, encoder_fingerprint
from rodctl.training.collection import CenterlineDataset

DEFAULT = str(REPO / "configs/default.yaml")
QUICK = ["--set", "logging.rerun=false", "--set", "logging.figures=false"]


@pytest.mark.parametrize(
    ("key", "value"), [("input_scale", None), ("fingerprint", [1, 2, 3]), ("metrics", "x")]
)
def test_a_checkpoint_with_a_wrong_typed_field_is_refused(tmp_path, key, value):
    torch = pytest.importorskip("torch")
    data = EncoderCheckpoint.load(REPO / "rodctl/assets/encoder.npz").to_dict()
    data[key] = value
    bad = tmp_path / "bad.pt"
    torch.save(data, bad)
    res = CliRunner().invoke(
        app,
        ["simulate", DEFAULT, "-o", str(tmp_path / "runs"), "--set", f"feature.checkpoint={bad}"],
    )
    assert res.exit_code == 2, res.output
    assert "not a valid rodctl encoder checkpoint" in res.output and "Traceback" not in res.output


def _dataset(tmp_path, n: int, points: int):
    cfg = load_config(DEFAULT, [f"camera.points={points}"] if points != 100 else [])
    rng = np.random.default_rng(0)
    data = CenterlineDataset(
        rng.uniform(100, 400, (n, points, 2)), np.zeros((n, 3)), np.arange(n) // 2, n
    )
    path = tmp_path / f"d{n}x{points}.npz"
    data.save(path, fingerprint=encoder_fingerprint(cfg))
    return path


@pytest.mark.parametrize(("n", "points", "why"), [(0, 100, "0 centerline"), (20, 50, "50 points")])
def test_an_empty_or_mismatched_dataset_is_refused_before_training(tmp_path, n, points, why):
    path = _dataset(tmp_path, n, points)
    res = CliRunner().invoke(
        app, ["train-encoder", DEFAULT, "-q", "-o", str(tmp_path / "runs"), "--dataset", str(path)]
    )
    assert res.exit_code == 2, res.output
    assert why in res.output and "Traceback" not in res.output


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["edit", "garbage", "delete"])
def test_verify_reports_a_config_yaml_that_no_longer_matches_the_log(tmp_path, damage):
    runner = CliRunner()
    res = runner.invoke(
        app, ["simulate", DEFAULT, "-q", "-o", str(tmp_path), "--set", "run.max_steps=5", *QUICK]
    )
    run_dir = tmp_path / res.output.strip().splitlines()[-1].split("/")[-1]
    cfg = run_dir / "config.yaml"
    if damage == "edit":
        cfg.write_text(cfg.read_text().replace("max_steps: 5", "max_steps: 6"))
    elif damage == "garbage":
        cfg.write_text("{{{ not yaml")
    else:
        cfg.unlink()
    res = runner.invoke(app, ["replay", str(run_dir), "--verify", "--no-figures"])
    assert res.exit_code == 1, res.output
    assert "config.yaml differs from the log" in res.output
    if damage == "edit":
        assert "run.max_steps" in res.output
    # The last line is the verdict (a trial read the rerun's "OK … identical" as a pass)
    assert res.stderr.strip().splitlines()[-1].startswith("verify: FAILED: the log's steps rerun")


def test_messages_print_plain_numbers(tmp_path):
    """A user reads 0.4, not np.float64(0.4), in error messages."""
    res = CliRunner().invoke(
        app,
        ["simulate", DEFAULT, "--set", "run.target.pose=[5.0, 0.0, 0.0]", "-q", "-o", str(tmp_path)]
        + list(QUICK),
    )
    assert res.exit_code == 2 and "np.float64" not in res.output, res.output
    assert "run.target.pose" in res.output
