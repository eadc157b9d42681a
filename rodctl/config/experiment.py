"""The whole experiment: one model that every command loads, validated once."""

from __future__ import annotations

import os
from typing import Annotated, Any

from pydantic import ConfigDict, Field, model_validator

from rodctl.config.base import (
    RUN_NAME,
    RUN_NAME_MAX,
    StageConfig,
    StageSlot,
    StrictModel,
    default_stage_types,
    stage_field,
)
from rodctl.config.camera import CameraConfig
from rodctl.config.events import EventState, validate_events
from rodctl.config.logging import LoggingConfig
from rodctl.config.rod import RodConfig
from rodctl.config.run import RunConfig
from rodctl.errors import UserError
from rodctl.registry import depends_on_stages

#: The config of each pluggable stage: every type registered in `rodctl.registry`, by `type`.
FeatureConfig = Annotated[StageConfig, StageSlot("feature")]
EstimatorConfig = Annotated[StageConfig, StageSlot("estimator")]
ControllerConfig = Annotated[StageConfig, StageSlot("controller")]

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
        pattern=RUN_NAME,
        max_length=RUN_NAME_MAX,
        description="Run name, used in the run directory name (letters, digits, . _ -).",
    )
    seed: int = Field(
        0, ge=0, le=2**63 - 1, description="The one seed every random consumer derives from."
    )
    rod: RodConfig = RodConfig()
    camera: CameraConfig = CameraConfig()
    feature: FeatureConfig = stage_field("feature", "The shape feature s = f_s(c), by `type`.")
    estimator: EstimatorConfig = stage_field("estimator", "How the Jacobian J is obtained.")
    controller: ControllerConfig = stage_field("controller", "The control law, by `type`.")
    run: RunConfig = Field(default_factory=RunConfig)
    logging: LoggingConfig = Field(default_factory=LoggingConfig)

    @model_validator(mode="before")
    @classmethod
    def _default_stage_types(cls, data: Any) -> Any:
        """A stage section written without `type` means the default type for that stage."""
        return default_stage_types(data, STAGE_SECTIONS)

    @model_validator(mode="after")
    def _fits_in_memory(self) -> ExperimentConfig:
        """Refuse up front a run whose frames cannot fit in memory, instead of failing late."""
        need = estimated_memory(self)
        have = physical_memory()
        if have and need > 0.5 * have:
            raise ValueError(
                f"this run would hold about {need / 2**30:.1f} GiB of camera frames "
                f"(camera.width x camera.height x 3 bytes, x logging.flush_every_steps frames "
                f"buffered by the logs, twice) but the machine has {have / 2**30:.1f} GiB; make "
                "the image smaller or flush the logs more often"
            )
        return self

    @model_validator(mode="after")
    def _camera_sees_the_rod(self) -> ExperimentConfig:
        """No point the rod can reach lies behind the camera (the renderer cannot draw it; the
        run failed at its first frame). Events that move the camera or the clamp are checked
        by their own `check`."""
        try:
            EventState.from_config(self).check_rod_in_front("camera")
        except UserError as exc:
            raise ValueError(str(exc)) from None
        return self

    @model_validator(mode="after")
    def _events_can_apply(self) -> ExperimentConfig:
        """Events that cannot apply (a slip longer than the rod, a clamp out of reach) are
        refused before the run, naming the field (`rodctl.config.events.validate_events`)."""
        if self.run.events:
            try:
                validate_events(list(self.run.events), self)
            except UserError as exc:
                raise ValueError(str(exc)) from None
        return self

    @model_validator(mode="after")
    def _dual_arm_supported(self) -> ExperimentConfig:
        """A target pose of both ends (6 values) needs rod.arms: 2 (docs/dual-arm.md)."""
        pose = self.run.target.pose
        if self.rod.arms == 1 and pose is not None and len(pose) == 6:
            raise ValueError(
                "run.target.pose has 6 values (both ends' poses): that needs rod.arms: 2"
            )
        ws = self.rod.clamp_arm.workspace
        if pose is not None and len(pose) == 6 and not ws.contains(pose[3:]):
            raise ValueError(
                f"run.target.pose: the x0 end's pose {list(pose[3:])} (values 4-6) is outside "
                f"rod.clamp_arm.workspace (x in {list(ws.x_limits)} m, y in "
                f"{list(ws.y_limits)} m, theta in {list(ws.theta_limits)} rad)"
            )
        return self

    @model_validator(mode="after")
    def _stages_fit_together(self) -> ExperimentConfig:
        """A stage config may check the rest of the experiment (`check_experiment(cfg)`), e.g.
        the offline model's servoed nodes must be the feature's."""
        for name in STAGE_SECTIONS:
            check = getattr(getattr(self, name), "check_experiment", None)
            if check is not None:
                check(self)
        return self


def estimated_memory(cfg: ExperimentConfig) -> int:
    """Bytes a run holds at its peak, roughly: the camera frames (the image, its noise and blur
    copies, and the frames the MCAP and Rerun writers buffer between flushes), plus the rod."""
    frame = cfg.camera.width * cfg.camera.height * 3
    buffered = cfg.logging.flush_every_steps if cfg.logging.image_rate_hz > 0 else 0
    return 4 * frame + 2 * frame * buffered + 4096 * cfg.rod.segments


def physical_memory() -> int:
    """Bytes of physical memory (0 when the platform does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 0
