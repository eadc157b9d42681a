"""The MCAP log: writing it during a run (`McapSink`) and reading it back (`read_mcap`).

Why MCAP is the source of truth: it is one self-describing, indexed, compressed file that Foxglove
opens without configuration and that `rodctl replay` turns back into the exact step records the
loop produced (see `codec`), so every other output (run.rrd, figures) can be rebuilt from it.

Layout (topic contract in the docs/outputs.md, "The MCAP log"):
- `/rod/state`, `/camera/centerline`, `/control`: JSON-schema channels, one message per step,
  contract fields exactly as named, extras after them; MCAP `sequence` = step.
- `/world/rod`, `/world/target`, `/world/gripper` (foxglove.SceneUpdate), `/camera/image`
  (foxglove.CompressedImage, PNG), `/camera/annotations` (foxglove.ImageAnnotations: target,
  extracted centerline and projected truth over each logged frame), `/log` (foxglove.Log),
  `/tf` (foxglove.FrameTransform: where the camera is in the world, frame `world` -> `camera`)
  and `/camera/calibration` (foxglove.CameraCalibration: its pinhole intrinsics), both at the
  start and again at each `camera_bump` event, so Foxglove's 3D panel places the camera and its
  image: what people look at in Foxglove, with the official schemas embedded.
- `/run/header`, `/run/summary`: one message each (RunHeader; summary.json + closing status).
- metadata `rodctl.run`, `rodctl.config` (the resolved config, flattened to dotted keys),
  `rodctl.end` (closing status); attachment `config.yaml`.

Clock: `log_time` = `publish_time` = `codec.LOG_EPOCH_NS` (2000-01-01T00:00:00Z) + simulated
time in ns, for every message; foxglove.* `timestamp` fields carry the same time. Camera frames
are chosen by `codec.FrameSchedule` (at most `logging.image_rate_hz` per simulated second).

Determinism: log times derive from simulated time only, attachment times 0, the library
string carries no version or time, channels and schemas are registered in a fixed order, and JSON
is written compactly with fixed key order: the same records give the same bytes.

Speed: camera frames are PNG-encoded on a background thread (`codec.FRAMES`), and a writer
thread encodes each step's JSON, writes, compresses and flushes, while the loop computes the
next one; `write` returns once the step `codec.LAG` steps back is in the file. OpenCV and zstd
release the GIL, and the JSON is built while the loop is in C (simulator, renderer, torch). The
order is fixed by step counts, so the bytes do not depend on timing.

Crash safety: every `flush_every_steps` steps the open chunk is closed and the file flushed to
the OS, so a run killed without warning (SIGKILL, power loss) loses at most those steps (plus
the `codec.LAG` steps not yet written); the
reader detects the missing footer and refuses the file unless asked to recover what is complete.
"""

from __future__ import annotations

import functools
import json
import math
import os
import signal
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import IO, Any

import numpy as np
import orjson
import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from rodctl import signals
from rodctl.config.logging import LoggingConfig
from rodctl.errors import UserError
from rodctl.logs import codec, schemas
from rodctl.logs.base import raise_or_warn
from rodctl.records import FIELD_UNITS, RunHeader, RunSummary, StepRecord

MAGIC = b"\x89MCAP0\r\n"
#: Written into the MCAP header; no version number, so reruns stay byte-identical.
LIBRARY = "rodctl"

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}

#: (topic, schema) in registration order; the order is part of the byte-stable layout.
CHANNELS: tuple[tuple[str, dict[str, Any]], ...] = (
    (codec.TOPIC_HEADER, schemas.RUN_HEADER),
    (codec.TOPIC_ROD_STATE, schemas.ROD_STATE),
    (codec.TOPIC_CAMERA_CENTERLINE, schemas.CAMERA_CENTERLINE),
    (codec.TOPIC_CONTROL, schemas.CONTROL),
    (codec.TOPIC_ROD_SCENE, schemas.SCENE_UPDATE),
    (codec.TOPIC_TARGET_SCENE, schemas.SCENE_UPDATE),
    (codec.TOPIC_GRIPPER_SCENE, schemas.SCENE_UPDATE),
    (codec.TOPIC_IMAGE, schemas.COMPRESSED_IMAGE),
    (codec.TOPIC_ANNOTATIONS, schemas.IMAGE_ANNOTATIONS),
    (codec.TOPIC_LOG, schemas.LOG),
    (codec.TOPIC_SUMMARY, schemas.RUN_SUMMARY),
    # Added after the others (registration order is part of the byte-stable layout).
    ("/tf", schemas.FRAME_TRANSFORM),
    ("/camera/calibration", schemas.CAMERA_CALIBRATION),
)
TOPIC_TRANSFORM = "/tf"
TOPIC_CALIBRATION = "/camera/calibration"

# Colours (r, g, b[, a]) of the 3D scene: rod blue on top, target a wider translucent green
# band just below it (so a rod lying on the target shows as blue inside green), gripper orange.
_ROD_RGB = (0.1, 0.45, 0.95)
_TARGET_RGB = (0.1, 0.75, 0.25, 0.6)
_GRIPPER_RGB = (1.0, 0.55, 0.0)
_TARGET_Z = -1e-3
# Image overlays (r, g, b, a), picked to differ from the rendered rod (red) and from each other:
# target green, projected ground truth a wide translucent yellow band, extracted centerline blue.
_ANN_TARGET = (0.0, 0.7, 0.2, 1.0)
_ANN_TRUTH = (1.0, 0.85, 0.0, 0.7)
_ANN_EXTRACTED = (0.1, 0.3, 1.0, 1.0)
_LINE_STRIP_2D = 3  # foxglove.PointsAnnotationType.LINE_STRIP


