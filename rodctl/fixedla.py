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
bits on every x86-64 machine running the same numpy build (see the docs/reproducibility.md).
The price is speed: these are written for the per-step sizes (vectors of a few hundred, matrices up
to about 20 x 20) where BLAS's advantage is small; `benchmarks/` measure what they cost.
"""

from __future__ import annotations

import importlib
import math
from operator import mul

import numpy as np

try:  # what `numpy.einsum` calls when `optimize` is False, without its Python wrapper (~0.6 us)
    einsum = importlib.import_module("numpy._core._multiarray_umath").c_einsum
except (ImportError, AttributeError):  # pragma: no cover - another numpy: the same loops
    einsum = np.einsum

__all__ = [
    "apply_reflectors",
    "cho_solve",
    "cholesky",
    "cholesky_ok",
    "cholesky_inverse_factor",
    "clip_eigenvalues",
    "dot",
    "eigh_small",
    "einsum",
    "gershgorin_clip",
    "inv3",
    "matmul",
    "matvec",
    "norm",
    "pinv",
    "pinv_tall",
    "singular_values",
    "spd_solve",
    "tridiagonal_eigenvalues",
    "tridiagonal_eigenvector",
    "tridiagonal_eigenvectors",
    "tridiagonalize",
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
    return einsum("...k,k->...", a, x)


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a (m, k) times b (k, n) -> (m, n) in a fixed order of operations (`numpy.einsum`
    without `optimize`, see `matvec`). Meant for small matrices."""
    return einsum("ik,kj->ij", a, b)


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


def _svd_columns(
    j: np.ndarray, vectors: bool = True
) -> tuple[list[float], list[list[float]], list[list[float]]]:
    """One-sided Jacobi SVD (Hestenes) of a (p, q) matrix with p >= q, in Python floats.

    Rotates pairs of columns until all are orthogonal: then the column norms are the singular
    values (each to a few ulps of itself, unlike the eigenvalues of J^T J), the normalised
    columns are U and the accumulated rotations V. Returns (sigma, U columns, V columns); U and
    V are empty lists unless `vectors` (they never feed back into sigma).
    """
    cols = np.asarray(j, dtype=np.float64).T.tolist()
    q = len(cols)
    V = [[1.0 if i == k else 0.0 for i in range(q)] for k in range(q)] if vectors else []
    # sum() adds the products left to right, as a loop would; map is faster. A column's sum
    # of squares is the same number until the column is rotated: computed once until then.
    sq: list[float | None] = [None] * q
    for _ in range(60):
        rotated = False
        for a in range(q - 1):
            for b in range(a + 1, q):
                ca, cb = cols[a], cols[b]
                alpha = sq[a]
                if alpha is None:
                    alpha = sq[a] = sum(map(mul, ca, ca))
                beta = sq[b]
                if beta is None:
                    beta = sq[b] = sum(map(mul, cb, cb))
                gamma = sum(map(mul, ca, cb))  # columns of one matrix: equal lengths
                if gamma == 0.0 or abs(gamma) <= 1e-15 * math.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = c * t
                cols[a] = [c * x - s * y for x, y in zip(ca, cb, strict=True)]
                cols[b] = [s * x + c * y for x, y in zip(ca, cb, strict=True)]
                sq[a] = sq[b] = None
                if vectors:
                    va, vb = V[a], V[b]
                    V[a] = [c * x - s * y for x, y in zip(va, vb, strict=True)]
                    V[b] = [s * x + c * y for x, y in zip(va, vb, strict=True)]
        if not rotated:
            break
    sigma = [
        math.sqrt(sum(map(mul, col, col)) if ss is None else ss)
        for col, ss in zip(cols, sq, strict=True)
    ]
    if not vectors:
        return sigma, [], []
    U = [
        [x / sg for x in col] if sg > 0.0 else [0.0] * len(col)
        for col, sg in zip(cols, sigma, strict=True)
    ]
    return sigma, U, V


