"""Building blocks shared by every config model.

Every model forbids unknown keys (a typo in a YAML file must fail loudly, not be ignored) and
validates on assignment, so a config mutated after loading cannot drift out of range.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


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
