"""rodctl.fixedla's faster kernels give the same bits as the textbook forms they replaced.

Issue 24 sped up the eigenvalue clip of the AKF's Q (an in-place Householder reduction, a QL
loop with fewer list reads, eigenvectors that skip the rotations acting on two zeros), the
positive-definiteness test of P (right-looking) and the singular values of J (no U, V; each
column's sum of squares once until it changes). A closed loop carries any changed bit into every
later step, so each is compared here, bit for bit, with the form it replaced (the oracles below,
kept only for this test) on random matrices of every kind the loop meets and on the matrices the
AKF itself clips.
"""

from __future__ import annotations

import math
from operator import mul

import numpy as np
import pytest

from rodctl import fixedla as fla
from rodctl.estimation.akf import AdaptiveKalmanJacobian

# --- the replaced forms (oracles) ---------------------------------------------------------


def _tridiagonalize_before(a):
    W = np.array(a, dtype=np.float64)
    n = W.shape[0]
    diag, sub, refl = [], [], []
    for k in range(n - 2):
        diag.append(float(W[0, 0]))
        x = W[1:, 0]
        xx = float(np.einsum("i,i->", x, x))
        if xx == 0.0:
            sub.append(0.0)
            W = W[1:, 1:]
            continue
        norm_x = math.sqrt(xx)
        x0 = float(x[0])
        alpha = -norm_x if x0 >= 0.0 else norm_x
        v = x.copy()
        v[0] = x0 - alpha
        beta = 1.0 / (norm_x * (norm_x + abs(x0)))
        B = W[1:, 1:]
        p = np.einsum("ij,j->i", B, v)
        w = beta * p - (0.5 * beta * beta * float(np.einsum("i,i->", p, v))) * v
        vw = np.multiply.outer(v, w)
        W = B - (vw + vw.T)
        sub.append(alpha)
        refl.append((k, v, beta))
    if n >= 2:
        diag += [float(W[0, 0]), float(W[1, 1])]
        sub.append(float(W[1, 0]))
    elif n == 1:
        diag.append(float(W[0, 0]))
    return diag, sub, refl


def _ql_before(diag, sub, max_iterations=fla.QL_MAX_ITERATIONS):  # noqa: C901 (verbatim)
    d = list(diag)
    n = len(d)
    e = list(sub) + [0.0]
    rots = []
    for l in range(n):  # noqa: E741
        it = 0
        while True:
            m = l
            while m < n - 1:
                dd = math.fabs(d[m]) + math.fabs(d[m + 1])
                if math.fabs(e[m]) + dd == dd:
                    break
                m += 1
            if m == l:
                break
            it += 1
            if it > max_iterations:
                raise np.linalg.LinAlgError("tridiagonal QL did not converge")
            g = (d[l + 1] - d[l]) / (2.0 * e[l])
            r = math.sqrt(g * g + 1.0)
            g = d[m] - d[l] + e[l] / (g + (r if g >= 0.0 else -r))
            s = c = 1.0
            p = 0.0
            i = m - 1
            split = False
            while i >= l:
                f = s * e[i]
                b = c * e[i]
                r = math.sqrt(f * f + g * g)
                e[i + 1] = r
                if r == 0.0:
                    d[i + 1] -= p
                    e[m] = 0.0
                    split = True
                    break
                s = f / r
                c = g / r
                g = d[i + 1] - p
                r = (d[i] - g) * s + 2.0 * c * b
                p = s * r
                d[i + 1] = g + p
                g = c * r - b
                rots.append((i, c, s))
                i -= 1
            if split:
                continue
            d[l] -= p
            e[l] = g
            e[m] = 0.0
    return d, rots


def _eigenvector_before(n, j, rots):
    x = [0.0] * n
    x[j] = 1.0
    for i, c, s in reversed(rots):
        a, b = x[i], x[i + 1]
        x[i] = c * a + s * b
        x[i + 1] = c * b - s * a
    return x


