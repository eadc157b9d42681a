"""Fourier-based shape servoing (after Navarro-Alarcon & Liu, IEEE T-RO 2018) as a rodctl plug-in.

An example of what a package outside rodctl can add: one feature map, one Jacobian estimator and
one controller, each a config model (a pydantic model with a `type` literal) plus a factory
registered in rodctl's registries. rodctl imports this module at start-up because
`pyproject.toml` names it in the entry-point group `rodctl.plugins`.

Our reading of the method (a re-implementation for demonstration, not the authors' code):

- Feature `navarro_fourier`: the centerline as truncated Fourier series of its image
  coordinates over normalised arc length rho in [0, 1]. The paper treats closed contours with a
  full series; an open rod is mirrored into a closed curve of period 2, whose series is a cosine
  series, x(rho) = a_0 + sum_j a_j cos(pi j rho) (likewise y). s = [a_0..a_H, b_0..b_H] (px).
- Estimator `navarro_rls`: the deformation Jacobian from the recent (ds, dr) pairs, as least
  squares over a window that forgets exponentially (the recursive form: one rank-1 update per
  step, forgetting factor lam, about 1/(1 - lam) pairs in the window).
- Controller `navarro_dls`: u = gain (J^T J + mu I)^-1 J^T sat(s* - s): the saturated
  pseudo-inverse law, with damping mu so that a direction J barely sees does not ask for a
  large move.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from rodctl.config.base import StrictModel
from rodctl.errors import UserError
from rodctl.registry import CONTROLLERS, ESTIMATORS, FEATURES, BuildContext

__all__ = [
    "CosineSeriesFeature",
    "DampedPinvController",
    "ForgettingLsJacobian",
    "NavarroDlsConfig",
    "NavarroFourierConfig",
    "NavarroRlsConfig",
]


# --- feature -----------------------------------------------------------------------------------


class CosineSeriesFeature:
    """s = least-squares cosine-series coefficients of u(rho) and v(rho) (pixels).

    Args:
        harmonics: H; the feature has 2 (H + 1) components.
        points: N, the centerline points it is given (equally spaced in arc length).
    """

    kind = "navarro_fourier"
    units = "px"

    def __init__(self, harmonics: int, points: int) -> None:
        if points < harmonics + 1:
            raise ValueError(f"{harmonics} harmonics need at least {harmonics + 1} points")
        rho = np.linspace(0.0, 1.0, points)
        self.basis = np.cos(np.pi * np.outer(rho, np.arange(harmonics + 1)))  # (N, H + 1)
        self._fit = np.linalg.pinv(self.basis)  # (H + 1, N)
        self.points = points
        self.dim = 2 * (harmonics + 1)
        self.scale = np.ones(self.dim)

    def encode(self, centerline_px: np.ndarray) -> np.ndarray:
        c = np.asarray(centerline_px, dtype=float)
        if c.shape != (self.points, 2):
            raise ValueError(f"expected ({self.points}, 2) pixels, got {c.shape}")
        return (self._fit @ c).T.reshape(-1)

    def encode_batch(self, centerlines_px: np.ndarray) -> np.ndarray:
        return np.stack([self.encode(c) for c in centerlines_px])

    def decode(self, s: np.ndarray) -> np.ndarray:
        """(p,) -> (N, 2) the curve the coefficients describe."""
        coef = np.asarray(s, dtype=float).reshape(2, -1).T  # (H + 1, 2)
        return self.basis @ coef


class NavarroFourierConfig(StrictModel):
    """Cosine series of the centerline in arc length (Navarro-Alarcon & Liu 2018; plug-in)."""

    type: Literal["navarro_fourier"] = "navarro_fourier"
    harmonics: int = Field(6, ge=1, le=40, description="Harmonics H; p = 2 (H + 1).")


@FEATURES.register(NavarroFourierConfig)
def _feature(cfg: NavarroFourierConfig, ctx: BuildContext) -> CosineSeriesFeature:
    try:
        return CosineSeriesFeature(cfg.harmonics, ctx.points)
    except ValueError as exc:
        raise UserError(f"feature ({cfg.type}) with camera.points={ctx.points}: {exc}") from None


# --- estimator ---------------------------------------------------------------------------------


class ForgettingLsJacobian:
    """Least squares over exponentially forgotten (ds, dr) pairs, updated recursively.

    Minimises sum_i lam^(k-i) ||ds_i - J dr_i||^2 (plus the forgotten prior J_0): the standard
    recursive least-squares update with one gain vector for every row of J.
    """

    def __init__(self, p: int, q: int, *, forgetting: float, p0: float, dead_zone: float) -> None:
        self.p, self.q = p, q
        self.lam, self.p0, self.dead_zone = forgetting, p0, dead_zone
        self.reset(np.zeros((p, q)))

    @property
    def J(self) -> np.ndarray:
        return self._J.copy()

    def reset(self, J0: np.ndarray) -> None:
        J0 = np.array(J0, dtype=float)
        if J0.shape != (self.p, self.q):
            raise ValueError(f"J0 must have shape {(self.p, self.q)}, got {J0.shape}")
        self._J = J0
        self._P = self.p0 * np.eye(self.q)
        self._residual = 0.0

    def update(self, ds: np.ndarray, dr: np.ndarray) -> np.ndarray:
        dr = np.asarray(dr, dtype=float)
        if np.linalg.norm(dr) < self.dead_zone:
            return self.J
        err = np.asarray(ds, dtype=float) - self._J @ dr
        Pdr = self._P @ dr
        gain = Pdr / (self.lam + dr @ Pdr)
        self._J = self._J + np.outer(err, gain)
        self._P = (self._P - np.outer(gain, Pdr)) / self.lam
        self._P = 0.5 * (self._P + self._P.T)
        self._residual = float(np.linalg.norm(err))
        return self.J

    def info(self) -> dict[str, float]:
        return {"residual": self._residual, "trace_P": float(np.trace(self._P))}


class NavarroRlsConfig(StrictModel):
    """Recursive least squares with forgetting (Navarro-Alarcon & Liu 2018 reading; plug-in)."""

    type: Literal["navarro_rls"] = "navarro_rls"
    forgetting: float = Field(
        0.9, gt=0.0, le=1.0, description="lam: weight of a pair one step older (~1/(1-lam) pairs)."
    )
    p0: float = Field(1e4, gt=0.0, le=1e12, description="Initial covariance of J's rows (1/m^2).")
    dead_zone: float = Field(
        1e-4, ge=0.0, le=1.0, description="Moves shorter than this are skipped."
    )


@ESTIMATORS.register(NavarroRlsConfig)
def _estimator(cfg: NavarroRlsConfig, ctx: BuildContext) -> ForgettingLsJacobian:
    return ForgettingLsJacobian(
        ctx.p, ctx.q, forgetting=cfg.forgetting, p0=cfg.p0, dead_zone=cfg.dead_zone
    )


# --- controller --------------------------------------------------------------------------------


class DampedPinvController:
    """u = gain (J^T J + mu I)^-1 J^T clip(s* - s, +-error_limit)."""

    def __init__(self, gain: float, damping: float, error_limit: float) -> None:
        self.gain, self.damping, self.error_limit = gain, damping, error_limit

    def reset(self) -> None:
        """The law has no memory."""

    def command(
        self, s: np.ndarray, s_target: np.ndarray, J: np.ndarray, r: np.ndarray
    ) -> np.ndarray:
        e = np.clip(np.asarray(s_target) - np.asarray(s), -self.error_limit, self.error_limit)
        J = np.asarray(J, dtype=float)
        H = J.T @ J + self.damping * np.eye(J.shape[1])
        return self.gain * np.linalg.solve(H, J.T @ e)


class NavarroDlsConfig(StrictModel):
    """Saturated, damped pseudo-inverse law (Navarro-Alarcon & Liu 2018 reading; plug-in)."""

    type: Literal["navarro_dls"] = "navarro_dls"
    gain: float = Field(0.6, gt=0.0, le=1.0, description="Fraction of the error one step removes.")
    damping: float = Field(
        1.0, ge=0.0, le=1e6, description="mu in (J^T J + mu I) (px^2 per unit^2)."
    )
    error_limit: float = Field(
        20.0, gt=0.0, le=1e6, description="Each feature error clipped to +-this (px)."
    )


@CONTROLLERS.register(NavarroDlsConfig)
def _controller(cfg: NavarroDlsConfig, ctx: BuildContext) -> DampedPinvController:
    return DampedPinvController(cfg.gain, cfg.damping, cfg.error_limit)
