"""Building blocks shared by every config model.

Every model forbids unknown keys (a typo in a YAML file must fail loudly, not be ignored) and
validates on assignment, so a config mutated after loading cannot drift out of range.
"""

from __future__ import annotations

from typing import Annotated, Any, Union

from pydantic import BaseModel, ConfigDict, Field, GetCoreSchemaHandler


class StrictModel(BaseModel):
    """Base for all config models: unknown keys, NaN and infinity are errors; defaults validated."""

    model_config = ConfigDict(
        extra="forbid", validate_default=True, validate_assignment=True, allow_inf_nan=False
    )


#: A planar pose ``[x, y, theta]`` in the world frame (metres, radians, y up).
Pose = Annotated[
    tuple[float, float, float],
    Field(description="Planar pose [x, y, theta]: metres, metres, radians; world frame, y up."),
]

#: A 2-D point ``[x, y]``.
Point2 = tuple[float, float]


class StageSlot:
    """The config of one pluggable stage: a union of every registered type, keyed by `type`.

    Used as ``feature: Annotated[BaseModel, StageSlot("feature")]``. The union is built from the
    registry (`rodctl.registry`) when the model's schema is built, and rebuilt when a plug-in
    registers a type, so `rodctl config schema` and validation always see every type.
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def __get_pydantic_core_schema__(self, source: Any, handler: GetCoreSchemaHandler) -> Any:
        from rodctl.registry import STAGES, load_builtins

        load_builtins()
        models = STAGES[self.kind].config_models()
        if len(models) == 1:
            return handler.generate_schema(models[0])
        union = Annotated[Union[tuple(models)], Field(discriminator="type")]  # noqa: UP007
        return handler.generate_schema(union)

    def __repr__(self) -> str:
        return f"StageSlot({self.kind!r})"


def stage_field(kind: str, description: str) -> Any:
    """A model field holding the config of stage `kind`, defaulting to the registry's default."""

    def default() -> BaseModel:
        from rodctl.registry import STAGES, load_builtins

        load_builtins()
        reg = STAGES[kind]
        return reg.get(reg.default).config()

    return Field(default_factory=default, description=description)


def default_stage_types(data: Any, sections: tuple[str, ...]) -> Any:
    """A stage section written without `type` means the registry's default type for it."""
    if not isinstance(data, dict):
        return data
    from rodctl.registry import STAGES

    data = dict(data)
    for name in sections:
        section = data.get(name)
        if isinstance(section, dict) and "type" not in section:
            data[name] = {"type": STAGES[name].default, **section}
    return data
