"""Training the quick encoder of `feature.checkpoint: auto` into its cache, before a run.

The feature factory only looks the quick encoder up (`rodctl.features.auto`); the commands that
run experiments call `prepare_feature` first, so a missing quick encoder is trained once, in the
command's own process, before any episode (or worker) starts.
"""

from __future__ import annotations

import multiprocessing
import sys
from pathlib import Path
from typing import Any

from rodctl.config.experiment import ExperimentConfig
from rodctl.errors import RunFailed, UserError
from rodctl.features import auto as quick
from rodctl.features.autoencoder import is_autoencoder, require_torch


def auto_checkpoint(cfg: ExperimentConfig) -> Path:
    """The cached quick encoder for `cfg`, trained and cached first if there is none.

    Args:
        cfg: the experiment config (its feature an autoencoder).

    Returns:
        The path of the cached `.npz` checkpoint.

    Raises:
        RunFailed: the training failed (a collection walk that gave too few centerlines, a
            numerical error): one line naming it, no traceback (the commands exit 1).
        UserError: the config cannot be trained (exit 2).
    """
    path = quick.cache_path(cfg)
    if path.is_file():
        return path
    # Lazy: the training code (rich progress, the collection pool) is needed only to train,
    # and `rodctl simulate` imports this module at start-up.
    from rodctl.training.encoder import quick_config, train_checkpoint  # noqa: PLC0415

    require_torch(f"feature.checkpoint=auto (no quick encoder cached for this setup at {path})")
    quick.say(
        f"no encoder cached for this rod and camera yet; training a quick one once "
        f"({quick.QUICK_SAMPLES:,} samples, {quick.QUICK_EPOCHS} epochs: about 30 s on 2 cores)"
    )
    data = quick_config(cfg).model_dump(mode="json")
    data["seed"] = quick.QUICK_SEED
    data["feature"]["checkpoint"] = None
    if multiprocessing.current_process().daemon:  # a pool worker cannot start its own workers
        data["feature"]["data"]["workers"] = 1
    try:
        ckpt = train_checkpoint(ExperimentConfig.model_validate(data), progress=sys.stderr.isatty())
    except (UserError, RunFailed):
        raise  # already one line: the config (exit 2) or the machine (exit 1)
    except Exception as exc:  # noqa: BLE001 (the system failed: one line, exit 1, no traceback)
        raise RunFailed(
            f"feature.checkpoint=auto: training the quick encoder for this rod and camera failed "
            f"({type(exc).__name__}: {exc}); nothing was cached. "
            "`rodctl train-encoder CONFIG --quick` runs the same training on its own"
        ) from exc
    path.parent.mkdir(parents=True, exist_ok=True)
    ckpt.save(path)  # atomic: a concurrent run sees no file or the whole file
    val = (ckpt.metrics.get("validation") or ckpt.metrics["train"])["mean_px"]
    quick.say(f"trained ({val:.2f} px mean reconstruction error) and cached: {path}")
    return path


def prepare_feature(cfg: Any) -> None:
    """Train the quick encoder `cfg` asks for with `feature.checkpoint: auto`, unless cached.

    A no-op for any other feature or checkpoint. Called by the commands before they build a
    method, so that the feature factory finds the file (`rodctl.features.auto`).
    """
    feature = getattr(cfg, "feature", None)
    if is_autoencoder(feature) and feature.checkpoint == "auto":
        auto_checkpoint(cfg)
