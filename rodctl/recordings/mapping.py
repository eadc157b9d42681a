"""`rodctl import BAG --topics mapping.yaml`: which of a bag's topics is which, in a small YAML.

Keys (docs/recordings.md, "A topic mapping"), all optional, unknown keys refused:

    image: /cam/image              # sensor_msgs/msg/Image or CompressedImage
    camera_info: /cam/info         # sensor_msgs/msg/CameraInfo
    points: /tracker/points        # MarkerArray, Marker, Path, PoseArray or PointCloud2
    poses: [/left/pose]            # PoseStamped topics, one or two (a single string is one)
    tf:                            # end effectors from tf instead (or after the poses)
      topic: /tf                   # tf2_msgs/msg/TFMessage (default /tf)
      frames: [left_tool, right_tool]
      world: base_link             # compose each chain up to this frame (default: the root)
    mask: /cam/rod_mask            # mono8/8UC1 masks of the rod, used instead of the HSV range

A flag given on the command line (--image-topic, --points-topic, --pose-topic, --tf-frame, ...)
replaces the mapping's key.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from rodctl.config.loading import format_validation_error, read_yaml
from rodctl.errors import UserError


def _topic(v: str) -> str:
    if not v.strip() or v != v.strip():
        raise ValueError("a topic name is a non-empty string without surrounding spaces")
    return v


class TfMapping(BaseModel):
    """End effectors from a tf topic: its name and the child frames (one or two)."""

    model_config = ConfigDict(extra="forbid")

    topic: str = Field("/tf", description="The tf2_msgs/msg/TFMessage topic.")
    frames: list[str] = Field(min_length=1, max_length=2, description="Child frame names.")
    world: str | None = Field(None, description="Compose up to this frame (default: the root).")

    @field_validator("topic")
    @classmethod
    def _check_topic(cls, v: str) -> str:
        return _topic(v)

    @field_validator("frames")
    @classmethod
    def _check_frames(cls, v: list[str]) -> list[str]:
        for f in v:
            if not f.strip("/ "):
                raise ValueError("a frame name is a non-empty string")
        return v


class TopicMapping(BaseModel):
    """Which topic of a bag is which (every key optional; flags replace keys)."""

    model_config = ConfigDict(extra="forbid")

    image: str | None = Field(None, description="Camera frames: Image or CompressedImage.")
    camera_info: str | None = Field(None, description="sensor_msgs/msg/CameraInfo (K, D).")
    points: str | None = Field(None, description="Tracked points of the rod.")
    poses: list[str] = Field(
        default_factory=list, max_length=2, description="End effectors' PoseStamped."
    )
    tf: TfMapping | None = None
    mask: str | None = Field(None, description="Rod masks (mono8/8UC1 Image) for the frames.")

    @field_validator("image", "camera_info", "points", "mask")
    @classmethod
    def _check_topic(cls, v: str | None) -> str | None:
        return None if v is None else _topic(v)

    @field_validator("poses", mode="before")
    @classmethod
    def _one_or_list(cls, v: object) -> object:
        return [v] if isinstance(v, str) else v

    @field_validator("poses")
    @classmethod
    def _check_poses(cls, v: list[str]) -> list[str]:
        return [_topic(t) for t in v]

    @model_validator(mode="after")
    def _consistent(self) -> TopicMapping:
        if self.image and self.points:
            raise ValueError("give image (camera frames) or points (tracked points), not both")
        if self.camera_info and not self.image:
            raise ValueError("camera_info goes with image")
        if self.mask and not self.image:
            raise ValueError("mask goes with image")
        ends = len(self.poses) + (len(self.tf.frames) if self.tf else 0)
        if ends > 2:
            raise ValueError(f"poses and tf.frames name {ends} end effectors; at most 2")
        return self


def load_mapping(path: str | Path) -> TopicMapping:
    """The topic mapping YAML at `path`.

    Raises:
        UserError: an unreadable file, not a mapping, an unknown key, a value of the wrong
            type, too many end effectors; the message names the file and the key (exit 2).
    """
    p = Path(path)
    data = read_yaml(p, "topic mapping")
    try:
        return TopicMapping.model_validate(data)
    except ValidationError as exc:
        msg = format_validation_error(exc, data, f"--topics {p}")
        raise UserError(_tidy(msg, "invalid topic mapping")) from None


def _tidy(msg: str, what: str) -> str:
    """The config loader's message for a file that is not an experiment config."""
    msg = msg.replace("invalid config", what).replace("\n  : ", "\n  ")
    return msg.replace(
        "`rodctl config schema` lists every key", "docs/recordings.md lists the keys"
    )
