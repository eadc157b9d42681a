"""The offline ASAP Jacobian (docs/baselines.md) on geometric cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from rodctl.estimation.asap import (
    OfflineJacobian,
    _cached_asap,
    asap_from_centerline,
    asap_jacobian,
    asap_matrix,
    asap_node_jacobian,
    gripper_block,
    resample_polyline,
    servoed_indices,
)

M = 20


def straight(m: int = M, length: float = 0.5) -> np.ndarray:
    return np.column_stack([np.linspace(0.0, length, m), np.zeros(m)])


def arc(m: int = M, bend: float = 1.2, length: float = 0.5) -> np.ndarray:
    th = np.linspace(0.0, bend, m - 1)
    seg = length / (m - 1)
    steps = np.column_stack([np.cos(th), np.sin(th)]) * seg
    return np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])


HELD = [0, 1, M - 2, M - 1]
SERVOED = [4, 9, 14]


def similarity_velocity(points: np.ndarray, t, w: float, sc: float) -> np.ndarray:
    """Velocity of each point under a translation t, rotation rate w and scale rate sc."""
    rot = np.array([[0.0, -1.0], [1.0, 0.0]])
    return (np.asarray(t) + w * points @ rot.T + sc * points).reshape(-1)


def test_asap_matrix_is_symmetric_nonpositive_with_similarity_null_space():
    for rest in (straight(), arc()):
        A = asap_matrix(rest)
        np.testing.assert_allclose(A, A.T, atol=1e-12)
        w = np.linalg.eigvalsh(-A)
        assert w[0] > -1e-10
        assert np.sum(w < 1e-9) == 4  # translation (2), rotation, scale
        for v in (
            similarity_velocity(rest, [1, 0], 0, 0),
            similarity_velocity(rest, [0, 0], 1, 0),
            similarity_velocity(rest, [0, 0], 0, 1),
        ):
            np.testing.assert_allclose(A @ v, 0.0, atol=1e-10)


@pytest.mark.parametrize("rest", [straight(), arc()], ids=["straight", "arc"])
def test_similarity_motion_of_the_held_nodes_carries_every_node_along(rest):
    Jn = asap_node_jacobian(rest, HELD, SERVOED)
    for t, w, sc in ([0.3, -0.7], 0.0, 0.0), ([0.0, 0.0], 1.0, 0.0), ([0.1, 0.2], 0.5, -0.3):
        v_held = similarity_velocity(rest[HELD], t, w, sc)
        v_serv = similarity_velocity(rest[SERVOED], t, w, sc)
        np.testing.assert_allclose(Jn @ v_held, v_serv, atol=1e-10)


@pytest.mark.parametrize("rest", [straight(), arc()], ids=["straight", "arc"])
def test_jacobian_equals_a_numerical_minimisation_of_the_asap_energy(rest):
    """Independent of `asap_matrix`: minimise the energy as defined, triad by triad.

    E = sum_k 1/2 sum_{i in T_k} ||(q_i - qbar_k) - H_k (c_i - cbar_k)||^2 with each H_k a free
    similarity [[a, -b], [b, a]]; the unknowns are the free nodes and every (a_k, b_k).
    """
    rng = np.random.default_rng(0)
    dg = rng.normal(0.0, 1e-2, (len(HELD), 2))
    free = [i for i in range(M) if i not in HELD]
    n_tri = M - 2

    def residuals(x):
        q = rest.copy()
        q[HELD] += dg
        q[free] += x[: 2 * len(free)].reshape(-1, 2)
        ab = x[2 * len(free) :].reshape(n_tri, 2)
        out = []
        for k in range(n_tri):
            c, qq = rest[k : k + 3], q[k : k + 3]
            c, qq = c - c.mean(axis=0), qq - qq.mean(axis=0)
            a, b = ab[k]
            H = np.array([[a, -b], [b, a]])
            out.append((qq - c @ H.T).reshape(-1))
        return np.concatenate(out)

    x0 = np.concatenate([np.zeros(2 * len(free)), np.tile([1.0, 0.0], n_tri)])
    res = least_squares(residuals, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    moved = res.x[: 2 * len(free)].reshape(-1, 2)[[free.index(i) for i in SERVOED]]
    Jn = asap_node_jacobian(rest, HELD, SERVOED)
    np.testing.assert_allclose(Jn @ dg.reshape(-1), moved.reshape(-1), atol=1e-9)


def test_straight_rod_gripper_jacobian_has_the_expected_geometry():
    J = asap_jacobian(straight(), SERVOED)  # (6, 3)
    jx, jy, jth = J[0::2], J[1::2], J  # rows of x and y components
    # Pulling along the rod moves nodes only along it, and more the nearer the gripper.
    np.testing.assert_allclose(J[1::2, 0], 0.0, atol=1e-12)
    assert np.all(np.diff(J[0::2, 0]) > 0) and np.all(J[0::2, 0] > 0)
    # A sideways move only moves nodes sideways, monotonically towards the gripper, at most as
    # much as the gripper itself.
    np.testing.assert_allclose(J[0::2, 1], 0.0, atol=1e-12)
    assert np.all(np.diff(J[1::2, 1]) > 0) and np.all((J[1::2, 1] > 0) & (J[1::2, 1] < 1))
    # Turning the gripper counter-clockwise about the rod's end swings the node behind it down,
    # and the interior nodes with it.
    np.testing.assert_allclose(J[0::2, 2], 0.0, atol=1e-12)
    assert np.all(J[1::2, 2] < 0)
    del jx, jy, jth


def test_mirror_image_rest_shape_gives_the_mirrored_jacobian():
    rest = arc()
    mirrored = rest * np.array([1.0, -1.0])
    J, Jm = asap_jacobian(rest, SERVOED), asap_jacobian(mirrored, SERVOED)
    flip_rows = np.tile([1.0, -1.0], len(SERVOED))[:, None]
    flip_cols = np.array([1.0, -1.0, -1.0])[None, :]  # y and theta change sign
    np.testing.assert_allclose(Jm, flip_rows * J * flip_cols, atol=1e-12)


def test_gripper_block_is_the_rigid_grip_derivative():
    rest = arc()
    B = gripper_block(rest)
    d = rest[-1] - rest[-2]
    grip, th = np.hypot(*d), np.arctan2(d[1], d[0])

    def held_nodes(pose):
        x, y, t = pose
        return np.array([x - grip * np.cos(t), y - grip * np.sin(t), x, y])

    pose = np.array([*rest[-1], th])
    h = 1e-7
    fd = np.column_stack(
        [(held_nodes(pose + h * e) - held_nodes(pose - h * e)) / (2 * h) for e in np.eye(3)]
    )
    np.testing.assert_allclose(B, fd, atol=1e-7)
    np.testing.assert_allclose(held_nodes(pose), rest[-2:].reshape(-1), atol=1e-12)


def test_from_centerline_resamples_and_picks_servoed_points():
    dense = arc(m=200)
    J, pts = asap_from_centerline(dense, 20, [0.25, 0.5, 0.75])
    assert J.shape == (6, 3)
    rest = resample_polyline(dense, 20)
    np.testing.assert_allclose(J, asap_jacobian(rest, servoed_indices(20, [0.25, 0.5, 0.75])))
    np.testing.assert_allclose(pts, rest[[5, 10, 14]])
    seg = np.linalg.norm(np.diff(rest, axis=0), axis=1)
    np.testing.assert_allclose(seg, seg.mean(), rtol=1e-3)
    with pytest.raises(ValueError, match="held nodes"):
        servoed_indices(20, [0.99])


def test_offline_jacobian_ignores_measurements():
    est = OfflineJacobian(6, 3)
    with pytest.raises(RuntimeError, match="reset"):
        _ = est.J
    Jm = np.arange(18.0).reshape(6, 3)
    est.reset(Jm)
    out = est.update(np.ones(6), np.array([0.01, 0.0, 0.0]))
    np.testing.assert_array_equal(out, Jm)
    np.testing.assert_array_equal(est.J, Jm)
    assert est.info() == {}


def test_the_per_process_model_cache_gives_a_fresh_builds_bits():
    """The ASAP model cached per rest shape (issue 24): a hit is the same bytes as a fresh build,
    another rest shape or q is not served the cached one, and a caller's edit cannot reach it."""
    for rest, q in ((arc(m=120), 3), (arc(m=120, bend=0.7), 3), (arc(m=120), 6)):
        fresh = asap_from_centerline(rest, 24, [0.25, 0.5, 0.75], q=q)
        for _ in range(2):
            got = _cached_asap(rest, 24, [0.25, 0.5, 0.75], q)
            for a, b in zip(got, fresh, strict=True):
                assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
            got[0][:] = 0.0  # the caller's copy
