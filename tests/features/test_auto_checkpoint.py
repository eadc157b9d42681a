"""`feature.checkpoint: auto`, `train-encoder --quick` and the checkpoint mismatch message that
names the user's config keys (issue #15)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config import ExperimentConfig, load_config
from rodctl.errors import UserError
from rodctl.features import auto, make_feature_map
from rodctl.features.auto import cache_dir, cache_path
from rodctl.features.autoencoder import encoder_fingerprint
from rodctl.training import encoder, prepare_feature

runner = CliRunner()


@pytest.fixture
def tiny_quick(monkeypatch, tmp_path):
    """Quick training shrunk to seconds, the cache in a temporary XDG_CACHE_HOME, and a count
    of the trainings."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(auto, "QUICK_SAMPLES", 24)
    monkeypatch.setattr(auto, "QUICK_EPOCHS", 3)
    calls = []
    real = encoder.train_checkpoint

    def counting(cfg, **kw):
        calls.append(cfg)
        return real(cfg, **kw)

    monkeypatch.setattr(encoder, "train_checkpoint", counting)
    return calls


def _cfg(**camera) -> ExperimentConfig:
    return ExperimentConfig.model_validate(
        {
            "seed": 4,
            "camera": {"tilt_deg": 30.0, **camera},
            "feature": {
                "checkpoint": "auto",
                "hidden": [16, 8],
                "data": {"workers": 1},
                "training": {"batch_size": 8, "threads": 1},
            },
        }
    )


@pytest.mark.slow
def test_auto_trains_once_caches_by_fingerprint_and_says_so(tiny_quick, tmp_path, capsys):
    cfg = _cfg()
    prepare_feature(cfg)  # what simulate, compare, sweep and replay do before building
    first = make_feature_map(cfg.feature, points=100, experiment=cfg)
    err = capsys.readouterr().err
    assert "training a quick one once" in err and "cached" in err
    path = cache_path(cfg)
    assert path.is_file() and path.parent == tmp_path / "xdg" / "rodctl" / "encoders"
    assert cache_dir() == path.parent
    assert len(tiny_quick) == 1 and tiny_quick[0].seed == 0  # seed fixed, not the run's 4
    assert tiny_quick[0].feature.data.samples == 24 and tiny_quick[0].feature.training.epochs == 3
    assert tiny_quick[0].feature.training.batch_size == 8  # already below QUICK_BATCH

    # a second run with the same rod and camera (another seed, noise) reuses the file
    again = _cfg(render={"noise_std": 2.0}).model_copy(update={"seed": 9})
    prepare_feature(again)
    second = make_feature_map(again.feature, points=100, experiment=again)
    assert "using the quick encoder cached" in capsys.readouterr().err
    assert len(tiny_quick) == 1
    x = np.column_stack([np.linspace(300, 500, 100), np.full(100, 240.0)])
    assert np.array_equal(first.encode(x), second.encode(x))

    # another camera pose: another fingerprint, another training
    other = _cfg(tilt_deg=20.0)
    prepare_feature(other)
    make_feature_map(other.feature, points=100, experiment=other)
    assert len(tiny_quick) == 2 and cache_path(other) != path


def test_the_feature_factory_never_trains_and_names_the_missing_file(tiny_quick):
    """Building the feature map only looks the quick encoder up: training is the command's."""
    cfg = _cfg()
    with pytest.raises(UserError, match="no quick encoder is cached") as err:
        make_feature_map(cfg.feature, points=100, experiment=cfg)
    assert str(cache_path(cfg)) in str(err.value) and "prepare_feature" in str(err.value)
    assert tiny_quick == [] and not cache_path(cfg).exists()


@pytest.mark.slow
def test_simulate_trains_the_quick_encoder_before_the_run(tiny_quick, tmp_path):
    res = runner.invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--out",
            str(tmp_path / "runs"),
            "--set",
            "feature.checkpoint=auto",
            "--set",
            "feature.hidden=[16, 8]",
            "--set",
            "feature.data.workers=1",
            "--set",
            "feature.training.batch_size=8",
            "--set",
            "run.max_steps=2",
            "--set",
            "logging.figures=false",
        ],
    )
    assert res.exit_code in (0, 1), res.output  # converging is not the point: no exit 2
    assert len(tiny_quick) == 1, res.output
    assert cache_path(tiny_quick[0]).is_file()