def singular_values(j: np.ndarray) -> np.ndarray:
    """Singular values (largest first) of a small (p, q) matrix, kernel-independent.

    One-sided Jacobi in a fixed order (`_svd_columns`); replaces LAPACK's SVD in the loop.
    """
    j = np.asarray(j, dtype=np.float64)
    if j.size == 0:
        return np.zeros(0)
    sigma, _, _ = _svd_columns(j if j.shape[0] >= j.shape[1] else j.T, vectors=False)
    return np.array(sorted(sigma, reverse=True))


def pinv(j: np.ndarray, rcond: float = 1e-15) -> np.ndarray:
    """Pseudo-inverse of a small (p, q) matrix, kernel-independent.

    J^+ = V diag(1/sigma) U^T over the singular triplets (one-sided Jacobi) whose sigma is above
    rcond * sigma_max; the others are dropped, as `numpy.linalg.pinv` does.
    """
    j = np.asarray(j, dtype=np.float64)
    wide = j.shape[0] < j.shape[1]
    sigma, U, V = _svd_columns(j.T if wide else j)
    top = max(sigma) if sigma else 0.0
    out = np.zeros((j.shape[1], j.shape[0]) if not wide else (j.shape[0], j.shape[1]))
    for sg, u, v in zip(sigma, U, V, strict=True):
        if sg > rcond * top and sg > 0.0:
            out += np.multiply.outer(np.array(v), np.array(u)) / sg
    return out.T if wide else out


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
                v -= einsum("j,jn->n", c, Q[:j])
        r = norm(v)
        if not r > 1e-13 * size:
            raise np.linalg.LinAlgError(f"column {j} is linearly dependent on the others")
        R[j, j] = r
        Q[j] = v / r
    out = np.zeros((k, n))  # R X = Q^T, row by row from the bottom
    for i in range(k - 1, -1, -1):
        row = Q[i].copy()
        if i + 1 < k:
            row -= einsum("j,jn->n", R[i, i + 1 :], out[i + 1 :])
        out[i] = row / R[i, i]
    return out


def cholesky_inverse_factor(a: np.ndarray) -> list[list[float]] | None:
    """L^-1 for the lower Cholesky factor L of a small SPD matrix (so a^-1 = L^-T L^-1), as
    nested lists; None if a is not positive definite. Forward substitution on the identity,
    in Python floats (fixed order): for the 6 x 6 innovation covariance of the AKF."""
    L = cholesky(a)
    if L is None:
        return None
    n = len(L)
    X = [[0.0] * n for _ in range(n)]
    for j in range(n):  # column j of L^-1: L x = e_j, x_i = 0 for i < j
        X[j][j] = 1.0 / L[j][j]
        for i in range(j + 1, n):
            Li = L[i]
            v = 0.0
            for k in range(j, i):
                v -= Li[k] * X[k][j]
            X[i][j] = v / Li[i]
    return X


def tridiagonalize(
    a: np.ndarray,
) -> tuple[list[float], list[float], list[tuple[int, np.ndarray, float]]]:
    """Householder reduction of a symmetric matrix to tridiagonal form, a = H T H^T, in a fixed
    order of operations (numpy elementwise ops, pairwise sums and `einsum`, no BLAS).

    The textbook reduction (Golub & Van Loan, Algorithm 8.3.1): for k = 0 .. n-3 a reflector
    I - beta v v^T on rows/columns k+1.. zeroes column k below the subdiagonal, and the trailing
    block is updated by the symmetric rank-2 form A - v w^T - w v^T. Only the lower triangle's
    values matter (the input is assumed symmetric).

    Returns:
        (diagonal (n), subdiagonal (n - 1), reflectors [(k, v, beta)]), to be applied by
        `apply_reflectors` to vectors of T.
    """
    # Reduced in place: step k reads column k below the diagonal and updates the trailing
    # block k+1.., so W[k, k] is final from step k on and the diagonal is read at the end. The
    # views have the strides the sums always had (a strided column, rows of unit stride), so
    # numpy runs the same loops on them (tests/test_fixedla_bits.py checks the bits).
    W = np.array(a, dtype=np.float64)
    n = W.shape[0]
    sub: list[float] = []
    refl: list[tuple[int, np.ndarray, float]] = []
    for k in range(n - 2):
        x = W[k + 1 :, k]
        xx = einsum("i,i->", x, x)
        if xx == 0.0:  # column already reduced: no reflector
            sub.append(0.0)
            continue
        norm_x = math.sqrt(xx)
        x0 = x.item(0)
        alpha = -norm_x if x0 >= 0.0 else norm_x  # sign opposite x0: no cancellation in v0
        v = x.copy()
        v[0] = x0 - alpha
        beta = 1.0 / (norm_x * (norm_x + abs(x0)))  # 2 / (v^T v), in closed form
        B = W[k + 1 :, k + 1 :]
        p = einsum("ij,j->i", B, v)
        w = beta * p - (0.5 * beta * beta * einsum("i,i->", p, v).item()) * v
        vw = v[:, None] * w  # the outer product v w^T
        B -= vw + vw.T  # exactly symmetric: v_i w_j + w_i v_j, in either order
        sub.append(alpha)
        refl.append((k, v, beta))
    if n >= 2:
        sub.append(W.item(n - 1, n - 2))
    return W.diagonal().tolist(), sub, refl


