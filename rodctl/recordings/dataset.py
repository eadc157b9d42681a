"""`rodctl train-encoder CONFIG --dataset RUN_DIR`: an autoencoder trained on a recording.

An imported run (or any rodctl run) holds the extracted pixel centerline of every frame
(`/camera/centerline.extracted`). Its good frames become the centerline dataset the encoder
trains on (`rodctl.training.collection.CenterlineDataset`): the frames in time order, cut into
`CHUNKS` consecutive pieces that play the part of the simulator's collection walks, so the
validation hold-out (`split_by_chunk`) is whole stretches of the recording, not frames next to
training frames. docs/recordings.md ("An autoencoder trained on a recording") has the steps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rodctl.config import ExperimentConfig
from rodctl.errors import UserError
from rodctl.features.autoencoder import encoder_fingerprint
from rodctl.features.autoencoder_config import AutoencoderFeatureConfig
from rodctl.training.collection import CenterlineDataset

#: Consecutive pieces a recording's frames are cut into (the held-out unit of validation).
CHUNKS = 10


def is_run(path: str | Path) -> bool:
    """A run folder (with run.mcap) or a run.mcap file, rather than a dataset.npz."""
    p = Path(path)
    return (p.is_dir() and (p / "run.mcap").is_file()) or (p.is_file() and p.suffix == ".mcap")


def run_dataset(path: str | Path) -> Any:
    """The `CenterlineDataset` of a run's good frames (extracted pixels, gripper poses).

    Raises:
        UserError: not a readable run, or fewer than 2 good frames.
    """
    # Lazy: the run reader brings OpenCV and the MCAP reader, and `train-encoder` imports this
    # module to ask `is_run` of every --dataset, a dataset.npz included.
    from rodctl.replay import read_run  # noqa: PLC0415

    run = read_run(path, images=False)
    good = [r for r in run.records if r.extraction_ok]
    if len(good) < 2:
        raise UserError(f"--dataset {path}: {len(good)} frame(s) with a centerline; need more")
    cl = np.array([np.asarray(r.extracted, dtype=float) for r in good], dtype=np.float32)
    poses = np.array([np.asarray(r.gripper, dtype=float)[:3] for r in good])
    chunk = (np.arange(len(good)) * min(CHUNKS, len(good)) // len(good)).astype(np.int32)
    return CenterlineDataset(cl, poses, chunk, attempts=len(run.records))


def with_points(cfg: Any, points: int) -> Any:
    """`cfg` with camera.points = `points` (the recording's N decides the encoder's input)."""
    data = cfg.model_dump(mode="json")
    data["camera"]["points"] = int(points)
    return ExperimentConfig.model_validate(data)


def write_run_dataset(data: Any, cfg: Any, dest: Path) -> Path:
    """Save the recording's dataset as `dest` (dataset.npz) for `cfg`'s encoder setup.

    Raises:
        UserError: the config's feature is not an autoencoder.
    """
    if not isinstance(cfg.feature, AutoencoderFeatureConfig):
        raise UserError(
            f"train-encoder trains the autoencoder feature, but feature.type is "
            f"{cfg.feature.type!r}; set feature.type=autoencoder"
        )
    data.save(dest, fingerprint=encoder_fingerprint(cfg))
    return dest
