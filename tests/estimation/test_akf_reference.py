"""The AKF against a plain transcription of docs/method.md §3 with the explicit matrices.

The implementation never forms M = I_p (x) u^T and uses LAPACK on small blocks; this reference
writes every equation as printed (with numpy.linalg), so the two must agree to rounding over
informative steps, outliers (alpha < 1) and dead-zone steps.
"""

from __future__ import annotations

import numpy as np

from rodctl.estimation.akf import AdaptiveKalmanJacobian


def _psd_clip(a, floor):
    a = 0.5 * (a + a.T)
    w, v = np.linalg.eigh(a)
    return (v * np.maximum(w, floor)) @ v.T if w.min() < floor else a


def reference_akf(J0, steps, *, p0, q0, r0, c0, c1, floor, b, dead_zone):
    p, q = J0.shape
    n = p * q
    x = J0.reshape(-1).copy()  # rows of J stacked
    P, Qn, R = p0 * np.eye(n), q0 * np.eye(n), r0 * np.eye(p)
    k = 0
    alphas = []
    for ds, u in steps:
        if np.linalg.norm(u) < dead_zone:  # no information about J: skip
            alphas.append(None)
            continue
        M = np.kron(np.eye(p), u[None, :])  # (p, pq): M x = J u
        P_pred = P + Qn  # random walk, A = I
        eps = ds - M @ x
        G = M @ P_pred @ M.T
        stat = np.sqrt(eps @ eps / np.trace(G))
        if stat <= c0:
            alpha = 1.0
        elif stat <= c1:
            alpha = (c0 / stat) * ((c1 - stat) / (c1 - c0)) ** 2  # c1 - |de|, typo fixed
        else:
            alpha = 0.0
        alpha = max(alpha, floor)
        K = (1 / alpha) * P_pred @ M.T @ np.linalg.inv((1 / alpha) * G + R)
        x = x + K @ eps
        P = (1 / alpha) * (np.eye(n) - K @ M) @ P_pred
        P = 0.5 * (P + P.T)
        k += 1
        d = (1 - b) / (1 - b ** (k + 1))
        R = _psd_clip((1 - d) * R + d * np.outer(eps, eps), 1e-8)  # eq. 33
        Qn = _psd_clip((1 - d) * Qn + d * (K @ np.outer(eps, eps) @ K.T + P - P_pred), 1e-8)
        alphas.append(alpha)
    return x.reshape(p, q), alphas


def test_akf_matches_the_equations_written_out():
    rng = np.random.default_rng(11)
    p, q = 6, 3
    J_true = rng.normal(size=(p, q)) * 20
    J0 = J_true * (1 + 0.3 * rng.normal(size=(p, q)))
    steps = []
    for i in range(60):
        u = rng.normal(size=q) * np.array([0.01, 0.01, 0.05])
        if i % 17 == 5:
            u *= 1e-6  # dead zone
        ds = J_true @ u + 1e-3 * rng.normal(size=p)
        if i % 13 == 7:
            ds += 0.5 * rng.normal(size=p)  # outlier: alpha drops
        steps.append((ds, u))
    kw = dict(p0=10.0, q0=1e-2, r0=1e-4, c0=1.5, c1=6.0, b=0.95, dead_zone=1e-4)
    ref_J, alphas = reference_akf(J0, steps, floor=1e-3, **kw)
    akf = AdaptiveKalmanJacobian(
        p,
        q,
        p0=kw["p0"],
        q0=kw["q0"],
        r0=kw["r0"],
        c0=kw["c0"],
        c1=kw["c1"],
        alpha_floor=1e-3,
        forgetting=kw["b"],
        q_min=1e-8,
        r_min=1e-8,
        dead_zone=kw["dead_zone"],
    )
    akf.reset(J0)
    got_alphas = []
    for ds, u in steps:
        akf.update(ds, u)
        info = akf.info()
        got_alphas.append(None if info["skipped"] else info["alpha"])
    assert any(a is not None and a < 1 for a in alphas), "the data must exercise alpha < 1"
    assert [a is None for a in got_alphas] == [a is None for a in alphas]
    np.testing.assert_allclose(
        [a for a in got_alphas if a is not None], [a for a in alphas if a is not None], rtol=1e-6
    )
    np.testing.assert_allclose(akf.J, ref_J, rtol=1e-6, atol=1e-8 * np.abs(ref_J).max())
