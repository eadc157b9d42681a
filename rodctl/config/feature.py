"""Config of the shape feature s = f_s(c): one union member per FeatureMap, keyed by `type`.

Owned by `rodctl/features/`.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from rodctl.config.base import StrictModel


class AutoencoderFeatureConfig(StrictModel):
    """The paper's feature (section VI-A): an autoencoder latent of the N-point centerline."""

    type: Literal["autoencoder"] = "autoencoder"
    latent_dim: int = Field(6, ge=1, description="Latent dimension p.")


FeatureConfig = Annotated[AutoencoderFeatureConfig, Field(discriminator="type")]
