"""Small linear algebra in a fixed order of operations, independent of the BLAS/LAPACK kernel.

Why: numpy's `@` on float64/float32 and every `numpy.linalg` / `scipy.linalg` call go to the
BLAS/LAPACK library, which picks its kernel per CPU (OpenBLAS: Haswell, SkylakeX, Zen, ...; or
`OPENBLAS_CORETYPE`). Kernels differ in how they block, unroll and fuse (FMA) the sums, so the last
bits of a product change from one machine to another, and a closed loop carries such a difference
into every later step: a run made on one computer did not verify on another (issue #18).

Everything here uses only numpy's elementwise operations (`*`, `+`, `-`, `/`, `sqrt`: correctly
rounded IEEE operations, the same whatever SIMD width numpy dispatches), `sum` along an axis,
whose pairwise order is fixed by numpy's source code, not by the CPU, and `einsum` without
`optimize` (numpy's own loops, compiled for its SIMD baseline; checked equal with numpy's
dispatched AVX2 paths disabled, `NPY_DISABLE_CPU_FEATURES=X86_V3`). So the results are the same
bits on every x86-64 machine running the same numpy build (see the README, "Reproducibility").
The price is speed: these are written for the per-step sizes (vectors of a few hundred, matrices up
to about 20 x 20) where BLAS's advantage is small; `benchmarks/` measure what they cost.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "cho_solve",
    "cholesky",
    "dot",
    "eigh_small",
    "inv3",
    "matmul",
    "matvec",
    "norm",
    "pinv",
    "pinv_tall",
    "singular_values",
    "spd_solve",
]


def dot(a: np.ndarray, b: np.ndarray) -> float:
    """sum_i a_i b_i of two 1-D arrays, in numpy's fixed pairwise order (no BLAS ddot)."""
    return float(np.multiply(a, b).sum())


def norm(a: np.ndarray) -> float:
    """Euclidean norm of a vector (or of all entries of an array), kernel-independent.

    `numpy.linalg.norm(x)` with no axis computes sqrt(x . x) with BLAS ddot.
    """
    a = np.asarray(a, dtype=np.float64)
    return math.sqrt(float(np.multiply(a, a).sum()))