def _clip_before(a, floor):
    a = np.asarray(a, dtype=np.float64)
    n = a.shape[0]
    diag, sub, refl = _tridiagonalize_before(a)
    try:
        w, rots = _ql_before(diag, sub)
    except np.linalg.LinAlgError:
        return fla.gershgorin_clip(a, floor)
    low = [j for j in range(n) if w[j] < floor]
    if not low:
        return a
    kept = [j for j in range(n) if w[j] >= floor]
    if max(floor - w[j] for j in low) <= max((abs(w[j]) for j in kept), default=0.0):
        side, out = low, a
    else:
        side, out = kept, floor * np.eye(n)
    if side:
        if len(side) > 32:
            z = fla.tridiagonal_eigenvectors(n, side, rots)
        else:
            z = np.array([_eigenvector_before(n, j, rots) for j in side]).T
        x = np.array(z, dtype=np.float64)
        for k, v, beta in reversed(refl):
            blk = x[k + 1 :]
            blk -= np.multiply.outer(v, beta * np.einsum("i,ij->j", v, blk))
        gap = np.array([abs(floor - w[j]) for j in side])
        out = out + np.einsum("ik,k,jk->ij", x, gap, x)
    return 0.5 * (out + out.T)


def _singular_values_before(j):
    j = np.asarray(j, dtype=np.float64)
    cols = (j if j.shape[0] >= j.shape[1] else j.T).T.tolist()
    q = len(cols)
    for _ in range(60):
        rotated = False
        for a in range(q - 1):
            for b in range(a + 1, q):
                ca, cb = cols[a], cols[b]
                alpha = sum(map(mul, ca, ca))
                beta = sum(map(mul, cb, cb))
                gamma = sum(map(mul, ca, cb))
                if gamma == 0.0 or abs(gamma) <= 1e-15 * math.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = c * t
                cols[a] = [c * x - s * y for x, y in zip(ca, cb, strict=True)]
                cols[b] = [s * x + c * y for x, y in zip(ca, cb, strict=True)]
        if not rotated:
            break
    return np.array(sorted((math.sqrt(sum(map(mul, c, c))) for c in cols), reverse=True))


# --- the matrices -------------------------------------------------------------------------


