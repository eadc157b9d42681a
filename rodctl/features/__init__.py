"""Shape features s = f_s(c): the map from an N-point pixel centerline to a small vector.

The paper's feature is an autoencoder latent (`autoencoder.py`, section VI-A); the baselines use
geometric ones: Bézier control points (Ma et al., `bezier.py`), a chord-plus-sine Fourier series
(`fourier.py`) and a few rod points (Aghajanzadeh et al., `nodes.py`). All follow the `FeatureMap`
protocol of `base.py`, and `make_feature_map` builds one from its config. Everything here is
numpy at run time; torch is only imported to load or train an autoencoder checkpoint.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rodctl.config.feature import (
    AutoencoderFeatureConfig,
    BezierFeatureConfig,
    FeatureConfig,
    FourierFeatureConfig,
    NodesFeatureConfig,
)
from rodctl.errors import UserError
from rodctl.features.base import FeatureMap
from rodctl.features.bezier import BezierFeatureMap
from rodctl.features.fourier import FourierFeatureMap
from rodctl.features.nodes import NodesFeatureMap

if TYPE_CHECKING:
    from rodctl.config.experiment import ExperimentConfig
    from rodctl.features.autoencoder import AutoencoderFeatureMap

__all__ = [
    "BezierFeatureMap",
    "FeatureMap",
    "FourierFeatureMap",
    "NodesFeatureMap",
    "load_autoencoder",
    "make_feature_map",
]


def load_autoencoder(
    cfg: AutoencoderFeatureConfig,
    *,
    points: int,
    experiment: ExperimentConfig | None = None,
) -> AutoencoderFeatureMap:
    """Load the checkpoint `cfg.checkpoint` (None: the packaged default) and check it fits.

    Args:
        cfg: the autoencoder feature config.
        points: N, the centerline points the experiment extracts.
        experiment: the whole config; when given, the checkpoint's fingerprint (rod, camera, N,
            architecture) must match it, otherwise only N and the architecture are checked.

    Raises:
        UserError: the file is missing or corrupt, or was trained for another setup; the message
            names the file and each mismatch.
    """
    from rodctl.features.autoencoder import (
        DEFAULT_CHECKPOINT,
        EncoderCheckpoint,
        architecture_of,
        encoder_fingerprint,
    )

    if cfg.checkpoint == "auto":
        if experiment is None:
            raise UserError("feature.checkpoint: 'auto' needs the whole experiment config")
        from rodctl.features.auto import auto_checkpoint

        path = auto_checkpoint(experiment)
    else:
        path = Path(cfg.checkpoint) if cfg.checkpoint is not None else DEFAULT_CHECKPOINT
    ckpt = EncoderCheckpoint.load(path)
    if experiment is not None:
        expected = encoder_fingerprint(experiment)
    else:
        expected = {
            **ckpt.fingerprint,
            "points": points,
            "architecture": architecture_of(cfg, points),
        }
    ckpt.check_compatible(expected, str(path), experiment)
    return ckpt.feature_map(source=str(path))


def make_feature_map(
    cfg: FeatureConfig, *, points: int, experiment: ExperimentConfig | None = None
) -> FeatureMap:
    """Build the feature map a config describes.

    Args:
        cfg: one member of the feature config union (`type` picks the map).
        points: N, the centerline points the maps will be given.
        experiment: the whole config, so that an autoencoder checkpoint can be checked against
            the rod and camera geometry too (recommended; see `load_autoencoder`).

    Raises:
        UserError: an autoencoder checkpoint that is missing, corrupt or for another setup.
    """
    if isinstance(cfg, AutoencoderFeatureConfig):
        return load_autoencoder(cfg, points=points, experiment=experiment)
    try:
        if isinstance(cfg, BezierFeatureConfig):
            return BezierFeatureMap(cfg.degree, points)
        if isinstance(cfg, FourierFeatureConfig):
            return FourierFeatureMap(cfg.harmonics, points)
        if isinstance(cfg, NodesFeatureConfig):
            return NodesFeatureMap(cfg.positions, points)
    except ValueError as exc:  # a combination one model alone cannot check (e.g. with N)
        raise UserError(f"feature ({cfg.type}) with camera.points={points}: {exc}") from None
    raise TypeError(f"unknown feature config {type(cfg).__name__}")