#: Iteration cap of the QL method per eigenvalue (EISPACK's tql1 uses 30; Numerical Recipes 30).
QL_MAX_ITERATIONS = 60


def tridiagonal_eigenvalues(
    diag: list[float], sub: list[float], max_iterations: int = QL_MAX_ITERATIONS
) -> tuple[list[float], list[tuple[int, float, float]]]:
    """Eigenvalues of a symmetric tridiagonal matrix by the implicit QL method with Wilkinson
    shifts (EISPACK tql1/tql2, Numerical Recipes' tqli), in Python floats.

    The eigenvectors are not accumulated here (that would be n operations per rotation): the
    plane rotations are returned in the order applied, so that `tridiagonal_eigenvector` can
    build just the eigenvectors wanted.

    Args:
        diag: (n) diagonal.
        sub: (n - 1) subdiagonal.
        max_iterations: QL iterations allowed per eigenvalue (the cap; it takes 1-3 on finite
            input, and never converges on NaN, whose comparisons are all false).

    Returns:
        (eigenvalues in the order QL leaves them (not sorted), rotations [(i, c, s)]: the
        eigenvector matrix is Z = G_1 G_2 ... G_R, G_r acting on coordinates i, i + 1 as
        [[c, s], [-s, c]]).

    Raises:
        numpy.linalg.LinAlgError: no convergence in `max_iterations` for one eigenvalue.
    """
    d = list(diag)
    n = len(d)
    e = list(sub)
    e.append(0.0)
    rots: list[tuple[int, float, float]] = []
    record = rots.append
    sqrt = math.sqrt
    last = n - 1
    for l in range(n):  # noqa: E741 (the classic name of the index)
        it = 0
        while True:
            # A negligible subdiagonal entry splits the matrix. |x| is written x or -x (no
            # call): it differs from fabs only in the sign of a zero, which no comparison sees.
            m = l
            x = d[l]
            ax = x if x >= 0.0 else -x
            while m < last:
                x = d[m + 1]
                ay = x if x >= 0.0 else -x
                dd = ax + ay
                x = e[m]
                if (x if x >= 0.0 else -x) + dd == dd:
                    break
                ax = ay
                m += 1
            if m == l:
                break
            it += 1
            if it > max_iterations:
                raise np.linalg.LinAlgError("tridiagonal QL did not converge")
            dl = d[l]
            el = e[l]
            g = (d[l + 1] - dl) / (2.0 * el)
            r = sqrt(g * g + 1.0)
            g = d[m] - dl + el / (g + (r if g >= 0.0 else -r))
            s = c = 1.0
            p = 0.0
            dn = d[m]  # d[i + 1] as it was before this sweep
            for i in range(m - 1, l - 1, -1):
                ei = e[i]
                f = s * ei
                b = c * ei
                r = sqrt(f * f + g * g)
                e[i + 1] = r
                if r == 0.0:  # underflow: the matrix splits here
                    d[i + 1] = dn - p
                    e[m] = 0.0
                    break
                s = f / r
                c = g / r
                g = dn - p
                dn = d[i]
                r = (dn - g) * s + 2.0 * c * b
                p = s * r
                d[i + 1] = g + p
                g = c * r - b
                record((i, c, s))
            else:
                d[l] -= p
                e[l] = g
                e[m] = 0.0
    return d, rots


