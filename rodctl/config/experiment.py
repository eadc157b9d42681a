"""The whole experiment: one model that every command loads, validated once."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from rodctl.config.base import StageSlot, StrictModel, default_stage_types, stage_field
from rodctl.config.camera import CameraConfig
from rodctl.config.logging import LoggingConfig
from rodctl.config.rod import RodConfig
from rodctl.config.run import RunConfig
from rodctl.registry import depends_on_stages

#: The config of each pluggable stage: every type registered in `rodctl.registry`, by `type`.
FeatureConfig = Annotated[BaseModel, StageSlot("feature")]
EstimatorConfig = Annotated[BaseModel, StageSlot("estimator")]
ControllerConfig = Annotated[BaseModel, StageSlot("controller")]

#: The sections that hold a method's stages.
STAGE_SECTIONS = ("feature", "estimator", "controller")


@depends_on_stages
class ExperimentConfig(StrictModel):
    """One shape-servoing experiment: rod, camera, feature, estimator, controller, run, logging."""

    # The stage unions are built from the registries when the schema is first needed (after
    # the built-in types and plug-ins have registered), and rebuilt when a type is added.
    model_config = ConfigDict(defer_build=True)

    name: str = Field(
        "default",
        pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]*$",
        max_length=64,
        description="Run name, used in the run directory name (letters, digits, . _ -).",
    )
    seed: int = Field(0, ge=0, description="The one seed every random consumer derives from.")
    rod: RodConfig = RodConfig()
    camera: CameraConfig = CameraConfig()
    feature: FeatureConfig = stage_field("feature", "The shape feature s = f_s(c), by `type`.")
    estimator: EstimatorConfig = stage_field("estimator", "How the Jacobian J is obtained.")
    controller: ControllerConfig = stage_field("controller", "The control law, by `type`.")
    run: RunConfig = RunConfig()
    logging: LoggingConfig = LoggingConfig()

    @model_validator(mode="before")
    @classmethod
    def _default_stage_types(cls, data: Any) -> Any:
        """A stage section written without `type` means the default type for that stage."""
        return default_stage_types(data, STAGE_SECTIONS)

    @model_validator(mode="after")
    def _stages_fit_together(self) -> ExperimentConfig:
        """A stage config may check the rest of the experiment (`check_experiment(cfg)`), e.g.
        the offline model's servoed nodes must be the feature's."""
        for name in STAGE_SECTIONS:
            check = getattr(getattr(self, name), "check_experiment", None)
            if check is not None:
                check(self)
        return self
