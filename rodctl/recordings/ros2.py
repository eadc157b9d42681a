"""`rodctl export RUN --ros2 BAG`: a run written as a ROS 2 bag (CDR), through `rosbags`.

No ROS 2 runtime is needed: `rosbags` (pure Python, pinned in pyproject.toml) serialises the
messages with its built-in ROS 2 Humble type definitions and writes either storage (sqlite3 or
MCAP). Topics (docs/recordings.md, "Export to a ROS 2 bag"):
- `/camera/image_raw` sensor_msgs/msg/Image (rgb8), every logged camera frame;
- `/camera/camera_info` sensor_msgs/msg/CameraInfo beside each frame: K from the run's camera
  config, no distortion (plumb_bob, D = 0; rodctl's camera is a pinhole);
- `/gripper/pose` geometry_msgs/msg/PoseStamped, the gripper pose of every step (x, y, z = 0,
  theta as a rotation about z), frame `world`;
- `/end_effector_1/pose` geometry_msgs/msg/PoseStamped, for a run with two end effectors
  (q = 6) only: end effector 1's pose, the run's clamp pose plus the sum of `/control.u[3:6]`
  (exact for an imported recording, whose u is the change of the poses);
- `/rod/centerline` visualization_msgs/msg/MarkerArray, one LINE_STRIP of the rod's centerline
  (`/rod/state.centerline`, world metres) per step.
Message times are the MCAP log times (2000-01-01 + simulated time), so a bag of a run is the
same bytes each time (sqlite3 aside, whose pages are the database's business).
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Sequence
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rodctl.errors import (
    RunFailed,
    UserError,
    describe_os_error,
    make_out_folder,
    out_error,
    out_path,
)

STORAGES = ("sqlite3", "mcap")
TOPIC_IMAGE = "/camera/image_raw"
TOPIC_INFO = "/camera/camera_info"
TOPIC_POSE = "/gripper/pose"
TOPIC_POSE_1 = "/end_effector_1/pose"
TOPIC_CENTERLINE = "/rod/centerline"


def _intrinsics(config_yaml: str, size: tuple[int, int]) -> np.ndarray:
    """K (3, 3) of the run's camera (its config's camera section; defaults where absent)."""
    from rodctl.config.camera import CameraConfig

    try:
        cam = (yaml.safe_load(config_yaml) or {}).get("camera") or {}
        cfg = CameraConfig.model_validate(cam)
    except Exception:  # noqa: BLE001 - a foreign config: rodctl's default camera
        cfg = CameraConfig()
    w, h = size
    cx = (w - 1) / 2.0 if cfg.cx is None else float(cfg.cx)
    cy = (h - 1) / 2.0 if cfg.cy is None else float(cfg.cy)
    return np.array([[cfg.fx, 0.0, cx], [0.0, cfg.fy, cy], [0.0, 0.0, 1.0]])


def _header(ts: Any, t_ns: int, frame: str) -> Any:
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](
        sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000
    )
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def pose_stamped(ts: Any, t_ns: int, pose: np.ndarray, frame: str = "world") -> Any:
    """geometry_msgs/msg/PoseStamped of a planar pose [x, y, theta] (z = 0, yaw = theta)."""
    T = ts.types
    x, y, th = (float(v) for v in pose)
    q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(th / 2.0), w=math.cos(th / 2.0))
    p = T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0)
    return T["geometry_msgs/msg/PoseStamped"](
        _header(ts, t_ns, frame), T["geometry_msgs/msg/Pose"](position=p, orientation=q)
    )


def line_marker(ts: Any, t_ns: int, line: np.ndarray, frame: str = "world") -> Any:
    """visualization_msgs/msg/Marker: a LINE_STRIP through the (N, 2) points (z = 0)."""
    T = ts.types
    Point, Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    return T["visualization_msgs/msg/Marker"](
        header=_header(ts, t_ns, frame),
        ns="rod",
        id=0,
        type=4,  # LINE_STRIP
        action=0,
        pose=T["geometry_msgs/msg/Pose"](
            position=Point(x=0.0, y=0.0, z=0.0), orientation=Quat(0.0, 0.0, 0.0, 1.0)
        ),
        scale=T["geometry_msgs/msg/Vector3"](x=0.004, y=0.0, z=0.0),
        color=T["std_msgs/msg/ColorRGBA"](r=0.85, g=0.2, b=0.1, a=1.0),
        lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
        frame_locked=False,
        points=[Point(x=float(p[0]), y=float(p[1]), z=0.0) for p in line],
        colors=[],
        texture_resource="",
        texture=T["sensor_msgs/msg/CompressedImage"](
            header=_header(ts, t_ns, ""), format="", data=np.zeros(0, dtype=np.uint8)
        ),
        uv_coordinates=[],
        text="",
        mesh_resource="",
        mesh_file=T["visualization_msgs/msg/MeshFile"](
            filename="", data=np.zeros(0, dtype=np.uint8)
        ),
        mesh_use_embedded_materials=False,
    )


def _image_msg(ts: Any, t_ns: int, img: np.ndarray) -> Any:
    """A sensor_msgs/Image (rgb8) of the frame `img` (H, W, 3) at `t_ns`."""
    h, w = img.shape[:2]
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, t_ns, "camera"),
        height=h,
        width=w,
        encoding="rgb8",
        is_bigendian=0,
        step=3 * w,
        data=img.reshape(-1),
    )


def _camera_info_msg(ts: Any, t_ns: int, h: int, w: int, K: np.ndarray) -> Any:
    """A sensor_msgs/CameraInfo with the pinhole intrinsics `K` and no distortion."""
    T = ts.types
    P = np.hstack([K, np.zeros((3, 1))])
    return T["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, t_ns, "camera"),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=K.reshape(-1),
        r=np.eye(3).reshape(-1),
        p=P.reshape(-1),
        binning_x=0,
        binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


def _export_connections(writer: Any, ts: Any, two: bool) -> dict[str, Any]:
    """The bag's connections: image, camera info, pose(s) and centerline."""
    conns = {
        TOPIC_IMAGE: writer.add_connection(TOPIC_IMAGE, "sensor_msgs/msg/Image", typestore=ts),
        TOPIC_INFO: writer.add_connection(TOPIC_INFO, "sensor_msgs/msg/CameraInfo", typestore=ts),
        TOPIC_POSE: writer.add_connection(
            TOPIC_POSE, "geometry_msgs/msg/PoseStamped", typestore=ts
        ),
        TOPIC_CENTERLINE: writer.add_connection(
            TOPIC_CENTERLINE, "visualization_msgs/msg/MarkerArray", typestore=ts
        ),
    }
    if two:
        conns[TOPIC_POSE_1] = writer.add_connection(
            TOPIC_POSE_1, "geometry_msgs/msg/PoseStamped", typestore=ts
        )
    return conns