def tridiagonal_eigenvector(n: int, j: int, rots: list[tuple[int, float, float]]) -> list[float]:
    """Column j of Z = G_1 ... G_R (the rotations of `tridiagonal_eigenvalues`): the
    eigenvector of the tridiagonal matrix for its j-th eigenvalue, as G_1 (G_2 (... G_R e_j)).
    Four multiplications per rotation, in Python floats.

    The rotations applied before the first that touches coordinate j act on two zeros: they
    are skipped, which can only change the sign of a zero entry (c 0 + s 0 is a zero of either
    sign). No result of `clip_eigenvalues` depends on such a sign: every use of a vector entry
    there is a product summed into an accumulator that starts at +0.0 (`einsum`), which a zero
    of either sign leaves the same."""
    x = [0.0] * n
    x[j] = 1.0
    todo = reversed(rots)
    for i, c, s in todo:
        if i == j or i + 1 == j:
            a, b = x[i], x[i + 1]
            x[i] = c * a + s * b
            x[i + 1] = c * b - s * a
            break
    for i, c, s in todo:
        a, b = x[i], x[i + 1]
        x[i] = c * a + s * b
        x[i + 1] = c * b - s * a
    return x


def tridiagonal_eigenvectors(
    n: int, js: list[int], rots: list[tuple[int, float, float]]
) -> np.ndarray:
    """Columns `js` of Z (see `tridiagonal_eigenvector`), (n, len(js)), all at once.

    The same operations on every column as `tridiagonal_eigenvector` (c a + s b and c b - s a,
    each product and sum rounded once: numpy's elementwise multiply and add are IEEE
    operations like Python's), so the bits are the same, with one numpy call per rotation
    instead of one Python loop per eigenvector: what makes the clip of a 120 x 120 covariance
    affordable.
    """
    x = np.zeros((n, len(js)))
    x[js, np.arange(len(js))] = 1.0
    for i, c, s in reversed(rots):
        a = x[i].copy()
        b = x[i + 1]
        x[i] = c * a + s * b
        x[i + 1] = c * b - s * a
    return x


def apply_reflectors(refl: list[tuple[int, np.ndarray, float]], x: np.ndarray) -> np.ndarray:
    """H x for the H = H_0 H_1 ... of `tridiagonalize`, x (n, m): vectors of T to those of a."""
    x = np.array(x, dtype=np.float64)
    for k, v, beta in reversed(refl):
        blk = x[k + 1 :]
        blk -= v[:, None] * (beta * einsum("i,ij->j", v, blk))  # v (beta v^T blk)
    return x


def cholesky_ok(a: np.ndarray) -> bool:
    """Whether a symmetric matrix (lower triangle read) is positive definite: its Cholesky
    factorisation meets only positive pivots. Column by column with numpy's elementwise
    operations and `einsum` (fixed order, no LAPACK), so it scales to the 120 x 120
    covariances of a p = 20, q = 6 Kalman filter, where `cholesky`'s Python loops are slow.
    """
    m = np.array(a, dtype=np.float64)
    n = m.shape[0]
    if not np.isfinite(m).all():
        return False
    if n <= 32:
        # `cholesky`'s pivots, right-looking: after column j is divided by its pivot, the
        # trailing block loses its outer product, so entry (i, l) is m_il - L_i0 L_l0 - L_i1 L_l1
        # - ... in the order `cholesky` subtracts them, one rounding each (the same bits, so
        # the same verdict), with one numpy pass per column (62 against 93 us at 18 x 18).
        for j in range(n):
            d = m.item(j, j)
            if not d > 0.0:
                return False
            col = m[j + 1 :, j] / math.sqrt(d)
            m[j + 1 :, j + 1 :] -= col[:, None] * col
        return True
    L = np.zeros_like(m)
    for j in range(n):
        row = L[j, :j]
        d = m[j, j] - float(einsum("k,k->", row, row))
        if not d > 0.0:
            return False
        ljj = math.sqrt(d)
        L[j, j] = ljj
        if j + 1 < n:
            L[j + 1 :, j] = (m[j + 1 :, j] - einsum("ik,k->i", L[j + 1 :, :j], row)) / ljj
    return True