@pytest.fixture
def blind_collection(monkeypatch):
    """A collection walk that gives too few centerlines: the extractor sees no rod in any
    frame, and a walk gives up after a few steps."""
    from rodctl.training import collection
    from rodctl.vision import CenterlineExtractor
    from rodctl.vision.centerline import Extraction

    def blind(self, image, gripper_pose=None):
        return Extraction(np.full((self.points, 2), np.nan), False, "hidden by the test")

    monkeypatch.setattr(CenterlineExtractor, "extract", blind)
    monkeypatch.setattr(collection, "_MAX_ATTEMPTS_PER_SAMPLE", 1)
    monkeypatch.setattr(collection, "_MAX_ATTEMPTS_SLACK", 2)


def _one_error_line(res) -> str:
    """The failed command's single `error:` line (exit 1, no traceback)."""
    assert res.exit_code == 1, res.output
    assert isinstance(res.exception, SystemExit), res.exception  # not the RuntimeError
    assert "Traceback" not in res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, res.output
    assert "data collection" in errors[0] and "not extracted" in errors[0]
    assert "hidden by the test" in errors[0]
    return errors[0]


def test_a_failing_quick_training_is_one_line_and_exit_1(tiny_quick, blind_collection, tmp_path):
    """`simulate` stops before the run with one line naming the failed quick training, exit 1,
    no traceback, nothing cached."""
    out = tmp_path / "runs"
    res = runner.invoke(
        app,
        [
            "simulate",
            str(REPO / "configs/default.yaml"),
            "--out",
            str(out),
            "--set",
            "feature.checkpoint=auto",
            "--set",
            "feature.data.workers=1",
            "--set",
            "rod.segments=20",
            "--set",
            "camera.points=20",
        ],
    )
    assert "training the quick encoder" in _one_error_line(res)
    assert not cache_path(tiny_quick[0]).exists()


def test_train_encoder_says_a_failed_collection_in_one_line(blind_collection, tmp_path):
    res = runner.invoke(
        app,
        [
            "train-encoder",
            str(REPO / "configs/default.yaml"),
            "-q",
            "--out",
            str(tmp_path),
            "--set",
            "feature.data.samples=8",
            "--set",
            "feature.data.workers=1",
            "--set",
            "rod.segments=20",
            "--set",
            "camera.points=20",
        ],
    )
    assert "train-encoder" in _one_error_line(res)


def test_the_cache_key_holds_the_code_versions(monkeypatch):
    """An encoder cached by older collection or training code (another QUICK_CODE_VERSION or
    rodctl version) is not found, so it is trained again rather than reused."""
    cfg = _cfg()
    now = cache_path(cfg)
    monkeypatch.setattr(auto, "QUICK_CODE_VERSION", auto.QUICK_CODE_VERSION + 1)
    bumped = cache_path(cfg)
    monkeypatch.setattr("rodctl.__version__", "0.0.0")
    assert len({now, bumped, cache_path(cfg)}) == 3


def test_the_cache_key_holds_the_engine():
    """The collection walks settle in the config's engine, whose shapes differ slightly from the
    other's: a quick encoder trained in one is not reused for the other."""
    cfg = _cfg()
    other = cfg.model_copy(update={"rod": cfg.rod.model_copy(update={"engine": "quasistatic"})})
    assert cache_path(cfg) != cache_path(other)
    assert encoder_fingerprint(cfg) == encoder_fingerprint(other)  # checkpoints fit both


def test_auto_needs_the_experiment():
    cfg = _cfg()
    with pytest.raises(UserError, match="auto"):
        make_feature_map(cfg.feature, points=100)