def _check_bag_folder(out: Path) -> None:
    """Make the bag folder's parents and check that the folder can be made.

    The writer makes the bag folder itself (and says nothing of why it could not): make and
    remove it once here, so that a wrong path is exit 2 and a refusing disk exit 1, as for
    every other command's output folder.
    """
    make_out_folder(out.parent, "--ros2")
    try:
        out.mkdir()
        out.rmdir()
    except OSError as exc:
        raise out_error("--ros2", out, "cannot create the bag folder", exc) from None


def export_ros2(
    run_path: str | Path, bag: str | Path, storage: str = "mcap", *, recover: bool = False
) -> dict[str, int]:
    """Write the run at `run_path` as the ROS 2 bag folder `bag`; return messages per topic.
    `recover`: a log whose writer never finished gives its complete steps (`read_run`).

    Raises:
        UserError: not a run, a bag folder that exists already, an unknown storage.
        RunFailed: interrupted (SIGINT) or a write error; the unfinished bag is removed.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.errors import WriterError
    from rosbags.typesys import Stores, get_typestore

    from rodctl.replay import read_run

    if storage not in STORAGES:
        raise UserError(f"--storage {storage}: choose one of {', '.join(STORAGES)}")
    out = out_path(bag, "--ros2")
    if out.exists():
        raise UserError(f"--ros2 {out}: exists already; a bag is written to a new folder")
    run = read_run(run_path, images=True, recover=recover)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    width, height = run.header.image_size
    K = _intrinsics(run.header.config_yaml, (width, height))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    counts = {TOPIC_IMAGE: 0, TOPIC_INFO: 0, TOPIC_POSE: 0, TOPIC_CENTERLINE: 0}

    _check_bag_folder(out)
    try:
        writer = Writer(out, version=8, storage_plugin=plugin)
        writer.open()  # makes the folder: from here on it is this export's own
    except WriterError as exc:
        raise UserError(f"{out}: {exc}") from None
    try:
        _write_bag(writer, run, ts, K, counts)
        writer.close()
    except BaseException as exc:
        # A bag cut short (Ctrl-C, a full disk) is not one a reader opens, and it would block
        # the next export to the same folder: it goes, and the message says so.
        with suppress(Exception):
            writer.abort()
        shutil.rmtree(out, ignore_errors=True)
        removed = f"the unfinished bag {out} was removed"
        if isinstance(exc, KeyboardInterrupt):
            raise RunFailed(f"interrupted by {str(exc) or 'SIGINT'}: {removed}") from None
        if isinstance(exc, OSError):
            raise RunFailed(f"{describe_os_error(exc)}; {removed}") from None
        raise
    return counts


def _write_bag(writer: Any, run: Any, ts: Any, K: np.ndarray, counts: dict[str, int]) -> None:
    """Every record of `run` into the opened bag `writer` (`export_ros2` closes it), counted
    by topic."""
    from rodctl.logs.codec import log_time_ns

    T = ts.types
    two = bool(run.records) and all(np.size(r.u) == 6 for r in run.records)
    conns = _export_connections(writer, ts, two)
    if two:
        counts[TOPIC_POSE_1] = 0
    end1 = np.asarray(run.header.clamp_pose, dtype=float)[:3].copy()

    def put(topic: str, t_ns: int, msg: Any) -> None:
        writer.write(conns[topic], t_ns, ts.serialize_cdr(msg, conns[topic].msgtype))
        counts[topic] += 1

    for r in run.records:
        t_ns = int(log_time_ns(r.sim_time))
        put(TOPIC_POSE, t_ns, pose_stamped(ts, t_ns, np.asarray(r.gripper)[:3]))
        if two:  # end effector 1: its first pose plus the logged changes (u[3:6])
            end1 = end1 + np.asarray(r.u, dtype=float)[3:6]
            put(TOPIC_POSE_1, t_ns, pose_stamped(ts, t_ns, end1))
        marker = line_marker(ts, t_ns, np.asarray(r.centerline, dtype=float))
        put(TOPIC_CENTERLINE, t_ns, T["visualization_msgs/msg/MarkerArray"](markers=[marker]))
        if r.image is None:
            continue
        img = np.ascontiguousarray(r.image, dtype=np.uint8)
        h, w = img.shape[:2]
        put(TOPIC_IMAGE, t_ns, _image_msg(ts, t_ns, img))
        put(TOPIC_INFO, t_ns, _camera_info_msg(ts, t_ns, h, w, K))


def _bag_error(path: str | Path, exc: Exception) -> str:
    """rosbags' reason a folder is not a bag, in one line: no metadata.yaml said plainly, and
    a multi-line YAML dump of a bad metadata.yaml cut to its first line."""
    folder = Path(path)
    if folder.is_dir() and not (folder / "metadata.yaml").is_file():
        return "no metadata.yaml in the folder: a ROS 2 bag folder has one beside its storage file"
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]


# --- reading tracked points and poses from a bag ------------------------------------------

#: Message types a tracked-points topic may have: the (N, 2) x, y of each message.
POINTS_TYPES = (
    "visualization_msgs/msg/MarkerArray",
    "visualization_msgs/msg/Marker",
    "nav_msgs/msg/Path",
    "geometry_msgs/msg/PoseArray",
    "sensor_msgs/msg/PointCloud2",
)
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
TF_TYPE = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class PoseSource:
    """Where an end effector's pose is read: a PoseStamped topic, or (`frame` given) the tf
    tree of a tf topic (with its static topic): the pose of child frame `frame` composed up
    to the frame `world` (None: the tree's root; `rodctl.recordings.tf`)."""

    topic: str
    frame: str | None = None
    world: str | None = None

    @property
    def label(self) -> str:
        return f"{self.topic} (child frame {self.frame})" if self.frame else self.topic


def pose_sources(
    pose_topics: Sequence[str] = (),
    tf_frames: Sequence[str] = (),
    tf_topic: str = "/tf",
    tf_world: str | None = None,
) -> list[PoseSource]:
    """The end effectors in order: the PoseStamped topics first, then the tf child frames."""
    out = [PoseSource(t) for t in pose_topics]
    world = tf_world.lstrip("/") if tf_world else None
    out += [PoseSource(tf_topic, f.lstrip("/"), world) for f in tf_frames]
    return out


#: PointCloud2 PointField datatypes (sensor_msgs/msg/PointField): the x, y read are FLOAT32 or
#: FLOAT64; the others are named in the refusal.
_PC2_NAMES = {1: "INT8", 2: "UINT8", 3: "INT16", 4: "UINT16", 5: "INT32", 6: "UINT32",
              7: "FLOAT32", 8: "FLOAT64"}  # fmt: skip
_PC2_FORMATS = {7: "f4", 8: "f8"}


def cloud_xy(msg: Any, where: str) -> np.ndarray:
    """(N, 2) x, y of a sensor_msgs/msg/PointCloud2, decoded by its own layout: each point is
    `point_step` bytes with the fields at their offsets, `row_step` bytes a row (padding after
    `width` points skipped), `height` rows, the byte order `is_bigendian`. Points are taken in
    storage order (row-major).

    Raises:
        UserError: no x or y field, one that is not FLOAT32/FLOAT64 or has count != 1, a field
            beyond point_step, a row_step shorter than width * point_step, data shorter than
            height * row_step; `where` (topic and frame) starts the message.
    """
    fields = {f.name: f for f in msg.fields}
    have = ", ".join(f"{f.name}:{_PC2_NAMES.get(int(f.datatype), f.datatype)}" for f in msg.fields)
    step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    row_step = int(msg.row_step)
    order = ">" if msg.is_bigendian else "<"
    formats, offsets = [], []
    for name in ("x", "y"):
        f = fields.get(name)
        if f is None:
            raise UserError(
                f"{where}: unsupported PointCloud2 layout: no field {name!r} (fields: "
                f"{have or 'none'}); x and y FLOAT32 or FLOAT64 fields are read"
            )
        dt = int(f.datatype)
        if dt not in _PC2_FORMATS or int(f.count) != 1:
            raise UserError(
                f"{where}: unsupported PointCloud2 layout: field {name!r} is "
                f"{_PC2_NAMES.get(dt, dt)} x {int(f.count)}; one FLOAT32 or FLOAT64 is read"
            )
        size = 4 if dt == 7 else 8
        if int(f.offset) + size > step:
            raise UserError(
                f"{where}: unsupported PointCloud2 layout: field {name!r} at offset "
                f"{int(f.offset)} does not fit in point_step {step}"
            )
        formats.append(order + _PC2_FORMATS[dt])
        offsets.append(int(f.offset))
    if row_step < width * step:
        raise UserError(
            f"{where}: unsupported PointCloud2 layout: row_step {row_step} < width {width} x "
            f"point_step {step}"
        )
    data = np.asarray(msg.data, dtype=np.uint8)
    if data.size < height * row_step:
        raise UserError(
            f"{where}: PointCloud2 data has {data.size} bytes, height {height} x row_step "
            f"{row_step} = {height * row_step} expected"
        )
    dtype = np.dtype({"names": ["x", "y"], "formats": formats, "offsets": offsets,
                      "itemsize": step})  # fmt: skip
    rows = data[: height * row_step].reshape(height, row_step)[:, : width * step]
    pts = np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dtype)
    return np.column_stack([pts["x"], pts["y"]]).astype(float).reshape(-1, 2)