def gershgorin_clip(a: np.ndarray, floor: float) -> np.ndarray:
    """a + c I with the smallest c >= 0 that lifts every Gershgorin disc of a to >= floor.

    Every eigenvalue of the result is then >= floor (Gershgorin's theorem), without computing
    any: the defined fallback of `clip_eigenvalues` when the QL iteration hits its cap. It
    raises all eigenvalues by the same c, so it is not the nearest such matrix, but it is
    exactly symmetric, in a fixed order of operations, and cannot fail on finite input.
    """
    a = np.asarray(a, dtype=np.float64)
    radius = np.abs(a).sum(axis=1) - np.abs(np.diagonal(a))
    low = float((np.diagonal(a) - radius).min())
    shift = floor - low if low < floor else 0.0
    out = a + shift * np.eye(a.shape[0])
    return 0.5 * (out + out.T)


#: Above this many eigenvectors `clip_eigenvalues` builds them together (the same bits).
_VECTORISE_ABOVE = 32


def clip_eigenvalues(
    a: np.ndarray, floor: float, max_iterations: int = QL_MAX_ITERATIONS
) -> np.ndarray:
    """Raise every eigenvalue of a symmetric matrix below `floor` to `floor`, kernel-independent.

    out = a + sum over {i: w_i < floor} of (floor - w_i) v_i v_i^T, the nearest matrix (Frobenius
    norm) whose eigenvalues are all >= floor. The eigenvalues come from `tridiagonalize` and
    `tridiagonal_eigenvalues`; eigenvectors (`tridiagonal_eigenvector`, `apply_reflectors`) only
    for one side: usually the clipped eigenpairs, added to a as above (the unclipped part stays
    as it was). When a clipped eigenvalue is further below the floor than every kept one is
    large, a + correction would cancel and leave errors of eps * |w_min| in a result whose
    size is only max(w); then out = floor I + sum over the kept {w_j >= floor} of
    (w_j - floor) v_j v_j^T is built instead. Either way the error is about eps * ||out||.

    If the QL iteration does not converge within `max_iterations` for some eigenvalue (never
    seen on finite input), the result is `gershgorin_clip(a, floor)` instead: defined, in fixed
    order, eigenvalues >= floor, but raised uniformly rather than only where they were low.

    Args:
        a: (n, n) symmetric (exactly: the caller symmetrises).
        floor: the eigenvalue floor.
        max_iterations: the QL iteration cap per eigenvalue.

    Returns:
        (n, n) exactly symmetric; `a` itself (not a copy) when no eigenvalue is below the floor.
        Its eigenvalues are >= floor to about eps * ||a||.

    Raises:
        ValueError: `a` has a NaN or infinite entry (there is no eigenvalue to clip).
    """
    a = np.asarray(a, dtype=np.float64)
    if not np.isfinite(a).all():
        raise ValueError("clip_eigenvalues: the matrix has non-finite entries")
    n = a.shape[0]
    diag, sub, refl = tridiagonalize(a)
    try:
        w, rots = tridiagonal_eigenvalues(diag, sub, max_iterations)
    except np.linalg.LinAlgError:
        return gershgorin_clip(a, floor)
    low = [j for j in range(n) if w[j] < floor]
    if not low:
        return a
    kept = [j for j in range(n) if w[j] >= floor]
    if max(floor - w[j] for j in low) <= max((abs(w[j]) for j in kept), default=0.0):
        side, out = low, a
    else:
        side, out = kept, floor * np.eye(n)
    if side:
        if len(side) > _VECTORISE_ABOVE:  # one numpy call per rotation for all k vectors
            z = tridiagonal_eigenvectors(n, side, rots)  # (n, k)
        else:  # Python floats: cheaper for a few vectors (the 18 x 18 Q of p = 6, q = 3)
            z = np.array([tridiagonal_eigenvector(n, j, rots) for j in side]).T  # (n, k)
        v = apply_reflectors(refl, z)
        gap = np.array([abs(floor - w[j]) for j in side])  # raise the low, or the kept above floor
        out = out + einsum("ik,k,jk->ij", v, gap, v)
    return 0.5 * (out + out.T)