def test_mismatch_names_the_users_keys_and_the_quick_command():
    cfg = load_config(REPO / "configs/default.yaml", ["camera.tilt_deg=35", "rod.length=0.4"])
    with pytest.raises(UserError) as err:
        make_feature_map(cfg.feature, points=100, experiment=cfg)
    msg = str(err.value)
    assert "camera.tilt_deg: the encoder's 25.0, this config's 35.0" in msg
    assert "rod.length: the encoder's 0.5, this config's 0.4" in msg
    assert "homography" not in msg
    assert "rodctl train-encoder CONFIG --quick" in msg and "feature.checkpoint=auto" in msg


@pytest.mark.slow
def test_train_encoder_quick_uses_the_quick_sizes(tiny_quick, tmp_path):
    res = runner.invoke(
        app,
        [
            "train-encoder",
            str(REPO / "configs/default.yaml"),
            "--quick",
            "-q",
            "--out",
            str(tmp_path),
            "--set",
            "feature.hidden=[16, 8]",
            "--set",
            "feature.data.workers=1",
            "--set",
            "feature.training.batch_size=8",
        ],
    )
    assert res.exit_code == 0, res.output
    run = Path(res.stdout.strip().splitlines()[-1])
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["epochs"] == 3
    assert metrics["train_samples"] + metrics["validation_samples"] == 24
    assert (run / "encoder.npz").is_file() and (run / "encoder.pt").is_file()


@pytest.mark.slow
def test_train_encoder_quick_keeps_the_sizes_given_by_set(tiny_quick, tmp_path):
    """Found by a new-user trial: --quick silently replaced an explicit --set of its sizes."""
    sets = ["feature.hidden=[16, 8]", "feature.data.workers=1", "feature.training.batch_size=8"]
    sets += ["feature.data.samples=30", "feature.training.epochs=2"]
    args = ["train-encoder", str(REPO / "configs/default.yaml"), "--quick", "-q"]
    args += ["--out", str(tmp_path), *[f"--set={s}" for s in sets]]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    run = Path(res.stdout.strip().splitlines()[-1])
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["epochs"] == 2
    assert metrics["train_samples"] + metrics["validation_samples"] == 30


@pytest.mark.slow
def test_train_encoder_on_one_walk_warns_that_nothing_is_held_out(tmp_path, monkeypatch):
    """Found by a new-user trial: a dataset of one walk trained with validation null silently."""
    monkeypatch.setattr("rodctl.notices._SAID", set())
    sets = ["feature.hidden=[16, 8]", "feature.data.workers=1", "feature.training.batch_size=8"]
    sets += ["feature.data.samples=24", "feature.data.chunk=24", "feature.training.epochs=2"]
    args = ["train-encoder", str(REPO / "configs/default.yaml"), "-q", "--out", str(tmp_path)]
    res = runner.invoke(app, [*args, *[f"--set={s}" for s in sets]])
    assert res.exit_code == 0, res.output
    assert "warning: the dataset holds 24 centerlines from one collection walk" in res.stderr
    run = Path(res.stdout.strip().splitlines()[-1])
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["validation_samples"] == 0 and metrics["validation"] is None


@pytest.mark.slow
def test_train_encoder_quick_survives_a_set_of_the_feature_type(tiny_quick, tmp_path):
    """Found by a review: the quick sizes went before the --sets, so a --set feature.type that
    switched the section to the autoencoder dropped them (a full-size training)."""
    sets = ["feature.type=autoencoder", "feature.hidden=[16, 8]", "feature.data.workers=1"]
    sets += ["feature.training.batch_size=8"]
    args = ["train-encoder", str(REPO / "configs/fourier.yaml"), "--quick", "-q"]
    res = runner.invoke(app, [*args, "--out", str(tmp_path), *[f"--set={s}" for s in sets]])
    assert res.exit_code == 0, res.output
    metrics = json.loads((Path(res.stdout.strip().splitlines()[-1]) / "metrics.json").read_text())
    assert metrics["epochs"] == 3
    assert metrics["train_samples"] + metrics["validation_samples"] == 24
