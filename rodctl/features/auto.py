"""`feature.checkpoint: auto`: where the quick encoder of a rod and camera is cached.

Why: the packaged encoder fits only the default rod and camera, and the paper's full training run
takes about 15 minutes on 2 cores. A quick encoder (`QUICK_SAMPLES` shapes, `QUICK_EPOCHS`
epochs: about 30 s) is enough to servo a new setup. With `auto` the first run for a setup trains
one and stores it in the user's cache folder under the setup's fingerprint (rod, camera, N,
architecture: `encoder_fingerprint`); every later run with the same fingerprint reuses it.

This module only *finds* the cached file, so that building a feature map never imports the
training code: the training is done beforehand by the command that runs the experiment
(`rodctl.training.auto.prepare_feature`, called by simulate, compare, sweep and replay).

The quick encoder is always trained with seed 0, whatever the run's seed, so the cached file does
not depend on which run happened to create it. The cache key also holds the rod's engine (the
walks settle in it), rodctl's version and `QUICK_CODE_VERSION`, so that an encoder trained by
older collection or training code is not reused. Cache folder: `$XDG_CACHE_HOME/rodctl/encoders`
(default `~/.cache/rodctl/encoders`).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from rodctl.errors import UserError
from rodctl.features.autoencoder import VERSION, encoder_fingerprint, is_autoencoder

if TYPE_CHECKING:
    from rodctl.config.experiment import ExperimentConfig

#: The seed of every quick encoder (module doc).
QUICK_SEED = 0

#: `rodctl train-encoder --quick` and `feature.checkpoint: auto` (issue #15): a working encoder
#: for a new rod or camera in about 30 s on 2 cores instead of the paper's 100,000-sample run.
#: Batches of 500 (6 Adam steps an epoch): on the same 3,000 shapes (camera tilted 35 degrees)
#: 1.89 px validation error against 4.73 px with one full batch an epoch, for 1.3x the time.
QUICK_SAMPLES = 3_000
QUICK_EPOCHS = 300
QUICK_BATCH = 500

#: The version of the code that makes a quick encoder's data and training (the collection walks
#: of `rodctl/training/collection.py`, the workspace clipping they go through, the quick sizes
#: and `rodctl/training/encoder.py`'s fit). It is part of the cache key with rodctl's version:
#: bump it whenever a change makes the same config collect other shapes or train another
#: encoder, so that a quick encoder cached by older code is trained again instead of reused.
#: 2 (2026-12-02): dual-arm walks after the reach check against the x0 end's new position.
#: 3 (2026-12-02): `rod.engine` joined the key (the walks settle in the config's engine, and
#: the two engines' settled shapes differ slightly: docs/encoders.md); quick encoders cached
#: before could have been trained in the other engine, so none of them is reused.
QUICK_CODE_VERSION = 3


def cache_dir() -> Path:
    """Where quick encoders are cached: $XDG_CACHE_HOME/rodctl/encoders (~/.cache by default)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rodctl" / "encoders"


def cache_path(cfg: ExperimentConfig) -> Path:
    """The cache file of the quick encoder for `cfg`'s rod, camera, N and architecture."""
    feature = cfg.feature
    assert is_autoencoder(feature), "the quick encoder is an autoencoder's"
    key = {
        "fingerprint": encoder_fingerprint(cfg),
        "samples": QUICK_SAMPLES,
        "epochs": QUICK_EPOCHS,
        "batch": min(feature.training.batch_size, QUICK_BATCH),
        "seed": QUICK_SEED,
        "format": VERSION,
        "code": QUICK_CODE_VERSION,
        # The collection walks settle in this engine (`RodSim(cfg.rod)`): its shapes are the
        # encoder's data. Not in `encoder_fingerprint`: both engines' shapes are one family
        # (a checkpoint of either encodes the other's), only the cached training differs.
        "engine": cfg.rod.engine,
        # The package is imported before any of its modules; read, not imported, here (an
        # import of `rodctl` would make the feature stage import everything it re-exports).
        "rodctl": sys.modules["rodctl"].__version__,
    }
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    return cache_dir() / f"quick-{digest}.npz"


def say(message: str) -> None:
    """One line on stderr about the quick encoder (each step of `auto` is said)."""
    print(f"feature.checkpoint=auto: {message}", file=sys.stderr, flush=True)


def cached_checkpoint(cfg: ExperimentConfig) -> Path:
    """The cached quick encoder for `cfg`.

    Raises:
        UserError: none is cached yet for this rod and camera; the message says how to train it.
    """
    path = cache_path(cfg)
    if not path.is_file():
        raise UserError(
            f"feature.checkpoint=auto: no quick encoder is cached for this rod and camera yet "
            f"({path}). `rodctl simulate`, `compare`, `sweep` and `replay` train it once "
            "before the run; from Python call rodctl.training.prepare_feature(cfg) first, or "
            "train one with `rodctl train-encoder CONFIG --quick` and set feature.checkpoint "
            "to its encoder.npz"
        )
    say(f"using the quick encoder cached for this rod and camera: {path}")
    return path
