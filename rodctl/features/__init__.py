"""Shape features s = f_s(c): the map from an N-point pixel centerline to a small vector.

The paper's feature is an autoencoder latent (`autoencoder.py`, section VI-A; its config and
registration in `autoencoder_config.py`, which never imports torch); the baselines use
geometric ones: Bézier control points (Ma et al., `bezier.py`), a chord-plus-sine Fourier series
(`fourier.py`) and a few rod points (Aghajanzadeh et al., `nodes.py`). All follow the `FeatureMap`
protocol of `base.py`; each type registers itself with its config model in
`rodctl.registry.FEATURES`, and `make_feature_map` builds one from its config.
"""

from __future__ import annotations

from typing import Any

from rodctl.features.autoencoder_config import load_autoencoder
from rodctl.features.base import FeatureMap
from rodctl.features.bezier import BezierFeatureMap
from rodctl.features.fourier import FourierFeatureMap
from rodctl.features.nodes import NodesFeatureMap
from rodctl.registry import FEATURES, BuildContext, load_plugins

__all__ = [
    "BezierFeatureMap",
    "FeatureMap",
    "FourierFeatureMap",
    "NodesFeatureMap",
    "load_autoencoder",
    "make_feature_map",
]


def make_feature_map(cfg: Any, *, points: int, experiment: Any = None) -> FeatureMap:
    """Build the feature map a config describes (its registered factory).

    Args:
        cfg: a registered feature config (`type` picks the map).
        points: N, the centerline points the maps will be given.
        experiment: the whole config, so that an autoencoder checkpoint can be checked against
            the rod and camera geometry too (recommended).

    Raises:
        UserError: a map that cannot be built (e.g. a checkpoint for another setup).
    """
    load_plugins()
    return FEATURES.build(cfg, BuildContext(points=points, experiment=experiment))
