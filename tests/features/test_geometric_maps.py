"""Bézier, Fourier and node features: shapes, exactness, truncation error, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.config import ExperimentConfig
from rodctl.features import (
    BezierFeatureMap,
    FourierFeatureMap,
    NodesFeatureMap,
    make_feature_map,
)
from rodctl.features.synthetic import centerlines_from_params, rod_like_centerlines

N = 100


def straight_line(n: int = N, start=(50.0, 300.0), end=(410.0, 120.0)) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) * np.asarray(start) + t * np.asarray(end)


@pytest.fixture(scope="module")
def shapes() -> np.ndarray:
    return rod_like_centerlines(np.random.default_rng(7), 400, N)


@pytest.mark.parametrize(
    "fmap,dim",
    [
        (BezierFeatureMap(4, N), 10),
        (FourierFeatureMap(4, N), 12),
        (NodesFeatureMap([1 / 3, 2 / 3, 1.0], N), 6),
    ],
)
def test_dimensions_single_and_batch_agree(fmap, dim, shapes):
    assert fmap.dim == dim and fmap.points == N
    assert fmap.scale.shape == (dim,) and fmap.units == "px"
    batch = fmap.encode_batch(shapes[:5])
    assert batch.shape == (5, dim) and batch.dtype == np.float64
    for b in range(5):
        np.testing.assert_allclose(fmap.encode(shapes[b]), batch[b], rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "fmap", [BezierFeatureMap(4, N), FourierFeatureMap(4, N), NodesFeatureMap([0.5, 1.0], N)]
)
def test_encoding_is_deterministic_and_does_not_touch_its_input(fmap, shapes):
    c = shapes[3].copy()
    first = fmap.encode(c)
    assert np.array_equal(c, shapes[3])
    assert np.array_equal(first, fmap.encode(c))
    assert np.array_equal(first, make_feature_map_like(fmap).encode(c))


def make_feature_map_like(fmap):
    """A second, independently built map of the same kind (via the config factory)."""
    cfg = ExperimentConfig.model_validate(
        {
            "feature": {"type": "bezier", "degree": 4}
            if fmap.kind == "bezier"
            else {"type": "fourier", "harmonics": 4}
            if fmap.kind == "fourier"
            else {"type": "nodes", "positions": list(fmap.positions)}
        }
    )
    return make_feature_map(cfg.feature, points=N)


@pytest.mark.parametrize(
    "fmap",
    [
        BezierFeatureMap(1, N),
        BezierFeatureMap(5, N),
        FourierFeatureMap(1, N),
        FourierFeatureMap(6, N),
    ],
)
def test_straight_line_is_represented_exactly(fmap):
    line = straight_line()
    assert fmap.reconstruction_error(line[None]).max() < 1e-9
    np.testing.assert_allclose(fmap.decode(fmap.encode(line)), line, atol=1e-9)


def test_bezier_end_control_points_are_the_rod_ends_for_a_line():
    line = straight_line()
    ctrl = BezierFeatureMap(3, N).encode(line).reshape(4, 2)
    np.testing.assert_allclose(ctrl[0], line[0], atol=1e-9)
    np.testing.assert_allclose(ctrl[-1], line[-1], atol=1e-9)
    # evenly spaced control points give uniform speed along a line
    np.testing.assert_allclose(
        np.diff(ctrl, axis=0), np.tile((line[-1] - line[0]) / 3, (3, 1)), atol=1e-9
    )


def test_fourier_chord_terms_are_the_ends_for_a_line():
    line = straight_line()
    coeffs = FourierFeatureMap(3, N).encode(line).reshape(5, 2)
    np.testing.assert_allclose(coeffs[0], line[0], atol=1e-9)
    np.testing.assert_allclose(coeffs[1], line[-1], atol=1e-9)
    np.testing.assert_allclose(coeffs[2:], 0.0, atol=1e-9)


# Stated truncation errors (module docstrings of bezier.py / fourier.py): 300 px rod-like curves.
@pytest.mark.parametrize(
    "fmap,mean_bound,max_bound",
    [
        (BezierFeatureMap(4, N), 0.3, 10.0),
        (BezierFeatureMap(6, N), 0.03, 1.5),
        (FourierFeatureMap(4, N), 0.3, 6.0),
        (FourierFeatureMap(8, N), 0.06, 1.5),
    ],
)
def test_truncation_error_within_stated_bound(fmap, mean_bound, max_bound, shapes):
    err = fmap.reconstruction_error(shapes)
    assert err.mean() <= mean_bound
    assert err.max() <= max_bound


@pytest.mark.parametrize("cls", [BezierFeatureMap, FourierFeatureMap])
def test_truncation_error_falls_with_order(cls, shapes):
    errs = [cls(order, N).reconstruction_error(shapes).mean() for order in range(2, 9)]
    assert all(b < a for a, b in zip(errs[:-1], errs[1:], strict=True)), errs


def test_bezier_is_exact_for_a_circle_in_the_limit_of_degree():
    # a circular arc of 120 degrees, 300 px long: degree 8 is far below a tenth of a pixel
    params = np.array([[2 * np.pi / 3, 0.0, 0.0]])
    arc = centerlines_from_params(params, N)
    assert BezierFeatureMap(8, N).reconstruction_error(arc).max() < 0.01


@pytest.mark.parametrize(
    "fmap", [BezierFeatureMap(4, N), FourierFeatureMap(4, N), NodesFeatureMap([0.25, 0.6, 1.0], N)]
)
def test_feature_does_not_depend_on_how_points_are_spread_along_the_rod(fmap):
    # the same curve sampled with uniform and with strongly non-uniform spacing
    params = np.array([[1.2, -0.8, 0.5]])
    dense = centerlines_from_params(params, 2001)[0]
    uniform = dense[np.round(np.linspace(0, 2000, N)).astype(int)]
    skewed = dense[np.round(2000 * np.linspace(0, 1, N) ** 1.5).astype(int)]
    # only the chord-versus-arc error of the coarse skewed sampling remains (~0.005 px measured)
    np.testing.assert_allclose(fmap.encode(skewed), fmap.encode(uniform), rtol=0, atol=0.02)


def test_nodes_pick_points_at_the_given_arc_length():
    line = straight_line()
    s = NodesFeatureMap([0.5, 1.0], N).encode(line).reshape(2, 2)
    np.testing.assert_allclose(s[0], (line[0] + line[-1]) / 2, atol=1e-9)
    np.testing.assert_allclose(s[1], line[-1], atol=1e-9)


@pytest.mark.parametrize("fmap", [BezierFeatureMap(4, N), NodesFeatureMap([1.0], N)])
def test_bad_input_is_rejected(fmap):
    with pytest.raises(ValueError, match="shape"):
        fmap.encode(np.zeros((N - 1, 2)))
    with pytest.raises(ValueError, match="shape"):
        fmap.encode_batch(np.zeros((N, 2)))
    bad = straight_line()
    bad[5, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fmap.encode(bad)
    with pytest.raises(ValueError, match="zero length"):
        fmap.encode(np.ones((N, 2)))


def test_factory_builds_each_kind_from_config():
    for section, cls, dim in [
        ({"type": "bezier", "degree": 3}, BezierFeatureMap, 8),
        ({"type": "fourier", "harmonics": 2}, FourierFeatureMap, 8),
        ({"type": "nodes", "positions": [0.5, 1.0]}, NodesFeatureMap, 4),
    ]:
        cfg = ExperimentConfig.model_validate({"feature": section})
        fmap = make_feature_map(cfg.feature, points=N)
        assert isinstance(fmap, cls) and fmap.dim == dim and fmap.kind == section["type"]