def matvec(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """a (..., m, k) times x (k,): (..., m), each entry summed over k in a fixed order.

    `numpy.einsum` without `optimize` never calls BLAS; its inner loops are compiled for numpy's
    SIMD baseline (not dispatched per CPU), so the order of the sums is fixed by the numpy build.
    Twice as fast as multiplying and summing, and 2-3x slower than BLAS for a 128 x 200 layer.
    """
    return np.einsum("...k,k->...", a, x)


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a (m, k) times b (k, n) -> (m, n) in a fixed order of operations (`numpy.einsum`
    without `optimize`, see `matvec`). Meant for small matrices."""
    return np.einsum("ik,kj->ij", a, b)


def cholesky(a: np.ndarray) -> list[list[float]] | None:
    """Lower Cholesky factor L (L L^T = a) of a small symmetric matrix, as nested lists; None if
    a is not positive definite (a pivot <= 0 or NaN). Only the lower triangle is read.

    Plain Python floats in a fixed order: for the 3 x 3 to 6 x 6 systems of the control laws
    this is faster than any numpy or LAPACK call (their per-call overhead dominates).
    """
    m = np.asarray(a, dtype=np.float64).tolist()
    n = len(m)
    L = [[0.0] * n for _ in range(n)]
    for j in range(n):
        Lj = L[j]
        d = m[j][j]
        for k in range(j):
            d -= Lj[k] * Lj[k]
        if not d > 0.0:
            return None
        ljj = math.sqrt(d)
        Lj[j] = ljj
        for i in range(j + 1, n):
            Li = L[i]
            v = m[i][j]
            for k in range(j):
                v -= Li[k] * Lj[k]
            Li[j] = v / ljj
    return L


def cho_solve(L: list[list[float]], b: np.ndarray) -> np.ndarray:
    """Solve (L L^T) x = b for x, b (n,) or (n, m), by forward and back substitution."""
    arr = np.asarray(b, dtype=np.float64)
    vec = arr.ndim == 1
    cols = [arr.tolist()] if vec else arr.T.tolist()
    n = len(L)
    out = []
    for y in cols:
        for i in range(n):  # L y = b
            Li = L[i]
            v = y[i]
            for k in range(i):
                v -= Li[k] * y[k]
            y[i] = v / Li[i]
        for i in range(n - 1, -1, -1):  # L^T x = y
            v = y[i]
            for k in range(i + 1, n):
                v -= L[k][i] * y[k]
            y[i] = v / L[i][i]
        out.append(y)
    return np.array(out[0]) if vec else np.array(out).T


def spd_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """x with a x = b for a small symmetric positive definite a; None if a is not SPD."""
    L = cholesky(a)
    return None if L is None else cho_solve(L, b)


def inv3(a: np.ndarray) -> np.ndarray:
    """Inverse of a 3 x 3 matrix by its adjugate (cofactors over the determinant), fixed order.

    Raises:
        numpy.linalg.LinAlgError: the matrix is singular.
    """
    m = [[float(v) for v in row] for row in np.asarray(a, dtype=np.float64)]
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = m
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0 or not math.isfinite(det):
        raise np.linalg.LinAlgError("singular 3 x 3 matrix")
    adj = [
        [c00, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11],
        [c01, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12],
        [c02, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10],
    ]
    return np.array(adj) / det


def eigh_small(
    a: np.ndarray, sweeps: int = 30, vectors: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """Eigenvalues (ascending) and eigenvectors (columns; None unless `vectors`) of a small
    symmetric matrix.

    Cyclic Jacobi rotations in plain Python floats (Rutishauser's formulation), a fixed sequence
    of operations: meant for n <= 6 (the 3 x 3 Gram matrices J^T J of the controllers), where it
    takes tens of microseconds. Only the lower triangle is read. Accurate to a few ulps of the
    largest eigenvalue.
    """
    m = np.asarray(a, dtype=np.float64)
    n = m.shape[0]
    A = [[float(m[max(i, j), min(i, j)]) for j in range(n)] for i in range(n)]
    V = [[1.0 if i == j else 0.0 for j in range(n)] for i in range(n)]
    for _ in range(sweeps):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p][q]
                # negligible against both diagonal entries (below their last bit): zero it
                g = 100.0 * abs(apq)
                if abs(A[p][p]) + g == abs(A[p][p]) and abs(A[q][q]) + g == abs(A[q][q]):
                    A[p][q] = A[q][p] = 0.0
                    continue
                rotated = True
                theta = (A[q][q] - A[p][p]) / (2.0 * apq)
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):  # columns p, q of A
                    akp, akq = A[k][p], A[k][q]
                    A[k][p] = c * akp - s * akq
                    A[k][q] = s * akp + c * akq
                for k in range(n):  # rows p, q of A
                    apk, aqk = A[p][k], A[q][k]
                    A[p][k] = c * apk - s * aqk
                    A[q][k] = s * apk + c * aqk
                if vectors:
                    for k in range(n):
                        vkp, vkq = V[k][p], V[k][q]
                        V[k][p] = c * vkp - s * vkq
                        V[k][q] = s * vkp + c * vkq
        if not rotated:
            break
    w = np.array([A[i][i] for i in range(n)])
    order = np.argsort(w, kind="stable")
    return w[order], (np.array(V)[:, order] if vectors else None)


def singular_values(j: np.ndarray) -> np.ndarray:
    """Singular values (largest first) of a (p, q) matrix with small q, kernel-independent.

    The square roots of the eigenvalues of J^T J (`eigh_small`): accurate to about
    eps * sigma_max^2 / sigma, ample for the diagnostics and stall tests they feed.
    """
    j = np.asarray(j, dtype=np.float64)
    if j.size == 0:
        return np.zeros(0)
    k = min(j.shape)
    gram = matmul(j.T, j) if j.shape[1] <= j.shape[0] else matmul(j, j.T)
    w, _ = eigh_small(gram, vectors=False)
    return np.sqrt(np.maximum(w[::-1][:k], 0.0))


def pinv(j: np.ndarray, rcond: float = 1e-15) -> np.ndarray:
    """Pseudo-inverse of a (p, q) matrix with q small (q <= 6), kernel-independent.

    J^+ = V diag(1/lambda) V^T J^T over the eigenpairs (lambda, V) of J^T J whose singular value
    sqrt(lambda) is above rcond * sigma_max (the others are dropped, as `numpy.linalg.pinv` does).
    """
    j = np.asarray(j, dtype=np.float64)
    w, v = eigh_small(matmul(j.T, j))
    top = float(np.sqrt(max(float(w[-1]), 0.0))) if w.size else 0.0
    keep = np.sqrt(np.maximum(w, 0.0)) > rcond * top
    inv_w = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    return matmul(v * inv_w, matmul(v.T, j.T))


def pinv_tall(a: np.ndarray) -> np.ndarray:
    """Pseudo-inverse (K, N) of a tall (N, K) matrix of full column rank, kernel-independent.

    A thin QR by classical Gram-Schmidt with one re-orthogonalisation pass ("twice is enough":
    orthogonal to rounding like Householder QR), then A^+ = R^-1 Q^T by back substitution.
    Accurate to about eps * cond(A), unlike the normal equations (eps * cond(A)^2).

    Raises:
        numpy.linalg.LinAlgError: a column is (numerically) in the span of the previous ones.
    """
    a = np.asarray(a, dtype=np.float64)
    n, k = a.shape
    Q = np.zeros((k, n))  # rows are the orthonormal columns of Q
    R = np.zeros((k, k))
    for j in range(k):
        v = a[:, j].copy()
        size = norm(v)
        for _ in range(2):
            if j:
                c = matvec(Q[:j], v)
                R[:j, j] += c
                v -= np.einsum("j,jn->n", c, Q[:j])
        r = norm(v)
        if not r > 1e-13 * size:
            raise np.linalg.LinAlgError(f"column {j} is linearly dependent on the others")
        R[j, j] = r
        Q[j] = v / r
    out = np.zeros((k, n))  # R X = Q^T, row by row from the bottom
    for i in range(k - 1, -1, -1):
        row = Q[i].copy()
        if i + 1 < k:
            row -= np.einsum("j,jn->n", R[i, i + 1 :], out[i + 1 :])
        out[i] = row / R[i, i]
    return out
