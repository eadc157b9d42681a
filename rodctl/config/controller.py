"""Config of the controller: one union member per law, keyed by `type`.

Owned by `rodctl/control/`.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from rodctl.config.base import StrictModel


class MfacControllerConfig(StrictModel):
    """MFAC velocity law with seven performance weights (paper eq. 24, method-notes section 2)."""

    type: Literal["mfac"] = "mfac"


ControllerConfig = Annotated[MfacControllerConfig, Field(discriminator="type")]
