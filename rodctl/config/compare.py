"""Config of `rodctl compare`: one shared experiment, several methods, one target set.

Owned by `rodctl/bench/compare.py`. A comparison is only fair if everything but the method is
the same for every method, so the model is built to make that the only possibility: `base` is
one full `ExperimentConfig` (rod, camera, speed limits, step budget, probing budget, success
criterion, logging), and a method may replace nothing but the three stages that *are* the method
— its `feature`, `estimator` and `controller`. Targets are shared too: sampled once from the
compare seed (easy to hard) or read from a file of gripper poses that labs can exchange.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pydantic import ConfigDict, Field, PositiveInt, field_validator, model_validator

from rodctl.config.base import RUN_NAME, RUN_NAME_MAX, Pose, StrictModel, is_run_name
from rodctl.config.experiment import (
    ControllerConfig,
    EstimatorConfig,
    ExperimentConfig,
    FeatureConfig,
)
from rodctl.config.logging import NO_LOGS_TO_KEEP
from rodctl.config.run import EndPoses
from rodctl.registry import depends_on_stages


@depends_on_stages
class MethodConfig(StrictModel):
    """One full pipeline under comparison: representation + estimation + control.

    Each stage needs its `type`: a comparison names its methods explicitly.
    """

    model_config = ConfigDict(defer_build=True)

    description: str = Field("", description="One line shown in summary.md (what this method is).")
    feature: FeatureConfig = Field(..., description="The shape feature s = f_s(c).")
    estimator: EstimatorConfig = Field(..., description="How the Jacobian J is obtained.")
    controller: ControllerConfig = Field(..., description="The control law.")


#: Most targets a compare or sweep may have: each is an episode per method (10,000 is days).
MAX_TARGETS = 10_000
#: Largest seed, the same for every command (`seed` of an experiment config).
MAX_SEED = 2**63 - 1


def pose_kind(arms: int) -> str:
    """What one target pose holds for `arms` moved ends (the targets.yaml header says it)."""
    if arms == 1:
        return "gripper poses [x, y, theta]"
    return "both ends' poses [x, y, theta, x0_x, x0_y, x0_theta]: the gripper's, then the x0 end's"


def check_pose_lengths(
    poses: Sequence[Sequence[float]], arms: int, where: str, error: type[Exception]
) -> None:
    """Every pose has 3 values for one arm, 6 (both ends') for rod.arms: 2.

    A 3-value pose of a dual-arm rod would leave the x0 end home unsaid (run.target.pose allows
    it, a shared target set does not: its targets.yaml and difficulties are 6-D).

    Raises:
        error: the first pose of the wrong length, named as `where`: item i.
    """
    want = 3 * arms
    for i, pose in enumerate(poses):
        if len(pose) != want:
            what = "one arm (rod.arms: 1)" if arms == 1 else "two arms (rod.arms: 2)"
            raise error(
                f"{where}: item {i} has {len(pose)} values, but the rod has {what}: each pose "
                f"needs {want} values ({pose_kind(arms)}; docs/dual-arm.md)"
            )


class CompareTargetsConfig(StrictModel):
    """The shared target set: sampled (seeded, spread from easy to hard) or read from a file."""

    count: PositiveInt = Field(
        100,
        le=MAX_TARGETS,
        description="Number of sampled targets K (ignored when `file` is given).",
    )
    min_offset: float = Field(
        0.1, ge=0.0, description="Easiest target: normalised distance from home (rodctl.targets)."
    )
    max_offset: float = Field(
        1.0, gt=0.0, description="Hardest target: normalised distance from home."
    )
    file: str | None = Field(
        None,
        description="YAML/JSON file holding gripper poses [[x, y, theta], ...] (world frame, m, "
        "rad; rod.arms: 2: six values, the gripper's pose then the x0 end's), or a mapping with "
        "key `targets` holding them; a relative path is resolved from the compare config's "
        "folder. Every compare run writes its targets as targets.yaml.",
    )
    poses: list[Pose | EndPoses] | None = Field(
        None,
        max_length=MAX_TARGETS,
        description="Target gripper poses given inline (alternative to `file`; rod.arms: 2: "
        "six values each, as in `file`).",
    )
    bands: list[float] = Field(
        [0.4, 0.7],
        description="Difficulty band edges (normalised offset): [0.4, 0.7] makes the bands easy "
        "< 0.4 <= medium < 0.7 <= hard.",
    )

    @field_validator("poses", mode="before")
    @classmethod
    def _three_or_six(cls, value: Any) -> Any:
        """One clear message for a pose of neither length (the union's would list both)."""
        for i, pose in enumerate(value if isinstance(value, list | tuple) else []):
            if isinstance(pose, list | tuple) and len(pose) not in (3, 6):
                raise ValueError(
                    f"item {i} has {len(pose)} values; a pose is [x, y, theta], or 6 values "
                    "(the gripper's pose, then the x0 end's) for rod.arms: 2"
                )
        return value

    @model_validator(mode="after")
    def _consistent(self) -> CompareTargetsConfig:
        if self.min_offset > self.max_offset:
            raise ValueError(
                f"min_offset ({self.min_offset}) must not exceed max_offset ({self.max_offset})"
            )
        if self.file is not None and self.poses is not None:
            raise ValueError("give target poses either in `file` or in `poses`, not both")
        if self.poses is not None and not self.poses:
            raise ValueError("`poses` is empty")
        if any(b >= a for b, a in zip(self.bands, self.bands[1:], strict=False)) or any(
            b <= 0 for b in self.bands
        ):
            raise ValueError(f"bands must be positive and increasing, got {self.bands}")
        return self


class ScenarioConfig(StrictModel):
    """One scenario of a benchmark suite: the shared experiment with some keys changed.

    Every method runs every scenario, each scenario on its own shared target set. Keys are
    dotted paths into `base`, as with `--set` (e.g. `rod.max_step: [0.05, 0.05, 0.25]`).
    """

    description: str = Field("", description="One line shown in the suite's summary.")
    set: dict[str, Any] = Field(
        default_factory=dict,
        description="Dotted keys of `base` and their values for this scenario (like --set).",
    )
    method_set: dict[str, Any] = Field(
        default_factory=dict,
        description="Dotted keys of the methods' stages and their values for this scenario, set "
        "in every method whose stage has that field (e.g. `feature.checkpoint` reaches every "
        "autoencoder method: a rod the packaged encoder was not trained for needs its own).",
    )
    targets: CompareTargetsConfig | None = Field(
        None, description="This scenario's target set (None: the suite's `targets`)."
    )


@depends_on_stages
class CompareConfig(StrictModel):
    """`rodctl compare`: the benchmark of several methods on one shared set of targets."""

    model_config = ConfigDict(defer_build=True)

    name: str = Field(
        "compare",
        pattern=RUN_NAME,
        max_length=RUN_NAME_MAX,
        description="Used in the output folder's name.",
    )
    scenario: str = Field(
        "nominal",
        pattern=RUN_NAME,
        max_length=RUN_NAME_MAX,
        description="The scenario this comparison is (the `scenario` column of results.csv).",
    )
    scenarios: dict[str, ScenarioConfig] | None = Field(
        None,
        description="A benchmark suite: every method on every scenario (`base` with some keys "
        "changed), each with its own shared targets. None: one comparison on `base`.",
    )
    reference: str | None = Field(
        None,
        description="The method others are compared with, paired by target (None: the first).",
    )
    seed: int = Field(
        0,
        ge=0,
        le=MAX_SEED,
        description="Seeds the targets ('targets' stream) and each target's camera noise "
        "('compare' stream); every method sees the same start, targets and noise.",
    )
    seeds: list[int] | None = Field(
        None,
        min_length=1,
        max_length=100,
        description="A suite only: run every scenario once per seed (each its own target set "
        "and camera noise, replacing `seed`), report each comparison per seed and pooled, and "
        "call a finding replicated only when every seed agrees (docs/statistics.md). None: "
        "`seed` alone.",
    )
    base: ExperimentConfig = Field(
        default_factory=ExperimentConfig,
        description="The experiment every method shares: rod, camera, speed limits (rod.max_step),"
        " step budget (run.max_steps), probing (run.probe_size), success criterion "
        "(run.pixel_tolerance), logging. Its feature/estimator/controller are unused.",
    )
    methods: dict[str, MethodConfig] = Field(
        ..., min_length=1, description="Methods by name, in the order they are reported."
    )
    targets: CompareTargetsConfig = CompareTargetsConfig()
    workers: PositiveInt | None = Field(
        None, description="Worker processes (None: one per CPU core; 1: run in this process)."
    )
    keep_logs: bool = Field(
        False,
        description="Keep every episode's logs (MCAP/.rrd as base.logging asks) under episodes/.",
    )
    figure_target: int | None = Field(
        None,
        ge=0,
        description="Index of the target drawn in the side-by-side figures (None: the target "
        "of median difficulty).",
    )

    @field_validator("methods")
    @classmethod
    def _method_names(cls, value: dict[str, MethodConfig]) -> dict[str, MethodConfig]:

        bad = [k for k in value if not is_run_name(k)]
        if bad:
            raise ValueError(f"method names must be letters, digits, . _ - ; got {bad}")
        return value

    @model_validator(mode="after")
    def _suite_names(self) -> CompareConfig:

        bad = [k for k in self.scenarios or {} if not is_run_name(k)]
        if bad:
            raise ValueError(f"scenario names must be letters, digits, . _ - ; got {bad}")
        if self.seeds is not None:
            if self.scenarios is None:
                raise ValueError(
                    "seeds: only a suite (with `scenarios`) runs several target seeds; one "
                    "comparison takes `seed`"
                )
            if any(s < 0 for s in self.seeds) or len(set(self.seeds)) < len(self.seeds):
                raise ValueError(f"seeds must be distinct and >= 0, got {self.seeds}")
            if len(self.seeds) > 1 and (
                self.targets.file is not None or self.targets.poses is not None
            ):
                # The seeds would re-run the same poses: pooled as independent pairs, they
                # would multiply n and shrink p, and "replicated" would mean "over noise".
                raise ValueError(
                    "seeds: several target seeds draw several target sets, but targets.file / "
                    "targets.poses fix the poses; give one seed, or sampled targets"
                )
        if self.reference is not None and self.reference not in self.methods:
            raise ValueError(
                f"reference {self.reference!r} is not one of the methods {list(self.methods)}"
            )
        return self

    @property
    def reference_method(self) -> str:
        """The method the others are compared with (`reference`, else the first)."""
        return self.reference or next(iter(self.methods))

    @model_validator(mode="after")
    def _poses_fit_the_arms(self) -> CompareConfig:
        """3 values a pose for one arm, 6 (both ends') for rod.arms: 2 (docs/dual-arm.md)."""
        if self.targets.poses is not None:
            check_pose_lengths(self.targets.poses, self.base.rod.arms, "targets.poses", ValueError)
        return self

    @model_validator(mode="after")
    def _logs_to_keep(self) -> CompareConfig:
        # A suite's scenarios may switch the base's logging on (`set:`): checked per scenario.
        if self.keep_logs and self.scenarios is None and not self.base.logging.writes_episode_logs:
            raise ValueError(NO_LOGS_TO_KEEP)
        return self

    @model_validator(mode="after")
    def _base_samples_no_target(self) -> CompareConfig:
        if self.base.run.target.pose is not None:
            raise ValueError(
                "base.run.target.pose is set, but compare chooses the targets: use "
                "targets.poses or targets.file"
            )
        return self
