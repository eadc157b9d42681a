"""Probing moves and the least-squares fit that give every online estimator its J_0.

The paper does not say how J_0 starts (docs/method.md §3). Ours: q + 1 small moves at the
start of a run, one along each axis and then one combined return, so the gripper ends where it
started and the q + 1 pairs (Delta r, Delta s) over-determine J by one equation per feature.
"""

from __future__ import annotations

import numpy as np

from rodctl import fixedla as fla


def probe_moves(q: int, size: np.ndarray) -> np.ndarray:
    """The q + 1 probing increments: +size_i along each axis i, then -sum of them.

    Args:
        q: command dimension.
        size: (q,) positive move size per axis (e.g. [0.005 m, 0.005 m, 0.03 rad]).

    Returns:
        (q + 1, q) increments; they sum to zero, so the gripper ends where it started.
    """
    size = np.asarray(size, dtype=float).reshape(-1)
    if size.shape != (q,):
        raise ValueError(f"size must have shape ({q},), got {size.shape}")
    if not np.all(size > 0.0):
        raise ValueError(f"probe sizes must be positive, got {size.tolist()}")
    moves = np.zeros((q + 1, q))
    moves[:q] = np.diag(size)
    moves[q] = -size
    return moves


def fit_jacobian(dS: np.ndarray, dR: np.ndarray) -> np.ndarray:
    """Least-squares J with dS_i ~ J dR_i for every row i.

    Args:
        dS: (n, p) feature changes.
        dR: (n, q) the pose increments that caused them, n >= q.

    Returns:
        (p, q) J minimising sum_i ||dS_i - J dR_i||^2.

    Raises:
        ValueError: shapes disagree, or the moves do not span all q axes (J is then not
            determined).
    """
    dS = np.asarray(dS, dtype=float)
    dR = np.asarray(dR, dtype=float)
    if dS.ndim != 2 or dR.ndim != 2 or dS.shape[0] != dR.shape[0]:
        raise ValueError(f"need dS (n, p) and dR (n, q) with equal n, got {dS.shape}, {dR.shape}")
    q = dR.shape[1]
    # Normal equations in fixed-order arithmetic (rodctl.fixedla) rather than LAPACK's lstsq,
    # whose result depends on the machine's BLAS kernel: J_0 seeds every later estimate. The
    # probing moves are q + 1 axis-aligned moves, so dR^T dR is well conditioned whenever it
    # has full rank. Rank: eigenvalues of dR^T dR above 64 q eps times the largest (rounding
    # leaves about eps * lambda_max where dR has no extent; a singular value ratio of 2e-7).
    gram = fla.matmul(np.ascontiguousarray(dR.T), dR)
    w, _ = fla.eigh_small(gram, vectors=False)
    tol = 64 * q * np.finfo(float).eps * float(w[-1])
    rank = int(np.sum(w > tol)) if w[-1] > 0 else 0
    JT = fla.spd_solve(gram, fla.matmul(np.ascontiguousarray(dR.T), dS)) if rank == q else None
    if JT is None:
        raise ValueError(
            f"the {dR.shape[0]} moves span only {rank} of {q} axes: J is not determined"
        )
    return JT.T
