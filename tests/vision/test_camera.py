"""The pinhole model against OpenCV, the plane inverse, field of view, handedness, rendering."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from rodctl.config import ExperimentConfig
from rodctl.config.camera import CameraConfig
from rodctl.vision import Camera
from rodctl.vision.shapes import rod_shape

POSES = [
    {},
    {"tilt_deg": 0.0},
    {"tilt_deg": 40.0, "azimuth_deg": 30.0, "look_at": (0.1, 0.2), "distance": 2.0},
    {"fx": 700.0, "fy": 650.0, "cx": 300.0, "cy": 250.0, "width": 800, "height": 600},
]


@pytest.mark.parametrize("over", POSES)
def test_project_matches_opencv_project_points(over: dict) -> None:
    cam = Camera(CameraConfig(**over))
    pts = np.random.default_rng(1).uniform([-0.2, -0.45], [0.7, 0.45], size=(500, 2))
    ours = cam.project(pts)
    obj = np.column_stack([pts, np.zeros(len(pts))])
    ref, _ = cv2.projectPoints(obj, cam.rvec, cam.tvec, cam.camera_matrix, None)
    assert np.abs(ours - ref.reshape(-1, 2)).max() < 1e-6


@pytest.mark.parametrize("over", POSES)
def test_unproject_is_the_ray_plane_intersection(over: dict) -> None:
    cam = Camera(CameraConfig(**over))
    pix = np.random.default_rng(2).uniform([0, 0], [cam.width, cam.height], size=(300, 2))
    world = cam.unproject(pix)
    # independent: ray from the camera centre through K^-1 [u v 1], rotated into the world
    rays_cam = np.linalg.solve(cam.camera_matrix, np.column_stack([pix, np.ones(len(pix))]).T)
    rays = (cam.rotation.T @ rays_cam).T
    lam = -cam.center[2] / rays[:, 2]
    expect = cam.center[None, :2] + lam[:, None] * rays[:, :2]
    assert np.abs(world - expect).max() < 1e-9
    assert np.abs(cam.project(world) - pix).max() < 1e-6


def test_default_camera_sees_the_workspace_with_margin_and_real_perspective() -> None:
    cam = Camera(CameraConfig())
    corners = np.array([[-0.2, -0.45], [0.7, -0.45], [0.7, 0.45], [-0.2, 0.45]])
    edge = np.linspace(0, 1, 50)[:, None]
    border = np.vstack(
        [c0 + edge * (c1 - c0) for c0, c1 in zip(corners, np.roll(corners, -1, 0), strict=True)]
    )
    pix = cam.project(border)
    assert pix[:, 0].min() >= 20 and pix[:, 0].max() <= cam.width - 21
    assert pix[:, 1].min() >= 20 and pix[:, 1].max() <= cam.height - 21
    near = np.diff(cam.project(corners[:2])[:, 0])[0]  # y = -0.45 edge (closer to the camera)
    far = np.diff(cam.project(corners[2:][::-1])[:, 0])[0]
    assert near / far > 1.15  # perspective, not an affine scale
    assert 15.0 <= CameraConfig().tilt_deg <= 30.0


def test_world_up_is_image_up_and_not_mirrored() -> None:
    cam = Camera(CameraConfig())
    o, x, y = cam.project(np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]]))
    assert x[0] > o[0] + 20 and abs(x[1] - o[1]) < 1e-6  # +x -> right
    assert y[1] < o[1] - 20  # +y -> up (smaller v)
    # a rod bent towards +y is drawn above the clamp's row, one bent towards -y below it
    for name, sign in (("arc", -1), ("arc_down", 1)):
        line, grip = rod_shape(name)
        r = CameraConfig().render.model_copy(update={"draw_gripper": False, "draw_clamp": False})
        img = Camera(CameraConfig(render=r)).render(line, grip, np.zeros(3))
        vs, _ = np.nonzero(img[..., 1] < 100)  # the red rod: low green
        assert np.sign(np.median(vs) - o[1]) == sign


def test_render_is_deterministic_without_rng_and_reproducible_with_seed() -> None:
    line, grip = rod_shape("s_shape")
    noisy = CameraConfig(render={"noise_std": 5.0, "random_occlusions": 2})
    a = Camera(noisy).render(line, grip, np.zeros(3))
    b = Camera(noisy).render(line, grip, np.zeros(3))
    assert np.array_equal(a, b)  # rng None: no noise, no random occluders
    c = Camera(noisy, np.random.default_rng(7)).render(line, grip, np.zeros(3))
    d = Camera(noisy, np.random.default_rng(7)).render(line, grip, np.zeros(3))
    assert np.array_equal(c, d) and not np.array_equal(a, c)
    assert a.shape == (480, 640, 3) and a.dtype == np.uint8
    assert (np.abs(c.astype(int) - a.astype(int)) > 0).mean() > 0.5  # noise over the frame


def test_default_render_is_plain_and_clean() -> None:
    cam = Camera(CameraConfig(), np.random.default_rng(0))
    line, grip = rod_shape("straight")
    img = cam.render(line, grip, np.zeros(3))
    corner = img[:40, :40].reshape(-1, 3)
    assert (corner == np.array(CameraConfig().render.background_color)).all()


def test_render_rejects_bad_shapes() -> None:
    cam = Camera(CameraConfig())
    with pytest.raises(ValueError):
        cam.render(np.zeros((5, 3)), np.zeros(3), np.zeros(3))


def test_config_rejects_unknown_keys_and_bad_values() -> None:
    with pytest.raises(ValidationError):
        CameraConfig(fov=60)
    with pytest.raises(ValidationError):
        CameraConfig(render={"rod_color": (300, 0, 0)})
    with pytest.raises(ValidationError):
        CameraConfig(render={"occlusions": [(10, 10, 5, 20)]})
    cfg = ExperimentConfig.model_validate({"camera": {"tilt_deg": 20, "render": {"blur_sigma": 1}}})
    assert cfg.camera.tilt_deg == 20 and cfg.camera.points == 100


def test_projection_jacobian_matches_finite_differences():
    from rodctl.config.camera import CameraConfig
    from rodctl.vision import Camera

    cam = Camera(CameraConfig())
    pts = np.random.default_rng(3).uniform([-0.2, -0.4], [0.7, 0.4], size=(20, 2))
    jac = cam.projection_jacobian(pts)
    h = 1e-6
    for i in range(2):
        d = np.zeros(2)
        d[i] = h
        fd = (cam.project(pts + d) - cam.project(pts - d)) / (2 * h)
        np.testing.assert_allclose(jac[:, :, i], fd, rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize(
    "render",
    [
        {"blur_sigma": 0.8},
        {"background": "checker", "blur_sigma": 1.0, "occlusions": [(-5, -5, 40, 30)]},
        {"background": "checker", "blur_sigma": 2.5, "random_occlusions": 3, "rod_width_px": 12},
    ],
)
def test_blur_near_the_drawing_equals_the_whole_frame_blur(render: dict) -> None:
    """The renderer re-blurs only the tiles near what it drew: bit for bit the whole-frame blur,
    also for a rod that leaves the image (its boxes are clipped at the border)."""
    cfg = CameraConfig(render=render)
    sharp = CameraConfig(render={**render, "blur_sigma": 0.0})
    shapes = [rod_shape("hook"), rod_shape("straight", length=1.5, clamp_pose=(-0.5, 0.1, 0.3))]
    for line, grip in shapes:
        got = Camera(cfg, np.random.default_rng(2)).render(line, grip, np.zeros(3))
        img = Camera(sharp, np.random.default_rng(2)).render(line, grip, np.zeros(3))
        assert np.array_equal(got, cv2.GaussianBlur(img, (0, 0), render["blur_sigma"]))


def test_pixel_noise_is_gaussian_fresh_each_frame_and_follows_set_noise() -> None:
    cam = Camera(CameraConfig(render={"noise_std": 5.0}), np.random.default_rng(3))
    line, grip = rod_shape("arc")
    clean = Camera(CameraConfig()).render(line, grip, np.zeros(3)).astype(int)
    frames = [cam.render(line, grip, np.zeros(3)).astype(int) - clean for _ in range(3)]
    corner = [f[:100, :100].ravel() for f in frames]  # plain background, far from saturation
    for c in corner:
        assert abs(c.mean()) < 0.1 and abs(c.std() - 5.0) < 0.1
    assert abs(np.corrcoef(corner[0], corner[1])[0, 1]) < 0.02  # frames do not repeat
    cam.set_noise(2.0)
    assert (
        abs((cam.render(line, grip, np.zeros(3)).astype(int) - clean)[:100, :100].std() - 2.0) < 0.1
    )


def test_checker_backgrounds_are_shared_only_between_equal_scenes() -> None:
    cfg = CameraConfig(render={"background": "checker"})
    a, b = Camera(cfg), Camera(cfg)
    assert a._background is b._background and not a._background.flags.writeable
    assert np.array_equal(a._background, a._draw_background())
    b.set_pose(tilt_deg=30.0)  # a bump: a new view of the board
    assert not np.array_equal(a._background, b._background)
    assert np.array_equal(b._background, b._draw_background())


@pytest.mark.parametrize(
    "render",
    [
        {"blur_sigma": 0.8, "random_occlusions": 2},
        {"noise_std": 3.0},
        {"background": "checker", "noise_std": 3.0, "blur_sigma": 1.2},
    ],
)
def test_a_frame_does_not_depend_on_the_frames_before(render: dict) -> None:
    """With blur or noise the camera draws on a kept scratch frame and restores only what the
    last frame drew: a frame must be the same after any other frame (here: another shape, a
    moved clamp, a new blur and noise) as after a frame of its own shape. Both cameras draw
    from equal generators, so the noise and random occluders line up frame by frame."""
    cfg = CameraConfig(render=render)
    line, grip = rod_shape("s_shape")
    others = [
        (rod_shape("hook"), np.zeros(3)),
        (rod_shape("straight", length=1.5, clamp_pose=(-0.5, 0.1, 0.3)), np.zeros(3)),
        (rod_shape("arc", clamp_pose=(0.02, -0.01, 0.0)), np.array([0.02, -0.01, 0.0])),
    ]
    a, b = Camera(cfg, np.random.default_rng(4)), Camera(cfg, np.random.default_rng(4))
    for (other, other_grip), clamp in others:
        for cam in (a, b):
            cam.render(line, grip, np.zeros(3))
        a.render(other, other_grip, clamp)
        b.render(line, grip, np.zeros(3))
        assert np.array_equal(a.render(line, grip, np.zeros(3)), b.render(line, grip, np.zeros(3)))
    for cam in (a, b):
        cam.set_noise(2.0, 0.6)
    a.render(others[0][0][0], others[0][0][1], np.zeros(3))
    b.render(line, grip, np.zeros(3))
    assert np.array_equal(a.render(line, grip, np.zeros(3)), b.render(line, grip, np.zeros(3)))


@pytest.mark.parametrize(
    "render",
    [{}, {"background": "checker", "occlusions": [(-5, -5, 40, 30)]}, {"noise_std": 3.0}],
)
def test_a_transient_frame_is_the_frame(render: dict) -> None:
    """A transient frame (the scratch frame itself, for a walk that extracts it at once) has
    the pixels of a kept one, whatever was drawn before it: other shapes, a moved clamp, a rod
    that leaves the image, kept frames in between."""
    cfg = CameraConfig(render=render)
    shapes = [
        (rod_shape("s_shape"), np.zeros(3)),
        (rod_shape("hook"), np.zeros(3)),
        (rod_shape("straight", length=1.5, clamp_pose=(-0.5, 0.1, 0.3)), np.zeros(3)),
        (rod_shape("arc", clamp_pose=(0.02, -0.01, 0.0)), np.array([0.02, -0.01, 0.0])),
        (rod_shape("s_shape"), np.zeros(3)),
    ]
    a, b = Camera(cfg, np.random.default_rng(5)), Camera(cfg, np.random.default_rng(5))
    for i, ((line, grip), clamp) in enumerate(shapes * 2):
        kept = b.render(line, grip, clamp)
        if i == 6:  # a kept frame between transient ones
            assert np.array_equal(a.render(line, grip, clamp), kept)
            continue
        assert np.array_equal(a.render(line, grip, clamp, transient=True), kept)