_DEFERRED = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back while the MCAP writer updates its state.

    The loop turns both signals into exceptions (`rodctl.simulate.interrupts_as_exceptions`);
    raised half-way through `Writer.add_message` or a chunk's finalisation, such an exception
    could leave a chunk written without its index, so the finished file would silently lack
    messages. Inside this block a signal is only noted; when the block ends the previous
    handlers are restored and the noted signal is handed to its handler (or re-raised with the
    default action), i.e. between two steps. Only the main thread can swap handlers; elsewhere
    this is a no-op. Costs a few microseconds.
    """
    pending: list[tuple[int, Any]] = []
    previous: dict[int, Any] = {}

    def hold(signum: int, frame: Any) -> None:
        pending.append((signum, frame))

    try:
        with signals.handled(hold, _DEFERRED, over_ignored=True) as previous:
            yield
    finally:
        if pending:
            signum, frame = pending[0]
            handler = previous[signum]
            if callable(handler):
                handler(signum, frame)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(signum)


def _dumps(msg: dict[str, Any]) -> bytes:
    """Compact JSON; floats in their shortest form that reads back to the same double.

    orjson instead of the standard library: 20x faster on the per-step messages (0.27 ms ->
    0.012 ms for the three contract topics), which is most of the MCAP sink's own cost. The
    codec has already replaced non-finite values (`codec.Encoder`), so none reach it.
    """
    return orjson.dumps(msg)


def _flatten(prefix: str, value: Any, out: dict[str, str]) -> None:
    """Dotted-key str->str view of a nested mapping (MCAP metadata holds strings only)."""
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    else:
        out[prefix] = json.dumps(value, default=str)


@functools.lru_cache(maxsize=2)
def _parsed(config_yaml: str) -> Any:
    """The run header's config YAML, parsed once for `config_metadata` and `camera_views` (read
    only: the same object goes to both), by libyaml where PyYAML has it: ~10x faster than the
    pure-Python parser (~40 ms of CPU a run), the same values (the YAML is rodctl's own
    `dump_config`; the same resolver and constructor, only the parser is in C)."""
    return yaml.load(config_yaml, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def config_metadata(config_yaml: str) -> dict[str, str]:
    """The resolved config as MCAP metadata: dotted keys, JSON-encoded values."""
    try:
        data = _parsed(config_yaml)
    except yaml.YAMLError:
        data = None
    if not isinstance(data, dict):
        return {"yaml": config_yaml}
    out: dict[str, str] = {}
    _flatten("", data, out)
    return out


def _color(rgb: tuple[float, ...]) -> dict[str, float]:
    return {"r": rgb[0], "g": rgb[1], "b": rgb[2], "a": rgb[3] if len(rgb) > 3 else 1.0}


_IDENTITY_POSE = {
    "position": {"x": 0.0, "y": 0.0, "z": 0.0},
    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
}


def _entity(t_ns: int, entity_id: str, **primitives: list[Any]) -> dict[str, Any]:
    ent: dict[str, Any] = {
        "timestamp": codec.foxglove_time(t_ns),
        "frame_id": "world",
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
    }
    for name in schemas.PRIMITIVE_LISTS:
        ent[name] = primitives.get(name, [])
    return ent


def line_strip_scene(
    t_ns: int,
    entity_id: str,
    points: np.ndarray,
    rgb: tuple[float, ...],
    width: float,
    z: float = 0.0,
) -> dict[str, Any]:
    """A foxglove.SceneUpdate holding one line strip through (M, 2) world points (at height z)."""
    pts = np.nan_to_num(np.asarray(points, dtype=np.float64)).tolist()
    line = {
        "type": 0,  # LINE_STRIP
        "pose": _IDENTITY_POSE,
        "thickness": width,
        "scale_invariant": False,
        "points": [{"x": x, "y": y, "z": z} for x, y in pts],
        "color": _color(rgb),
        "colors": [],
        "indices": [],
    }
    return {"deletions": [], "entities": [_entity(t_ns, entity_id, lines=[line])]}


def _strip_2d(ts: dict[str, int], points: np.ndarray, rgba: tuple, width: float) -> dict:
    pts = np.nan_to_num(np.asarray(points, dtype=np.float64)).reshape(-1, 2).tolist()
    return {
        "timestamp": ts,
        "type": _LINE_STRIP_2D,
        "points": [{"x": u, "y": v} for u, v in pts],
        "outline_color": _color(rgba),
        "outline_colors": [],
        "fill_color": _color((0.0, 0.0, 0.0, 0.0)),
        "thickness": width,
    }


def image_annotations(t_ns: int, header: RunHeader, r: StepRecord) -> dict[str, Any]:
    """A foxglove.ImageAnnotations for the frame of step r (same timestamp, so Foxglove's Image
    panel draws it over that frame): target, projected ground truth, extracted centerline."""
    ts = codec.foxglove_time(t_ns)
    return {
        "circles": [],
        "points": [
            _strip_2d(ts, header.target_pixels, _ANN_TARGET, 2.0),
            _strip_2d(ts, r.projected_truth, _ANN_TRUTH, 6.0),
            _strip_2d(ts, r.extracted, _ANN_EXTRACTED, 1.5),
        ],
        "texts": [],
    }


def gripper_scene(
    t_ns: int, pose: np.ndarray, rod_length: float, clamp: np.ndarray | None = None
) -> dict[str, Any]:
    """A foxglove.SceneUpdate with an arrow at the gripper pose, pointing along theta (and,
    dual-arm, a second entity `clamp_arm` at the x0 end's pose, pointing into the rod)."""
    out = {"deletions": [], "entities": [_arrow_entity(t_ns, "gripper", pose, rod_length)]}
    if clamp is not None:
        out["entities"].append(_arrow_entity(t_ns, "clamp_arm", clamp, rod_length))
    return out


def _arrow_entity(t_ns: int, name: str, pose: np.ndarray, rod_length: float) -> dict[str, Any]:
    x, y, th = (float(v) for v in np.nan_to_num(np.asarray(pose, dtype=np.float64))[:3])
    size = 0.12 * rod_length if np.isfinite(rod_length) and rod_length > 0 else 0.05
    arrow = {
        "pose": {
            "position": {"x": x, "y": y, "z": 0.0},
            "orientation": {
                "x": 0.0,
                "y": 0.0,
                "z": float(np.sin(th / 2)),
                "w": float(np.cos(th / 2)),
            },
        },
        "shaft_length": 0.7 * size,
        "shaft_diameter": 0.08 * size,
        "head_length": 0.3 * size,
        "head_diameter": 0.2 * size,
        "color": _color(_GRIPPER_RGB),
    }
    return _entity(t_ns, name, arrows=[arrow])


#: Where the camera is, by the step from which it holds: (FrameTransform, CameraCalibration).
CameraViews = dict[int, tuple[dict[str, Any], dict[str, Any]]]


def _quaternion(matrix: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix, w >= 0 (what scipy's `Rotation.as_quat(canonical=
    True)` gives, without importing scipy.spatial at start-up: Shepperd's method, from the
    largest of 1 + trace and 1 + 2 m_ii − trace for accuracy)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(matrix, dtype=float).tolist()
    trace = m00 + m11 + m22
    big = max(range(4), key=(1 + trace, 1 + 2 * m00 - trace, 1 + 2 * m11 - trace,
                             1 + 2 * m22 - trace).__getitem__)  # fmt: skip
    if big == 0:
        w = 0.5 * math.sqrt(1 + trace)
        x, y, z = (m21 - m12) / (4 * w), (m02 - m20) / (4 * w), (m10 - m01) / (4 * w)
    elif big == 1:
        x = 0.5 * math.sqrt(1 + 2 * m00 - trace)
        w, y, z = (m21 - m12) / (4 * x), (m01 + m10) / (4 * x), (m02 + m20) / (4 * x)
    elif big == 2:
        y = 0.5 * math.sqrt(1 + 2 * m11 - trace)
        w, x, z = (m02 - m20) / (4 * y), (m01 + m10) / (4 * y), (m12 + m21) / (4 * y)
    else:
        z = 0.5 * math.sqrt(1 + 2 * m22 - trace)
        w, x, y = (m10 - m01) / (4 * z), (m02 + m20) / (4 * z), (m12 + m21) / (4 * z)
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    q = [v / norm for v in (x, y, z, w)]
    # Canonical sign: w > 0, or for w = 0 the first nonzero of x, y, z positive.
    first = next((v for v in (q[3], q[0], q[1], q[2]) if v != 0.0), 1.0)
    if first < 0:
        q = [-v for v in q]
    return q[0], q[1], q[2], q[3]


def camera_views(config_yaml: str) -> CameraViews:
    """The camera as Foxglove places it, by the control step from which it holds: step 0 the
    configured camera, then one entry per `camera_bump` event (`rodctl.events`), replayed on
    the configured pose in the loop's order. Each is (FrameTransform fields, CameraCalibration
    fields) without the timestamp. Empty when the config does not describe a camera.

    The transform is the camera frame in the world frame (OpenCV's camera axes: +x right in
    the image, +y down, +z along the optical axis, which is what CameraCalibration's frame
    means): translation = the camera centre, rotation = R^T as a quaternion, R being
    `Camera.rotation` (world -> camera).
    """
    from pydantic import ValidationError

    from rodctl.config.camera import CameraConfig
    from rodctl.events import CameraBump
    from rodctl.vision.camera import Camera

    try:
        data = _parsed(config_yaml)
        cam = Camera(CameraConfig.model_validate(data.get("camera", {})))
        run = data.get("run") or {}
        bumps = [
            CameraBump.model_validate(e)
            for e in (run.get("events") or [])
            if isinstance(e, dict) and e.get("type") == "camera_bump"
        ]
    except (yaml.YAMLError, AttributeError, TypeError, ValidationError):
        return {}

    def view(camera: Camera) -> tuple[dict[str, Any], dict[str, Any]]:
        qx, qy, qz, qw = _quaternion(camera.rotation.T)
        cx, cy, cz = (float(v) for v in camera.center)
        transform = {
            "parent_frame_id": "world",
            "child_frame_id": "camera",
            "translation": {"x": cx, "y": cy, "z": cz},
            "rotation": {"x": float(qx), "y": float(qy), "z": float(qz), "w": float(qw)},
        }
        k = [float(v) for v in camera.camera_matrix.ravel()]
        calibration = {
            "frame_id": "camera",
            "width": int(camera.width),
            "height": int(camera.height),
            "distortion_model": "plumb_bob",
            "D": [0.0, 0.0, 0.0, 0.0, 0.0],  # the rendering has no lens distortion
            "K": k,
            "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            "P": k[0:3] + [0.0] + k[3:6] + [0.0] + k[6:9] + [0.0],
        }
        return transform, calibration

    out = {0: view(cam)}
    for bump in sorted(bumps, key=lambda e: e.at_step):  # stable: list order within a step
        c = cam.cfg
        cam.set_pose(**bump.new_pose(c.look_at, c.distance, c.tilt_deg, c.azimuth_deg))
        out[int(bump.at_step)] = view(cam)
    return out


def camera_messages(views: CameraViews, step: int, t_ns: int) -> list[tuple[str, dict[str, Any]]]:
    """/tf and /camera/calibration when the camera is placed from `step` on (at the start,
    after a camera_bump; `camera_views`), else none."""
    if step not in views:
        return []
    transform, calibration = views[step]
    ts = {"timestamp": codec.foxglove_time(t_ns)}
    return [(TOPIC_TRANSFORM, ts | transform), (TOPIC_CALIBRATION, ts | calibration)]


def step_messages(
    header: RunHeader, r: StepRecord, t_ns: int, png: bytes | None, views: CameraViews
) -> list[tuple[str, dict[str, Any]]]:
    """The messages of one step, in the order they are written: the three contract topics, the
    scene, the frame (`png`, if this step logs one) with its annotations, and the camera's
    place if a camera_bump moved it before this step. Shared by the file and the live view."""
    msgs = [
        (codec.TOPIC_ROD_STATE, codec.rod_state_message(r)),
        (codec.TOPIC_CAMERA_CENTERLINE, codec.camera_message(r)),
        (codec.TOPIC_CONTROL, codec.control_message(r)),
        (codec.TOPIC_ROD_SCENE, line_strip_scene(t_ns, "rod", r.centerline, _ROD_RGB, 0.006)),
        (codec.TOPIC_GRIPPER_SCENE, gripper_scene(t_ns, r.gripper, header.rod_length, r.clamp)),
    ]
    if r.clamp is not None:  # dual-arm: the second arm's end
        msgs.insert(3, (codec.TOPIC_CLAMP_STATE, codec.clamp_state_message(r)))
    if png is not None:
        image = {
            "timestamp": codec.foxglove_time(t_ns),
            "frame_id": "camera",
            "data": codec.b64(png),
            "format": "png",
        }
        msgs.append((codec.TOPIC_IMAGE, image))
        msgs.append((codec.TOPIC_ANNOTATIONS, image_annotations(t_ns, header, r)))
    if int(r.step) > 0:  # a camera_bump applied before this step moved the camera
        msgs += camera_messages(views, int(r.step), t_ns)
    return msgs


def target_scene(t_ns: int, header: RunHeader) -> dict[str, Any]:
    """/world/target: the target centerline as a wide translucent band just under the rod."""
    return line_strip_scene(
        t_ns, "target", header.target_centerline, _TARGET_RGB, 0.012, z=_TARGET_Z
    )


def log_message(t_ns: int, level: str, text: str) -> dict[str, Any]:
    """A foxglove.Log message."""
    return {
        "timestamp": codec.foxglove_time(t_ns),
        "level": codec.LOG_LEVELS[level],
        "message": text,
        "name": "rodctl",
        "file": "",
        "line": 0,
    }


#: The array fields of a StepRecord (everything the writer thread reads but the frame).
_ARRAY_FIELDS = tuple(
    f.name for f in fields(StepRecord) if f.name != "image" and f.type in ("np.ndarray", np.ndarray)
)


def _snapshot(r: StepRecord) -> StepRecord:
    """A copy of `r` the loop cannot change any more: its arrays and dict copied (~10 us), the
    frame left out (it travels as its PNG future). The writer thread reads the copy later."""
    copies: dict[str, Any] = {name: np.array(getattr(r, name)) for name in _ARRAY_FIELDS}
    return replace(r, image=None, estimator_info=dict(r.estimator_info), **copies)


def _write_run_metadata(w: Writer, header: RunHeader) -> None:
    """The metadata records (`rodctl.run`, `rodctl.config`, `rodctl.provenance`) and the
    config.yaml attachment, at log_time 0."""
    w.add_metadata(
        "rodctl.run",
        {
            "method": header.method,
            "format_version": codec.FORMAT_VERSION,
            "log_time": "ns: 2000-01-01T00:00:00Z + simulated time",
        },
    )
    w.add_metadata("rodctl.config", config_metadata(header.config_yaml))
    if header.provenance:
        # Plug-ins loaded and the factory of each stage: a result is traceable to its code.
        w.add_metadata(
            "rodctl.provenance",
            {k: json.dumps(v, sort_keys=True) for k, v in header.provenance.items()},
        )
    w.add_attachment(
        create_time=0,
        log_time=0,
        name="config.yaml",
        media_type="application/yaml",
        data=header.config_yaml.encode("utf-8"),
    )


class McapSink:
    """Writes a run as run.mcap (see the module docstring for the layout).

    Args:
        path: the file to write (created or overwritten when `open` is called).
        cfg: the logging config (compression, chunk size, flush interval, PNG level).
    """

    def __init__(self, path: str | Path, cfg: LoggingConfig | None = None) -> None:
        self.path = Path(path)
        self.cfg = cfg if cfg is not None else LoggingConfig()
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._header: RunHeader | None = None
        self._prev: StepRecord | None = None
        self._steps = 0
        self._last_ns = codec.LOG_EPOCH_NS
        self._frames = codec.FrameSchedule(self.cfg.image_rate_hz)
        self._queue: deque[Future[None]] = deque()
        self._worker: ThreadPoolExecutor | None = None
        self._closed = False
        self._camera_views: CameraViews = {}

    # ---------------------------------------------------------------------------- Sink protocol
    def open(self, header: RunHeader) -> None:
        """Create the file and write the header, config and target (log_time 0)."""
        if self._writer is not None or self._closed:
            raise RuntimeError("McapSink.open called twice")
        self._header = header
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        w = Writer(
            self._file,
            chunk_size=self.cfg.mcap_chunk_size,
            compression=_COMPRESSION[self.cfg.mcap_compression],
        )
        self._writer = w
        w.start(profile="", library=LIBRARY)
        self._register_channels(w, header)
        _write_run_metadata(w, header)
        t0 = codec.LOG_EPOCH_NS
        self._add(codec.TOPIC_HEADER, t0, 0, codec.header_to_json(header))
        self._add(codec.TOPIC_TARGET_SCENE, t0, 0, target_scene(t0, header))
        self._camera_views = camera_views(header.config_yaml)
        for topic, msg in camera_messages(self._camera_views, 0, t0):
            self._add(topic, t0, 0, msg)
        self._log(t0, *codec.open_log_line(header))
        self._flush()

    def _register_channels(self, w: Writer, header: RunHeader) -> None:
        """Every channel with its schema (one schema per title) and unit metadata; dual-arm,
        `/rod/clamp` last."""
        schema_ids: dict[str, int] = {}
        for topic, schema in CHANNELS:
            name = schema["title"]
            if name not in schema_ids:
                schema_ids[name] = w.register_schema(
                    name=name,
                    encoding=SchemaEncoding.JSONSchema,
                    data=schemas.schema_bytes(schema),
                )
            units = codec.UNITS.get(topic, {})
            self._channels[topic] = w.register_channel(
                topic=topic,
                message_encoding=MessageEncoding.JSON,
                schema_id=schema_ids[name],
                metadata={f"unit.{k}": v for k, v in units.items()},
            )
        if np.asarray(header.home_pose).size == 6:  # dual-arm: registered last, only then
            sid = w.register_schema(
                name=schemas.CLAMP_STATE["title"],
                encoding=SchemaEncoding.JSONSchema,
                data=schemas.schema_bytes(schemas.CLAMP_STATE),
            )
            self._channels[codec.TOPIC_CLAMP_STATE] = w.register_channel(
                topic=codec.TOPIC_CLAMP_STATE,
                message_encoding=MessageEncoding.JSON,
                schema_id=sid,
                metadata={"unit.clamp": FIELD_UNITS["clamp"].described},
            )

    def write(self, record: StepRecord) -> None:
        """Queue one step: the three contract messages, the scene, the frame, log lines.

        The writer thread encodes the step's JSON, writes it (waiting for its PNG from the
        background encoder), compresses and flushes chunks, in step order, while the loop
        computes the next step; the loop's thread only checks the record and picks the frame.
        `write` returns once every step up to `codec.LAG` steps back is in the file: which step
        lands in which chunk is fixed by step counts alone, so the bytes never depend on timing,
        and a run killed after `write(k)` keeps what was flushed up to step k - LAG. The thread
        works on a copy of the record, so the loop may reuse its arrays. An error while encoding
        step k is raised by `write(k + LAG)` or `close`, and step k is then not in the file.
        """
        if self._writer is None or self._header is None:
            raise RuntimeError("McapSink.write called before open (or after close)")
        r = record
        if np.ndim(r.J) != 2:
            raise ValueError(f"step {r.step}: J must be (p, q), got shape {np.shape(r.J)}")
        frame: Future[bytes] | None = None
        if r.image is not None and self._frames.due(r):
            frame = codec.FRAMES.submit(r.image, self.cfg.png_compression)
            self._frames.take(r)
        if self._worker is None:
            self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rodctl-mcap")
        r = _snapshot(r)
        self._queue.append(self._worker.submit(self._commit, r, self._prev, frame))
        self._prev = r
        self._last_ns = max(self._last_ns, codec.log_time_ns(r.sim_time))
        while len(self._queue) > codec.LAG:
            self._queue.popleft().result()  # normally long done: it had a loop step's time

    def _commit(self, r: StepRecord, prev: StepRecord | None, frame: Future[bytes] | None) -> None:
        """Encode and write one step (waiting for its PNG if need be); flush every N steps.

        Runs on the writer thread, one step at a time in order. Everything is encoded before
        the first message is added, so an encoding error leaves the file as it was. Signals are
        delivered to the main thread only, so an interrupt cannot cut a chunk in half here.
        """
        assert self._writer is not None and self._header is not None
        t = codec.log_time_ns(r.sim_time)
        k = int(r.step)
        png = frame.result() if frame is not None else None
        msgs = step_messages(self._header, r, t, png, self._camera_views)
        data = [(topic, _dumps(m)) for topic, m in msgs]
        lines = codec.step_log_lines(prev, r)
        with signals_deferred():
            for topic, payload in data:
                self._writer.add_message(
                    channel_id=self._channels[topic],
                    log_time=t,
                    publish_time=t,
                    sequence=k,
                    data=payload,
                )
            for level, text in lines:
                self._log(t, level, text, sequence=k)
            self._steps += 1
            if self._steps % self.cfg.flush_every_steps == 0:
                self._flush()

    def close(self, summary: RunSummary | None, status: str) -> None:
        """Write the summary and finish the file (footer, indexes). Idempotent.

        Every finishing step is attempted even if an earlier one fails. Errors are raised for a
        completed run; for a failed or interrupted one they become warnings, so that they never
        mask the exception that ended the run.
        """
        if self._closed:
            return
        self._closed = True
        errors: list[BaseException] = []
        w, f = self._writer, self._file
        if w is not None:
            while self._queue:  # the steps the writer thread has not finished
                try:
                    self._queue.popleft().result()
                except Exception as exc:  # noqa: BLE001 - collected, see docstring
                    errors.append(exc)
            if self._worker is not None:
                self._worker.shutdown(wait=True)
            self._writer = None
            t = self._last_ns
            try:
                self._add_with(
                    w, codec.TOPIC_SUMMARY, t, self._steps, codec.summary_to_json(summary, status)
                )
                level, text = codec.close_log_line(summary, status, self._steps)
                self._add_with(w, codec.TOPIC_LOG, t, self._steps, self._log_msg(t, level, text))
                w.add_metadata("rodctl.end", {"status": status, "steps": str(self._steps)})
            except Exception as exc:  # noqa: BLE001 - collected, see docstring
                errors.append(exc)
            try:
                with signals_deferred():
                    w.finish()
            except Exception as exc:  # noqa: BLE001
                errors.append(exc)
        if f is not None:
            try:
                f.flush()
                os.fsync(f.fileno())
            except Exception as exc:  # noqa: BLE001
                errors.append(exc)
            finally:
                f.close()
        raise_or_warn(errors, status, f"{self.path}: closing the MCAP log failed")

    # -------------------------------------------------------------------------------- helpers
    def _add(self, topic: str, t_ns: int, seq: int, msg: dict[str, Any]) -> None:
        assert self._writer is not None
        self._add_with(self._writer, topic, t_ns, seq, msg)

    def _add_with(self, w: Writer, topic: str, t_ns: int, seq: int, msg: dict[str, Any]) -> None:
        w.add_message(
            channel_id=self._channels[topic],
            log_time=t_ns,
            publish_time=t_ns,
            sequence=seq,
            data=_dumps(msg),
        )

    _log_msg = staticmethod(log_message)

    def _log(self, t_ns: int, level: str, text: str, sequence: int = 0) -> None:
        self._add(codec.TOPIC_LOG, t_ns, sequence, self._log_msg(t_ns, level, text))

    def _flush(self) -> None:
        """Close the open chunk and push the bytes to the OS (kill-safe up to here)."""
        assert self._writer is not None and self._file is not None
        # mcap 1.6 (pinned) has no public "end chunk now"; its private finaliser is the one the
        # writer itself calls when a chunk is full. Without it chunks still close at
        # mcap_chunk_size, only less often.
        end_chunk = getattr(self._writer, "_Writer__finalize_chunk", None)
        if end_chunk is not None:
            end_chunk()
        self._file.flush()


# ---------------------------------------------------------------------------------- reading
_Raw = tuple[str, int, int, bytes]  # topic, sequence, log_time, data

#: Largest inflation a chunk may claim: uncompressed <= MAX_CHUNK_RATIO x compressed + 1 MiB.
#: rodctl's chunks inflate about 4.5x (JSON and base64 PNG frames); zeros inflate 30,000x.
MAX_CHUNK_RATIO = 1000
_MIB = 1 << 20


def chunk_ceiling(config: dict[str, str] | None) -> int:
    """The most uncompressed bytes a chunk of a run may hold, from its `rodctl.config` metadata
    (the logging defaults and a 640x480 camera when it has none): a chunk closes once it passes
    `logging.mcap_chunk_size`, so it holds at most that plus one message, the largest of which is
    a camera frame (an RGB PNG barely larger than the raw pixels, base64 in JSON)."""

    def get(key: str, default: int) -> int:
        try:
            value = json.loads((config or {}).get(key, "null"))
        except (ValueError, RecursionError):
            value = None
        ok = isinstance(value, int) and not isinstance(value, bool) and 0 < value <= 1 << 30
        return value if ok else default

    chunk = get("logging.mcap_chunk_size", LoggingConfig().mcap_chunk_size)
    width, height = get("camera.width", 640), get("camera.height", 480)
    frame = (width * height * 3 * 101 // 100 + height + 4096) * 4 // 3
    return chunk + frame + _MIB


def check_sizes(f: IO[bytes], path: Path, size: int) -> None:
    """Refuse a file whose records or chunks are bigger than the run can have written, before
    anything is decompressed (a zstd or lz4 "bomb" inflating to gigabytes of zeros).

    Every record must fit in the file; each chunk's declared uncompressed size must stay under
    `chunk_ceiling` (from the run's own metadata, which precedes its chunks) and under
    `MAX_CHUNK_RATIO` times its compressed size; a zstd frame must declare the same size as its
    chunk, and an lz4 chunk is inflated at most one byte past its declared size to check it.
    Damage that stops the scan is left to the reader, which reports it.

    Raises:
        UserError: naming the file, the chunk's offset and the sizes.
    """
    ceiling = chunk_ceiling(None)
    stream = StreamReader(f, emit_chunks=True, record_size_limit=size)
    records = stream.records
    chunks = 0
    while True:
        try:
            rec = next(records)
        except StopIteration:
            break
        except Exception:  # noqa: BLE001 - damage: the reader says what and where
            break
        if isinstance(rec, Metadata) and rec.name == "rodctl.config":
            ceiling = chunk_ceiling(dict(rec.metadata))
        if isinstance(rec, Attachment) and len(rec.data) > ceiling:
            raise UserError(
                f"{path}: attachment {rec.name!r} holds {len(rec.data)} bytes, more than a "
                f"rodctl run writes ({ceiling}); refused"
            )
        if not isinstance(rec, Chunk):
            continue
        chunks += 1
        _check_chunk(rec, f"{path}: chunk {chunks}", ceiling)


def _check_chunk(rec: Chunk, where: str, ceiling: int) -> None:
    """One chunk of `check_sizes`: its declared uncompressed size against `ceiling` and its
    compressed size, and against what its zstd frame declares or its lz4 data inflates to."""
    import lz4.frame
    import zstandard

    declared, compressed = rec.uncompressed_size, len(rec.data)
    limit = min(ceiling, MAX_CHUNK_RATIO * compressed + _MIB)
    if declared > limit:
        raise UserError(
            f"{where} declares {declared} bytes uncompressed from {compressed}, more than "
            f"this run can have written ({limit}); refused without decompressing it"
        )
    if rec.compression == "zstd":
        framed = zstandard.frame_content_size(rec.data[:18]) if compressed >= 4 else -1
        if framed not in (-1, declared):
            raise UserError(
                f"{where} declares {declared} bytes but its zstd frame {framed}; refused "
                "without decompressing it"
            )
    elif rec.compression == "lz4":
        out = 0
        data = rec.data
        try:
            while data and out <= declared:
                dec = lz4.frame.LZ4FrameDecompressor()
                out += len(dec.decompress(data, max_length=declared + 1 - out))
                data = dec.unused_data if dec.eof else b""
        except RuntimeError as exc:
            raise UserError(f"{where}: damaged lz4 data ({exc})") from None
        if out > declared:
            raise UserError(f"{where} inflates past the {declared} bytes it declares; refused")


def _read_indexed(f: IO[bytes]) -> tuple[list[_Raw], dict[str, dict[str, str]]]:
    """Messages (file order) and metadata of a finished file, via its summary and indexes."""
    reader = make_reader(f, validate_crcs=True)
    summary = reader.get_summary()
    if summary is None:
        raise McapError("no summary section")
    raw = [
        (ch.topic, m.sequence, m.log_time, m.data)
        for _, ch, m in reader.iter_messages(log_time_order=False)
    ]
    stats = summary.statistics
    if stats is not None and stats.message_count != len(raw):
        # A chunk written without its index: the indexes cannot be trusted to be complete.
        raise McapError(
            f"the indexes list {len(raw)} messages, the statistics {stats.message_count}"
        )
    meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return raw, meta


def _read_stream(f: IO[bytes]) -> tuple[list[_Raw], dict[str, dict[str, str]], str]:
    """Every complete record of a file front to back, stopping at the first damaged one."""
    raw: list[_Raw] = []
    meta: dict[str, dict[str, str]] = {}
    topics: dict[int, str] = {}
    error = ""
    records: Iterator[Any] = StreamReader(f, validate_crcs=True).records
    while True:
        try:
            rec = next(records)
        except StopIteration:
            break
        except Exception as exc:  # noqa: BLE001 - any damage ends the readable part
            error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
            break
        if isinstance(rec, Channel):
            topics[rec.id] = rec.topic
        elif isinstance(rec, Message):
            if rec.channel_id in topics:
                raw.append((topics[rec.channel_id], rec.sequence, rec.log_time, rec.data))
        elif isinstance(rec, Metadata):
            meta[rec.name] = dict(rec.metadata)
    return raw, meta, error


def _json(path: Path, topic: str, data: bytes) -> dict[str, Any]:
    try:
        msg = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: malformed JSON message on {topic}: {exc}") from None
    except RecursionError:  # rodctl's messages nest 6 deep; the parser stops near 1000
        raise UserError(
            f"{path}: JSON message on {topic} nested too deeply to be a rodctl message; refused"
        ) from None
    if not isinstance(msg, dict):
        raise UserError(f"{path}: message on {topic} is not a JSON object")
    return msg


def read_mcap(path: str | Path, *, recover: bool = False, images: bool = True) -> codec.ReadRun:
    """Read a rodctl run.mcap back into its header, step records and summary.

    Args:
        path: the MCAP file.
        recover: accept a file whose writer never finished (killed run, power loss) and return
            its complete steps with `complete=False` and a warning. Without it such a file raises.
        images: decode the logged camera frames into `StepRecord.image` (PNG decoding costs a
            few ms per frame); False leaves every `image` None.

    Returns:
        A `ReadRun` (records in step order).

    Raises:
        UserError: the file is missing, is not MCAP, is not a rodctl run log, is damaged, or is
            incomplete and `recover` is False. The message names the file and the problem.
    """
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if not path.is_file():
        raise UserError(f"{path}: not a file")
    notes: list[str] = []
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
        if head != MAGIC:
            raise UserError(
                f"{path}: not an MCAP file (it does not start with the MCAP magic "
                f"bytes); expected a run.mcap written by rodctl"
            )
        size = f.seek(0, os.SEEK_END)
        f.seek(0)
        check_sizes(f, path, size)
        f.seek(max(0, size - len(MAGIC)))
        complete = size >= 2 * len(MAGIC) and f.read(len(MAGIC)) == MAGIC
        reason = "it has no footer"
        if complete:
            f.seek(0)
            try:
                raw, meta = _read_indexed(f)
            except Exception as exc:  # noqa: BLE001 - any damage: fall back to streaming
                complete = False
                reason = f"its summary or indexes are unreadable ({type(exc).__name__}: {exc})"
        if not complete:
            f.seek(0)
            raw, meta, error = _read_stream(f)
            if error:
                reason += f"; reading stopped at a damaged record ({error})"
    run = _assemble(path, raw, meta, images, notes)
    if not complete:
        what = (
            f"{path}: incomplete MCAP file: its writer never finished (crash, kill or power "
            f"loss): {reason}. {len(run.records)} complete steps are readable"
        )
        if not recover:
            raise UserError(what + "; `rodctl replay --recover` or `export --recover` reads them.")
        notes.insert(0, what + ".")
    run.complete = complete
    return run


#: The three per-step topics whose messages make one StepRecord, in `record_from_messages` order.
_STEP_TOPICS = (codec.TOPIC_ROD_STATE, codec.TOPIC_CAMERA_CENTERLINE, codec.TOPIC_CONTROL)


@dataclass
class _Messages:
    """A log's messages sorted by step (`_sort_messages`): what `_records` joins."""

    per_step: dict[int, dict[str, dict[str, Any]]] = field(default_factory=dict)
    order: list[int] = field(default_factory=list)
    frames: dict[int, bytes] = field(default_factory=dict)
    clamps: dict[int, np.ndarray] = field(default_factory=dict)
    summary: dict[str, Any] | None = None


def _assemble(
    path: Path, raw: list[_Raw], meta: dict[str, dict[str, str]], images: bool, notes: list[str]
) -> codec.ReadRun:
    header = _read_header(path, raw, meta)
    msgs = _sort_messages(path, raw, images, notes)
    records = _records(path, msgs, notes)
    summary = msgs.summary
    status = meta.get("rodctl.end", {}).get("status")
    if summary is not None:
        closing = summary.pop("closing_status", None)
        status = status or closing
        if len(summary) == 0:
            summary = None
    return codec.ReadRun(
        path=path,
        header=header,
        records=records,
        summary=summary,
        status=status,
        complete=True,
        warnings=notes,
    )


def run_id_of(path: Path) -> str:
    """The run id a log file stands for (it is not in the log, `codec.header_to_json`): the
    run folder's name for a `run.mcap`, else the file's own stem (a log copied out of its
    folder is not its new folder's run)."""
    path = path.absolute()  # not resolved: a run.mcap linked into a blob store is its folder's
    return path.parent.name if path.name == "run.mcap" else path.stem


def _read_header(path: Path, raw: list[_Raw], meta: dict[str, dict[str, str]]) -> RunHeader:
    """The run header of /run/header, its embedded config checked as config files are."""
    header_msgs = [d for topic, _, _, d in raw if topic == codec.TOPIC_HEADER]
    if not header_msgs:
        raise UserError(
            f"{path}: not a rodctl run log (no {codec.TOPIC_HEADER} message)"
            if raw or meta
            else f"{path}: the MCAP file holds no readable messages"
        )
    try:
        header = codec.header_from_json(
            _json(path, codec.TOPIC_HEADER, header_msgs[0]), run_id=run_id_of(path)
        )
    except codec.FormatVersionError as exc:
        raise UserError(f"{path}: {exc}") from None
    except (KeyError, TypeError, ValueError, RecursionError) as exc:
        raise UserError(f"{path}: malformed run header: {exc!r}") from None
    from rodctl.config.loading import safe_load as strict_load

    try:  # replay and --verify parse it: the rules of config files (nesting, size, aliases)
        strict_load(header.config_yaml)
    except (yaml.YAMLError, RecursionError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else "nested too deeply"
        raise UserError(
            f"{path}: the config embedded in {codec.TOPIC_HEADER} is unusable: {why}"
        ) from None
    return header


def _sort_messages(path: Path, raw: list[_Raw], images: bool, notes: list[str]) -> _Messages:
    """The per-step messages by step (a duplicate noted and ignored), the x0 end's poses
    (dual-arm), the frames (when `images`) and the summary."""
    out = _Messages()
    for topic, seq, _, data in raw:
        if topic == codec.TOPIC_CLAMP_STATE:  # dual-arm: the x0 end's pose
            msg = codec.restore_nonfinite(_json(path, topic, data))
            try:
                out.clamps[int(msg["step"])] = codec.decode_vec(msg["clamp"], 3)
            except (KeyError, TypeError, ValueError) as exc:
                raise UserError(f"{path}: malformed {topic} message: {exc!r}") from None
        elif topic in _STEP_TOPICS:
            msg = _json(path, topic, data)
            step = msg.get("step")
            if not isinstance(step, int):
                raise UserError(f"{path}: message on {topic} without an integer `step`")
            slot = out.per_step.get(step)
            if slot is None:
                slot = out.per_step[step] = {}
                out.order.append(step)
            if topic in slot:
                notes.append(f"step {step}: duplicate {topic} message ignored")
                continue
            slot[topic] = msg
        elif topic == codec.TOPIC_IMAGE and images:
            out.frames.setdefault(seq, data)
        elif topic == codec.TOPIC_SUMMARY:
            out.summary = _json(path, topic, data)
    return out


def _records(path: Path, msgs: _Messages, notes: list[str]) -> list[StepRecord]:
    """One StepRecord per step that has all three per-step messages, in step order (a step
    missing one is noted and skipped; an unreadable frame noted and left out)."""
    records: list[StepRecord] = []
    for step in sorted(msgs.order):
        slot = msgs.per_step[step]
        missing = [t for t in _STEP_TOPICS if t not in slot]
        if missing:
            notes.append(f"step {step}: skipped, missing {', '.join(missing)}")
            continue
        image = None
        if step in msgs.frames:
            try:
                image = codec.decode_png(
                    _b64decode(_json(path, codec.TOPIC_IMAGE, msgs.frames[step])["data"])
                )
            except (KeyError, ValueError) as exc:
                notes.append(f"step {step}: camera frame unreadable ({exc}); left out")
        try:
            rod, cam, ctl = (slot[t] for t in _STEP_TOPICS)
            records.append(codec.record_from_messages(rod, cam, ctl, image))
        except (KeyError, TypeError, ValueError) as exc:
            raise UserError(f"{path}: malformed step {step}: {exc!r}") from None
        records[-1].clamp = msgs.clamps.get(step)
    return records


def _b64decode(text: Any) -> bytes:
    import base64
    import binascii

    if not isinstance(text, str):
        raise ValueError("image data is not base64 text")
    try:
        return base64.b64decode(text, validate=True)
    except binascii.Error as exc:
        raise ValueError(f"bad base64: {exc}") from None
