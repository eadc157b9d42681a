"""The whole experiment: one model that every command loads, validated once."""

from __future__ import annotations

from typing import Any

from pydantic import Field, model_validator

from rodctl.config.base import StrictModel
from rodctl.config.camera import CameraConfig
from rodctl.config.controller import ControllerConfig, MfacControllerConfig
from rodctl.config.estimator import AkfEstimatorConfig, EstimatorConfig
from rodctl.config.feature import AutoencoderFeatureConfig, FeatureConfig
from rodctl.config.logging import LoggingConfig
from rodctl.config.rod import RodConfig
from rodctl.config.run import RunConfig


class ExperimentConfig(StrictModel):
    """One shape-servoing experiment: rod, camera, feature, estimator, controller, run, logging."""

    name: str = Field(
        "default",
        pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]*$",
        max_length=64,
        description="Run name, used in the run directory name (letters, digits, . _ -).",
    )
    seed: int = Field(0, ge=0, description="The one seed every random consumer derives from.")
    rod: RodConfig = RodConfig()
    camera: CameraConfig = CameraConfig()
    feature: FeatureConfig = Field(default_factory=AutoencoderFeatureConfig)
    estimator: EstimatorConfig = Field(default_factory=AkfEstimatorConfig)
    controller: ControllerConfig = Field(default_factory=MfacControllerConfig)
    run: RunConfig = RunConfig()
    logging: LoggingConfig = LoggingConfig()

    @model_validator(mode="before")
    @classmethod
    def _default_stage_types(cls, data: Any) -> Any:
        """A stage section written without `type` means the default method for that stage."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        for name in ("feature", "estimator", "controller"):
            section = data.get(name)
            if isinstance(section, dict) and "type" not in section:
                default = cls.model_fields[name].default_factory()  # type: ignore[misc]
                data[name] = {"type": default.type, **section}
        return data

    @model_validator(mode="after")
    def _offline_servoes_the_feature_nodes(self) -> ExperimentConfig:
        """The offline (ASAP) Jacobian is of the servoed nodes: the feature must observe them."""
        if self.estimator.type == "offline":
            servoed = list(self.estimator.servoed)
            if self.feature.type != "nodes" or list(self.feature.positions) != servoed:
                raise ValueError(
                    "estimator.type=offline models the servoed nodes estimator.servoed="
                    f"{servoed}; the feature must be those nodes: feature.type=nodes with "
                    f"feature.positions={servoed}"
                )
        return self