def _symmetric_cases(rng: np.random.Generator, count: int) -> list[tuple[np.ndarray, float]]:
    """(exactly symmetric matrix, floor): Q-like (low rank plus a tiny part, the floor among the
    small eigenvalues), integers (exact zeros in sums), sparse, diagonal, block-diagonal (QL
    splits), a clipped side that dwarfs the kept one, and wide scales."""
    out = []
    for t in range(count):
        n = int(rng.integers(1, 25))
        kind = t % 7
        floor = 1e-8
        if kind <= 1:
            V = rng.normal(size=(n, int(rng.integers(1, n + 1))))
            V *= 10.0 ** rng.uniform(-6, 2, V.shape[1])
            m = V @ V.T + rng.normal(size=(n, n)) * 10.0 ** rng.uniform(-12, -7)
        elif kind == 2:
            m, floor = np.round(rng.normal(size=(n, n)) * 3), float(rng.integers(-2, 3))
        elif kind == 3:
            m, floor = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.4), 0.1
        elif kind == 4:
            m = np.zeros((n, n))
            k = n // 2
            m[:k, :k], m[k:, k:] = rng.normal(size=(k, k)), rng.normal(size=(n - k, n - k))
            m[np.arange(n), np.arange(n)] *= rng.random() < 0.5  # sometimes a zero diagonal
            floor = 0.0
        elif kind == 5:
            Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
            w = rng.uniform(0.1, 10.0, n)
            w[: max(1, n // 3)] = -1e9
            m = (Q * w) @ Q.T
        else:
            m = rng.normal(size=(n, n)) * 10.0 ** float(rng.integers(-30, 30))
            floor = float(np.median(np.diagonal(m)))
        out.append((0.5 * (m + m.T), floor))
    return out


@pytest.fixture(scope="module")
def akf_inputs() -> list[tuple[np.ndarray, float]]:
    """The (Q, floor) the AKF clips over 200 steps with outliers, an abrupt change of J and
    dead-zone steps (the filter's own matrices, as the loop gives them)."""
    seen: list[tuple[np.ndarray, float]] = []
    clip = fla.clip_eigenvalues

    def recording(a, floor, *args, **kwargs):
        seen.append((np.array(a), floor))
        return clip(a, floor, *args, **kwargs)

    rng = np.random.default_rng(5)
    J = rng.normal(0.0, 30.0, (6, 3))
    est = AdaptiveKalmanJacobian(6, 3)
    est.reset(J + rng.normal(0.0, 3.0, J.shape))
    mp = pytest.MonkeyPatch()
    mp.setattr(fla, "clip_eigenvalues", recording)
    try:
        for k in range(200):
            if k == 100:
                J = rng.normal(0.0, 30.0, (6, 3))
            u = rng.uniform(-1, 1, 3) * np.array([0.01, 0.01, 0.05]) * rng.choice([1e-3, 1.0])
            noise = rng.normal(0.0, 1e-3, 6) + (rng.random() < 0.05) * rng.normal(0.0, 5.0, 6)
            est.update(J @ u + noise, u)
    finally:
        mp.undo()
    assert len(seen) > 80
    return seen


# --- the tests ----------------------------------------------------------------------------


def test_the_eigenvalue_clip_is_the_same_bits(akf_inputs):
    cases = akf_inputs + _symmetric_cases(np.random.default_rng(2), 700)
    for k, (a, floor) in enumerate(cases):
        want, got = _clip_before(a, floor), fla.clip_eigenvalues(a, floor)
        assert got.tobytes() == want.tobytes(), (k, a.shape, floor)


def test_the_reduction_and_the_ql_rotations_are_the_same_bits(akf_inputs):
    for a, _ in akf_inputs[::5] + _symmetric_cases(np.random.default_rng(3), 300):
        diag, sub, refl = fla.tridiagonalize(a)
        d0, s0, r0 = _tridiagonalize_before(a)
        assert np.array(diag).tobytes() == np.array(d0).tobytes()
        assert np.array(sub).tobytes() == np.array(s0).tobytes()
        assert [(k, v.tobytes(), b) for k, v, b in refl] == [(k, v.tobytes(), b) for k, v, b in r0]
        w, rots = fla.tridiagonal_eigenvalues(diag, sub)
        w0, rots0 = _ql_before(diag, sub)
        assert np.array(w).tobytes() == np.array(w0).tobytes()
        assert np.array(rots).tobytes() == np.array(rots0).tobytes()
        # the eigenvectors skip rotations on zeros: equal values (a zero's sign may differ)
        n = len(diag)
        for j in range(n):
            assert fla.tridiagonal_eigenvector(n, j, rots) == _eigenvector_before(n, j, rots)


def test_the_definiteness_verdict_is_choleskys(akf_inputs):
    """`cholesky_ok` (right-looking, numpy) says what `cholesky` (Python floats) says, on the
    edge too: matrices whose smallest eigenvalue is a few ulps either side of zero."""
    rng = np.random.default_rng(4)
    mats = [a for a, _ in akf_inputs] + [a for a, _ in _symmetric_cases(rng, 300)]
    for _ in range(300):
        n = int(rng.integers(1, 33))
        Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
        w = rng.uniform(0.1, 10.0, n)
        w[0] = rng.choice([1e-17, -1e-17, 1e-16, 0.0, 1e-15, -1e-15])
        m = (Q * w) @ Q.T
        mats.append(0.5 * (m + m.T))
    verdicts = [fla.cholesky_ok(m) for m in mats]
    assert verdicts == [fla.cholesky(m) is not None for m in mats]
    assert 0 < sum(verdicts) < len(verdicts)  # both verdicts occur


def test_the_singular_values_are_the_same_bits():
    rng = np.random.default_rng(6)
    for _ in range(400):
        shape = (int(rng.integers(1, 13)), int(rng.integers(1, 7)))
        j = rng.normal(size=shape) * 10.0 ** float(rng.integers(-5, 5))
        if rng.random() < 0.3:
            j = np.round(j)  # exact zeros, repeated columns
        assert fla.singular_values(j).tobytes() == _singular_values_before(j).tobytes()
        sigma, U, V = fla._svd_columns(j if shape[0] >= shape[1] else j.T)
        assert sorted(sigma, reverse=True) == fla.singular_values(j).tolist()
        assert len(U) == len(V) == min(shape)


def test_the_einsum_is_numpys():
    """`fixedla.einsum` is the loop `numpy.einsum` runs without `optimize`: the same bits."""
    rng = np.random.default_rng(8)
    a, b = rng.normal(size=(18, 18)), rng.normal(size=18)
    for spec, ops in [("ij,j->i", (a, b)), ("i,i->", (b, b)), ("ik,jk->ij", (a, a))]:
        assert fla.einsum(spec, *ops).tobytes() == np.einsum(spec, *ops).tobytes()
