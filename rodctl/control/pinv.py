"""The Ma et al. 2022 baseline law: u = lambda J^+ sat(s* - s).

A re-implementation from published descriptions (docs/baselines.md), not the authors' code.
The description writes u = -lambda J^+ sat(s - s*); sat is odd, so that is the same law.
Assumptions we made:
- sat clips each feature-error component to +-`error_limit` (per component, not by norm);
- J^+ is the pseudo-inverse with singular values below rcond * sigma_max dropped (as numpy's
  SVD pinv does; computed in fixed-order arithmetic, `rodctl.fixedla.pinv`), so a direction J
  barely observes does not ask for a huge move;
- the per-axis speed saturation of u is the loop's, as for every law.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field, PositiveFloat

from rodctl import fixedla as fla
from rodctl.config.base import StrictModel
from rodctl.registry import CONTROLLERS, BuildContext


class PinvController:
    """Saturated pseudo-inverse shape servo, stateless."""

    def __init__(self, **settings: Any) -> None:
        """Args: **settings: fields of `PinvControllerConfig` (gain lambda, error_limit of sat,
        rcond of the pseudo-inverse): its defaults and checks are the only ones."""
        cfg = PinvControllerConfig(**settings)
        self._gain, self._limit, self._rcond = cfg.gain, cfg.error_limit, cfg.rcond

    def reset(self) -> None:
        """Nothing to forget: the law is memoryless."""

    def command(
        self, s: np.ndarray, s_target: np.ndarray, J: np.ndarray, r: np.ndarray
    ) -> np.ndarray:
        """u = lambda J^+ clip(s* - s, +-error_limit); s, s* (p,), J (p, q), r unused. (q,)."""
        e = np.clip(np.asarray(s_target, float) - np.asarray(s, float), -self._limit, self._limit)
        # rodctl.fixedla: the same bits on every machine, unlike LAPACK's SVD
        # (docs/reproducibility.md); same truncation rule as numpy.linalg.pinv.
        return self._gain * fla.matvec(fla.pinv(np.asarray(J, float), rcond=self._rcond), e)


# --- config and registration ------------------------------------------------------------


class PinvControllerConfig(StrictModel):
    """u = lambda J^+ sat(s* - s), the Ma et al. 2022 law (our re-implementation).

    docs/baselines.md writes -lambda J^+ sat(s - s*): the same thing, since sat is odd.
    """

    type: Literal["pinv"] = "pinv"
    gain: float = Field(
        0.5, gt=0.0, le=1.0, description="lambda: the fraction of the linearised error removed."
    )
    error_limit: PositiveFloat = Field(
        0.5,
        le=1e6,
        description="sat(): each feature error component is clipped to +-this (feature units).",
    )
    rcond: float = Field(
        1e-4,
        gt=0.0,
        lt=1.0,
        description="Singular values below rcond * the largest are dropped in J^+ (numpy pinv).",
    )


@CONTROLLERS.register(PinvControllerConfig)
def _build(cfg: PinvControllerConfig, ctx: BuildContext) -> PinvController:
    return PinvController(**cfg.model_dump(exclude={"type"}))