def _stamp_ns(msg: Any, log_ns: int) -> int:
    """The message's header stamp (ns), or its log time when it has none (or a zero one)."""
    h = getattr(msg, "header", None)
    if h is None and getattr(msg, "markers", None):
        h = msg.markers[0].header
    if h is None:
        return int(log_ns)
    t = int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
    return t if t > 0 else int(log_ns)


def _xy(msg: Any, msgtype: str, where: str = "") -> np.ndarray:
    if msgtype.endswith("PointCloud2"):
        return cloud_xy(msg, where)
    if msgtype.endswith("MarkerArray"):
        pts = msg.markers[0].points if msg.markers else []
        return np.array([[p.x, p.y] for p in pts], dtype=float).reshape(-1, 2)
    if msgtype.endswith("/Marker"):
        return np.array([[p.x, p.y] for p in msg.points], dtype=float).reshape(-1, 2)
    if msgtype.endswith("Path"):
        return np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses]).reshape(-1, 2)
    return np.array([[p.position.x, p.position.y] for p in msg.poses], dtype=float).reshape(-1, 2)


def _yaw(o: Any) -> float:
    """The yaw of a quaternion, scale-free: atan2(2(wz + xy), w^2 + x^2 - y^2 - z^2)."""
    w, x, y, z = float(o.w), float(o.x), float(o.y), float(o.z)
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def check_pose(position: Any, o: Any, where: str) -> None:
    """Refuse a pose with a non-finite position or quaternion, or a zero quaternion."""
    q = [float(o.x), float(o.y), float(o.z), float(o.w)]
    p = [float(position.x), float(position.y), float(position.z)]
    if not all(math.isfinite(v) for v in p + q):
        raise UserError(
            f"{where}: the pose has non-finite values (position {_plain(np.array(p))}, "
            f"orientation {_plain(np.array(q))})"
        )
    if math.sqrt(sum(v * v for v in q)) < 1e-9:
        raise UserError(f"{where}: the orientation quaternion is zero (no rotation is defined)")


