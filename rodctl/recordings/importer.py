"""`rodctl import`: a recording turned into a rodctl run folder with the contract topics.

The run folder is what `rodctl simulate` writes (config.yaml, meta.json, summary.json,
run.mcap), so `replay` rebuilds run.rrd and the figures from it, Foxglove opens its run.mcap and
`estimate` reads its (Delta s, Delta r). What a recording does not have is said, not invented
(docs/recordings.md, "What an imported run contains"):
- one record per frame: step k, `sim_time` = t_k - t_0, phase "initial" then "control";
- `gripper` = end effector 0's pose; `u` = the change of all end-effector poses since the
  previous frame (q = 3 or 6 values, angles unwrapped);
- `s` = the tracked points flattened (x0, y0, x1, ...; the `points` feature), `J` = zeros: no
  estimate is made at import (`rodctl estimate` makes them offline);
- there is no target: `s_target` and the target shape are the last frame's, so T1 is the
  distance to the final shape;
- points in pixels are the `extracted` centerline as they are; points in metres are the world
  centerline, and `extracted` is their view through a nominal top-down camera of
  `NOMINAL_PX_PER_M` pixels per metre (y down), recorded in config.yaml's `source`.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rodctl.config.base import RUN_NAME_MAX, is_run_name
from rodctl.errors import RunFailed, UserError, make_out_folder, out_error
from rodctl.recordings.synthetic import PointsRecording

#: Scale of the nominal top-down view of a recording in metres (pixels per metre).
NOMINAL_PX_PER_M = 1000.0


def _views(rec: PointsRecording) -> tuple[np.ndarray, np.ndarray, tuple[int, int], dict]:
    """(world centerline (T, N, 2) m, pixels (T, N, 2), image size, the view's description)."""
    pts = np.asarray(rec.points, dtype=float)
    if rec.units == "px":
        px = pts
        lo = np.zeros(2)
        size = (int(np.ceil(px[..., 0].max())) + 1, int(np.ceil(px[..., 1].max())) + 1)
        world = np.stack([px[..., 0], -px[..., 1]], axis=-1) / NOMINAL_PX_PER_M
        view: dict[str, Any] = {
            "points_are": "pixels",
            "world": f"x / {NOMINAL_PX_PER_M:g}, -y / same",
        }
    else:
        world = pts
        lo = world.reshape(-1, 2).min(axis=0) - 0.05
        hi = world.reshape(-1, 2).max(axis=0) + 0.05
        px = np.stack(
            [
                (world[..., 0] - lo[0]) * NOMINAL_PX_PER_M,
                (hi[1] - world[..., 1]) * NOMINAL_PX_PER_M,
            ],
            axis=-1,
        )
        size = (
            int(np.ceil((hi[0] - lo[0]) * NOMINAL_PX_PER_M)),
            int(np.ceil((hi[1] - lo[1]) * NOMINAL_PX_PER_M)),
        )
        view = {
            "points_are": "metres",
            "nominal_camera": {
                "px_per_m": NOMINAL_PX_PER_M,
                "origin_m": [float(lo[0]), float(hi[1])],
            },
        }
    return world, px, (max(size[0], 1), max(size[1], 1)), view


def import_points(path: str | Path, out: str | Path, name: str | None = None) -> Path:
    """Write the points recording at `path` as a run folder under `out`; return the folder.

    Raises:
        UserError: a bad recording (`read_points`) or an output folder that cannot be made.
    """
    from rodctl.recordings.points import read_points

    src = Path(path)
    return write_run(read_points(src), src, out, name, {"kind": "points"})


def import_bag(
    bag: str | Path,
    out: str | Path,
    points_topic: str,
    pose_topics: list[str],
    *,
    tolerance: float = 0.2,
    name: str | None = None,
    tf_frames: list[str] | None = None,
    tf_topic: str = "/tf",
    tf_world: str | None = None,
) -> tuple[Path, list[str]]:
    """Write the tracked points and poses of a ROS 2 bag as a run folder under `out`
    (`rodctl.recordings.ros2.read_bag_points`; end effectors from PoseStamped topics, then tf
    child frames); return the folder and the notes.
    """
    from rodctl.recordings.ros2 import read_bag_points

    src = Path(bag)
    with _bag_named(src):
        rec, notes = read_bag_points(
            src,
            points_topic,
            pose_topics,
            tolerance,
            tf_frames=tf_frames or (),
            tf_topic=tf_topic,
            tf_world=tf_world,
        )
    source = {
        "kind": "ros2_bag",
        "points_topic": points_topic,
        "pose_topics": list(pose_topics),
        "tolerance_s": tolerance,
        "notes": notes,
    }
    if tf_frames:
        source["tf"] = {"topic": tf_topic, "frames": list(tf_frames), "world": tf_world}
    return write_run(rec, src, out, name, source), notes


@contextmanager
def _bag_named(bag: Path) -> Iterator[None]:
    """A bag's refusals start with the bag, as its others do (a zero quaternion or a pose gap
    was named by topic and stamp alone)."""
    try:
        yield
    except UserError as exc:
        if str(exc).startswith(str(bag)):
            raise
        raise UserError(f"{bag}: {exc}") from None


def _listed(v: str | list[str] | None) -> list[str]:
    """An option given once or repeated, as a list (empty entries dropped)."""
    return [v] if isinstance(v, str) else [x for x in v or [] if x]


def _image_ends(
    src: Path,
    pose_topics: list[str],
    tf_frames: list[str],
    tf_topic: str,
    tf_world: str | None,
    clamp_pose: list[float] | None,
) -> list[Any]:
    """The camera frames' one or two end effectors (`PoseSource`s), checked with `clamp_pose`:
    needed with one (where the rod starts), refused with two (end effector 0 is the start)."""
    from rodctl.recordings.ros2 import pose_sources

    ends = pose_sources(pose_topics, tf_frames, tf_topic, tf_world)
    if not 1 <= len(ends) <= 2:
        raise UserError(
            f"{src}: camera frames need one or two end effectors (--pose-topic, --tf-frame); "
            f"got {len(ends)}"
        )
    if len(ends) == 2 and clamp_pose is not None:
        raise UserError(
            "--clamp-pose: with two end effectors the rod's walk starts at end effector 0's "
            "pose in each frame; leave --clamp-pose out"
        )
    if len(ends) == 1:
        _need_clamp(src, clamp_pose)
    return ends


def import_bag_images(
    bag: str | Path,
    out: str | Path,
    *,
    image_topic: str,
    info_topic: str | None,
    pose_topic: str | list[str] | None,
    camera: str | Path,
    clamp_pose: list[float] | None,
    hsv_low: list[int],
    hsv_high: list[int],
    tolerance: float = 0.2,
    name: str | None = None,
    tf_frame: str | list[str] | None = None,
    tf_topic: str = "/tf",
    tf_world: str | None = None,
    calibration: Any = None,
    mask_topic: str | None = None,
) -> tuple[Path, list[str]]:
    """Segment and extract the rod in a bag's camera frames; write the run folder
    (`rodctl.recordings.ros2.read_bag_images`). The end effectors are the PoseStamped
    `pose_topic`(s), then the tf child frame(s) `tf_frame`: one (the gripper; the rod starts
    at the fixed `clamp_pose`) or two (the rod runs from end effector 0 to 1); `mask_topic`
    replaces the HSV threshold; `calibration` (`rodctl.recordings.calibration`) replaces the
    camera file's pose. The world centerline is the extracted one unprojected onto the rod's
    plane by the calibrated camera."""
    from rodctl.recordings.ros2 import camera_config, read_bag_images

    src = Path(bag)
    cam_cfg = camera_config(camera)
    pose_topics, tf_frames = _listed(pose_topic), _listed(tf_frame)
    ends = _image_ends(src, pose_topics, tf_frames, tf_topic, tf_world, clamp_pose)
    with _bag_named(src):
        rec, world, used, notes = read_bag_images(
            src, image_topic, info_topic, ends, cam_cfg, clamp_pose,
            hsv_low=hsv_low, hsv_high=hsv_high, tolerance=tolerance, calibration=calibration,
            mask_topic=mask_topic,
        )  # fmt: skip
    source: dict[str, Any] = {
        "kind": "ros2_bag_images",
        "image_topic": image_topic,
        "camera_info_topic": info_topic,
        "pose_topics": pose_topics,
    }
    if mask_topic:
        source["mask_topic"] = mask_topic
    if tf_frames:
        source["tf"] = {"topic": tf_topic, "frames": tf_frames, "world": tf_world}
    if calibration is not None:
        source["calibration"] = calibration.describe()
    frames = (rec, world, used, notes)
    return _write_frames_run(
        frames, src, out, name, source, clamp_pose, hsv_low, hsv_high, tolerance
    )


def import_image_folder(
    folder: str | Path,
    out: str | Path,
    *,
    poses: str | Path,
    camera: str | Path,
    clamp_pose: list[float] | None,
    hsv_low: list[int],
    hsv_high: list[int],
    tolerance: float = 0.2,
    name: str | None = None,
    calibration: Any = None,
) -> tuple[Path, list[str]]:
    """The camera-frame import of `import_bag_images` for an image folder with frames.csv
    and a poses CSV (`rodctl.recordings.folder`); the intrinsics come from `camera`."""
    from rodctl.recordings.folder import read_folder
    from rodctl.recordings.ros2 import camera_config

    src = Path(folder)
    _need_clamp(src, clamp_pose)
    cam_cfg = camera_config(camera)
    frames, pose_rows = read_folder(src, poses)
    source: dict[str, Any] = {"kind": "image_folder", "poses": str(poses)}
    return _import_posed_frames(
        src, "frames.csv", frames, (poses, pose_rows), source, out, camera=cam_cfg,
        clamp_pose=clamp_pose, hsv_low=hsv_low, hsv_high=hsv_high, tolerance=tolerance,
        name=name, calibration=calibration,
    )  # fmt: skip


def import_video(
    video: str | Path,
    out: str | Path,
    *,
    poses: str | Path,
    camera: str | Path,
    clamp_pose: list[float] | None,
    hsv_low: list[int],
    hsv_high: list[int],
    tolerance: float = 0.2,
    name: str | None = None,
    fps: float | None = None,
    frame_times: str | Path | None = None,
    calibration: Any = None,
) -> tuple[Path, list[str]]:
    """The camera-frame import of `import_image_folder` for a video file (OpenCV) and a poses
    CSV (`rodctl.recordings.video`): frame times from `frame_times` or fps."""
    from rodctl.recordings.ros2 import camera_config
    from rodctl.recordings.video import read_video

    src = Path(video)
    _need_clamp(src, clamp_pose)
    cam_cfg = camera_config(camera)
    frames, pose_rows, used_times = read_video(src, poses, fps=fps, frame_times=frame_times)
    source: dict[str, Any] = {"kind": "video", "poses": str(poses), **used_times}
    return _import_posed_frames(
        src, src.name, frames, (poses, pose_rows), source, out, camera=cam_cfg,
        clamp_pose=clamp_pose, hsv_low=hsv_low, hsv_high=hsv_high, tolerance=tolerance,
        name=name, calibration=calibration,
    )  # fmt: skip


def _import_posed_frames(
    src: Path,
    label: str,
    frames: Any,
    poses: tuple[str | Path, Any],
    source: dict[str, Any],
    out: str | Path,
    *,
    camera: Any,
    clamp_pose: list[float] | None,
    hsv_low: list[int],
    hsv_high: list[int],
    tolerance: float,
    name: str | None,
    calibration: Any,
) -> tuple[Path, list[str]]:
    """The shared end of an image-folder or video import: `frames` with one end effector's
    poses (file, rows) through the extractor, seen by `camera` (its config), into a run folder."""
    from rodctl.recordings.ros2 import RowSeries, extract_frames

    path, rows = poses
    rec, world, used, notes = extract_frames(
        str(src), label, frames, [RowSeries(str(path), rows)], camera, clamp_pose,
        None,
        hsv_low=hsv_low, hsv_high=hsv_high, tolerance=tolerance, calibration=calibration,
    )  # fmt: skip
    if calibration is not None:
        source["calibration"] = calibration.describe()
    return _write_frames_run(
        (rec, world, used, notes), src, out, name, source, clamp_pose, hsv_low, hsv_high, tolerance
    )


def _need_clamp(src: Path, clamp_pose: list[float] | None) -> None:
    """Camera frames with one end effector start the rod's walk at the fixed end."""
    if clamp_pose is None:
        raise UserError(
            f"{src}: camera frames with one end effector need --clamp-pose X,Y,THETA (the "
            "fixed end)"
        )


def _write_frames_run(
    frames: tuple,
    src: Path,
    out: str | Path,
    name: str | None,
    source: dict,
    clamp_pose: list[float] | None,
    hsv_low: list[int],
    hsv_high: list[int],
    tolerance: float,
) -> tuple[Path, list[str]]:
    """The run folder of a camera-frame import (a bag's or a folder's): `frames` = (recording,
    world centerline, the camera used, notes) of `extract_frames`; `source` the kind's own
    keys, to which the segmentation settings are added. An import cut short (Ctrl-C) keeps
    the frames it converted and raises `RunFailed` naming the folder."""
    from rodctl.recordings.ros2 import INTERRUPTED

    rec, world, used, notes = frames
    source = {
        **source,
        "clamp_pose": None if clamp_pose is None else [float(v) for v in clamp_pose],
        "hsv_low": [int(v) for v in hsv_low],
        "hsv_high": [int(v) for v in hsv_high],
        "tolerance_s": tolerance,
        "notes": notes,
    }
    views = (world, rec.points, (used.width, used.height), {"camera": used.model_dump(mode="json")})
    clamp = None if clamp_pose is None else np.asarray(clamp_pose, dtype=float)
    cut = [n for n in notes if n.startswith(INTERRUPTED)]
    run_dir = write_run(
        rec, src, out, name, source, views=views, clamp=clamp, cut=cut[0] if cut else None
    )
    return run_dir, notes


def run_name(name: str | None, src: str | Path) -> str:
    """The imported run's name: `name` checked (exit 2 naming `--name`), or `import-<stem>`
    with the file stem's characters that cannot be in a folder's name replaced by `-`."""
    if name is None:
        stem = re.sub(r"[^A-Za-z0-9._-]+", "-", Path(src).stem).strip("-.") or "recording"
        return f"import-{stem}"[:RUN_NAME_MAX]
    if not is_run_name(name):
        raise UserError(
            f"--name {name!r}: a run name is letters, digits, '.', '_' and '-', starting with a "
            f"letter or digit, at most {RUN_NAME_MAX} characters (it becomes the folder's name)"
        )
    return name


def _new_run_dir(out: str | Path, stem: str) -> Path:
    """A new, empty `<time>_<stem>` folder under `out` (`-2`, `-3`, ... when taken)."""
    parent = make_out_folder(out)
    try:
        run_dir = parent / f"{time.strftime('%Y%m%d-%H%M%S')}_{stem}"
        for n in range(2, 10_000):
            if not run_dir.exists():
                break
            run_dir = parent / f"{time.strftime('%Y%m%d-%H%M%S')}_{stem}-{n}"
        run_dir.mkdir()
    except OSError as exc:
        raise out_error("--out", parent, "cannot create the run folder", exc) from None
    return run_dir


def _run_config(rec: PointsRecording, src: Path, stem: str, source: dict, view: dict) -> dict:
    """The imported run's config.yaml: its name and the recording's `source` description."""
    T, N = rec.points.shape[:2]
    source = {
        **source,
        "file": str(src),
        "frames": int(T),
        "points": int(N),
        "end_effectors": int(rec.poses.shape[1]),
        "q": rec.q,
        **view,
    }
    config = {"name": stem, "seed": 0, "source": source}
    if "camera" in view:  # camera frames: the camera the logs' /camera/calibration describes
        config["camera"] = view["camera"]
    return config


def _run_header(
    rec: PointsRecording, run_id: str, config_yaml: str, size: Any, clamp: np.ndarray | None,
    world: np.ndarray, px: np.ndarray, s_target: np.ndarray, kind: str,
) -> Any:  # fmt: skip
    """The run.mcap header: the last frame is the target, the clamp as `write_run` says; the
    method names what was imported (`recording/<source kind>`: points, ros2_bag, video, ...)."""
    from rodctl.records import RunHeader

    return RunHeader(
        run_id=run_id,
        method=f"recording/{kind}",
        config_yaml=config_yaml,
        image_size=size,
        clamp_pose=np.asarray(
            clamp
            if clamp is not None
            else (rec.poses[0, -1] if rec.poses.shape[1] == 2 else np.zeros(3)),
            dtype=float,
        ),
        # Two moving ends (q = 6): both ends' poses, gripper first, as a dual-arm run's header
        # holds them (readers tell q from the home pose's size).
        home_pose=np.asarray(rec.poses[0, :2] if rec.q == 6 else rec.poses[0, 0]).reshape(-1),
        target_centerline=world[-1],
        target_pixels=px[-1],
        target_feature=s_target,
        target_pose=np.asarray(rec.poses[-1, :2] if rec.q == 6 else rec.poses[-1, 0]).reshape(-1),
        rod_length=float(np.sqrt((np.diff(world[0], axis=0) ** 2).sum(axis=1)).sum()),
    )


def _write_frames(
    sink: Any, rec: PointsRecording, world: np.ndarray, px: np.ndarray, s_all: np.ndarray
) -> tuple[Any, int, bool]:
    """One step record per frame into `sink`: (the last record, frames written, cut by Ctrl-C)."""
    from rodctl.records import StepRecord

    T, r = rec.points.shape[0], rec.r
    p, q = s_all.shape[1], rec.q
    s_target = s_all[-1]
    last, written = None, 0
    try:
        for k in range(T):
            u = np.zeros(q) if k == 0 else r[k] - r[k - 1]
            err = float(np.sqrt(((px[k] - px[-1]) ** 2).sum(axis=1)).mean())
            last = StepRecord(
                step=k,
                sim_time=float(rec.t[k] - rec.t[0]),
                phase="initial" if k == 0 else "control",
                gripper=np.asarray(rec.poses[k, 0]),
                centerline=world[k],
                extracted=px[k],
                projected_truth=px[k],
                u=u,
                u_raw=u,
                s=s_all[k],
                s_target=s_target,
                T1=float(np.sqrt(((s_target - s_all[k]) ** 2).sum())),
                J=np.zeros((p, q)),
                J_singular_values=np.zeros(min(p, q)),
                pixel_error=err,
                image=None if rec.images is None else rec.images[k],
            )
            sink.write(last)
            written = k + 1
    except KeyboardInterrupt:
        return last, written, True
    return last, written, False


def _run_summary(
    status: str, method: str, last: Any, written: int, wall: float, run_id: str, frames: int
) -> Any:
    """The imported run's summary: `written` of `frames` frames, `last` the last step record."""
    from rodctl.records import RunSummary

    return RunSummary(
        status=status,
        outcome="interrupted" if status == "interrupted" else "recording",
        method=method,
        steps=max(written - 1, 0),
        converged=False,
        steps_to_converge=None,
        final_T1=float(last.T1) if last is not None else float("nan"),
        final_pixel_error=float(last.pixel_error) if last is not None else float("nan"),
        wall_time_s=wall,
        steps_per_s=written / wall if wall > 0 else 0.0,
        extra={"run_id": run_id, "frames_imported": written, "frames": int(frames)},
    )


def write_run(
    rec: PointsRecording,
    src: Path,
    out: str | Path,
    name: str | None,
    source: dict,
    views: tuple | None = None,
    clamp: np.ndarray | None = None,
    cut: str | None = None,
) -> Path:
    """Write a checked points recording as a run folder under `out` (the module docstring).

    `views` = (world (T, N, 2), pixels (T, N, 2), image size, description) replaces the nominal
    views of `_views` when a calibrated camera gave both; `clamp` is the fixed end's pose
    (default: end effector 1's first pose for two ends, else zeros); `cut` is the note of an
    extraction cut short (Ctrl-C): the frames done are written, the run's status is
    `interrupted` and `RunFailed` is raised naming the folder.
    """
    from rodctl.logs.mcap import McapSink
    from rodctl.runs import jsonable, write_json_atomic

    world, px, size, view = views if views is not None else _views(rec)
    T = rec.points.shape[0]
    stem = run_name(name, src)
    run_dir = _new_run_dir(out, stem)
    config_yaml = yaml.safe_dump(_run_config(rec, src, stem, source, view), sort_keys=False)
    (run_dir / "config.yaml").write_text(config_yaml, encoding="utf-8")
    meta = {
        "run_id": run_dir.name,
        "command": "import",
        "status": "running",
        "source": str(src),
        "started_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    write_json_atomic(run_dir / "meta.json", meta)

    s_all = px.reshape(T, -1) if rec.units == "px" else world.reshape(T, -1)
    kind = str(source.get("kind", "points"))
    header = _run_header(rec, run_dir.name, config_yaml, size, clamp, world, px, s_all[-1], kind)
    sink = McapSink(run_dir / "run.mcap")
    sink.open(header)
    t0 = time.perf_counter()
    last, written, stopped = _write_frames(sink, rec, world, px, s_all)
    wall = time.perf_counter() - t0
    status = "interrupted" if cut or stopped else "completed"
    summary = _run_summary(status, header.method, last, written, wall, run_dir.name, T)
    sink.close(summary, status)
    write_json_atomic(run_dir / "summary.json", jsonable(summary.to_json()))
    meta.update(status=status, ended_at=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    write_json_atomic(run_dir / "meta.json", meta)
    if cut and written == T:
        raise RunFailed(f"import of {src} cut short ({cut}); {run_dir} keeps them")
    if status != "completed":
        raise RunFailed(
            f"import of {src} cut short after {written} of {T} frames; {run_dir} keeps them"
        )
    return run_dir
