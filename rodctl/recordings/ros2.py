"""`rodctl export RUN --ros2 BAG`: a run written as a ROS 2 bag (CDR), through `rosbags`.

No ROS 2 runtime is needed: `rosbags` (pure Python, pinned in pyproject.toml) serialises the
messages with its built-in ROS 2 Humble type definitions and writes either storage (sqlite3 or
MCAP). Topics (docs/recordings.md, "Export to a ROS 2 bag"):
- `/camera/image_raw` sensor_msgs/msg/Image (rgb8), every logged camera frame;
- `/camera/camera_info` sensor_msgs/msg/CameraInfo beside each frame: K from the run's camera
  config, no distortion (plumb_bob, D = 0; rodctl's camera is a pinhole);
- `/gripper/pose` geometry_msgs/msg/PoseStamped, the gripper pose of every step (x, y, z = 0,
  theta as a rotation about z), frame `world`;
- `/rod/centerline` visualization_msgs/msg/MarkerArray, one LINE_STRIP of the rod's centerline
  (`/rod/state.centerline`, world metres) per step.
Message times are the MCAP log times (2000-01-01 + simulated time), so a bag of a run is the
same bytes each time (sqlite3 aside, whose pages are the database's business).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rodctl.errors import UserError

STORAGES = ("sqlite3", "mcap")
TOPIC_IMAGE = "/camera/image_raw"
TOPIC_INFO = "/camera/camera_info"
TOPIC_POSE = "/gripper/pose"
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


def export_ros2(run_path: str | Path, bag: str | Path, storage: str = "mcap") -> dict[str, int]:
    """Write the run at `run_path` as the ROS 2 bag folder `bag`; return messages per topic.

    Raises:
        UserError: not a run, a bag folder that exists already, an unknown storage.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.errors import WriterError
    from rosbags.typesys import Stores, get_typestore

    from rodctl.logs.codec import log_time_ns
    from rodctl.replay import read_run

    if storage not in STORAGES:
        raise UserError(f"--storage {storage}: choose one of {', '.join(STORAGES)}")
    out = Path(bag)
    if out.exists():
        raise UserError(f"{out}: exists already; a bag is written to a new folder")
    run = read_run(run_path, images=True)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Point, Quat, Pose = (
        T["geometry_msgs/msg/Point"],
        T["geometry_msgs/msg/Quaternion"],
        T["geometry_msgs/msg/Pose"],
    )
    K = _intrinsics(run.header.config_yaml, tuple(run.header.image_size))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    counts = {TOPIC_IMAGE: 0, TOPIC_INFO: 0, TOPIC_POSE: 0, TOPIC_CENTERLINE: 0}

    def header(t_ns: int, frame: str) -> Any:
        return Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000),
                      frame_id=frame)  # fmt: skip

    try:
        writer = Writer(out, version=8, storage_plugin=plugin)
    except WriterError as exc:
        raise UserError(f"{out}: {exc}") from None
    with writer:
        conns = {
            TOPIC_IMAGE: writer.add_connection(TOPIC_IMAGE, "sensor_msgs/msg/Image", typestore=ts),
            TOPIC_INFO: writer.add_connection(
                TOPIC_INFO, "sensor_msgs/msg/CameraInfo", typestore=ts
            ),
            TOPIC_POSE: writer.add_connection(
                TOPIC_POSE, "geometry_msgs/msg/PoseStamped", typestore=ts
            ),
            TOPIC_CENTERLINE: writer.add_connection(
                TOPIC_CENTERLINE, "visualization_msgs/msg/MarkerArray", typestore=ts
            ),
        }

        def put(topic: str, t_ns: int, msg: Any) -> None:
            writer.write(conns[topic], t_ns, ts.serialize_cdr(msg, conns[topic].msgtype))
            counts[topic] += 1

        for r in run.records:
            t_ns = int(log_time_ns(r.sim_time))
            x, y, th = (float(v) for v in np.asarray(r.gripper)[:3])
            q = Quat(x=0.0, y=0.0, z=math.sin(th / 2.0), w=math.cos(th / 2.0))
            pose = Pose(position=Point(x=x, y=y, z=0.0), orientation=q)
            put(TOPIC_POSE, t_ns, T["geometry_msgs/msg/PoseStamped"](header(t_ns, "world"), pose))
            line = np.asarray(r.centerline, dtype=float)
            marker = T["visualization_msgs/msg/Marker"](
                header=header(t_ns, "world"),
                ns="rod",
                id=0,
                type=4,  # LINE_STRIP
                action=0,
                pose=Pose(
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
                    header=header(t_ns, ""), format="", data=np.zeros(0, dtype=np.uint8)
                ),
                uv_coordinates=[],
                text="",
                mesh_resource="",
                mesh_file=T["visualization_msgs/msg/MeshFile"](
                    filename="", data=np.zeros(0, dtype=np.uint8)
                ),
                mesh_use_embedded_materials=False,
            )
            put(TOPIC_CENTERLINE, t_ns, T["visualization_msgs/msg/MarkerArray"](markers=[marker]))
            if r.image is None:
                continue
            img = np.ascontiguousarray(r.image, dtype=np.uint8)
            h, w = img.shape[:2]
            put(
                TOPIC_IMAGE,
                t_ns,
                T["sensor_msgs/msg/Image"](
                    header=header(t_ns, "camera"),
                    height=h,
                    width=w,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=3 * w,
                    data=img.reshape(-1),
                ),
            )
            P = np.hstack([K, np.zeros((3, 1))])
            put(
                TOPIC_INFO,
                t_ns,
                T["sensor_msgs/msg/CameraInfo"](
                    header=header(t_ns, "camera"),
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
                ),
            )
    return counts