def _bracket(
    frame_t: np.ndarray, pt: np.ndarray, label: str, tolerance: float, what: str = "poses"
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For the frame times inside the sorted sample times `pt`: the samples' indices before
    and after each (lo, hi), its fraction between them (w) and the mask of those frames.

    Raises:
        UserError: no frame inside the span, or two samples around a frame further apart than
            `tolerance` seconds (`label` and the frame's time are named).
    """
    inside = (frame_t >= pt[0]) & (frame_t <= pt[-1])
    if not inside.any():
        raise UserError(
            f"{label}: {what} (t {pt[0]:.6f}..{pt[-1]:.6f} s) and frames (t {frame_t[0]:.6f}.."
            f"{frame_t[-1]:.6f} s) do not overlap"
        )
    ft = frame_t[inside]
    idx = np.searchsorted(pt, ft, side="left")  # pt[idx - 1] < ft <= pt[idx]
    exact = pt[np.minimum(idx, len(pt) - 1)] == ft
    hi = np.where(exact, idx, np.clip(idx, 1, len(pt) - 1))
    lo = np.where(exact, idx, hi - 1)
    gap = np.where(exact, 0.0, pt[hi] - pt[lo])
    if (gap > tolerance).any():
        k = int(np.argmax(gap > tolerance))
        raise UserError(
            f"{label}: no {what[:-1]} within {tolerance:g} s of the frame at t = {ft[k]:.6f} s "
            f"({what} at {pt[lo[k]]:.6f} and {pt[hi[k]]:.6f} s); raise --tolerance or fill the gap"
        )
    w = np.where(exact, 1.0, (ft - pt[lo]) / np.where(gap > 0, gap, 1.0))
    return lo, hi, w, inside


def sync_poses(
    frame_t: np.ndarray, pose_t: np.ndarray, poses: np.ndarray, topic: str, tolerance: float
) -> tuple[np.ndarray, np.ndarray]:
    """Poses (K, 3) interpolated at the frame times inside the poses' time span, and the mask
    of those frames (T,). Linear in x, y and the unwrapped angle.

    Raises:
        UserError: no frame inside the span (they do not overlap), or two poses around a frame
            further apart than `tolerance` seconds (the frame's time is named).
    """
    order = np.argsort(pose_t, kind="stable")
    pt, pv = pose_t[order], poses[order].copy()
    pv[:, 2] = np.unwrap(pv[:, 2])
    lo, hi, w, inside = _bracket(frame_t, pt, topic, tolerance)
    w = w[:, None]
    return (1.0 - w) * pv[lo] + w * pv[hi], inside


def _bag_messages(
    path: Path,
    need: list[tuple[str, tuple[str, ...]]],
    optional: Sequence[tuple[str, tuple[str, ...]]] = (),
) -> Any:
    """Yield (topic, msgtype, log time ns, message) of the `need`ed topics of the bag at
    `path`, in log-time order, after checking each topic exists with an allowed type; the
    `optional` topics too where the bag has them.

    Raises:
        UserError: not a bag, a topic missing (the bag's topics are listed) or of another type.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags' errors for a missing/foreign folder
        raise UserError(f"{path}: not a readable ROS 2 bag ({_bag_error(path, exc)})") from None
    try:
        types = {c.topic: c.msgtype for c in reader.connections}
        listing = ", ".join(f"{t} ({m})" for t, m in sorted(types.items())) or "none"
        need = list(need) + [(t, a) for t, a in optional if t in types]
        for topic, allowed in need:
            if topic not in types:
                raise UserError(f"{path}: no topic {topic}; the bag has: {listing}")
            if types[topic] not in allowed:
                raise UserError(
                    f"{path}: topic {topic} is {types[topic]}, expected {' or '.join(allowed)}"
                )
        topics = {t for t, _ in need}
        wanted = [c for c in reader.connections if c.topic in topics]
        for conn, log_ns, raw in reader.messages(connections=wanted):
            yield conn.topic, conn.msgtype, log_ns, reader.deserialize(raw, conn.msgtype)
    finally:
        reader.close()


class RowSeries:
    """A pose series [(t_ns, [x, y, theta])] (a PoseStamped topic, a CSV of poses), evaluated
    at frame times by `sync_poses`."""

    def __init__(self, label: str, rows: list[tuple[int, list[float]]]) -> None:
        self.label, self.rows = label, rows

    def at(self, frame_ns: np.ndarray, t0: int, tolerance: float) -> tuple[np.ndarray, Any]:
        """(poses (K, 3) at the frames inside the span, the mask (T,)) of `sync_poses`."""
        ft = (np.asarray(frame_ns, dtype=np.int64) - t0) / 1e9
        pt = (np.array([p[0] for p in self.rows], dtype=np.int64) - t0) / 1e9
        pv = np.array([p[1] for p in self.rows], dtype=float).reshape(-1, 3)
        return sync_poses(ft, pt, pv, self.label, tolerance)


class TfSeries:
    """A tf child frame's pose in the world frame, composed along its chain at frame times."""

    def __init__(self, src: PoseSource, tree: Any) -> None:
        self.src, self.tree, self.label = src, tree, src.label

    def at(self, frame_ns: np.ndarray, t0: int, tolerance: float) -> tuple[np.ndarray, Any]:
        return self.tree.poses_at(self.src.frame, self.src.world, frame_ns, t0, tolerance, _bracket)


class _Poses:
    """The pose series of each `PoseSource`, filled message by message: a PoseStamped topic's
    poses; a tf topic's (and its static topic's) transforms, kept as a tree."""

    def __init__(self, sources: list[PoseSource]) -> None:
        from rodctl.recordings.tf import TfTree, static_topic

        self.sources = sources
        self.series: dict[str, list[tuple[int, list[float]]]] = {
            s.topic: [] for s in sources if not s.frame
        }
        self.trees = {s.topic: TfTree(s.topic) for s in sources if s.frame}
        self.static = {static_topic(t): t for t in self.trees}

    def need(self) -> list[tuple[str, tuple[str, ...]]]:
        return [(s.topic, (TF_TYPE,) if s.frame else (POSE_TYPE,)) for s in self.sources]

    def optional(self) -> list[tuple[str, tuple[str, ...]]]:
        """The static tf topics, read where the bag has them."""
        return [(t, (TF_TYPE,)) for t in self.static]

    def topics(self) -> set[str]:
        return {s.topic for s in self.sources} | set(self.static)

    def add(self, topic: str, msgtype: str, log_ns: int, msg: Any) -> None:
        if topic in self.trees:
            self.trees[topic].add(msg, log_ns, static=False, topic=topic)
        if topic in self.static:
            self.trees[self.static[topic]].add(msg, log_ns, static=True, topic=topic)
        if topic in self.series:
            p = msg.pose
            t = _stamp_ns(msg, log_ns)
            check_pose(p.position, p.orientation, f"{topic} at stamp {t / 1e9:.6f} s")
            self.series[topic].append((t, [p.position.x, p.position.y, _yaw(p.orientation)]))

    def get(self, path: Path, src: PoseSource) -> RowSeries | TfSeries:
        """The source's series, or a UserError naming the topic (and the frames a tf has)."""
        if src.frame:
            tree = self.trees[src.topic]
            if src.frame not in tree.links:
                seen = ", ".join(sorted(tree.links)) or "none"
                raise UserError(
                    f"{path}: topic {src.topic} has no transform to child frame {src.frame!r}; "
                    f"its child frames are: {seen}"
                )
            if src.world is not None and src.world not in tree.frames():
                raise UserError(
                    f"{path}: {src.topic}: child frame {src.frame!r} is not connected to the "
                    f"world frame {src.world!r}: no transform names it (its frames are: "
                    f"{', '.join(sorted(tree.frames()))})"
                )
            return TfSeries(src, tree)
        rows = self.series[src.topic]
        if rows:
            return RowSeries(src.topic, rows)
        raise UserError(f"{path}: topic {src.topic} has no messages")


def read_bag_points(
    bag: str | Path,
    points_topic: str,
    pose_topics: Sequence[str] = (),
    tolerance: float = 0.2,
    *,
    tf_frames: Sequence[str] = (),
    tf_topic: str = "/tf",
    tf_world: str | None = None,
) -> tuple[Any, list[str]]:
    """A points recording from a ROS 2 bag (sqlite3 or MCAP storage): the tracked points of
    `points_topic` (MarkerArray, Marker, nav_msgs/Path, PoseArray or PointCloud2; x, y, world
    metres) and the poses of one or two end effectors (PoseStamped topics, then tf child
    frames), interpolated at the points' times.

    Returns:
        (the `PointsRecording`, notes: e.g. frames outside the poses' span that were left out).

    Raises:
        UserError: not a bag, a topic missing or of another type (the bag's topics are listed),
            a tf child frame never published, a PointCloud2 layout that is not read, a frame
            with another number of points or a non-finite one, the sync errors of `sync_poses`.
    """
    from rodctl.recordings.synthetic import PointsRecording

    path = Path(bag)
    sources = pose_sources(pose_topics, tf_frames, tf_topic, tf_world)
    if not 1 <= len(sources) <= 2:
        raise UserError(
            "--pose-topic/--tf-frame: give one or two end effectors "
            f"(got {len(sources)}: {', '.join(s.label for s in sources) or 'none'})"
        )
    poses = _Poses(sources)
    frames = _point_frames(path, points_topic, poses)
    ft = np.array([f[0] for f in frames], dtype=np.int64)
    t0 = int(ft[0])
    frame_t = (ft - t0) / 1e9
    mask = np.ones(len(frames), dtype=bool)
    synced = []
    for src in sources:
        vals, inside = poses.get(path, src).at(ft, t0, tolerance)
        full = np.full((len(frames), 3), np.nan)
        full[inside] = vals
        synced.append(full)
        mask &= inside
    notes = []
    if not mask.all():
        notes.append(
            f"{int((~mask).sum())} of {len(frames)} frames lie outside the poses' time span "
            "and were left out"
        )
    pts = np.stack([f[1] for f in frames])[mask]
    pose_arr = np.stack(synced, axis=1)[mask]
    times = frame_t[mask]
    if len(times) < 3:
        raise UserError(f"{path}: only {len(times)} frames overlap the poses; need at least 3")
    return PointsRecording(t=times, points=pts, poses=pose_arr, units="m"), notes


def _point_frames(path: Path, points_topic: str, poses: _Poses) -> list[tuple[int, np.ndarray]]:
    """The frames (time in ns, (N, 2) points) of `points_topic` in time order, the same N >= 2
    finite points in each; the pose topics' messages go into `poses` on the way. Decoded in
    time order, so that every refusal names its frame on one clock (t = 0 at the first)."""
    stamped: list[tuple[int, int, str, Any]] = []
    need = [(points_topic, POINTS_TYPES), *poses.need()]
    for topic, msgtype, log_ns, msg in _bag_messages(path, need, poses.optional()):
        if topic == points_topic:
            stamped.append((_stamp_ns(msg, log_ns), len(stamped), msgtype, msg))
        if topic in poses.topics():
            poses.add(topic, msgtype, log_ns, msg)
    if not stamped:
        raise UserError(f"{path}: topic {points_topic} has no messages")
    stamped.sort(key=lambda f: f[:2])  # by time, then as written
    t0 = stamped[0][0]
    frames: list[tuple[int, np.ndarray]] = []
    n = 0
    for k, (t, _, msgtype, msg) in enumerate(stamped):
        where = f"{path}: {points_topic}: frame {k} (t = {(t - t0) / 1e9:.6f} s)"
        xy = _xy(msg, msgtype, where)
        n = len(xy) if k == 0 else n
        if n < 2:
            raise UserError(f"{where} has {n} points (need the same N >= 2 in every frame)")
        if len(xy) != n:
            raise UserError(
                f"{where} has {len(xy)} points, frame 0 has {n} (need the same N >= 2 in every "
                "frame)"
            )
        if not np.isfinite(xy).all():
            i = int(np.argmax(~np.isfinite(xy).all(axis=1)))
            raise UserError(f"{where}: point {i} is not a finite number")
        frames.append((t, xy))
    return frames


# --- camera images from a bag ---------------------------------------------------------------

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")


def _rgb(msg: Any, msgtype: str, where: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an Image (rgb8, bgr8, mono8) or CompressedImage (PNG, JPEG)."""
    import cv2

    data = np.asarray(msg.data, dtype=np.uint8)
    if msgtype.endswith("CompressedImage"):
        img = cv2.imdecode(data, cv2.IMREAD_COLOR)
        if img is None:
            raise UserError(f"{where}: the compressed image ({msg.format!r}) does not decode")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    h, w, enc = int(msg.height), int(msg.width), str(msg.encoding)
    ch = {"rgb8": 3, "bgr8": 3, "mono8": 1}.get(enc)
    if ch is None:
        raise UserError(f"{where}: image encoding {enc!r}; rgb8, bgr8 or mono8 are read")
    step = int(msg.step)
    if step < w * ch or data.size < h * step:
        raise UserError(
            f"{where}: {enc} image data has {data.size} bytes for {w}x{h} pixels, step {step}"
        )
    rows = data[: h * step].reshape(h, step)[:, : w * ch]
    img = rows.reshape(h, w, ch)
    if enc == "bgr8":
        return np.ascontiguousarray(img[..., ::-1])
    if enc == "mono8":
        return np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img)


def camera_config(path: str | Path) -> Any:
    """The rodctl camera (pose, rendering colours, extraction settings) in a YAML file: an
    experiment config (its `camera` section, the defaults where it has none) or a camera
    section alone."""
    from pydantic import ValidationError

    from rodctl.config.camera import CameraConfig
    from rodctl.config.loading import format_validation_error, read_yaml

    p = Path(path)
    data = read_yaml(p, "camera")  # the config loader's limits and messages (exit 2, the file)
    if "camera" in data or not set(data) & set(CameraConfig.model_fields):
        section = data.get("camera") or {}  # an experiment config: its camera, or the default
    else:
        section = data
    try:
        return CameraConfig.model_validate(section)
    except ValidationError as exc:
        where = f"{p} (camera)" if "camera" in data else str(p)
        raise UserError(f"--camera: {format_validation_error(exc, section, where)}") from None


#: Encodings a mask topic's sensor_msgs/msg/Image may have (one byte a pixel; non-zero = rod).
MASK_ENCODINGS = ("mono8", "8UC1")


def _mask(msg: Any, where: str) -> np.ndarray:
    """(H, W) bool of a mono8/8UC1 Image: True where the pixel is non-zero (the rod)."""
    enc = str(msg.encoding)
    if enc not in MASK_ENCODINGS:
        raise UserError(f"{where}: mask encoding {enc!r}; {' or '.join(MASK_ENCODINGS)} is read")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w or data.size < h * step:
        raise UserError(f"{where}: mask data has {data.size} bytes for {w}x{h} pixels, step {step}")
    return data[: h * step].reshape(h, step)[:, :w] > 0


def read_bag_images(
    bag: str | Path,
    image_topic: str,
    info_topic: str | None,
    pose_topic: str | PoseSource | Sequence[PoseSource],
    camera: Any,
    clamp_pose: Sequence[float] | None,
    *,
    hsv_low: Sequence[int],
    hsv_high: Sequence[int],
    tolerance: float = 0.2,
    calibration: Any = None,
    mask_topic: str | None = None,
) -> tuple[Any, np.ndarray, Any, list[str]]:
    """Frames of a bag's image topic segmented and their centerline extracted.

    The camera's intrinsics come from the first CameraInfo on `info_topic` (K; D undistorts
    each frame), its pose and the extraction settings from `camera` (a `CameraConfig`), or
    the pose from `calibration` (`rodctl.recordings.calibration.Calibration`) when given. The
    end effectors (`pose_topic`: a PoseStamped topic, a `PoseSource`, or a list of one or two)
    are interpolated at each frame's time; with one, it is the gripper, the extractor's hint,
    and the walk starts at the fixed `clamp_pose` [x, y, theta]; with two, the walk starts at
    end effector 0's pose of the frame and end effector 1 is the hint. The rod is segmented by
    the HSV threshold, or (`mask_topic`) by the mono8/8UC1 mask nearest in time to the frame.

    Returns:
        (PointsRecording of the pixel centerlines, (T, N, 2) world centerlines on the rod's
        plane, the camera config used, notes).

    Raises:
        UserError: the errors of `read_bag_points` for topics and sync, a mask of another
            encoding or size or none within `tolerance` of a frame, and a frame where the
            segmentation finds no rod or the extractor loses it (topic and time named).
    """
    path = Path(bag)
    topics = [pose_topic] if isinstance(pose_topic, str | PoseSource) else pose_topic
    srcs = [p if isinstance(p, PoseSource) else PoseSource(p) for p in topics]
    poses = _Poses(srcs)
    frames, masks, info = _image_messages(path, image_topic, info_topic, mask_topic, poses)
    series = [poses.get(path, s) for s in srcs]
    if info_topic and info is None:
        raise UserError(f"{path}: topic {info_topic} has no messages")
    frames, masks = _decoded(frames, masks, image_topic, mask_topic)
    KD = None
    if info is not None:
        KD = camera_intrinsics(info, f"{path}: {info_topic}")
        camera = camera.model_copy(
            update={"width": int(info.width) or camera.width,
                    "height": int(info.height) or camera.height}
        )  # fmt: skip
    return extract_frames(
        str(path), image_topic, frames, series, camera, clamp_pose, KD,
        hsv_low=hsv_low, hsv_high=hsv_high, tolerance=tolerance, calibration=calibration,
        masks=(mask_topic, masks) if mask_topic else None,
    )  # fmt: skip


def _decoded(
    frames: list[tuple[int, Any]],
    masks: list[tuple[int, Any]],
    image_topic: str,
    mask_topic: str | None,
) -> tuple[list[tuple[int, Any]], list[tuple[int, Any]]]:
    """The frames as (t_ns, (H, W, 3) RGB) and the masks as (t_ns, (H, W) bool), each in time
    order; an error names the frame's or mask's time from frame 0."""
    frames = sorted(frames, key=lambda f: f[0])
    t0 = frames[0][0]
    images = [
        (t, _rgb(m, mt, f"{image_topic}: frame {i} (t = {(t - t0) / 1e9:.6f} s)"))
        for i, (t, (m, mt)) in enumerate(frames)
    ]
    masks = sorted(masks, key=lambda m: m[0])
    bools = [
        (t, _mask(m, f"{mask_topic}: mask {i} (t = {(t - t0) / 1e9:.6f} s)"))
        for i, (t, m) in enumerate(masks)
    ]
    return images, bools


def _image_messages(
    path: Path, image_topic: str, info_topic: str | None, mask_topic: str | None, poses: _Poses
) -> tuple[list[tuple[int, Any]], list[tuple[int, Any]], Any]:
    """A bag's camera messages as read, not yet decoded: ([(t_ns, (Image, its type))], [(t_ns,
    mask Image)], the first CameraInfo or None); the pose topics' go into `poses`."""
    frames: list[tuple[int, Any]] = []
    masks: list[tuple[int, Any]] = []
    info = None
    need = [(image_topic, IMAGE_TYPES), *poses.need()]
    if info_topic:
        need.append((info_topic, ("sensor_msgs/msg/CameraInfo",)))
    if mask_topic:
        need.append((mask_topic, ("sensor_msgs/msg/Image",)))
    for topic, msgtype, log_ns, msg in _bag_messages(path, need, poses.optional()):
        if topic == image_topic:  # decoded once sorted: errors name the time from frame 0
            frames.append((_stamp_ns(msg, log_ns), (msg, msgtype)))
        elif topic == mask_topic:
            masks.append((_stamp_ns(msg, log_ns), msg))
        elif topic in poses.topics():
            poses.add(topic, msgtype, log_ns, msg)
        elif info is None:
            info = msg
    if not frames:
        raise UserError(f"{path}: topic {image_topic} has no messages")
    if mask_topic and not masks:
        raise UserError(f"{path}: topic {mask_topic} has no messages")
    return frames, masks, info


#: CameraInfo distortion models read, with the number of D coefficients each has.
DISTORTION_MODELS = {"plumb_bob": (5,), "rational_polynomial": (8,), "equidistant": (4,)}


def camera_intrinsics(info: Any, where: str) -> tuple[np.ndarray, np.ndarray, str]:
    """(K (3, 3), D, distortion model) of a CameraInfo, checked.

    Raises:
        UserError: an all-zero K (an uncalibrated driver), a K that is not finite or has no
            positive focal lengths, a D that is not finite or whose length does not match the
            distortion model, or a model other than plumb_bob, rational_polynomial and
            equidistant (`where` names the topic).
    """
    k = np.asarray(info.k, dtype=float).ravel()
    d = np.asarray(info.d, dtype=float).ravel()
    model = str(info.distortion_model or "") or "plumb_bob"
    if k.size != 9:
        raise UserError(f"{where}: CameraInfo K has {k.size} values, not 9")
    if not np.all(np.isfinite(k)):
        raise UserError(f"{where}: CameraInfo K has non-finite values: {_plain(k)}")
    if not np.any(k):
        raise UserError(
            f"{where}: CameraInfo K is all zeros: the camera is uncalibrated; pass the "
            "intrinsics in --camera (fx, fy, cx, cy) and leave --camera-info-topic out, and "
            "the pose with --calibration or --extrinsic"
        )
    K = k.reshape(3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise UserError(f"{where}: CameraInfo K has focal lengths fx = {K[0, 0]:g}, "
                        f"fy = {K[1, 1]:g}; both must be > 0")  # fmt: skip
    if model not in DISTORTION_MODELS:
        raise UserError(
            f"{where}: CameraInfo distortion_model {model!r} is not read; "
            f"{', '.join(DISTORTION_MODELS)} are"
        )
    if not np.all(np.isfinite(d)):
        raise UserError(f"{where}: CameraInfo D has non-finite values: {_plain(d)}")
    if d.size and d.size not in DISTORTION_MODELS[model]:
        raise UserError(
            f"{where}: CameraInfo D has {d.size} coefficients; the {model} model has "
            f"{DISTORTION_MODELS[model][0]}"
        )
    if not d.size:
        d = np.zeros(DISTORTION_MODELS[model][0])
    return K, d, model


def _plain(v: np.ndarray) -> str:
    """A vector as plain numbers (no numpy repr): [1, nan, 0.5]."""
    return "[" + ", ".join(f"{float(x):g}" for x in v) + "]"


def undistorter(K: np.ndarray, D: np.ndarray, model: str, size: tuple[int, int]) -> Any:
    """img -> the image undistorted onto K (plumb_bob and rational_polynomial by
    cv2.initUndistortRectifyMap, equidistant by cv2.fisheye's), or None when D is zero."""
    import cv2

    if not np.any(D != 0.0):
        return None
    if model == "equidistant":
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(
            K, D.reshape(4, 1), np.eye(3), K, size, cv2.CV_16SC2
        )
    else:
        m1, m2 = cv2.initUndistortRectifyMap(K, D, np.eye(3), K, size, cv2.CV_16SC2)
    return lambda img: cv2.remap(img, m1, m2, cv2.INTER_LINEAR)


def _match_masks(
    label: str, masks: list[tuple[int, np.ndarray]], frame_ns: np.ndarray, t0: int,
    chosen: np.ndarray, size: tuple[int, int], tolerance: float,
) -> list[np.ndarray]:  # fmt: skip
    """The mask nearest in time to each chosen frame, checked before any extraction.

    Raises:
        UserError: no mask within `tolerance` s of a frame, or one of another size than the
            frames (the topic, the frame and its time are named).
    """
    mt = np.array([m[0] for m in masks], dtype=np.int64)
    out = []
    for k in chosen:
        t = int(frame_ns[k])
        j = int(np.argmin(np.abs(mt - t)))
        where = f"{label}: frame {int(k)} (t = {(t - t0) / 1e9:.6f} s)"
        dt = abs(int(mt[j]) - t) / 1e9
        if dt > tolerance:
            raise UserError(
                f"{where}: no mask within {tolerance:g} s (the nearest is at t = "
                f"{(int(mt[j]) - t0) / 1e9:.6f} s); raise --tolerance or publish its mask"
            )
        m = masks[j][1]
        if m.shape != (size[1], size[0]):
            raise UserError(
                f"{where}: the mask (t = {(int(mt[j]) - t0) / 1e9:.6f} s) is "
                f"{m.shape[1]}x{m.shape[0]}, the frames are {size[0]}x{size[1]}"
            )
        out.append(m)
    return out


def _frames_camera(
    path: str, image_topic: str, size: tuple[int, int], camera: Any,
    KD: tuple[np.ndarray, np.ndarray, str] | None, calibration: Any,
) -> tuple[Any, Any, np.ndarray | None, np.ndarray | None, str, list[str]]:  # fmt: skip
    """The camera of frames of `size` (w, h): (config, Camera, K, D, model, notes); K, D
    replace the config's intrinsics, a `calibration` its pose over the plane."""
    from rodctl.vision.camera import Camera

    w, h = size
    K = D = None
    model = "plumb_bob"
    if KD is not None:
        K, D, model = KD
        camera = camera.model_copy(
            update={"fx": float(K[0, 0]), "fy": float(K[1, 1]),
                    "cx": float(K[0, 2]), "cy": float(K[1, 2])}
        )  # fmt: skip
    if (camera.width, camera.height) != (w, h):
        raise UserError(
            f"{path}: {image_topic} frames are {w}x{h}, the camera is "
            f"{camera.width}x{camera.height}"
        )
    cam = Camera(camera)
    notes = []
    if calibration is not None:
        dist = D if D is not None else np.zeros(5)
        cam, note = calibration.camera(camera, cam.camera_matrix, dist, model)
        notes.append(note)
    return camera, cam, K, D, model, notes


def _synced_poses(
    frames: list[tuple[int, Any]], poses: Sequence[Any], tolerance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The end effectors' poses at the frames' times: (frame_ns, inside (F,) bool, ends
    (K, E, 3) for the K frames inside every pose series' time span)."""
    t0 = frames[0][0]
    frame_ns = np.array([f[0] for f in frames], dtype=np.int64)
    inside = np.ones(len(frames), dtype=bool)
    synced = []
    for series in poses:
        vals, ins = series.at(frame_ns, t0, tolerance)
        full = np.full((len(frames), 3), np.nan)
        full[ins] = vals
        synced.append(full)
        inside &= ins
    return frame_ns, inside, np.stack(synced, axis=1)[inside]


def _frame_mask(
    where: str, img: np.ndarray, given: np.ndarray | None, mask_topic: str,
    undistort: Any, hsv_low: Sequence[int], hsv_high: Sequence[int],
) -> np.ndarray:  # fmt: skip
    """The frame's rod mask (uint8 0/255): the `given` one (undistorted), else HSV's."""
    from rodctl.recordings.segment import hsv_mask

    if given is not None:
        mask = given.astype(np.uint8) * 255
        if undistort is not None:
            mask = np.where(undistort(mask) >= 128, 255, 0).astype(np.uint8)
        if not mask.any():
            raise UserError(f"{where}: its mask ({mask_topic}) has no rod pixel")
        return mask
    mask = hsv_mask(img, hsv_low, hsv_high)
    if not mask.any():
        raise UserError(f"{where}: the HSV threshold finds no rod (--hsv-low/--hsv-high)")
    return mask


def _load_frame(f: Any) -> np.ndarray:
    """A frame: the image, or what its loader returns."""
    return f() if callable(f) else f


def _convert_frames(
    image_topic: str, frames: list[tuple[int, Any]], frame_ns: np.ndarray, ft: np.ndarray,
    inside: np.ndarray, ends: np.ndarray, camera: Any, cam: Any,
    clamp_pose: Sequence[float] | None, lens: tuple[Any, Any, str], size: tuple[int, int],
    masks: tuple[str, list[tuple[int, np.ndarray]]] | None, tolerance: float,
    hsv: tuple[Sequence[int], Sequence[int]], notes: list[str],
) -> tuple[list[np.ndarray], list[np.ndarray | None], np.ndarray]:  # fmt: skip
    """`extract_frames`' walk over the frames inside the poses' span: (centerlines in pixels,
    the images logged or None, the frames chosen); Ctrl-C keeps the frames done (a note)."""
    from types import SimpleNamespace

    from rodctl.config.logging import LoggingConfig
    from rodctl.logs.codec import FrameSchedule
    from rodctl.recordings.segment import mask_image
    from rodctl.vision.centerline import CenterlineExtractor

    t0 = frames[0][0]
    two = ends.shape[1] == 2
    fixed = None if two else CenterlineExtractor(camera, cam, np.asarray(clamp_pose, float))
    rod, bg = camera.render.rod_color, camera.render.background_color
    pts = []
    K, D, model = lens
    undistort = None if K is None or D is None else undistorter(K, D, model, size)
    chosen = np.flatnonzero(inside)
    given = None
    if masks is not None:
        given = _match_masks(masks[0], masks[1], frame_ns, t0, chosen, size, tolerance)
    # the frames the run logs on /camera/image: the simulated runs' schedule (at most
    # logging.image_rate_hz per second of the run's time), each frame as it was segmented
    schedule = FrameSchedule(LoggingConfig().image_rate_hz)
    t_first = ft[chosen[0]] if len(chosen) else 0.0
    logged: list[np.ndarray | None] = []
    try:
        for i, (k, g) in enumerate(zip(chosen, ends, strict=True)):
            t_ns, img = frames[k][0], _load_frame(frames[k][1])
            where = f"{image_topic}: frame {int(k)} (t = {(t_ns - t0) / 1e9:.6f} s)"
            slot = SimpleNamespace(image=img, sim_time=float(ft[k] - t_first))
            take = schedule.take(slot)
            if undistort is not None and (given is None or take):
                img = undistort(img)
            keep = img if take else None
            mask = _frame_mask(
                where, img, None if given is None else given[i],
                "" if masks is None else masks[0], undistort, *hsv,
            )  # fmt: skip
            # two moving ends: the walk starts at end effector 0's pose of this frame
            extractor = CenterlineExtractor(camera, cam, g[0]) if two else fixed
            assert extractor is not None  # one fixed extractor unless both ends move
            ex = extractor.extract(mask_image(mask, rod, bg), g[-1])
            if not ex.ok:
                raise UserError(f"{where}: the centerline was not extracted: {ex.note}")
            pts.append(ex.points)
            logged.append(keep)
    except KeyboardInterrupt:
        notes.append(f"{INTERRUPTED}: {len(pts)} of {len(chosen)} frames converted")
        if len(pts) < 3:
            raise
    return pts, logged, chosen


def extract_frames(
    source: str,
    image_label: str,
    frames: list[tuple[int, Any]],
    poses: Sequence[Any],
    camera: Any,
    clamp_pose: Sequence[float] | None,
    KD: tuple[np.ndarray, np.ndarray, str] | None,
    *,
    hsv_low: Sequence[int],
    hsv_high: Sequence[int],
    tolerance: float,
    calibration: Any = None,
    masks: tuple[str, list[tuple[int, np.ndarray]]] | None = None,
) -> tuple[Any, np.ndarray, Any, list[str]]:
    """Segment and extract time-sorted frames [(t_ns, RGB image or a () -> image loader)]
    with the end effectors' poses (`poses`: one or two `RowSeries`/`TfSeries`) at their
    times; K, D (when given) replace the camera's intrinsics and undistort; a `calibration`
    replaces the camera config's pose over the plane (`rodctl.recordings.calibration`);
    `masks` = (topic, [(t_ns, (H, W) bool)]) replaces the HSV threshold. The body of
    `read_bag_images`, of the image-folder and of the video import; see `read_bag_images` for
    the walk's start, the result and the errors."""
    from rodctl.recordings.synthetic import PointsRecording

    h, w = _load_frame(frames[0][1]).shape[:2]
    camera, cam, K, D, model, notes = _frames_camera(
        source, image_label, (w, h), camera, KD, calibration
    )
    frame_ns, inside, ends = _synced_poses(frames, poses, tolerance)  # ends: (K, E, 3)
    ft = (frame_ns - frames[0][0]) / 1e9
    if not inside.all():
        notes.append(
            f"{int((~inside).sum())} of {len(frames)} frames lie outside the poses' time span "
            "and were left out"
        )
    pts, logged, chosen = _convert_frames(
        image_label, frames, frame_ns, ft, inside, ends, camera, cam, clamp_pose,
        (K, D, model), (w, h), masks, tolerance, (hsv_low, hsv_high), notes,
    )  # fmt: skip
    n = len(pts)
    px = np.stack(pts)
    world = np.stack([cam.unproject(p) for p in px])
    rec = PointsRecording(
        t=ft[chosen[:n]], points=px, poses=ends[:n], units="px", images=logged[:n]
    )
    return rec, world, camera, notes


#: The note `read_bag_images` leaves when Ctrl-C cut the extraction short.
INTERRUPTED = "interrupted"
