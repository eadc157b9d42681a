"""Building blocks shared by every config model.

Every model forbids unknown keys (a typo in a YAML file must fail loudly, not be ignored) and
validates on assignment, so a config mutated after loading cannot drift out of range.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING, Annotated, Any, Union, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    GetCoreSchemaHandler,
    model_validator,
)
from pydantic_core import PydanticCustomError

if TYPE_CHECKING:

    class StageConfig(BaseModel):
        """What the checker knows of the config of a registered type (a stage, an event, a
        sink, an executor): a model with a `type` name (`Registry.register` refuses one
        without). At run time it is `BaseModel`: the union of the registered models is built
        by `StageSlot`."""

        type: str

else:
    StageConfig = BaseModel


#: The error type of a YAML boolean given for a number (its context names the field).
BOOL_FOR_NUMBER = "bool_for_number"

#: A run, comparison, sweep or scenario name: it becomes part of a folder's name, so letters,
#: digits, `.`, `_` and `-` only, starting with a letter or digit (no `/`, no `..` escape).
RUN_NAME = r"^[A-Za-z0-9][A-Za-z0-9._-]*$"
#: The longest such name.
RUN_NAME_MAX = 64


def is_run_name(text: str) -> bool:
    """Whether `text` is a usable run name (`RUN_NAME`, at most `RUN_NAME_MAX` characters)."""
    return len(text) <= RUN_NAME_MAX and re.fullmatch(RUN_NAME, text) is not None


class StrictModel(BaseModel):
    """Base for all config models: unknown keys, NaN and infinity are errors; defaults validated;
    a YAML boolean is not a number (`max_steps: true` would otherwise be 1)."""

    model_config = ConfigDict(
        extra="forbid", validate_default=True, validate_assignment=True, allow_inf_nan=False
    )

    @model_validator(mode="before")
    @classmethod
    def _no_booleans_for_numbers(cls, data: Any) -> Any:
        # A model validator: a field validator on every field would reach a union's `type`,
        # which pydantic refuses. The error's type and context let `format_validation_error`
        # name the field itself (`rod.length`), not its section.
        if isinstance(data, dict):
            for name, value in data.items():
                field = cls.model_fields.get(name) if isinstance(name, str) else None
                if field is not None and _holds_bool(value) and not _accepts_bool(field.annotation):
                    raise PydanticCustomError(
                        BOOL_FOR_NUMBER,
                        "{field}: expected a number, not a boolean",
                        {"field": name, "given": value},
                    )
        return data


def _holds_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    return isinstance(value, list | tuple) and any(_holds_bool(v) for v in value)


def _accepts_bool(annotation: Any) -> bool:
    """Whether `bool` appears anywhere in a type annotation."""
    if annotation is bool:
        return True
    return any(_accepts_bool(a) for a in get_args(annotation))


#: Physically sensible limits every config value is held to (validated up front, in the schema):
#: a world coordinate within 100 m of the origin, an angle within 10 turns.
MAX_COORDINATE_M = 100.0
MAX_ANGLE_RAD = 20 * math.pi

#: A world coordinate (m).
Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE_M, le=MAX_COORDINATE_M)]
#: An angle (rad).
Angle = Annotated[float, Field(ge=-MAX_ANGLE_RAD, le=MAX_ANGLE_RAD)]

#: A planar pose ``[x, y, theta]`` in the world frame (metres, radians, y up).
Pose = Annotated[
    tuple[Coordinate, Coordinate, Angle],
    Field(description="Planar pose [x, y, theta]: metres, metres, radians; world frame, y up."),
]

#: A 2-D point ``[x, y]`` (m).
Point2 = tuple[Coordinate, Coordinate]


class StageSlot:
    """The config of one pluggable stage (or event, sink, executor): a union of every registered
    type of that kind, keyed by `type`.

    Used as ``feature: Annotated[BaseModel, StageSlot("feature")]``. The union is built from the
    registry (`rodctl.registry`) when the model's schema is built, and rebuilt when a plug-in
    registers a type, so `rodctl config schema` and validation always see every type.
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def __get_pydantic_core_schema__(self, source: Any, handler: GetCoreSchemaHandler) -> Any:
        from rodctl.registry import KINDS, load_builtins

        load_builtins()
        models = KINDS[self.kind].config_models()
        if len(models) == 1:
            return handler.generate_schema(models[0])
        # A union built at run time from the registry: it has no static type to check.
        union = Annotated[Union[tuple(models)], Field(discriminator="type")]  # type: ignore[valid-type]  # noqa: E501, UP007
        return handler.generate_schema(union)

    def __repr__(self) -> str:
        return f"StageSlot({self.kind!r})"


def stage_field(kind: str, description: str) -> Any:
    """A model field holding the config of stage `kind`, defaulting to the registry's default."""

    def default() -> BaseModel:
        from rodctl.registry import STAGES, load_builtins

        load_builtins()
        reg = STAGES[kind]
        assert reg.default is not None, f"the {kind} kind has no default type"
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
