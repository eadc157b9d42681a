"""`rodctl estimate`: offline estimation over a run or a points recording (issue #26)."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.estimate import estimate, pairs_from_run
from rodctl.recordings.points import read_points, write_points_csv, write_points_npz
from rodctl.recordings.synthetic import dual_arm_recording
from rodctl.replay import read_run

FAST = ["--set", "feature.type=bezier", "--set", "run.max_steps=30", "-q"]


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    res = CliRunner().invoke(app, ["simulate", "configs/default.yaml", *FAST, "--out", str(out)])
    assert res.exit_code in (0, 1), res.output
    return Path(res.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_estimate_on_a_simulated_run_reproduces_its_live_estimates_bit_for_bit(sim_run):
    pairs = pairs_from_run(read_run(sim_run, images=False), feature="logged")
    assert pairs.logged_J is not None and len(pairs.ds) > 5
    res = estimate(pairs, ["akf"])
    (akf,) = res.runs
    assert akf.outcome == "completed"
    assert len(akf.J) == len(pairs.logged_J)
    for k, (mine, live) in enumerate(zip(akf.J, pairs.logged_J, strict=True)):
        assert mine.tobytes() == live.tobytes(), f"pair {k} (step {pairs.steps[k]})"


@pytest.mark.slow
def test_estimate_command_on_a_run_writes_results_and_steps(sim_run, tmp_path):
    out = tmp_path / "est"
    res = CliRunner().invoke(
        app,
        ["estimate", str(sim_run), "-e", "akf", "-e", "broyden", "--out", str(out), "--no-plots"],
    )
    assert res.exit_code == 0, res.output
    assert res.stdout.strip().splitlines()[-1] == str(out)
    rows = list(csv.DictReader((out / "results.csv").open()))
    names = [r["estimator"] for r in rows]
    assert names == ["zero_motion", "hindsight_ls", "akf", "broyden"]
    assert all(r["outcome"] in ("reference", "completed") for r in rows)
    steps = list(csv.reader((out / "steps.csv").open()))
    assert steps[0] == ["step", *names]
    assert len(steps) - 1 == int(rows[2]["updates"])


def test_a_two_end_points_recording_reads_back_and_estimates(tmp_path):
    rec = dual_arm_recording(150, seed=2, points=8)
    path = write_points_csv(rec, tmp_path / "rec.csv")
    back = read_points(path)
    assert np.array_equal(back.points, rec.points) and np.array_equal(back.poses, rec.poses)
    npz = read_points(write_points_npz(rec, tmp_path / "rec.npz"))
    assert np.array_equal(npz.points, rec.points) and npz.q == 6
    out = tmp_path / "est"
    res = CliRunner().invoke(
        app,
        [
            "estimate",
            str(path),
            "-e",
            "broyden",
            "-e",
            "windowed_ls",
            "--scaled",
            "-o",
            str(out),
            "--no-plots",
        ],
    )
    assert res.exit_code == 0, res.output
    rows = {r["estimator"]: r for r in csv.DictReader((out / "results.csv").open())}
    assert rows["broyden"]["outcome"] == rows["windowed_ls"]["outcome"] == "completed"
    assert int(rows["broyden"]["updates"]) == 150 - 60  # J_0 from the first 10 q pairs
    assert float(rows["windowed_ls"]["ratio_to_zero_motion"]) < 1.0


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("t,x0,y0,x1,y1\n0,0,0,1,0\n", "e0_x"),
        (
            "t,x0,y0,x1,y1,e0_x,e0_y,e0_theta\n0,0,0,1,0,0,0,0\n0,0,0,1,0,0,0,0\n0,0,0,1,0,0,0,0\n",
            "frame 1: t",
        ),
        ("t,x0,y0,x1,y1,e0_x,e0_y,e0_theta,zz\n", "column 'zz'"),
        (
            "t,x0,y0,x1,y1,e0_x,e0_y,e0_theta\n0,0,0,1,0,0,0,0\n1,0,a,1,0,0,0,0\n",
            "line 3 (frame 1), column y0: 'a' is not a number",
        ),
    ],
)
def test_a_bad_points_file_exits_2_naming_the_column_or_frame(tmp_path, text, needle):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    res = CliRunner().invoke(app, ["estimate", str(path)])
    assert res.exit_code == 2
    assert needle in res.output and "bad.csv" in res.output
    assert "Traceback" not in res.output


@pytest.mark.slow
def test_an_imported_recording_replays_and_estimates_like_the_file(tmp_path):
    rec = dual_arm_recording(90, seed=4, points=6)
    path = write_points_csv(rec, tmp_path / "arm.csv")
    runner = CliRunner()
    res = runner.invoke(app, ["import", str(path), "--out", str(tmp_path / "runs")])
    assert res.exit_code == 0, res.output
    run_dir = Path(res.stdout.strip().splitlines()[-1])
    assert {"config.yaml", "meta.json", "summary.json", "run.mcap"} <= {
        p.name for p in run_dir.iterdir()
    }
    run = read_run(run_dir, images=False)
    assert len(run.records) == 91 and run.status == "completed"
    assert np.array_equal(run.records[5].centerline, rec.points[5])
    assert np.asarray(run.records[5].u).shape == (6,)
    res = runner.invoke(app, ["replay", str(run_dir), "--no-figures"])
    assert res.exit_code == 0, res.output
    assert (run_dir / "run.rrd").is_file()
    # Nothing to re-run: --verify says so in one line instead of refusing the config.
    res = runner.invoke(app, ["replay", str(run_dir), "--verify", "--no-figures"])
    assert res.exit_code == 2 and "imported recording" in res.output, res.output
    from rodctl.estimate import pairs_from_recording

    a = estimate(pairs_from_run(run), ["broyden"])
    b = estimate(pairs_from_recording(read_points(path)), ["broyden"])
    assert a.runs[0].errors.tobytes() == b.runs[0].errors.tobytes()


def test_import_of_a_bad_file_exits_2(tmp_path):
    res = CliRunner().invoke(app, ["import", str(tmp_path / "missing.csv")])
    assert res.exit_code == 2 and "missing.csv" in res.output


_CAMERA = str(Path(__file__).resolve().parents[1] / "configs" / "default.yaml")


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["{dir}", "--poses", "p.csv", "--camera", _CAMERA, "--clamp-pose", "0,0,nan"],
         "--clamp-pose 0,0,nan: give 3 comma-separated finite numbers"),
        (["{dir}", "--poses", "p.csv", "--camera", _CAMERA, "--hsv-low", "300,0,0"],
         "H = 300 is outside 0-180"),
        (["{dir}", "--poses", "p.csv", "--camera", _CAMERA, "--hsv-high", "10,-1,255"],
         "S = -1 is outside 0-255"),
        (["{dir}/v.avi", "--poses", "p.csv", "--fps", "0"], "0.0 is not a positive finite"),
        (["{dir}/v.avi", "--poses", "p.csv", "--fps", "10", "--frame-times", "t.csv"],
         "--fps and --frame-times: give one of them"),
        (["{dir}", "--poses", "p.csv", "--camera", _CAMERA, "--fps", "10"],
         "--fps: frame times of a video"),
        (["{dir}", "--points-topic", "/pts", "--pose-topic", "/grip", "--pose-topic", "/grip"],
         "--pose-topic /grip /grip: each end's own; one is given twice"),
        (["{dir}", "--tolerance", "inf"], "inf is not a finite number"),
        (["{dir}/twice.csv"], "column t is named twice"),
        (["{dir}/text.npz"], "not a NumPy .npz archive"),
        (["{dir}/object.npz"], "(object arrays; ValueError)"),
        (["{dir}/complex.npz"], "array 'points' is complex128, not real numbers"),
        (["{dir}/column.npz"], "array 't' has shape (5, 1); one time per frame"),
        (["/dev/null"], "/dev/null: not a regular file"),
    ],
)  # fmt: skip
def test_import_refuses_option_values_and_inputs_it_cannot_use(tmp_path, args, needle):
    """Found by a new-user trial: each was accepted and then blamed on the frames (the rod not
    visible, lost), or silently used one way (--fps beside --frame-times, a pose topic twice
    as a second arm, one of two t columns)."""
    (tmp_path / "twice.csv").write_text("t,x0,y0,t\n0,0,0,0\n")
    (tmp_path / "text.npz").write_text("not an archive")
    pts, poses = np.zeros((5, 3, 2)), np.zeros((5, 3))
    np.savez(tmp_path / "object.npz", t=np.array([1, "a"], dtype=object), points=pts, poses=poses)
    np.savez(tmp_path / "complex.npz", t=np.arange(5.0), points=pts + 0j, poses=poses)
    np.savez(tmp_path / "column.npz", t=np.arange(5.0)[:, None], points=pts, poses=poses)
    res = CliRunner().invoke(app, ["import", *[a.format(dir=tmp_path) for a in args]])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    assert needle in " ".join(res.output.split()), res.output


# --- export to a ROS 2 bag (shares the simulated run above) -------------------------------


@pytest.mark.slow
def test_export_of_a_run_cut_short_needs_recover_and_then_writes_its_whole_steps(sim_run, tmp_path):
    """The refusal names the option that reads a log whose writer never finished, and export
    takes it (a new-user trial found it pointing to `replay --recover`, which export lacked)."""
    cut = tmp_path / "cut"
    cut.mkdir()
    data = (sim_run / "run.mcap").read_bytes()
    (cut / "run.mcap").write_bytes(data[: len(data) // 2])
    res = CliRunner().invoke(app, ["export", str(cut), "--ros2", str(tmp_path / "a")])
    assert res.exit_code == 2 and "export --recover" in " ".join(res.output.split())
    res = CliRunner().invoke(app, ["export", str(cut), "--ros2", str(tmp_path / "b"), "--recover"])
    assert res.exit_code == 0, res.output
    steps = len(read_run(cut, recover=True, images=False).records)
    assert 0 < steps < len(read_run(sim_run, images=False).records)
    assert f"/gripper/pose: {steps} messages" in res.output


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_export_writes_a_ros2_bag_that_rosbags_reads_back(sim_run, tmp_path, storage):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag = tmp_path / f"bag-{storage}"
    res = CliRunner().invoke(
        app, ["export", str(sim_run), "--ros2", str(bag), "--storage", storage]
    )
    assert res.exit_code == 0, res.output
    run = read_run(sim_run, images=True)
    frames = [r for r in run.records if r.image is not None]
    assert frames
    got: dict[str, list] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for conn, t_ns, raw in reader.messages():
            got.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    assert len(got["/gripper/pose"]) == len(got["/rod/centerline"]) == len(run.records)
    assert len(got["/camera/image_raw"]) == len(got["/camera/camera_info"]) == len(frames)
    for rec, (_, pose) in zip(run.records, got["/gripper/pose"], strict=True):
        o = pose.pose.orientation
        theta = 2 * np.arctan2(o.z, o.w)
        assert [pose.pose.position.x, pose.pose.position.y] == list(rec.gripper[:2])
        assert abs(np.angle(np.exp(1j * (theta - rec.gripper[2])))) < 1e-12
    last = got["/rod/centerline"][-1][1].markers[0]
    pts = np.array([[p.x, p.y] for p in last.points])
    assert np.array_equal(pts, run.records[-1].centerline)
    img = got["/camera/image_raw"][0][1]
    assert img.encoding == "rgb8"
    pixels = np.asarray(img.data).reshape(img.height, img.width, 3)
    assert np.array_equal(pixels, frames[0].image)
    info = got["/camera/camera_info"][0][1]
    assert (
        info.k[0] > 0 and info.k[8] == 1.0 and (info.width, info.height) == (img.width, img.height)
    )


@pytest.mark.slow
def test_export_refuses_an_existing_bag_folder(sim_run, tmp_path):
    res = CliRunner().invoke(app, ["export", str(sim_run), "--ros2", str(tmp_path)])
    assert res.exit_code == 2 and "exists already" in res.output


# --- import of tracked points and poses from a ROS 2 bag -----------------------------------


@pytest.mark.slow
def test_a_bag_exported_from_a_run_imports_back_to_the_same_shapes_and_poses(sim_run, tmp_path):
    run = read_run(sim_run, images=False)
    for storage in ("mcap", "sqlite3"):
        bag = tmp_path / f"bag-{storage}"
        runner = CliRunner()
        assert (
            runner.invoke(
                app, ["export", str(sim_run), "--ros2", str(bag), "--storage", storage]
            ).exit_code
            == 0
        )
        res = runner.invoke(
            app,
            ["import", str(bag), "--points-topic", "/rod/centerline", "--pose-topic",
             "/gripper/pose", "-o", str(tmp_path / storage)],
        )  # fmt: skip
        assert res.exit_code == 0, res.output
        back = read_run(Path(res.stdout.strip().splitlines()[-1]), images=False)
        assert len(back.records) == len(run.records)
        for a, b in zip(run.records, back.records, strict=True):
            assert np.array_equal(a.centerline, b.centerline)
            assert np.array_equal(a.gripper[:2], b.gripper[:2])
            assert abs(a.gripper[2] - b.gripper[2]) < 1e-12
            assert abs((a.sim_time - run.records[0].sim_time) - b.sim_time) < 1e-8


def _bag(path: Path, frames: list[tuple[float, np.ndarray]], poses: list[tuple[float, list]]):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    from rodctl.recordings.ros2 import line_marker, pose_stamped

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(path, version=8) as w:
        c_pts = w.add_connection(
            "/tracker/points", "visualization_msgs/msg/MarkerArray", typestore=ts
        )
        c_pose = w.add_connection("/arm/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for t, xy in frames:
            ns = int(round(t * 1e9)) + 10**18
            msg = ts.types["visualization_msgs/msg/MarkerArray"](markers=[line_marker(ts, ns, xy)])
            w.write(c_pts, ns, ts.serialize_cdr(msg, c_pts.msgtype))
        for t, pose in poses:
            ns = int(round(t * 1e9)) + 10**18
            msg = pose_stamped(ts, ns, np.array(pose))
            w.write(c_pose, ns, ts.serialize_cdr(msg, c_pose.msgtype))


def _import(bag: Path, out: Path, tol: str = "0.2"):
    return CliRunner().invoke(
        app,
        ["import", str(bag), "--points-topic", "/tracker/points", "--pose-topic", "/arm/pose",
         "--tolerance", tol, "-o", str(out)],
    )  # fmt: skip


def test_bag_poses_are_interpolated_at_the_frame_times(tmp_path):
    line = np.array([[0.0, 0.0], [0.1, 0.02], [0.2, 0.0]])
    frames = [(0.1 * k, line + 0.001 * k) for k in range(12)]
    # the pose moves linearly in time, sampled at 7 Hz from before the first frame
    poses = [(t, [0.3 + 0.05 * t, -0.1 * t, 0.2 * t]) for t in np.arange(-0.05, 1.3, 1 / 7)]
    _bag(tmp_path / "bag", frames, poses)
    res = _import(tmp_path / "bag", tmp_path / "runs")
    assert res.exit_code == 0, res.output
    run = read_run(Path(res.stdout.strip().splitlines()[-1]), images=False)
    assert len(run.records) == 12
    for k, r in enumerate(run.records):
        t = 0.1 * k
        assert np.allclose(r.gripper, [0.3 + 0.05 * t, -0.1 * t, 0.2 * t], atol=1e-9)
        assert np.array_equal(r.centerline, frames[k][1])


@pytest.mark.slow
@pytest.mark.parametrize(
    ("pose_times", "needle"),
    [
        (np.arange(5.0, 6.0, 0.1), "do not overlap"),
        (np.r_[np.arange(0.0, 0.45, 0.1), np.arange(0.95, 1.3, 0.1)], "t = 0.500000 s"),
    ],
)
def test_bag_poses_that_miss_the_frames_exit_2_naming_the_time(tmp_path, pose_times, needle):
    line = np.array([[0.0, 0.0], [0.1, 0.0]])
    _bag(
        tmp_path / "bag", [(0.1 * k, line) for k in range(12)], [(t, [0, 0, 0]) for t in pose_times]
    )
    res = _import(tmp_path / "bag", tmp_path / "runs")
    assert res.exit_code == 2, res.output
    assert needle in res.output and "/arm/pose" in res.output


@pytest.mark.slow
def test_a_bag_frame_with_another_point_count_exits_2_naming_it(tmp_path):
    frames = [(0.1 * k, np.zeros((3 if k != 4 else 2, 2))) for k in range(8)]
    _bag(tmp_path / "bag", frames, [(0.05 * k, [0, 0, 0]) for k in range(20)])
    res = _import(tmp_path / "bag", tmp_path / "runs")
    assert res.exit_code == 2 and "/tracker/points" in res.output
    # On the run's clock (t = 0 at the first frame), not the bag's stamps (10^9 s here)
    assert "frame 4 (t = 0.400000 s) has 2 points, frame 0 has 3" in res.output
    # Too few points in frame 0 is not compared with frame 0
    frames = [(0.1 * k, np.zeros((1, 2))) for k in range(8)]
    _bag(tmp_path / "bag1", frames, [(0.05 * k, [0, 0, 0]) for k in range(20)])
    res = _import(tmp_path / "bag1", tmp_path / "runs")
    assert res.exit_code == 2 and "frame 0 (t = 0.000000 s) has 1 points (need" in res.output


# --- camera images from a bag: segmentation and extraction on a textured scene ------------


def _textured(frames, cam_cfg, header, seed=0):
    """rodctl's frames re-lit on a textured background: the rod's coverage (exact, from the
    renderer's known colours) composited over smooth colour noise, under a left-to-right
    lighting gradient, plus pixel noise."""
    import cv2

    from rodctl.vision.camera import Camera
    from rodctl.vision.centerline import CenterlineExtractor

    cam = Camera(cam_cfg)
    ext = CenterlineExtractor(cam_cfg, cam, header.clamp_pose)
    rng = np.random.default_rng(seed)
    h, w = cam.height, cam.width
    tex = rng.uniform(0, 255, (h // 8, w // 8, 3)).astype(np.float32)
    tex = cv2.resize(cv2.GaussianBlur(tex, (0, 0), 1.5), (w, h), interpolation=cv2.INTER_CUBIC)
    tex = 0.5 * tex + 90.0
    light = (0.6 + 0.5 * np.linspace(0.0, 1.0, w))[None, :, None]
    out = []
    for img in frames:
        a = ext.coverage(img)[..., None].clip(0.0, 1.0)
        mix = (a * np.array([200.0, 40.0, 40.0]) + (1 - a) * tex) * light
        out.append((mix + rng.normal(0.0, 4.0, mix.shape)).clip(0, 255).astype(np.uint8))
    return out


def _image_bag(path, storage, run, images, K, blank_at=None):
    import cv2
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from rodctl.logs.codec import log_time_ns
    from rodctl.recordings.ros2 import _header, pose_stamped

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    kind = "sensor_msgs/msg/CompressedImage" if storage == "mcap" else "sensor_msgs/msg/Image"
    with Writer(path, version=8, storage_plugin=plugin) as w:
        c_img = w.add_connection("/cam/image", kind, typestore=ts)
        c_info = w.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        c_pose = w.add_connection("/arm/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for r in run.records:
            ns = int(log_time_ns(r.sim_time))
            w.write(c_pose, ns, ts.serialize_cdr(pose_stamped(ts, ns, r.gripper), c_pose.msgtype))
        for k, (r, img) in enumerate(images):
            ns = int(log_time_ns(r.sim_time))
            if k == blank_at:
                img = np.full_like(img, 120)
            hd = _header(ts, ns, "camera")
            if kind.endswith("CompressedImage"):
                ok, png = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
                msg = T[kind](header=hd, format="png", data=png.reshape(-1))
            else:
                h, wd = img.shape[:2]
                msg = T[kind](header=hd, height=h, width=wd, encoding="rgb8", is_bigendian=0,
                              step=3 * wd, data=img.reshape(-1))  # fmt: skip
            w.write(c_img, ns, ts.serialize_cdr(msg, kind))
            info = T["sensor_msgs/msg/CameraInfo"](
                header=hd, height=img.shape[0], width=img.shape[1], distortion_model="plumb_bob",
                d=np.zeros(5), k=K.reshape(-1), r=np.eye(3).reshape(-1),
                p=np.hstack([K, np.zeros((3, 1))]).reshape(-1), binning_x=0, binning_y=0,
                roi=T["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
            )  # fmt: skip
            w.write(c_info, ns, ts.serialize_cdr(info, c_info.msgtype))


def _image_import(bag, out, clamp, cfg_path):
    return CliRunner().invoke(
        app,
        ["import", str(bag), "--image-topic", "/cam/image", "--camera-info-topic", "/cam/info",
         "--pose-topic", "/arm/pose", "--camera", str(cfg_path),
         "--clamp-pose", ",".join(repr(float(v)) for v in clamp), "--tolerance", "1",
         "-o", str(out)],
    )  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_bag_images_segment_and_extract_within_a_pixel_of_the_truth(sim_run, tmp_path, storage):
    import yaml

    from rodctl.config.camera import CameraConfig
    from rodctl.vision.camera import Camera

    run = read_run(sim_run, images=True)
    cam_cfg = CameraConfig.model_validate(yaml.safe_load(run.header.config_yaml)["camera"])
    framed = [r for r in run.records if r.image is not None]
    images = list(
        zip(framed, _textured([r.image for r in framed], cam_cfg, run.header), strict=True)
    )
    bag = tmp_path / "bag"
    _image_bag(bag, storage, run, images, Camera(cam_cfg).camera_matrix)
    res = _image_import(bag, tmp_path / "runs", run.header.clamp_pose, sim_run / "config.yaml")
    assert res.exit_code == 0, res.output
    back = read_run(Path(res.stdout.strip().splitlines()[-1]), images=False)
    assert len(back.records) == len(framed) >= 3
    for r, b in zip(framed, back.records, strict=True):
        err = np.sqrt(((b.extracted - r.projected_truth) ** 2).sum(axis=1))
        assert err.max() <= 1.0, (r.step, err.max())
        assert np.allclose(b.gripper, r.gripper, atol=1e-9)  # synced at the frame's own time


@pytest.mark.slow
def test_a_bag_frame_without_the_rod_exits_2_naming_it(sim_run, tmp_path):
    import yaml

    from rodctl.config.camera import CameraConfig
    from rodctl.vision.camera import Camera

    run = read_run(sim_run, images=True)
    cam_cfg = CameraConfig.model_validate(yaml.safe_load(run.header.config_yaml)["camera"])
    framed = [r for r in run.records if r.image is not None][:3]
    images = list(
        zip(framed, _textured([r.image for r in framed], cam_cfg, run.header), strict=True)
    )
    _image_bag(tmp_path / "bag", "sqlite3", run, images, Camera(cam_cfg).camera_matrix, blank_at=1)
    res = _image_import(
        tmp_path / "bag", tmp_path / "runs", run.header.clamp_pose, sim_run / "config.yaml"
    )
    assert res.exit_code == 2, res.output
    assert "/cam/image: frame 1" in res.output and "no rod" in res.output


@pytest.mark.slow
def test_an_image_import_cut_short_keeps_the_frames_it_converted(sim_run, tmp_path, monkeypatch):
    import yaml

    from rodctl.config.camera import CameraConfig
    from rodctl.errors import RunFailed
    from rodctl.recordings.importer import import_bag_images
    from rodctl.vision import centerline
    from rodctl.vision.camera import Camera

    run = read_run(sim_run, images=True)
    cam_cfg = CameraConfig.model_validate(yaml.safe_load(run.header.config_yaml)["camera"])
    framed = [r for r in run.records if r.image is not None][:6]
    images = list(
        zip(framed, _textured([r.image for r in framed], cam_cfg, run.header), strict=True)
    )
    _image_bag(tmp_path / "bag", "sqlite3", run, images, Camera(cam_cfg).camera_matrix)
    real, calls = centerline.CenterlineExtractor.extract, []

    def ctrl_c_at_the_fifth(self, image, gripper_pose=None):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return real(self, image, gripper_pose)

    monkeypatch.setattr(centerline.CenterlineExtractor, "extract", ctrl_c_at_the_fifth)
    with pytest.raises(RunFailed, match="cut short .*4 of 6 frames") as err:
        import_bag_images(
            tmp_path / "bag", tmp_path / "runs", image_topic="/cam/image", info_topic="/cam/info",
            pose_topic="/arm/pose", camera=sim_run / "config.yaml",
            clamp_pose=list(run.header.clamp_pose), hsv_low=[170, 120, 50],
            hsv_high=[10, 255, 255], tolerance=1.0,
        )  # fmt: skip
    (run_dir,) = (tmp_path / "runs").iterdir()
    assert str(run_dir) in str(err.value)
    assert len(read_run(run_dir, images=False).records) == 4


# --- an image folder with a CSV of poses -----------------------------------------------------


def _folder(tmp_path, sim_run, missing_at=None):
    import cv2
    import yaml

    from rodctl.config.camera import CameraConfig

    run = read_run(sim_run, images=True)
    cam_cfg = CameraConfig.model_validate(yaml.safe_load(run.header.config_yaml)["camera"])
    framed = [r for r in run.records if r.image is not None]
    folder = tmp_path / "frames"
    folder.mkdir()
    lines = ["file,t"]
    for k, (r, img) in enumerate(
        zip(framed, _textured([r.image for r in framed], cam_cfg, run.header, seed=1), strict=True)
    ):
        name = f"f{k:03d}.png"
        if k != missing_at:
            cv2.imwrite(str(folder / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        lines.append(f"{name},{float(r.sim_time)!r}")
    (folder / "frames.csv").write_text("\n".join(lines) + "\n")
    poses = tmp_path / "poses.csv"
    rows = ["t,x,y,theta"] + [",".join(repr(float(v)) for v in (r.sim_time, *r.gripper))
                              for r in run.records]  # fmt: skip
    poses.write_text("\n".join(rows) + "\n")
    args = ["import", str(folder), "--poses", str(poses), "--camera", str(sim_run / "config.yaml"),
            "--clamp-pose", ",".join(repr(float(v)) for v in run.header.clamp_pose),
            "--tolerance", "1", "-o", str(tmp_path / "runs")]  # fmt: skip
    return run, framed, args


@pytest.mark.slow
def test_an_image_folder_with_poses_imports_within_a_pixel_of_the_truth(sim_run, tmp_path):
    run, framed, args = _folder(tmp_path, sim_run)
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    back = read_run(Path(res.stdout.strip().splitlines()[-1]), images=False)
    assert len(back.records) == len(framed) >= 3
    for r, b in zip(framed, back.records, strict=True):
        err = np.sqrt(((b.extracted - r.projected_truth) ** 2).sum(axis=1))
        assert err.max() <= 1.0, (r.step, err.max())
        assert np.allclose(b.gripper, r.gripper, atol=1e-9)


@pytest.mark.slow
def test_an_image_folder_missing_a_frame_file_exits_2_naming_it(sim_run, tmp_path):
    _, _, args = _folder(tmp_path, sim_run, missing_at=1)
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2 and "f001.png" in res.output and "frames.csv" in res.output


DOCS_CSV = """# units: m
t,x0,y0,x1,y1,x2,y2,e0_x,e0_y,e0_theta,e1_x,e1_y,e1_theta
0.0,0.000,0.000,0.280,0.011,0.560,0.000,0.000,0.000,0.00,0.560,0.000,0.00
0.1,0.004,0.002,0.283,0.015,0.566,0.001,0.004,0.002,0.01,0.566,0.001,-0.02
0.2,0.008,0.004,0.286,0.019,0.571,0.002,0.008,0.004,0.02,0.571,0.002,-0.04
"""


def test_a_recording_too_short_for_the_default_init_names_the_default_and_the_fix(tmp_path):
    # docs/recordings.md's 3-frame example: the user passed no --init.
    path = tmp_path / "three.csv"
    path.write_text(DOCS_CSV)
    res = CliRunner().invoke(app, ["estimate", str(path)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    msg = " ".join(res.output.split())
    assert "three.csv: --init (not given) defaults to 10 q = 60 pairs" in msg
    assert "3 frames, i.e. 2 pairs" in msg
    assert "at least 8 with --init 6, 62 without --init" in msg


def test_a_second_estimate_never_overwrites_the_first(tmp_path):
    path = write_points_csv(dual_arm_recording(70, seed=3, points=4), tmp_path / "rec.csv")
    runner = CliRunner()
    args = ["estimate", str(path), "-e", "broyden", "--no-plots"]
    # The default folder: a second estimate goes to the next numbered one.
    res = runner.invoke(app, args)
    assert res.exit_code == 0 and res.stdout.splitlines()[-1] == str(tmp_path / "rec-estimate")
    first = (tmp_path / "rec-estimate" / "results.csv").read_bytes()
    res = runner.invoke(app, [*args, "-e", "windowed_ls"])
    assert res.exit_code == 0 and res.stdout.splitlines()[-1] == str(tmp_path / "rec-estimate-2")
    assert (tmp_path / "rec-estimate" / "results.csv").read_bytes() == first
    assert "windowed_ls" in (tmp_path / "rec-estimate-2" / "results.csv").read_text()
    # A folder named by --out: refused (exit 2) unless --force, which leaves no earlier plot.
    out = tmp_path / "rec-estimate"
    (out / "errors.png").write_bytes(b"an earlier estimate's plot")
    res = runner.invoke(app, [*args, "-o", str(out)])
    assert res.exit_code == 2 and "--force" in res.output and "--out" in res.output
    assert (out / "results.csv").read_bytes() == first
    res = runner.invoke(app, [*args, "-o", str(out), "--force"])
    assert res.exit_code == 0, res.output
    assert (out / "results.csv").is_file() and not (out / "errors.png").exists()


def test_checkpoint_options_are_refused_where_they_cannot_apply(tmp_path):
    """--checkpoint with a feature that takes none would be ignored: refused. An encoder that
    does not fit the recording is refused with what estimate takes (--checkpoint), not the
    config keys (feature.checkpoint, --set) of a run's advice."""
    path = write_points_csv(dual_arm_recording(70, seed=3, points=4), tmp_path / "rec.csv")
    runner = CliRunner()
    res = runner.invoke(app, ["estimate", str(path), "--checkpoint", str(tmp_path / "no.npz")])
    assert res.exit_code == 2 and "give --feature autoencoder" in res.output, res.output
    res = runner.invoke(app, ["estimate", str(path), "--feature", "autoencoder"])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    msg = " ".join(res.output.split())
    assert "the packaged encoder does not fit this input (4 points)" in msg, msg
    assert "give --checkpoint an encoder.npz trained for 4 points" in msg
    assert "feature.checkpoint" not in msg and "--set feature" not in msg
    assert not (tmp_path / "rec-estimate").exists()


def test_an_init_below_q_on_a_long_recording_says_only_to_raise_it(tmp_path):
    """Found by a new-user trial: --init 1 on 151 frames advised 'record more frames (at
    least 3)'."""
    path = write_points_csv(dual_arm_recording(40, seed=3, points=4), tmp_path / "rec.csv")
    res = CliRunner().invoke(app, ["estimate", str(path), "--init", "1", "--no-plots"])
    assert res.exit_code == 2, res.output
    msg = " ".join(res.output.split())
    assert "J_0 needs at least q = 6 pairs" in msg and "pass --init N with 6 <= N < 40" in msg
    assert "record more frames" not in msg


def test_a_checkpoint_that_is_not_an_encoder_file_is_named_as_such(tmp_path):
    path = write_points_csv(dual_arm_recording(40, seed=3, points=4), tmp_path / "rec.csv")
    args = ["estimate", str(path), "--feature", "autoencoder", "--checkpoint", str(path)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    assert "not an encoder checkpoint" in res.output and "torch" not in res.output


def test_a_recording_without_a_finite_hindsight_error_warns_nothing(tmp_path):
    """Found by a new-user trial: a short dual-arm run printed numpy's 'All-NaN slice
    encountered' from the hindsight reference; it is NaN in results.csv, without a warning."""
    from rodctl.estimate import EstimateResult, Pairs, write_plots

    n = 4
    pairs = Pairs(
        init_ds=np.zeros((3, 2)), init_dr=np.eye(3), ds=np.ones((n, 2)), dr=np.ones((n, 3)),
        steps=np.arange(n), feature="points",
    )  # fmt: skip
    result = EstimateResult(
        pairs=pairs, runs=[], zero=np.ones(n), hindsight=np.full(n, np.nan), J_ls=None,
        settings={},
    )  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rows = result.rows()
        write_plots(result, tmp_path)
    assert np.isnan(rows[1]["median_error"])
