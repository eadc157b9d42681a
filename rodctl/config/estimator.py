"""Config of the deformation-Jacobian estimator: one union member per method, keyed by `type`.

Owned by `rodctl/estimation/`.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from rodctl.config.base import StrictModel


class AkfEstimatorConfig(StrictModel):
    """Adaptive Kalman filter on vec_rows(J) (paper eqs. 25-33, method-notes section 1)."""

    type: Literal["akf"] = "akf"


EstimatorConfig = Annotated[AkfEstimatorConfig, Field(discriminator="type")]
