"""Recordings (issue #26), the last three pieces: a mask topic for segmentation, tf chains
composed up to a world frame (with /tf_static), and camera frames whose two ends both move
(q = 6). Frames are rodctl's own renders (quasi-static rod, both ends driven the way the
clamp_move event drives the clamp), re-lit on a textured scene; bags written with rosbags."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore
from test_estimate import _textured
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config import load_config
from rodctl.errors import RunFailed, UserError
from rodctl.geometry import resample_polyline
from rodctl.recordings.importer import import_bag_images
from rodctl.recordings.ros2 import _header, line_marker, pose_stamped
from rodctl.recordings.tf import TfTree, slerp, yaw
from rodctl.replay import read_run
from rodctl.sim.rod import RodSim
from rodctl.vision.camera import Camera
from rodctl.vision.centerline import CenterlineExtractor

DT = 0.1  # seconds between frames


def _ns(t: float) -> int:
    return int(round(t * 1e9)) + 10**18


def _ts():
    return get_typestore(Stores.ROS2_HUMBLE)


def _last_line(res) -> Path:
    return Path(res.stdout.strip().splitlines()[-1])


def _import(bag: Path, out: Path, *args: str):
    return CliRunner().invoke(app, ["import", str(bag), "-o", str(out), *args])


# --- tf chains --------------------------------------------------------------------------------


def _quat(yaw: float, roll: float = 0.0) -> list[float]:
    """[x, y, z, w] of a rotation by `yaw` about z after `roll` about x (R = Rz Rx)."""
    cz, sz, cx, sx = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(roll / 2), math.sin(roll / 2)
    return [cz * sx, sz * sx, sz * cx, cz * cx]


#: The chain world -> base (static) -> link1 -> tool0 (both timed), and a static side branch
#: world -> camera_link: (parent, child, translation(t), yaw(t)).
CHAIN = {
    "base": ("world", lambda t: [0.5, 0.2, 0.1], lambda t: 0.3),
    "link1": ("base", lambda t: [0.3 + 0.01 * t, 0.0, 0.0], lambda t: 0.4 + 0.2 * t),
    "tool0": ("link1", lambda t: [0.25, 0.05 * t, 0.0], lambda t: -0.1 - 0.3 * t),
    "camera_link": ("world", lambda t: [0.0, 0.0, 1.2], lambda t: 0.0),
}
STATIC = ("base", "camera_link")


def _se2(*poses) -> np.ndarray:
    """The composition of planar poses [x, y, yaw], left to right."""
    x, y, th = 0.0, 0.0, 0.0
    for px, py, pth in poses:
        x, y = x + math.cos(th) * px - math.sin(th) * py, y + math.sin(th) * px + math.cos(th) * py
        th += pth
    return np.array([x, y, th])


def _link(name: str, t: float) -> list[float]:
    _, tr, yaw = CHAIN[name]
    return [tr(t)[0], tr(t)[1], yaw(t)]


def _tf(ts, t: float, names, static_t: float | None = None):
    T = ts.types
    out = []
    for name in names:
        parent, tr, yaw = CHAIN[name]
        x, y, z = tr(t)
        q = _quat(yaw(t))
        out.append(
            T["geometry_msgs/msg/TransformStamped"](
                header=_header(ts, 0 if static_t is not None else _ns(t), parent),
                child_frame_id=name,
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                    rotation=T["geometry_msgs/msg/Quaternion"](*q),
                ),
            )
        )
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


def _chain_bag(path: Path, *, gap: tuple[float, float] | None = None) -> list[float]:
    """Tracked points at frames t = 0.013 + 0.1 k (k < 8), /tf_static once (stamp 0), /tf at
    0.05 s steps (none for link1 inside `gap`); returns the frame times."""
    ts = _ts()
    line = np.array([[0.0, 0.0], [0.1, 0.02], [0.2, 0.0]])
    frames = [0.013 + DT * k for k in range(8)]
    with Writer(path, version=8) as w:
        c_pts = w.add_connection(
            "/tracker/points", "visualization_msgs/msg/MarkerArray", typestore=ts
        )
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_st = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        w.write(c_st, _ns(0.0), ts.serialize_cdr(_tf(ts, 0.0, STATIC, 0.0), c_st.msgtype))
        for t in np.arange(0.0, 0.85, 0.05):
            names = ["tool0"] if gap and gap[0] < t < gap[1] else ["link1", "tool0"]
            w.write(c_tf, _ns(t), ts.serialize_cdr(_tf(ts, t, names), c_tf.msgtype))
        for t in frames:
            msg = ts.types["visualization_msgs/msg/MarkerArray"](
                markers=[line_marker(ts, _ns(t), line)]
            )
            w.write(c_pts, _ns(t), ts.serialize_cdr(msg, c_pts.msgtype))
    return frames


def test_a_tf_chain_composes_to_the_known_pose_in_the_root_or_a_named_frame(tmp_path):
    frames = _chain_bag(tmp_path / "bag")
    res = _import(tmp_path / "bag", tmp_path / "r", "--points-topic", "/tracker/points",
                  "--tf-frame", "tool0")  # fmt: skip
    assert res.exit_code == 0, res.output
    m = tmp_path / "topics.yaml"
    m.write_text("points: /tracker/points\ntf: {frames: [tool0], world: base}\n")
    res_base = _import(tmp_path / "bag", tmp_path / "r", "--topics", str(m))
    assert res_base.exit_code == 0, res_base.output
    in_world = read_run(_last_line(res), images=False).records
    in_base = read_run(_last_line(res_base), images=False).records
    assert len(in_world) == len(in_base) == len(frames)
    for t, a, b in zip(frames, in_world, in_base, strict=True):
        arm = (_link("link1", t), _link("tool0", t))
        assert np.allclose(a.gripper, _se2(_link("base", t), *arm), atol=1e-9), (t, a.gripper)
        assert np.allclose(b.gripper, _se2(*arm), atol=1e-9), (t, b.gripper)


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--tf-world", "camera_link"],
         ["'tool0' is not connected to the world frame 'camera_link'", "link1 -> base -> world"]),
        (["--tf-world", "table"], ["'tool0' is not connected to the world frame 'table'"]),
        (["--tolerance", "0.12"],
         ["link 'link1' in 'base'", "t = 0.300000 s", "0.237000 and 0.387000"]),
    ],
)  # fmt: skip
def test_a_tf_chain_refuses_an_unconnected_world_or_a_gap_naming_frame_and_time(
    tmp_path, args, needles
):
    _chain_bag(tmp_path / "bag", gap=(0.26, 0.39))
    res = _import(tmp_path / "bag", tmp_path / "r", "--points-topic", "/tracker/points",
                  "--tf-frame", "tool0", *args)  # fmt: skip
    assert res.exit_code == 2, res.output
    for n in needles:
        assert n in res.output, res.output


def test_a_tf_child_with_two_parents_and_misplaced_flags_are_refused(tmp_path):
    ts = _ts()
    tree = TfTree("/tf")
    tree.add(_tf(ts, 0.0, ["link1"]), _ns(0.0), static=False, topic="/tf")
    with pytest.raises(UserError, match="'tool0' has two parents, 'link1' \\(/tf\\) and 'world'"):
        tree.add(_tf(ts, 0.0, ["tool0"]), _ns(0.0), static=False, topic="/tf")
        msg = _tf(ts, 0.1, ["tool0"])
        msg.transforms[0].header.frame_id = "world"
        tree.add(msg, _ns(0.1), static=False, topic="/tf")
    _chain_bag(tmp_path / "bag")
    for args, needle in [
        (["--points-topic", "/tracker/points", "--pose-topic", "/p", "--tf-world", "base"],
         "--tf-world: goes with --tf-frame"),
        (["--points-topic", "/tracker/points", "--tf-frame", "tool0", "--mask-topic", "/m"],
         "--mask-topic: masks are read from a ROS 2 bag beside its --image-topic"),
    ]:  # fmt: skip
        res = _import(tmp_path / "bag", tmp_path / "r", *args)
        assert res.exit_code == 2 and needle in res.output, res.output


def test_slerp_interpolates_a_general_rotation_along_the_shortest_arc():
    q0, q1 = np.array([_quat(0.2, 0.5)]), -np.array([_quat(0.8, 0.5)])  # same rotation, -q
    mid = slerp(q0, q1, np.array([0.5]))
    assert np.allclose(np.abs(mid), np.abs(_quat(0.5, 0.5)), atol=1e-12)
    assert np.isclose(yaw(mid)[0], 0.5)


# --- camera frames: rodctl's renders with both ends moving ----------------------------------


@pytest.fixture(scope="module")
def scene():
    """Frames of a quasi-static rod (default camera): 4 with the gripper moving and the clamp
    fixed, then 5 with both ends moving (the clamp driven by `RodSim.move_clamp`, as the
    clamp_move event drives it). Each: (gripper, clamp, clean render, projected truth)."""
    cfg = load_config("configs/default.yaml", ["rod.engine=quasistatic", "rod.segments=30"])
    sim = RodSim.at_home(cfg.rod)
    cam = Camera(cfg.camera)

    def shot():
        g, c, line = sim.gripper_pose.copy(), sim.clamp_pose.copy(), sim.centerline()
        truth = cam.project(resample_polyline(line, cfg.camera.points))
        return g, c, cam.render(line, g, c), truth

    fixed, both = [], []
    for _ in range(4):
        assert sim.apply(np.array([0.01, 0.012, 0.06])).settled
        fixed.append(shot())
    for _ in range(5):
        assert sim.apply(np.array([0.008, 0.01, 0.05])).settled
        assert sim.move_clamp(sim.clamp_pose + np.array([0.006, -0.008, 0.04])).settled
        both.append(shot())
    return cfg, cam, fixed, both


def _camera_file(tmp_path: Path, cfg) -> Path:
    p = tmp_path / "camera.yaml"
    p.write_text(yaml.safe_dump({"camera": cfg.camera.model_dump(mode="json")}))
    return p


def _relit(cfg, shots, *, distractors: bool = False, seed: int = 0):
    """The renders on a textured, unevenly lit scene with pixel noise (`_textured` of
    tests/test_estimate.py); `distractors` adds discs of the rod's own colour to the
    background, one touching the rod beyond its tip and one beside its middle."""
    imgs = _textured(
        [s[2] for s in shots], cfg.camera, SimpleNamespace(clamp_pose=np.zeros(3)), seed
    )
    if not distractors:
        return imgs
    out = []
    for img, (_, _, _, truth) in zip(imgs, shots, strict=True):
        img = img.copy()
        tip = truth[-1] + 14.0 * (truth[-1] - truth[-4]) / np.linalg.norm(truth[-1] - truth[-4])
        mid = truth[len(truth) // 2]
        normal = np.array([-(truth[-1] - truth[0])[1], (truth[-1] - truth[0])[0]])
        side = mid + 13.0 * normal / np.linalg.norm(normal)
        for c, r in ((tip, 10), (side, 8)):
            cv2.circle(img, tuple(int(v) for v in np.round(c)), r, (200, 40, 40), -1, cv2.LINE_AA)
        out.append(img)
    return out


def _image_msg(ts, ns: int, img: np.ndarray, encoding: str = "rgb8"):
    h, w = img.shape[:2]
    ch = 1 if img.ndim == 2 else img.shape[2]
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, ns, "camera"), height=h, width=w, encoding=encoding, is_bigendian=0,
        step=ch * w, data=np.ascontiguousarray(img).reshape(-1),
    )  # fmt: skip


def _frames_bag(path: Path, shots, images, *, masks=None, mask_encoding="mono8", two=False):
    """Frames on /cam/image at t = 0.1 k, the gripper on /arm/pose (and, `two`, the clamp on
    /clamp/pose as end effector 0), masks [(t, mask)] on /cam/mask."""
    ts = _ts()
    with Writer(path, version=8) as w:
        c_img = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        c_arm = w.add_connection("/arm/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        c_clamp = w.add_connection("/clamp/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        c_mask = w.add_connection("/cam/mask", "sensor_msgs/msg/Image", typestore=ts)
        for k, ((g, c, _, _), img) in enumerate(zip(shots, images, strict=True)):
            ns = _ns(DT * k)
            w.write(c_arm, ns, ts.serialize_cdr(pose_stamped(ts, ns, g), c_arm.msgtype))
            if two:
                w.write(c_clamp, ns, ts.serialize_cdr(pose_stamped(ts, ns, c), c_clamp.msgtype))
            w.write(c_img, ns, ts.serialize_cdr(_image_msg(ts, ns, img), c_img.msgtype))
        for t, m in masks or []:
            msg = _image_msg(ts, _ns(t), m, mask_encoding)
            w.write(c_mask, _ns(t), ts.serialize_cdr(msg, c_mask.msgtype))


def _truth_masks(cfg, cam, shots):
    """Masks from the renderer's truth: the rod's coverage of each clean render >= 0.5."""
    ext = CenterlineExtractor(cfg.camera, cam, np.zeros(3))
    return [np.where(ext.coverage(s[2]) >= 0.5, 255, 0).astype(np.uint8) for s in shots]


def _errors(run_dir: Path, shots) -> np.ndarray:
    back = read_run(run_dir, images=False).records
    assert len(back) == len(shots)
    return np.array([np.sqrt(((b.extracted - s[3]) ** 2).sum(axis=1)).max()
                     for b, s in zip(back, shots, strict=True)])  # fmt: skip


def test_a_mask_topic_segments_frames_where_the_hsv_threshold_is_misled(scene, tmp_path):
    cfg, cam, shots, _ = scene
    images = _relit(cfg, shots, distractors=True)
    masks = [(DT * k + 0.004, m) for k, m in enumerate(_truth_masks(cfg, cam, shots))]
    _frames_bag(tmp_path / "bag", shots, images, masks=masks)
    common = ["--image-topic", "/cam/image", "--pose-topic", "/arm/pose",
              "--camera", str(_camera_file(tmp_path, cfg)), "--clamp-pose", "0,0,0"]  # fmt: skip
    res = _import(tmp_path / "bag", tmp_path / "r", *common, "--mask-topic", "/cam/mask")
    assert res.exit_code == 0, res.output
    assert _errors(_last_line(res), shots).max() <= 1.0
    # the same frames by colour: the rod-coloured discs are taken for rod
    hsv = _import(tmp_path / "bag", tmp_path / "r", *common)
    if hsv.exit_code == 0:
        assert _errors(_last_line(hsv), shots).max() > 2.0
    else:
        assert hsv.exit_code == 2 and "/cam/image: frame" in hsv.output, hsv.output


@pytest.mark.parametrize("case", ["size", "encoding", "missing"])
def test_a_bad_mask_exits_2_naming_the_topic_and_the_frame(scene, tmp_path, case):
    cfg, cam, shots, _ = scene
    shots = shots[:3]
    masks = _truth_masks(cfg, cam, shots)
    rows = [(DT * k, m) for k, m in enumerate(masks)]
    enc = "mono8"
    if case == "size":
        rows[1] = (DT, masks[1][:, :-2])
    elif case == "encoding":
        enc = "mono16"
    else:
        rows.pop(2)
    images = [s[2] for s in shots]
    _frames_bag(tmp_path / "bag", shots, images, masks=rows, mask_encoding=enc)
    res = _import(tmp_path / "bag", tmp_path / "r", "--image-topic", "/cam/image",
                  "--pose-topic", "/arm/pose", "--camera", str(_camera_file(tmp_path, cfg)),
                  "--clamp-pose", "0,0,0", "--mask-topic", "/cam/mask",
                  "--tolerance", "0.05")  # fmt: skip
    assert res.exit_code == 2, res.output
    needles = {
        "size": ["/cam/mask: frame 1 (t = 0.100000 s)", "638x480", "640x480"],
        "encoding": ["/cam/mask: mask 0", "'mono16'", "mono8 or 8UC1"],
        "missing": ["/cam/mask: frame 2 (t = 0.200000 s): no mask within 0.05 s"],
    }[case]
    for n in needles:
        assert n in res.output, res.output


def test_camera_frames_with_both_ends_moving_extract_from_end_0_each_frame(scene, tmp_path):
    cfg, _, _, shots = scene
    _frames_bag(tmp_path / "bag", shots, _relit(cfg, shots, seed=3), two=True)
    cam_file = str(_camera_file(tmp_path, cfg))
    args = ["--image-topic", "/cam/image", "--pose-topic", "/clamp/pose",
            "--pose-topic", "/arm/pose", "--camera", cam_file]  # fmt: skip
    res = _import(tmp_path / "bag", tmp_path / "r", *args)
    assert res.exit_code == 0, res.output
    assert _errors(_last_line(res), shots).max() <= 1.0
    back = read_run(_last_line(res), images=False).records
    for k in range(1, len(shots)):
        (g0, c0, _, _), (g, c, _, _) = shots[k - 1], shots[k]
        assert np.allclose(back[k].gripper, c, atol=1e-9)  # end 0: the clamp
        assert np.allclose(back[k].u, np.r_[c - c0, g - g0], atol=1e-9)  # q = 6: both ends
    # one end from a fixed clamp cannot follow these frames
    one = _import(tmp_path / "bag", tmp_path / "r", *args[:2], "--pose-topic", "/arm/pose",
                  "--camera", cam_file, "--clamp-pose", "0,0,0")  # fmt: skip
    assert one.exit_code == 2 and "frame 0" in one.output, one.output
    both = _import(tmp_path / "bag", tmp_path / "r", *args, "--clamp-pose", "0,0,0")
    assert both.exit_code == 2 and "leave --clamp-pose out" in both.output, both.output


def test_an_imported_camera_run_logs_its_frames_and_exports_them(scene, tmp_path):
    cfg, _, shots, _ = scene
    images = [s[2] for s in shots]
    _frames_bag(tmp_path / "bag", shots, images)
    res = _import(tmp_path / "bag", tmp_path / "r", "--image-topic", "/cam/image",
                  "--pose-topic", "/arm/pose", "--camera", str(_camera_file(tmp_path, cfg)),
                  "--clamp-pose", "0,0,0")  # fmt: skip
    assert res.exit_code == 0, res.output
    run_dir = _last_line(res)
    back = read_run(run_dir, images=True).records
    # 4 frames 0.1 s apart at the logging image rate (5 Hz): frames 0 and 2, as recorded
    logged = [r.step for r in back if r.image is not None]
    assert logged == [0, 2]
    assert np.array_equal(back[2].image, images[2])
    with (run_dir / "run.mcap").open("rb") as f:
        calib = [json.loads(m.data) for _, ch, m in make_reader(f).iter_messages()
                 if ch.topic == "/camera/calibration"]  # fmt: skip
    assert calib and calib[0]["K"][0] == pytest.approx(cfg.camera.fx)
    out = CliRunner().invoke(app, ["export", str(run_dir), "--ros2", str(tmp_path / "ros")])
    assert out.exit_code == 0, out.output
    assert "/camera/image_raw: 2 messages" in out.output


def test_an_import_cut_short_keeps_its_frames_as_an_interrupted_run(scene, tmp_path, monkeypatch):
    cfg, _, shots, _ = scene
    _frames_bag(tmp_path / "bag", shots, [s[2] for s in shots])
    real, calls = CenterlineExtractor.extract, []

    def extract(self, *a, **kw):  # Ctrl-C while the 4th frame is extracted
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return real(self, *a, **kw)

    monkeypatch.setattr(CenterlineExtractor, "extract", extract)
    with pytest.raises(RunFailed, match="cut short"):
        import_bag_images(
            tmp_path / "bag", tmp_path / "r", image_topic="/cam/image", info_topic=None,
            pose_topic="/arm/pose", camera=_camera_file(tmp_path, cfg), clamp_pose=[0, 0, 0],
            hsv_low=[170, 120, 50], hsv_high=[10, 255, 255],
        )  # fmt: skip
    (run_dir,) = (tmp_path / "r").iterdir()
    assert json.loads((run_dir / "meta.json").read_text())["status"] == "interrupted"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == summary["outcome"] == "interrupted"  # as a simulate run's
    assert summary["method"] == "recording/ros2_bag_images"
    assert len(read_run(run_dir, images=False).records) == 3
