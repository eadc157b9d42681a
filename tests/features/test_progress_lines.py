"""Training and collection show their progress when stderr is not a terminal (a log file, a pipe):
a plain line every few seconds with the count, the loss, the elapsed time and an ETA."""

from __future__ import annotations

import re

import numpy as np

from rodctl import display
from rodctl.config import ExperimentConfig
from rodctl.features.synthetic import rod_like_centerlines
from rodctl.training.encoder import fit_autoencoder

LINE = re.compile(
    r"^training: (\d+)/4 epochs \((\d+)%\), rms [0-9.]+ px, \d+:\d\d elapsed, ETA (\d+:\d\d|\?)$"
)


def test_training_prints_epoch_loss_and_eta_lines_off_a_terminal(capsys, monkeypatch):
    monkeypatch.setattr(display, "LINE_EVERY_S", 0.0)  # a line at every epoch
    feature = ExperimentConfig.model_validate(
        {"feature": {"hidden": [16], "training": {"epochs": 4, "batch_size": 50, "threads": 1}}}
    ).feature
    shapes = rod_like_centerlines(np.random.default_rng(0), 100, 20)
    fit_autoencoder(shapes, shapes[:10], feature, seed=0, fingerprint={}, progress=True)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 4, lines
    matches = [LINE.match(line) for line in lines]
    assert all(matches), lines
    assert [int(m.group(1)) for m in matches] == [1, 2, 3, 4]
    assert matches[-1].group(2) == "100" and matches[-1].group(3) == "0:00"


def test_lines_are_spaced_in_time_and_the_last_one_always_shows(capsys, monkeypatch):
    monkeypatch.setattr(display, "LINE_EVERY_S", 3600.0)
    with display.task_progress("collecting", 30, True, lines_unit="samples") as advance:
        for _ in range(3):
            advance(n=10)
    lines = capsys.readouterr().err.strip().splitlines()
    # The first line at once, nothing for an hour, then the end.
    assert [line.split(",")[0] for line in lines] == [
        "collecting: 10/30 samples (33%)",
        "collecting: 30/30 samples (100%)",
    ]
