"""`feature.checkpoint: auto`: a quick encoder trained once per rod and camera, then cached.

Why: the packaged encoder fits only the default rod and camera, and the paper's full training run
takes about 15 minutes on 2 cores. A quick encoder (`rodctl.features.training.QUICK_SAMPLES`
shapes, `QUICK_EPOCHS` epochs: about 30 s) is enough to servo a new setup. With `auto` the first
run for a setup trains one and stores it in the user's cache folder under the setup's
fingerprint (rod, camera, N, architecture: `encoder_fingerprint`); every later run with the same
fingerprint reuses it. Each step is said on stderr.

The quick encoder is always trained with seed 0, whatever the run's seed, so the cached file does
not depend on which run happened to create it. Cache folder: `$XDG_CACHE_HOME/rodctl/encoders`
(default `~/.cache/rodctl/encoders`).
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import sys
from pathlib import Path

from rodctl.config.experiment import ExperimentConfig

#: The seed of every quick encoder (module doc).
QUICK_SEED = 0


def cache_dir() -> Path:
    """Where quick encoders are cached: $XDG_CACHE_HOME/rodctl/encoders (~/.cache by default)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rodctl" / "encoders"


def cache_path(cfg: ExperimentConfig) -> Path:
    """The cache file of the quick encoder for `cfg`'s rod, camera, N and architecture."""
    from rodctl.features.autoencoder import VERSION, encoder_fingerprint
    from rodctl.features.training import QUICK_BATCH, QUICK_EPOCHS, QUICK_SAMPLES

    key = {
        "fingerprint": encoder_fingerprint(cfg),
        "samples": QUICK_SAMPLES,
        "epochs": QUICK_EPOCHS,
        "batch": min(cfg.feature.training.batch_size, QUICK_BATCH),  # type: ignore[union-attr]
        "seed": QUICK_SEED,
        "format": VERSION,
    }
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    return cache_dir() / f"quick-{digest}.npz"


def _say(message: str) -> None:
    print(f"feature.checkpoint=auto: {message}", file=sys.stderr, flush=True)


def auto_checkpoint(cfg: ExperimentConfig) -> Path:
    """The cached quick encoder for `cfg`, trained and cached first if there is none.

    Args:
        cfg: the experiment config (its feature an autoencoder).

    Returns:
        The path of the cached `.npz` checkpoint.
    """
    from rodctl.features.training import (
        QUICK_EPOCHS,
        QUICK_SAMPLES,
        quick_config,
        train_checkpoint,
    )

    path = cache_path(cfg)
    if path.is_file():
        _say(f"using the quick encoder cached for this rod and camera: {path}")
        return path
    from rodctl.features.autoencoder import require_torch

    require_torch(f"feature.checkpoint=auto (no quick encoder cached for this setup at {path})")
    _say(
        f"no encoder cached for this rod and camera yet; training a quick one once "
        f"({QUICK_SAMPLES:,} samples, {QUICK_EPOCHS} epochs: about 30 s on 2 cores)"
    )
    data = quick_config(cfg).model_dump(mode="json")
    data["seed"] = QUICK_SEED
    data["feature"]["checkpoint"] = None
    if multiprocessing.current_process().daemon:  # a pool worker cannot start its own workers
        data["feature"]["data"]["workers"] = 1
    ckpt = train_checkpoint(ExperimentConfig.model_validate(data), progress=sys.stderr.isatty())
    path.parent.mkdir(parents=True, exist_ok=True)
    ckpt.save(path)  # atomic: a concurrent run sees no file or the whole file
    val = (ckpt.metrics.get("validation") or ckpt.metrics["train"])["mean_px"]
    _say(f"trained ({val:.2f} px mean reconstruction error) and cached: {path}")
    return path
