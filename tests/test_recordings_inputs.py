"""More recording inputs (issue #26): tf poses, PointCloud2 points, a topic mapping YAML, video,
calibration from an extrinsic or marked points, estimate plots, an encoder trained on a
recording; and the bad input of each (exit 2 naming the topic, key or file)."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from test_estimate import _textured
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config.camera import CameraConfig
from rodctl.recordings import ros2 as ros2_module
from rodctl.recordings.calibration import Calibration
from rodctl.recordings.points import write_points_csv
from rodctl.recordings.ros2 import _header, _yaw, line_marker, pose_stamped, undistorter
from rodctl.recordings.synthetic import dual_arm_recording
from rodctl.recordings.tf import yaw
from rodctl.recordings.video import read_video
from rodctl.replay import read_run
from rodctl.vision.camera import Camera

FAST = ["--set", "feature.type=bezier", "--set", "run.max_steps=12", "-q",
        "--set", "logging.rerun=false", "--set", "logging.figures=false"]  # fmt: skip


def _ns(t: float) -> int:
    return int(round(t * 1e9)) + 10**18


def _ts():
    return get_typestore(Stores.ROS2_HUMBLE)


def _tf_msg(ts, t: float, frames: dict[str, list[float]]):
    """A TFMessage with one TransformStamped per child frame: world -> child, planar pose."""
    T = ts.types
    out = []
    for child, (x, y, th) in frames.items():
        tr = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
            rotation=T["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2)
            ),
        )
        out.append(
            T["geometry_msgs/msg/TransformStamped"](
                header=_header(ts, _ns(t), "world"), child_frame_id=child, transform=tr
            )
        )
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


def _cloud(ts, t: float, xy: np.ndarray, *, big: bool = False, bad_type: int | None = None):
    """A PointCloud2 of the points: little endian x, y, z FLOAT32 + an intensity, point_step 16
    and height 1; or (big) big-endian FLOAT64 x at offset 8, y at 0, point_step 24, two rows
    padded by 8 bytes each."""
    T = ts.types
    F = T["sensor_msgs/msg/PointField"]
    n = len(xy)
    if not big:
        rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4")])
        rec["x"], rec["y"], rec["i"] = xy[:, 0], xy[:, 1], 7.0
        fields = [
            F(name="x", offset=0, datatype=bad_type or 7, count=1),
            F(name="y", offset=4, datatype=7, count=1),
            F(name="z", offset=8, datatype=7, count=1),
            F(name="intensity", offset=12, datatype=7, count=1),
        ]
        data, h, w, step, row = rec.tobytes(), 1, n, 16, 16 * n
    else:
        assert n % 2 == 0
        dt = np.dtype(
            {"names": ["y", "x"], "formats": [">f8", ">f8"], "offsets": [0, 8], "itemsize": 24}
        )
        rec = np.zeros(n, dtype=dt)
        rec["x"], rec["y"] = xy[:, 0], xy[:, 1]
        rows = rec.tobytes()
        half = 24 * (n // 2)
        data = rows[:half] + b"\0" * 8 + rows[half:] + b"\0" * 8
        fields = [
            F(name="y", offset=0, datatype=8, count=1),
            F(name="x", offset=8, datatype=8, count=1),
        ]
        h, w, step, row = 2, n // 2, 24, half + 8
    return T["sensor_msgs/msg/PointCloud2"](
        header=_header(ts, _ns(t), "world"),
        height=h,
        width=w,
        fields=fields,
        is_bigendian=big,
        point_step=step,
        row_step=row,
        data=np.frombuffer(data, dtype=np.uint8),
        is_dense=True,
    )


def _points_bag(path: Path, frames, *, kind: str = "marker", tf=None, storage="sqlite3", **kw):
    """A bag with tracked points on /tracker/points (MarkerArray or PointCloud2) and, when
    `tf` = [(t, {child: pose})], a /tf topic."""
    ts = _ts()
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    pts_type = {
        "marker": "visualization_msgs/msg/MarkerArray",
        "cloud": "sensor_msgs/msg/PointCloud2",
    }[kind]
    with Writer(path, version=8, storage_plugin=plugin) as w:
        c_pts = w.add_connection("/tracker/points", pts_type, typestore=ts)
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts) if tf else None
        for t, xy in frames:
            if kind == "marker":
                msg = ts.types[pts_type](markers=[line_marker(ts, _ns(t), xy)])
            else:
                msg = _cloud(ts, t, xy, **kw)
            w.write(c_pts, _ns(t), ts.serialize_cdr(msg, pts_type))
        for t, fr in tf or []:
            w.write(c_tf, _ns(t), ts.serialize_cdr(_tf_msg(ts, t, fr), c_tf.msgtype))


def _last_line(res) -> Path:
    return Path(res.stdout.strip().splitlines()[-1])


def _two_arm_motion(t: float) -> dict[str, list[float]]:
    return {
        "left_tool": [0.3 + 0.05 * t, -0.1 * t, 0.2 * t],
        "right_tool": [0.9 - 0.02 * t, 0.04 * t, -0.3 * t],
        "camera_link": [0.0, 0.0, 0.0],
    }


def test_tf_frames_give_two_end_effectors_interpolated_at_the_frames(tmp_path):
    line = np.array([[0.0, 0.0], [0.1, 0.02], [0.2, 0.0]])
    frames = [(0.1 * k, line + 0.001 * k) for k in range(10)]
    tf = [(t, _two_arm_motion(t)) for t in np.arange(-0.05, 1.1, 1 / 7)]
    _points_bag(tmp_path / "bag", frames, tf=tf, storage="mcap")
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(tmp_path / "bag"),
            "--points-topic",
            "/tracker/points",
            "--tf-frame",
            "left_tool",
            "--tf-frame",
            "/right_tool",
            "-o",
            str(tmp_path / "r"),
        ],
    )
    assert res.exit_code == 0, res.output
    run = read_run(_last_line(res), images=False)
    assert len(run.records) == 10
    for k, r in enumerate(run.records):
        want = _two_arm_motion(0.1 * k)
        assert np.allclose(r.gripper, want["left_tool"], atol=1e-9)
        if k:  # u = the change of both ends' poses since the previous frame (q = 6)
            prev = _two_arm_motion(0.1 * (k - 1))
            du = np.r_[
                np.subtract(want["left_tool"], prev["left_tool"]),
                np.subtract(want["right_tool"], prev["right_tool"]),
            ]
            assert np.allclose(r.u, du, atol=1e-9)
    assert yaml.safe_load(run.header.config_yaml)["source"]["q"] == 6


def test_a_topic_mapping_yaml_chooses_the_topics_and_flags_replace_its_keys(tmp_path):
    line = np.array([[0.0, 0.0], [0.1, 0.02], [0.2, 0.0], [0.3, 0.01]])
    frames = [(0.1 * k, line + 0.002 * k) for k in range(8)]
    tf = [(0.05 * k, _two_arm_motion(0.05 * k)) for k in range(20)]
    _points_bag(tmp_path / "bag", frames, kind="cloud", tf=tf)
    m = tmp_path / "topics.yaml"
    m.write_text("points: /tracker/points\ntf:\n  frames: [right_tool]\n")
    res = CliRunner().invoke(
        app, ["import", str(tmp_path / "bag"), "--topics", str(m), "-o", str(tmp_path / "r")]
    )
    assert res.exit_code == 0, res.output
    run = read_run(_last_line(res), images=False)
    assert np.allclose(run.records[3].gripper, _two_arm_motion(0.3)["right_tool"], atol=1e-9)
    assert np.allclose(run.records[3].centerline, frames[3][1], atol=1e-7)  # float32 cloud
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(tmp_path / "bag"),
            "--topics",
            str(m),
            "--tf-frame",
            "left_tool",
            "-o",
            str(tmp_path / "r"),
        ],
    )
    assert res.exit_code == 0, res.output
    run = read_run(_last_line(res), images=False)
    assert np.allclose(run.records[3].gripper, _two_arm_motion(0.3)["left_tool"], atol=1e-9)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("points: /p\nimgae: /cam\n", "imgae: unknown key"),
        ("points: /p\nposes: [/a, /b, /c]\n", "poses:"),
        ("points: /p\ntf:\n  frames: []\n", "tf.frames:"),
        ("points: /p\nimage: /cam\n", "not both"),
        ("", "the file is empty (no topic mapping keys)"),
        # a list with only a maximum length keeps "at most" (not "expected a list of 2")
        ("points: /p\ntf:\n  frames: [a, b, c]\n", "tf.frames: List should have at most 2"),
        ("- /p\n", "expected a mapping of topic mapping keys"),
    ],
)
def test_a_bad_topic_mapping_exits_2_naming_the_key(tmp_path, text, needle):
    m = tmp_path / "topics.yaml"
    m.write_text(text)
    (tmp_path / "bag").mkdir()
    res = CliRunner().invoke(app, ["import", str(tmp_path / "bag"), "--topics", str(m)])
    assert res.exit_code == 2, res.output
    assert needle in res.output and "topics.yaml" in res.output, res.output
    assert "config" not in res.output, res.output  # a mapping, not an experiment config


def test_point_clouds_decode_by_their_layout_big_endian_padded_rows(tmp_path):
    rng = np.random.default_rng(0)
    frames = [(0.1 * k, rng.uniform(-1, 1, (6, 2))) for k in range(5)]
    tf = [(0.05 * k, _two_arm_motion(0.05 * k)) for k in range(12)]
    _points_bag(tmp_path / "bag", frames, kind="cloud", tf=tf, big=True)
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(tmp_path / "bag"),
            "--points-topic",
            "/tracker/points",
            "--tf-frame",
            "left_tool",
            "-o",
            str(tmp_path / "r"),
        ],
    )
    assert res.exit_code == 0, res.output
    run = read_run(_last_line(res), images=False)
    for (_, xy), r in zip(frames, run.records, strict=True):
        assert np.array_equal(r.centerline, xy)  # float64: bit for bit, in storage order


@pytest.mark.parametrize(
    ("case", "needles"),
    [
        ("int16_x", ["/tracker/points", "unsupported PointCloud2 layout", "INT16"]),
        ("no_tf_topic", ["no topic /tf", "/tracker/points (sensor_msgs/msg/PointCloud2)"]),
        ("missing_frame", ["no transform to child frame 'gripper'", "left_tool, right_tool"]),
        ("no_overlap", ["/tf (child frame left_tool)", "do not overlap"]),
    ],
)
def test_bad_bag_input_exits_2_naming_the_topic(tmp_path, case, needles):
    line = np.array([[0.0, 0.0], [0.1, 0.02], [0.2, 0.0]])
    frames = [(0.1 * k, line) for k in range(6)]
    t_tf = np.arange(5.0, 6.0, 0.1) if case == "no_overlap" else np.arange(0.0, 0.7, 0.05)
    tf = None if case == "no_tf_topic" else [(t, _two_arm_motion(t)) for t in t_tf]
    kw = {"bad_type": 3} if case == "int16_x" else {}
    _points_bag(tmp_path / "bag", frames, kind="cloud", tf=tf, **kw)
    frame = "gripper" if case == "missing_frame" else "left_tool"
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(tmp_path / "bag"),
            "--points-topic",
            "/tracker/points",
            "--tf-frame",
            frame,
            "-o",
            str(tmp_path / "r"),
        ],
    )
    assert res.exit_code == 2, res.output
    for n in needles:
        assert n in res.output, res.output
    assert not (tmp_path / "r").exists() or not any((tmp_path / "r").iterdir())


# --- camera frames: video, calibration -------------------------------------------------------


@pytest.fixture(scope="module")
def sim_frames(tmp_path_factory):
    """A short simulated run, its camera config and its frames re-lit on a textured scene."""
    out = tmp_path_factory.mktemp("runs")
    res = CliRunner().invoke(app, ["simulate", "configs/default.yaml", *FAST, "--out", str(out)])
    assert res.exit_code in (0, 1), res.output
    run_dir = _last_line(res)
    run = read_run(run_dir, images=True)
    cam_cfg = CameraConfig.model_validate(yaml.safe_load(run.header.config_yaml)["camera"])
    framed = [r for r in run.records if r.image is not None]
    images = _textured([r.image for r in framed], cam_cfg, run.header, seed=2)
    return run_dir, run, cam_cfg, framed, images


def _poses_csv(path: Path, run, t0: float) -> Path:
    rows = ["t,x,y,theta"] + [
        ",".join(repr(float(v)) for v in (r.sim_time - t0, *r.gripper)) for r in run.records
    ]
    path.write_text("\n".join(rows) + "\n")
    return path


def _video(path: Path, images, fps: float = 10.0) -> Path:
    h, w = images[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    assert vw.isOpened()
    for img in images:
        vw.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    vw.release()
    return path


def test_a_video_with_poses_imports_within_a_pixel_of_the_truth(sim_frames, tmp_path):
    run_dir, run, _, framed, images = sim_frames
    t0 = float(framed[0].sim_time)
    video = _video(tmp_path / "rod.avi", images)
    times = tmp_path / "times.csv"
    times.write_text("t\n" + "".join(f"{float(r.sim_time) - t0!r}\n" for r in framed))
    poses = _poses_csv(tmp_path / "poses.csv", run, t0)
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(video),
            "--poses",
            str(poses),
            "--frame-times",
            str(times),
            "--camera",
            str(run_dir / "config.yaml"),
            "--tolerance",
            "1",
            "--clamp-pose",
            ",".join(repr(float(v)) for v in run.header.clamp_pose),
            "-o",
            str(tmp_path / "r"),
        ],
    )
    assert res.exit_code == 0, res.output
    back = read_run(_last_line(res), images=False)
    assert len(back.records) == len(framed) >= 3
    for r, b in zip(framed, back.records, strict=True):
        err = np.sqrt(((b.extracted - r.projected_truth) ** 2).sum(axis=1))
        assert err.max() <= 1.0, (r.step, err.max())  # through MJPG's JPEG compression
        assert np.allclose(b.gripper, r.gripper, atol=1e-9)


def test_video_frame_times_from_fps_and_an_unreadable_video(sim_frames, tmp_path):
    _, run, _, _, images = sim_frames
    video = _video(tmp_path / "rod.avi", images[:4], fps=8.0)
    poses = _poses_csv(tmp_path / "poses.csv", run, 0.0)
    frames, _, used = read_video(video, poses)  # the container's own fps
    assert [f[0] for f in frames] == [int(round(k / 8.0 * 1e9)) for k in range(4)]
    assert used == {"frames": 4, "fps": 8.0}
    assert frames[2][1]().shape == images[0].shape
    frames, _, _ = read_video(video, poses, fps=20.0)
    assert frames[3][0] == 150_000_000
    bad = tmp_path / "broken.avi"
    bad.write_bytes(b"RIFF not really a video" * 50)
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(bad),
            "--poses",
            str(poses),
            "--camera",
            "configs/default.yaml",
            "--clamp-pose",
            "0,0,0",
        ],
    )
    assert res.exit_code == 2, res.output
    assert "broken.avi" in res.output and "not a video OpenCV can read" in res.output


def test_a_calibration_reproduces_rodctls_camera_model():
    """The extrinsic (R|t with K) and the homography of 6 marked points give the camera's own
    projection, for a tilted and turned camera."""
    cfg = CameraConfig(tilt_deg=25.0, azimuth_deg=12.0, look_at=(0.3, -0.05))
    cam = Camera(cfg)
    plane = np.array([[0.0, 0.0], [0.5, 0.1], [0.2, -0.3], [0.6, -0.2], [0.1, 0.25], [0.4, 0.0]])
    grid = np.random.default_rng(1).uniform(-0.2, 0.7, (50, 2))
    K, D = cam.camera_matrix, np.zeros(5)
    ext, _ = Calibration(rotation=cam.rotation, translation=cam.translation).camera(cfg, K, D)
    marked = Calibration(pixels=cam.project(plane), plane=plane)
    hom, note = marked.camera(cfg, K, D)
    assert "RMS reprojection 0.000 px" in note
    for c in (ext, hom):
        assert np.allclose(c.project(grid), cam.project(grid), atol=1e-6)
        assert np.allclose(c.unproject(cam.project(grid)), grid, atol=1e-9)
    # marked on a distorted image: undistorted before the fit, so the same model comes back
    D = np.array([-0.12, 0.03, 0.0, 0.0, 0.0])
    norm = cv2.undistortPoints(cam.project(plane).reshape(-1, 1, 2), K, None).reshape(-1, 2)
    raw, _ = cv2.projectPoints(np.c_[norm, np.ones(len(norm))], np.zeros(3), np.zeros(3), K, D)
    back, _ = Calibration(pixels=raw.reshape(-1, 2), plane=plane).camera(cfg, K, D)
    assert np.allclose(back.project(grid), cam.project(grid), atol=1e-3)


@pytest.mark.parametrize("how", ["plane_points", "extrinsic"])
def test_a_calibration_replaces_a_wrong_camera_pose_in_an_image_import(sim_frames, tmp_path, how):
    run_dir, run, cam_cfg, framed, images = sim_frames
    images, framed = images[:4], framed[:4]
    cam = Camera(cam_cfg)
    folder = tmp_path / "frames"
    folder.mkdir()
    lines = ["file,t"]
    for k, (r, img) in enumerate(zip(framed, images, strict=True)):
        cv2.imwrite(str(folder / f"f{k}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        lines.append(f"f{k}.png,{float(r.sim_time)!r}")
    (folder / "frames.csv").write_text("\n".join(lines) + "\n")
    poses = _poses_csv(tmp_path / "poses.csv", run, 0.0)
    wrong = {
        "camera": {
            **cam_cfg.model_dump(mode="json"),
            "distance": cam_cfg.distance * 1.3,
            "tilt_deg": cam_cfg.tilt_deg + 10.0,
        }
    }
    (tmp_path / "wrong.yaml").write_text(yaml.safe_dump(wrong))
    plane = np.array([[0.0, 0.1], [0.4, 0.15], [0.1, -0.25], [0.5, -0.2], [0.25, 0.0]])
    if how == "plane_points":
        calib = {
            "plane_points": [
                {"pixel": [float(a), float(b)], "plane": [float(c), float(d)]}
                for (a, b), (c, d) in zip(cam.project(plane), plane, strict=True)
            ]
        }
    else:
        calib = {"extrinsic": {"rvec": cam.rvec.tolist(), "translation": cam.tvec.tolist()}}
    (tmp_path / "calib.yaml").write_text(yaml.safe_dump(calib))
    args = [
        "import",
        str(folder),
        "--poses",
        str(poses),
        "--camera",
        str(tmp_path / "wrong.yaml"),
        "--clamp-pose",
        ",".join(repr(float(v)) for v in run.header.clamp_pose),
        "--tolerance",
        "1",
        "-o",
        str(tmp_path / "r"),
    ]
    res = CliRunner().invoke(app, args)  # the wrong pose alone: the rod is lost or misplaced
    if res.exit_code == 0:
        b = read_run(_last_line(res), images=False).records[0]
        assert np.abs(b.centerline[-1] - framed[0].centerline[-1]).max() > 0.02
    else:
        assert res.exit_code == 2, res.output
    res = CliRunner().invoke(app, [*args, "--calibration", str(tmp_path / "calib.yaml")])
    assert res.exit_code == 0, res.output
    back = read_run(_last_line(res), images=False)
    for r, b in zip(framed, back.records, strict=True):
        assert np.sqrt(((b.extracted - r.projected_truth) ** 2).sum(axis=1)).max() <= 1.0
        # the world centerline is unprojected through the calibration, not the wrong pose
        assert np.abs(b.centerline[-1] - r.centerline[-1]).max() < 3e-3
    source = yaml.safe_load(back.header.config_yaml)["source"]
    assert source["calibration"]["kind"] == how


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        (
            "plane_points:\n  - {pixel: [1, 2], plane: [0, 0]}\n",
            "plane_points: List should have at least 4",
        ),
        (
            "extrinsic: {rotation: [[1, 0, 0], [0, 2, 0], [0, 0, 1]], translation: [0, 0, 1]}\n",
            "extrinsic.rotation: not a rotation",
        ),
        ("extrinsic: {rvec: [0, 0, 0]}\n", "extrinsic.translation: required key is missing"),
        ("homography: 1\n", "homography: unknown key"),
    ],
)
def test_a_bad_calibration_exits_2_naming_the_key(tmp_path, text, needle):
    (tmp_path / "c.yaml").write_text(text)
    res = CliRunner().invoke(app, ["import", "x.avi", "--calibration", str(tmp_path / "c.yaml")])
    assert res.exit_code == 2, res.output
    assert needle in res.output and "c.yaml" in res.output, res.output


@pytest.mark.parametrize("name", ["../evil", "a/b", ".hidden", "x" * 65, "bad name"])
def test_a_bad_import_name_is_refused_before_any_folder(tmp_path, name):
    path = write_points_csv(dual_arm_recording(10, seed=3, points=4), tmp_path / "rec.csv")
    out = tmp_path / "runs"
    res = CliRunner().invoke(app, ["import", str(path), "-o", str(out), "--name", name])
    assert res.exit_code == 2, res.output
    assert "--name" in res.output and "letters, digits" in res.output, res.output
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"]


def test_the_default_import_name_is_the_file_stem_made_safe(tmp_path):
    path = write_points_csv(dual_arm_recording(10, seed=3, points=4), tmp_path / "my rec (1).csv")
    res = CliRunner().invoke(app, ["import", str(path), "-o", str(tmp_path / "runs")])
    assert res.exit_code == 0, res.output
    run = _last_line(res)
    assert run.parent == tmp_path / "runs" and run.name.endswith("_import-my-rec-1"), run
    assert yaml.safe_load((run / "config.yaml").read_text())["name"] == "import-my-rec-1"


# --- estimate plots; an encoder trained on a recording --------------------------------------


def test_estimate_writes_plots_and_a_table(tmp_path):
    path = write_points_csv(dual_arm_recording(80, seed=3, points=4), tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["estimate", str(path), "-e", "broyden"])
    assert res.exit_code == 0, res.output
    out = _last_line(res)
    for name in ("errors.png", "medians.png"):
        head = (out / name).read_bytes()[:8]
        assert head == b"\x89PNG\r\n\x1a\n", name
    assert "ratio_to_zero_motion" in res.stderr and "broyden" in res.stderr


def test_a_short_imported_run_is_told_what_init_to_pass(tmp_path):
    """The run folder says what the points file says: the default, and the --init range."""
    path = write_points_csv(dual_arm_recording(20, seed=3, points=4), tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["import", str(path), "-o", str(tmp_path / "runs")])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["estimate", str(_last_line(res)), "--no-plots"])
    assert res.exit_code == 2, res.output
    assert "--init (not given) defaults to 10 q = 60 pairs" in res.output, res.output
    assert "the run has 20 pairs" in res.output and "6 <= N < 20" in res.output, res.output


def test_a_dataset_folder_that_is_not_a_run_is_named_so(tmp_path):
    (tmp_path / "empty").mkdir()
    res = CliRunner().invoke(
        app, ["train-encoder", "configs/default.yaml", "--dataset", str(tmp_path / "empty")]
    )
    assert res.exit_code == 2, res.output
    assert "a folder that is not a run folder (no run.mcap)" in res.output, res.output


def test_an_encoder_trained_on_an_imported_recording_estimates(tmp_path):
    pytest.importorskip("torch")
    rec = write_points_csv(dual_arm_recording(60, seed=4, points=8), tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["import", str(rec), "-o", str(tmp_path / "runs")])
    assert res.exit_code == 0, res.output
    imported = _last_line(res)
    res = CliRunner().invoke(
        app,
        [
            "train-encoder",
            "configs/default.yaml",
            "--dataset",
            str(imported),
            "--set",
            "feature.type=autoencoder",
            "--set",
            "feature.training.epochs=5",
            "--set",
            "feature.hidden=[16]",
            "--set",
            "feature.latent_dim=4",
            "-o",
            str(tmp_path / "runs"),
            "-q",
        ],
    )
    assert res.exit_code == 0, res.output
    trained = _last_line(res)
    assert (trained / "encoder.npz").is_file() and (trained / "dataset.npz").is_file()
    res = CliRunner().invoke(
        app,
        [
            "estimate",
            str(imported),
            "--feature",
            "autoencoder",
            "--checkpoint",
            str(trained / "encoder.npz"),
            "-e",
            "broyden",
            "--init",
            "30",
            "--no-plots",
        ],
    )
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader((_last_line(res) / "results.csv").open()))
    assert [r["feature"] for r in rows] == ["autoencoder"] * 3
    assert rows[2]["outcome"] == "completed" and int(rows[2]["updates"]) == 60 - 30


def test_camera_frames_with_a_tf_gripper_chosen_by_a_topic_mapping(sim_frames, tmp_path):
    run_dir, run, cam_cfg, framed, images = sim_frames
    framed, images = framed[:3], images[:3]
    ts = _ts()
    T = ts.types
    K = Camera(cam_cfg).camera_matrix
    with Writer(tmp_path / "bag", version=8) as w:
        c_img = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        c_info = w.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        for r in run.records:
            msg = _tf_msg(ts, r.sim_time, {"tool0": list(r.gripper[:3]), "base": [0.0] * 3})
            w.write(c_tf, _ns(r.sim_time), ts.serialize_cdr(msg, c_tf.msgtype))
        for r, img in zip(framed, images, strict=True):
            ns = _ns(r.sim_time)
            hd = _header(ts, ns, "camera")
            h, wd = img.shape[:2]
            msg = T["sensor_msgs/msg/Image"](
                header=hd, height=h, width=wd, encoding="rgb8", is_bigendian=0, step=3 * wd,
                data=img.reshape(-1),
            )  # fmt: skip
            w.write(c_img, ns, ts.serialize_cdr(msg, c_img.msgtype))
            info = T["sensor_msgs/msg/CameraInfo"](
                header=hd, height=h, width=wd, distortion_model="plumb_bob", d=np.zeros(5),
                k=K.reshape(-1), r=np.eye(3).reshape(-1),
                p=np.hstack([K, np.zeros((3, 1))]).reshape(-1), binning_x=0, binning_y=0,
                roi=T["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
                ),
            )  # fmt: skip
            w.write(c_info, ns, ts.serialize_cdr(info, c_info.msgtype))
    m = tmp_path / "topics.yaml"
    m.write_text("image: /cam/image\ncamera_info: /cam/info\ntf: {frames: [tool0]}\n")
    res = CliRunner().invoke(
        app,
        ["import", str(tmp_path / "bag"), "--topics", str(m), "--camera",
         str(run_dir / "config.yaml"), "--tolerance", "1", "-o", str(tmp_path / "r"),
         "--clamp-pose", ",".join(repr(float(v)) for v in run.header.clamp_pose)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    back = read_run(_last_line(res), images=False)
    assert len(back.records) == 3
    for r, b in zip(framed, back.records, strict=True):
        assert np.sqrt(((b.extracted - r.projected_truth) ** 2).sum(axis=1)).max() <= 1.0
        assert np.allclose(b.gripper, r.gripper, atol=1e-9)


# --- refused camera info, images, poses and flags (review of issue #26) ----------------------


def _tiny_bag(path: Path, case: str) -> None:
    """Three 32x24 frames on /cam/image, the gripper on /arm/pose (or tool0 on /tf) and a
    CameraInfo on /cam/info, spoilt as `case` says."""
    ts = _ts()
    T = ts.types
    w_, h_ = 32, 24
    K = np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])
    k = {"k_zero": np.zeros(9), "k_nan": np.r_[K.ravel()[:8], np.nan]}.get(case, K.ravel())
    model = "equidistant" if case == "d_len" else ("kannala" if case == "model" else "plumb_bob")
    d = {"d_len": np.zeros(5), "d_nan": np.array([0.1, np.nan, 0, 0, 0])}.get(case, np.zeros(5))
    with Writer(path, version=8) as w:
        c_img = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        c_info = w.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        c_arm = w.add_connection("/arm/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        for i in range(3):
            ns = _ns(0.1 * i)
            hd = _header(ts, ns, "camera")
            pose = pose_stamped(ts, ns, np.array([0.1, 0.0, 0.0]))
            if case == "pose_nan" and i == 1:
                pose.pose.orientation.w = float("nan")
            if case == "pose_zero" and i == 1:
                pose.pose.orientation.z = pose.pose.orientation.w = 0.0
            w.write(c_arm, ns, ts.serialize_cdr(pose, c_arm.msgtype))
            tf = _tf_msg(ts, 0.1 * i, {"tool0": [0.1, 0.0, 0.0]})
            if case == "tf_zero" and i == 2:
                o = tf.transforms[0].transform.rotation
                o.x = o.y = o.z = o.w = 0.0
            w.write(c_tf, ns, ts.serialize_cdr(tf, c_tf.msgtype))
            data = np.zeros(h_ * w_ * 3, dtype=np.uint8)
            if case == "short" and i == 2:
                data = data[: -w_ * 3]
            img = T["sensor_msgs/msg/Image"](
                header=hd, height=h_, width=w_, encoding="rgb8", is_bigendian=0, step=3 * w_,
                data=data,
            )  # fmt: skip
            w.write(c_img, ns, ts.serialize_cdr(img, c_img.msgtype))
            info = T["sensor_msgs/msg/CameraInfo"](
                header=hd, height=h_, width=w_, distortion_model=model, d=d, k=k,
                r=np.eye(3).reshape(-1), p=np.zeros(12), binning_x=0, binning_y=0,
                roi=T["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
                ),
            )  # fmt: skip
            w.write(c_info, ns, ts.serialize_cdr(info, c_info.msgtype))


@pytest.mark.parametrize(
    ("case", "needles"),
    [
        ("k_zero", ["/cam/info", "K is all zeros", "uncalibrated", "--camera"]),
        ("k_nan", ["/cam/info", "K has non-finite values", "nan"]),
        ("d_len", ["/cam/info", "D has 5 coefficients", "equidistant model has 4"]),
        ("d_nan", ["/cam/info", "D has non-finite values"]),
        ("model", ["/cam/info", "distortion_model 'kannala' is not read", "equidistant"]),
        (
            "short",
            ["/cam/image: frame 2 (t = 0.200000 s)", "rgb8 image data has 2208 bytes for 32x24"],
        ),
        ("pose_nan", ["/arm/pose at stamp ", "non-finite", "nan"]),
        ("pose_zero", ["/arm/pose at stamp ", "quaternion is zero"]),
        ("tf_zero", ["/tf: child frame 'tool0' at stamp ", "quaternion is zero"]),
    ],
)
def test_bad_camera_info_image_or_pose_exits_2_naming_the_topic(tmp_path, case, needles):
    _tiny_bag(tmp_path / "bag", case)
    cam = tmp_path / "cam.yaml"
    cam.write_text("camera: {}\n")
    ends = ["--tf-frame", "tool0"] if case.startswith("tf") else ["--pose-topic", "/arm/pose"]
    res = CliRunner().invoke(
        app,
        ["import", str(tmp_path / "bag"), "--image-topic", "/cam/image", *ends,
         "--camera-info-topic", "/cam/info", "--camera", str(cam), "--clamp-pose", "0,0,0",
         "-o", str(tmp_path / "r")],
    )  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    assert res.output.startswith(f"error: {tmp_path / 'bag'}: "), res.output  # the bag first
    for n in needles:
        assert n in res.output, res.output


def test_the_distortion_model_chooses_the_undistortion():
    K = np.array([[60.0, 0, 40], [0, 60.0, 30], [0, 0, 1]])
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.integers(0, 255, (60, 80, 3), dtype=np.uint8), (5, 5), 0)
    D4 = np.array([0.2, -0.05, 0.01, 0.0])
    fish = undistorter(K, D4, "equidistant", (80, 60))(img)
    ref = cv2.fisheye.undistortImage(img, K, D4.reshape(4, 1), Knew=K)
    assert np.abs(fish[10:50, 10:70].astype(int) - ref[10:50, 10:70]).mean() < 1.0
    D5 = np.array([0.2, -0.05, 0.0, 0.0, 0.01])
    pinhole = undistorter(K, D5, "plumb_bob", (80, 60))(img)
    ref = cv2.undistort(img, K, D5)
    assert np.abs(pinhole[10:50, 10:70].astype(int) - ref[10:50, 10:70]).mean() < 1.0
    assert np.abs(fish.astype(int) - pinhole).mean() > 5.0
    assert undistorter(K, np.zeros(8), "rational_polynomial", (80, 60)) is None


def test_yaw_is_scale_free():
    q = np.array([0.0, 0.0, math.sin(0.35), math.cos(0.35)]) * 3.0  # 0.7 rad, norm 3
    assert math.isclose(_yaw(SimpleNamespace(x=q[0], y=q[1], z=q[2], w=q[3])), 0.7)
    assert math.isclose(float(yaw(q)), 0.7)


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["rec.csv", "--pose-topic", "/x"], ["--pose-topic", "not a ROS 2 bag"]),
        (["rod.avi", "--pose-topic", "/x", "--poses", "p.csv"], ["--pose-topic"]),
        (["bag", "--image-topic", "/i", "--points-topic", "/p", "--pose-topic", "/x"],
         ["--image-topic and --points-topic", "not both"]),
        (["bag", "--topics", "map.yaml", "--points-topic", "/p"], ["not both"]),
        (["rod.avi", "--poses", "p.csv"], ["--clamp-pose"]),
        (["frames", "--poses", "p.csv"], ["--clamp-pose"]),
        (["frames", "--poses", "p.csv", "--clamp-pose", "0,0,0", "--extrinsic",
          "nan,0,0,0,0,1"], ["--extrinsic", "finite", "nan"]),
    ],
)  # fmt: skip
def test_misplaced_or_missing_flags_exit_2_naming_them(tmp_path, args, needles):
    (tmp_path / "bag").mkdir()
    (tmp_path / "frames").mkdir()
    (tmp_path / "rec.csv").write_text("t,x0,y0\n")
    (tmp_path / "rod.avi").write_bytes(b"")
    (tmp_path / "p.csv").write_text("t,x,y,theta\n")
    (tmp_path / "map.yaml").write_text("image: /cam/image\nposes: [/arm/pose]\n")
    (tmp_path / "cam.yaml").write_text("camera: {}\n")
    args = [str(tmp_path / a) if (tmp_path / a).exists() else a for a in args]
    res = CliRunner().invoke(
        app, ["import", *args, "--camera", str(tmp_path / "cam.yaml"), "-o", str(tmp_path / "r")]
    )
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    for n in needles:
        assert n in res.output, res.output


def test_a_time_that_does_not_increase_is_named_as_a_plain_number(tmp_path):
    rows = ["t,x0,y0,x1,y1,x2,y2,e0_x,e0_y,e0_theta"] + [
        f"{t},0,0,0.1,0,0.2,0,0.2,0,0" for t in (0.0, 0.4, 0.4, 0.6)
    ]
    (tmp_path / "rec.csv").write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(app, ["import", str(tmp_path / "rec.csv"), "-o", str(tmp_path / "r")])
    assert res.exit_code == 2, res.output
    assert "frame 2: t = 0.4 does not increase (previous 0.4)" in res.output, res.output
    assert "np." not in res.output


def test_export_of_a_two_end_recording_writes_both_ends_poses(tmp_path):
    rec = dual_arm_recording(8, seed=3)
    csv_path = write_points_csv(rec, tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["import", str(csv_path), "-o", str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    bag = tmp_path / "bag"
    res = CliRunner().invoke(app, ["export", _last_line(res).as_posix(), "--ros2", str(bag)])
    assert res.exit_code == 0, res.output
    got: dict[str, list] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for conn, _, raw in reader.messages():
            got.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    for topic, end in (("/gripper/pose", 0), ("/end_effector_1/pose", 1)):
        poses = got[topic]
        assert len(poses) == len(rec.t)
        for want, msg in zip(rec.poses[:, end], poses, strict=True):
            o, p = msg.pose.orientation, msg.pose.position
            assert np.allclose([p.x, p.y], want[:2], atol=1e-12)
            assert abs(np.angle(np.exp(1j * (2 * np.arctan2(o.z, o.w) - want[2])))) < 1e-9


@pytest.mark.parametrize("fault", [KeyboardInterrupt, OSError])
def test_an_export_cut_short_removes_its_unfinished_bag_and_exits_1(tmp_path, monkeypatch, fault):
    """Found by a new-user trial: a Ctrl-C mid-export left a bag folder without metadata.yaml
    (no reader opens it, and the next export to it said 'exists already'), exit 130."""
    rec = dual_arm_recording(8, seed=3)
    csv_path = write_points_csv(rec, tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["import", str(csv_path), "-o", str(tmp_path / "r")])
    run = _last_line(res).as_posix()
    real, calls = ros2_module.line_marker, []

    def marker(*args):  # cut while the 4th step is written
        calls.append(1)
        if len(calls) == 4:
            raise fault(28, "No space left on device") if fault is OSError else fault()
        return real(*args)

    monkeypatch.setattr(ros2_module, "line_marker", marker)
    bag = tmp_path / "bag"
    res = CliRunner().invoke(app, ["export", run, "--ros2", str(bag)])
    assert res.exit_code == 1, res.output
    assert f"the unfinished bag {bag} was removed" in res.output and "Traceback" not in res.output
    assert not bag.exists()
    monkeypatch.undo()
    res = CliRunner().invoke(app, ["export", run, "--ros2", str(bag)])  # the same folder again
    assert res.exit_code == 0, res.output


def test_replay_verify_of_an_imported_recording_is_refused_before_anything_is_written(tmp_path):
    """Found by a new-user trial: exit 2 came after run.rrd and figures/ had been written."""
    csv_path = write_points_csv(dual_arm_recording(8, seed=3), tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["import", str(csv_path), "-o", str(tmp_path / "r")])
    run = _last_line(res)
    before = sorted(p.name for p in run.iterdir())
    res = CliRunner().invoke(app, ["replay", str(run), "--verify"])
    assert res.exit_code == 2, res.output
    assert res.output.startswith("error: ") and "--verify does not apply" in res.output
    assert sorted(p.name for p in run.iterdir()) == before


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--clamp-pose", "0,0,0"], "--clamp-pose applies to camera frames"),
        (["--hsv-low", "1,2,3", "--camera", "c.yaml"], "--camera, --hsv-low apply to camera"),
        (["--extrinsic", "1,2,3,4,5,6"], "--extrinsic applies to camera frames"),
        (["--poses", "p.csv"], "--poses applies to an image folder or a video"),
        (["--tolerance", "5"], "--tolerance applies to inputs whose poses are matched"),
    ],
)
def test_options_that_do_not_apply_to_tracked_points_are_refused(tmp_path, extra, said):
    """Found by a new-user trial: a points file took --clamp-pose, --camera, --hsv-low,
    --tolerance, ... and silently ignored them (exit 0), while it refused --fps."""
    csv_path = write_points_csv(dual_arm_recording(8, seed=3), tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["import", str(csv_path), *extra, "-o", str(tmp_path / "r")])
    assert res.exit_code == 2, res.output
    assert res.output.startswith(f"error: {said}") and "a file of tracked points" in res.output
    assert not (tmp_path / "r").exists()
    if "--poses" in extra or "--tolerance" in extra:
        return  # a bag takes --tolerance; --poses is refused there by the bag flags' check
    line = np.array([[0.0, 0.0], [0.1, 0.02], [0.2, 0.0]])
    tf = [(t, _two_arm_motion(t)) for t in np.arange(-0.05, 1.1, 1 / 7)]
    _points_bag(tmp_path / "bag", [(0.1 * k, line) for k in range(10)], tf=tf, storage="mcap")
    args = ["import", str(tmp_path / "bag"), "--points-topic", "/tracker/points"]
    res = CliRunner().invoke(app, [*args, "--tf-frame", "left_tool", *extra])
    assert res.exit_code == 2, res.output
    assert said in res.output and "a bag of tracked points" in res.output


@pytest.mark.parametrize(
    ("first", "said"),
    [
        ("# unit: px", "'# unit: px': the units comment is '# units: px' (or m)"),
        ("# Units: px", "'# Units: px': the units comment is"),
    ],
)
def test_a_misspelt_units_comment_is_refused_not_read_as_metres(tmp_path, first, said):
    rows = [first, "t,x0,y0,x1,y1,e0_x,e0_y,e0_theta", "0,0,0,100,0,0,0,0", "1,0,0,100,0,0,0,0.1"]
    (tmp_path / "rec.csv").write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(app, ["import", str(tmp_path / "rec.csv"), "-o", str(tmp_path / "r")])
    assert res.exit_code == 2, res.output
    assert "line 1: " + said in res.output, res.output


@pytest.mark.parametrize(
    ("first", "scale", "warned"),
    [
        (
            "",
            1000.0,
            "the tracked rod is 400 m long (median over frames), read as metres; "
            "if they are pixels, add a `# units: px` line",
        ),
        ("# units: px", 1000.0, None),
        ("", 1.0, None),
        ("# units: px", 1.0, "the tracked rod is 0.4 px long (median over frames), read as pixels"),
    ],
)
def test_points_whose_size_fits_the_other_unit_are_warned_about(tmp_path, first, scale, warned):
    """Found by a new-user trial: a file of pixels without `# units: px` imported as a rod
    hundreds of metres long, without a word."""
    xs = [0.0, 0.1, 0.2, 0.3, 0.4]
    rows = [first] if first else []
    rows.append("t," + ",".join(f"x{i},y{i}" for i in range(5)) + ",e0_x,e0_y,e0_theta")
    for k in range(4):
        pts = ",".join(f"{scale * x:g},{scale * 0.01 * k:g}" for x in xs)
        rows.append(f"{0.1 * k:g},{pts},0.4,0,{0.05 * k:g}")
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(app, ["import", str(path), "-o", str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    if warned is None:
        assert "warning" not in res.output, res.output
    else:
        assert f"warning: {path}: {warned}" in res.output, res.output


def test_a_points_npz_with_an_array_it_does_not_know_is_refused(tmp_path):
    """Found by a new-user trial: `unit='px'` was ignored and the pixels imported as metres."""
    path = tmp_path / "rec.npz"
    t, pts = np.arange(5) * 0.1, np.random.default_rng(0).random((5, 4, 2)) * 500
    np.savez(path, t=t, points=pts, poses=np.zeros((5, 1, 3)), unit="px")
    res = CliRunner().invoke(app, ["import", str(path), "-o", str(tmp_path / "r")])
    assert res.exit_code == 2, res.output
    assert "array 'unit' is not one a points file has (t, points, poses, units)" in res.output


def test_a_csv_with_a_byte_order_mark_is_read_and_one_with_semicolons_is_named(tmp_path):
    rows = ["t,x0,y0,x1,y1,e0_x,e0_y,e0_theta"] + [f"{k},0,0,0.1,0,0,0,{k / 10}" for k in range(4)]
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + ("\n".join(rows) + "\n").encode())
    res = CliRunner().invoke(app, ["import", str(tmp_path / "bom.csv"), "-o", str(tmp_path / "r")])
    assert res.exit_code == 0, res.output  # Excel's "CSV UTF-8"
    (tmp_path / "semi.csv").write_text("\n".join(r.replace(",", ";") for r in rows) + "\n")
    res = CliRunner().invoke(app, ["import", str(tmp_path / "semi.csv"), "-o", str(tmp_path / "r")])
    assert res.exit_code == 2 and "the columns are separated by ';'" in res.output, res.output


@pytest.mark.parametrize("which", ["frames.csv", "poses.csv"])
def test_an_image_folder_whose_times_do_not_increase_is_refused(sim_frames, tmp_path, which):
    """Found by a new-user trial: two frames at one time in frames.csv (or a reversed one) were
    re-sorted silently, and a frame got another frame's pose."""
    run_dir, run, cam_cfg, framed, images = sim_frames
    folder = tmp_path / "frames"
    folder.mkdir()
    times = [float(r.sim_time) for r in framed[:4]]
    lines = ["file,t"]
    for k, img in enumerate(images[:4]):
        cv2.imwrite(str(folder / f"f{k}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        t = times[1] if (which == "frames.csv" and k == 2) else times[k]
        lines.append(f"f{k}.png,{t!r}")
    (folder / "frames.csv").write_text("\n".join(lines) + "\n")
    poses = _poses_csv(tmp_path / "poses.csv", run, 0.0)
    if which == "poses.csv":
        rows = poses.read_text().splitlines()
        rows[2], rows[3] = rows[3], rows[2]
        poses.write_text("\n".join(rows) + "\n")
    (tmp_path / "cam.yaml").write_text(yaml.safe_dump({"camera": cam_cfg.model_dump(mode="json")}))
    clamp = ",".join(repr(float(v)) for v in run.header.clamp_pose)
    res = CliRunner().invoke(app, ["import", str(folder), "--poses", str(poses), "--camera",
                                   str(tmp_path / "cam.yaml"), "--clamp-pose", clamp,
                                   "-o", str(tmp_path / "r")])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert f"{which}: row 3: t = " in res.output and "does not increase" in res.output


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_a_non_finite_csv_value_is_named_by_its_line_and_column(tmp_path, bad):
    rows = ["t,x0,y0,x1,y1,e0_x,e0_y,e0_theta"] + [f"{k},0,0,0.1,0,0,0,{k / 10}" for k in range(4)]
    rows[3] = rows[3].rsplit(",", 1)[0] + f",{bad}"
    (tmp_path / "rec.csv").write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(app, ["import", str(tmp_path / "rec.csv"), "-o", str(tmp_path / "r")])
    assert res.exit_code == 2, res.output
    assert f"line 4 (frame 2), column e0_theta: '{bad}' is not a finite number" in res.output


def test_a_folder_that_is_not_a_bag_is_one_line_naming_what_is_missing(tmp_path):
    """Found by a new-user trial: rosbags' own text ('Expected metadata file … does not exist',
    a multi-line YAML dump) was passed on."""
    args = ["--points-topic", "/p", "--pose-topic", "/x", "-o", str(tmp_path / "r")]
    (tmp_path / "empty").mkdir()
    res = CliRunner().invoke(app, ["import", str(tmp_path / "empty"), *args])
    assert res.exit_code == 2 and "no metadata.yaml in the folder" in res.output, res.output
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 8\n  x: [1, 2\n")
    res = CliRunner().invoke(app, ["import", str(bad), *args])
    assert res.exit_code == 2 and "not a readable ROS 2 bag (" in res.output
    assert "metadata.yaml" in res.output  # rosbags names the file it could not load
    assert len(res.output.strip().splitlines()) == 1, res.output


def test_a_topic_given_empty_or_twice_in_the_mapping_is_named_where_it_was_given(tmp_path):
    (tmp_path / "bag").mkdir()
    bag = str(tmp_path / "bag")
    res = CliRunner().invoke(app, ["import", bag, "--points-topic", "/p", "--pose-topic", ""])
    assert res.exit_code == 2 and "--pose-topic is empty" in res.output, res.output
    mapping = tmp_path / "m.yaml"
    mapping.write_text("points: /p\nposes: [/arm/pose, /arm/pose]\n")
    res = CliRunner().invoke(app, ["import", bag, "--topics", str(mapping)])
    assert res.exit_code == 2, res.output
    assert f"{mapping}: poses /arm/pose /arm/pose: each end's own" in res.output
    assert "--pose-topic" not in res.output


def test_a_file_that_is_not_a_video_gives_rodctls_line_without_ffmpegs_log(tmp_path):
    """Found by a new-user trial: FFmpeg printed '[mov,mp4,...] moov atom not found' on stderr
    before the error. A fresh process: FFmpeg reads its log level when first used."""
    fake = tmp_path / "fake.mp4"
    fake.write_text("t,x0,y0\n0,0,0\n")
    code = "from pathlib import Path; from rodctl.recordings.video import _Decoder\n"
    code += f"_Decoder(Path({str(fake)!r}))._open()"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "not a video OpenCV can read" in proc.stderr
    assert "moov" not in proc.stderr and "[mov" not in proc.stderr, proc.stderr
