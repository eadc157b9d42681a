"""Config of `rodctl sweep`: config values searched over seeds, targets and methods.

Owned by `rodctl/bench/sweep.py`. A sweep is a compare (`rodctl/config/compare.py`) with one more
axis: *parameters*, dotted keys of the experiment each method runs (as `--set` writes them:
`controller.weights`, `estimator.p0`, `rod.EI`), each given a list of values (a grid, or a
choice in random search) or a range (random search). Every point of the search runs every
method on the same targets, for every seed of `seeds` (each seed its own target set and camera
noise), so points differ only by the swept values.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, ClassVar, Literal

from pydantic import ConfigDict, Field, PositiveInt, field_validator, model_validator

from rodctl.config.base import RUN_NAME, RUN_NAME_MAX, StrictModel, is_run_name
from rodctl.config.compare import MAX_SEED, MAX_TARGETS, CompareTargetsConfig, MethodConfig
from rodctl.config.experiment import ExperimentConfig
from rodctl.config.logging import NO_LOGS_TO_KEEP
from rodctl.registry import depends_on_stages

_KEY = r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z0-9_]+)*$"

#: Ranking metrics of a (point, method) group, and whether larger is better.
METRICS: dict[str, bool] = {
    "success_rate": True,
    "steps_median": False,
    "steps_mean": False,
    "final_pixel_error_median": False,
    "smoothness_median": False,
    "path_length_median": False,
    "wall_time_median": False,
}

#: Largest number of points a sweep may have (a typo in a grid must not mean a week of work).
MAX_POINTS = 10_000


class ParameterConfig(StrictModel):
    """One swept key: a list of values, or (random search only) a numeric range."""

    values: list[Any] | None = Field(
        None,
        min_length=1,
        description="The values to try (any YAML value the key accepts, e.g. a list of "
        "weights). Grid: every one; random: one drawn uniformly per sample.",
    )
    low: float | None = Field(None, description="Random search: lower end of the range.")
    high: float | None = Field(None, description="Random search: upper end of the range.")
    log: bool = Field(False, description="Random search: draw uniformly in log(value).")
    integer: bool = Field(False, description="Random search: round the draw to an integer.")
    elements: list[ParameterConfig] | None = Field(
        None,
        min_length=1,
        description="Random search: a list value drawn element by element, each element its own "
        "`values` or range (e.g. the seven MFAC weights, each on its own log range).",
    )
    normalize: bool = Field(
        False,
        description="With `elements`: divide the drawn list by its sum, so that it sums to 1 "
        "(the MFAC weights must); every element must then be positive.",
    )

    @model_validator(mode="after")
    def _one_kind(self) -> ParameterConfig:
        ranged = self.low is not None or self.high is not None
        if self.elements is not None:
            if ranged or self.values is not None or self.log or self.integer:
                raise ValueError(
                    "`elements` gives each element its own values or range: leave `values`, "
                    "`low`/`high`, `log` and `integer` to the elements"
                )
            if self.normalize:
                bad = [
                    i
                    for i, e in enumerate(self.elements)
                    if e.elements is not None
                    or (e.values is not None and not all(_positive(v) for v in e.values))
                    or (e.low is not None and e.low <= 0)
                ]
                if bad:
                    raise ValueError(
                        f"`normalize` needs positive numbers in every element; elements {bad} "
                        "may draw something else"
                    )
            return self
        if self.normalize:
            raise ValueError("`normalize` applies to a list drawn by `elements` only")
        if (self.values is None) == (not ranged):
            raise ValueError("give either `values` or a range `low`/`high`, not both or neither")
        if ranged:
            if self.low is None or self.high is None:
                raise ValueError("a range needs both `low` and `high`")
            if not self.low < self.high:
                raise ValueError(f"low ({self.low}) must be below high ({self.high})")
            if self.log and self.low <= 0:
                raise ValueError(f"a log range needs low > 0, got {self.low}")
        elif self.log or self.integer:
            raise ValueError("`log` and `integer` apply to a range (`low`/`high`) only")
        return self


def _positive(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and v > 0


@depends_on_stages
class SweepConfig(StrictModel):
    """`rodctl sweep`: a grid or seeded random search over experiment keys."""

    model_config = ConfigDict(defer_build=True)
    #: Sections keyed by dotted experiment keys (`parameters: {estimator.p0: ...}`), with the
    #: fields their values take: `--set parameters.rod.length.values=[...]` names the key
    #: `rod.length` even before the file sweeps it (`rodctl.config.loading.apply_override`).
    DOTTED_SECTIONS: ClassVar[dict[str, frozenset[str]]] = {
        "parameters": frozenset(ParameterConfig.model_fields)
    }

    name: str = Field(
        "sweep",
        pattern=RUN_NAME,
        max_length=RUN_NAME_MAX,
        description="Used in the output folder's name.",
    )
    seed: int = Field(0, ge=0, le=MAX_SEED, description="Seeds the random search's draws.")
    base: ExperimentConfig = Field(
        default_factory=ExperimentConfig,
        description="The experiment every point shares before its swept values are applied. "
        "Without `methods`, its own feature/estimator/controller are the one method `base`.",
    )
    methods: dict[str, MethodConfig] | None = Field(
        None,
        description="Methods (as in compare configs) each point runs; None: the base's stages.",
    )
    parameters: dict[str, ParameterConfig] = Field(
        ...,
        min_length=1,
        description="Swept keys: dotted paths into each method's experiment config (as "
        "`--set` writes them), e.g. `controller.weights`, `estimator.p0`, `rod.EI`.",
    )
    search: Literal["grid", "random"] = Field(
        "grid", description="grid: every combination of `values`; random: `samples` draws."
    )
    samples: PositiveInt | None = Field(
        None, le=MAX_POINTS, description="Random search: number of points."
    )
    include_base: bool = Field(
        False,
        description="Random search: point 0 is the base's own values of the swept keys (the "
        "current setting, run on the same targets), before the `samples` draws.",
    )
    seeds: list[Annotated[int, Field(ge=0, le=MAX_SEED)]] = Field(
        [0],
        min_length=1,
        max_length=MAX_TARGETS,
        description="Compare seeds: each gives its own target set (sampled as `targets` says) "
        "and camera noise; every point runs on every seed.",
    )
    targets: CompareTargetsConfig = CompareTargetsConfig(count=10)
    rank_by: list[str] = Field(
        ["success_rate", "steps_median"],
        min_length=1,
        description=f"Ranking of (point, method) groups, first key first; one of "
        f"{sorted(METRICS)} (success rate: higher is better; the others: lower).",
    )
    workers: PositiveInt | None = Field(
        None, description="Worker processes (None: one per CPU core; 1: run in this process)."
    )
    keep_logs: bool = Field(
        False, description="Keep every episode's logs under episodes/ (as base.logging asks)."
    )

    @model_validator(mode="after")
    def _logs_to_keep(self) -> SweepConfig:
        if self.keep_logs and not self.base.logging.writes_episode_logs:
            raise ValueError(NO_LOGS_TO_KEEP)
        return self

    @field_validator("parameters")
    @classmethod
    def _keys(cls, value: dict[str, ParameterConfig]) -> dict[str, ParameterConfig]:
        bad = [k for k in value if not re.match(_KEY, k)]
        if bad:
            raise ValueError(f"swept keys must be dotted paths like estimator.p0; got {bad}")
        clash = [k for k in value if k in ("name", "seed")]
        if clash:
            raise ValueError(f"{clash}: the episode's name and seed are set by the sweep")
        return value

    @field_validator("rank_by")
    @classmethod
    def _metrics(cls, value: list[str]) -> list[str]:
        bad = [m for m in value if m not in METRICS]
        if bad:
            raise ValueError(f"unknown metric(s) {bad}; expected some of {sorted(METRICS)}")
        return value

    @field_validator("methods")
    @classmethod
    def _method_names(cls, value: dict[str, MethodConfig] | None) -> Any:
        if value is not None:
            if not value:
                raise ValueError("`methods` is empty; leave it out to sweep the base's stages")
            bad = [k for k in value if not is_run_name(k)]
            if bad:
                raise ValueError(f"method names must be letters, digits, . _ - ; got {bad}")
        return value

    @model_validator(mode="after")
    def _search(self) -> SweepConfig:
        if self.search == "grid":
            ranged = [k for k, p in self.parameters.items() if p.values is None]
            if ranged:
                raise ValueError(
                    f"grid search needs `values` for every key; {ranged} give a range or "
                    "`elements` (use search: random, or list values)"
                )
            if self.samples is not None:
                raise ValueError("`samples` is for search: random; a grid runs every point")
            if self.include_base:
                raise ValueError("`include_base` is for search: random (a grid lists its values)")
            sizes = [len(p.values or []) for p in self.parameters.values()]
            if math.prod(sizes) > MAX_POINTS:  # counted before any point is made
                raise ValueError(
                    f"the grid has {math.prod(sizes)} points ({' x '.join(map(str, sizes))} "
                    f"values); at most {MAX_POINTS} (split it, or use search: random)"
                )
        elif self.samples is None:
            raise ValueError("search: random needs `samples` (the number of points to draw)")
        if len(set(self.seeds)) != len(self.seeds):  # each seed's episodes would count twice
            raise ValueError(f"seeds must be distinct, got {self.seeds}")
        if self.base.run.target.pose is not None:
            raise ValueError(
                "base.run.target.pose is set, but the sweep chooses the targets: use "
                "targets.poses or targets.file"
            )
        return self
