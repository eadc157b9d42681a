"""rodctl.fixedla: the kernel-independent small linear algebra agrees with numpy/LAPACK."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl import fixedla as fla


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_products_agree_with_blas(rng):
    a, b, x = rng.normal(size=(6, 4)), rng.normal(size=(4, 3)), rng.normal(size=4)
    np.testing.assert_allclose(fla.matmul(a, b), a @ b, rtol=0, atol=1e-14)
    np.testing.assert_allclose(fla.matvec(a, x), a @ x, rtol=0, atol=1e-14)
    np.testing.assert_allclose(fla.matvec(a.T, fla.matvec(a, x)), a.T @ (a @ x), atol=1e-13)
    assert fla.dot(x, x) == pytest.approx(float(x @ x), rel=1e-15)
    assert fla.norm(a) == pytest.approx(float(np.linalg.norm(a)), rel=1e-15)


@pytest.mark.parametrize("n", [1, 3, 6, 18])
def test_cholesky_solve(rng, n):
    m = rng.normal(size=(n, n))
    a = m @ m.T + n * np.eye(n)
    L = np.array(fla.cholesky(a))
    np.testing.assert_allclose(L, np.linalg.cholesky(a), atol=1e-12)
    b = rng.normal(size=(n, 2))
    np.testing.assert_allclose(fla.spd_solve(a, b), np.linalg.solve(a, b), atol=1e-12)
    np.testing.assert_allclose(fla.spd_solve(a, b[:, 0]), np.linalg.solve(a, b[:, 0]), atol=1e-12)


def test_not_positive_definite_is_none():
    assert fla.cholesky(np.diag([1.0, -1.0, 2.0])) is None
    assert fla.spd_solve(np.zeros((2, 2)), np.ones(2)) is None
    assert fla.cholesky(np.diag([1.0, np.nan])) is None


def test_inv3(rng):
    a = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    np.testing.assert_allclose(fla.inv3(a) @ a, np.eye(3), atol=1e-14)
    with pytest.raises(np.linalg.LinAlgError):
        fla.inv3(np.ones((3, 3)))


@pytest.mark.parametrize("shape", [(6, 3), (10, 3), (3, 3), (2, 3)])
def test_singular_values_and_pinv(rng, shape):
    j = rng.normal(size=shape) * np.array([30.0, 5.0, 0.5])
    sv = np.linalg.svd(j, compute_uv=False)
    np.testing.assert_allclose(fla.singular_values(j), sv, rtol=1e-12, atol=1e-12 * sv[0])
    np.testing.assert_allclose(fla.pinv(j), np.linalg.pinv(j), atol=1e-10)


def test_pinv_drops_small_singular_values_like_numpy(rng):
    u, _ = np.linalg.qr(rng.normal(size=(6, 3)))
    v, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    j = u @ np.diag([10.0, 1.0, 1e-6]) @ v.T
    for rcond in (1e-4, 1e-8):
        np.testing.assert_allclose(fla.pinv(j, rcond), np.linalg.pinv(j, rcond=rcond), atol=1e-6)


def test_eigh_small(rng):
    m = rng.normal(size=(5, 5))
    a = m + m.T
    w, v = fla.eigh_small(a)
    np.testing.assert_allclose(w, np.linalg.eigvalsh(a), atol=1e-13)
    np.testing.assert_allclose(v @ np.diag(w) @ v.T, a, atol=1e-12)
    w2, none = fla.eigh_small(a, vectors=False)
    assert none is None and np.array_equal(w, w2)


def test_pinv_tall(rng):
    a = rng.normal(size=(100, 6))
    np.testing.assert_allclose(fla.pinv_tall(a), np.linalg.pinv(a), atol=1e-13)
    with pytest.raises(np.linalg.LinAlgError):
        fla.pinv_tall(np.column_stack([a[:, 0], 2 * a[:, 0]]))
