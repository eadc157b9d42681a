"""The eye-to-hand pinhole camera: geometry (plane <-> pixels) and a fast renderer.

Why a homography: the rod lives on the world plane z = 0, so the full pinhole model
``pixel ~ K [R | t] (x, y, 0, 1)`` collapses to a 3x3 homography ``H = K [r1 r2 t]``. Projection
and its exact inverse onto the plane are then one small matrix product each, which matters because
the closed loop projects and renders every control step. The same `K`, `R`, `t` are exposed
(`camera_matrix`, `rvec`, `tvec`) so that the model can be checked against OpenCV's own
`cv2.projectPoints`.

Conventions: world frame y up (the rod's plane), camera frame as in OpenCV (x right, y down, z along
the optical axis), pixel centres at integer coordinates (OpenCV's drawing convention), so pixel
(0, 0) covers [-0.5, 0.5]^2. At tilt 0 the image is an upright, non-mirrored view of the plane:
u grows with world x, v grows with world -y.

Why OpenCV for drawing: `cv2.polylines(..., LINE_AA, shift=4)` draws a thick anti-aliased rod at
1/16 px resolution in about 0.1 ms; its measured centre-line bias is below 0.2 px
(tests/vision/test_render.py), which a hand-written rasteriser would have to beat in both speed and
accuracy to be worth owning.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from rodctl import fixedla as fla
from rodctl.config.camera import CameraConfig

#: Sub-pixel bits for OpenCV drawing calls: coordinates are passed in units of 1/16 px.
_SHIFT = 4
_SCALE = float(1 << _SHIFT)

# Fixture outlines in the frame of their pose (metres): ``along`` the pose's tangent, ``lateral``
# to its left. The clamp block sits behind the clamped end; the gripper's palm sits beyond the
# rod's end and two fingers hold the last 2.5 cm from either side. The rod is drawn over both (as
# if held from below), so its whole length stays visible to the extractor.
_CLAMP_BOXES = (((-0.045, 0.0), (-0.025, 0.025)),)
_GRIPPER_BOXES = (
    ((0.006, 0.046), (-0.03, 0.03)),  # palm
    ((-0.025, 0.006), (0.007, 0.015)),  # left finger
    ((-0.025, 0.006), (-0.015, -0.007)),  # right finger
)


def _as_points(points: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (M, 2), got {arr.shape}")
    return arr


def principal_point(cfg: CameraConfig) -> tuple[float, float]:
    """(cx, cy) in pixels: `camera.cx`/`cy`, or the image centre where they are null."""
    cx = (int(cfg.width) - 1) / 2.0 if cfg.cx is None else float(cfg.cx)
    cy = (int(cfg.height) - 1) / 2.0 if cfg.cy is None else float(cfg.cy)
    return cx, cy


class Camera:
    """A calibrated pinhole camera over the rod's plane, and a renderer of the scene it sees.

    Args:
        cfg: the camera config (intrinsics, pose, rendering options).
        rng: source of the per-frame randomness (pixel noise, random occluders). None = neither
            is drawn, whatever the config says, so a camera without an rng is deterministic.

    Attributes:
        width, height: image size in pixels.
        camera_matrix: (3, 3) intrinsics K.
        rotation: (3, 3) world -> camera rotation R.
        translation: (3,) world -> camera translation t (camera frame, metres).
        center: (3,) camera centre in the world frame (metres).
        homography: (3, 3) plane (x, y, 1) -> pixel (u, v, 1) up to scale.
    """

    def __init__(self, cfg: CameraConfig, rng: np.random.Generator | None = None) -> None:
        self.cfg = cfg
        self.rng = rng
        self.width = int(cfg.width)
        self.height = int(cfg.height)
        cx, cy = principal_point(cfg)
        self.camera_matrix = np.array([[cfg.fx, 0.0, cx], [0.0, cfg.fy, cy], [0.0, 0.0, 1.0]])
        self._set_extrinsics(cfg)

    def _set_extrinsics(self, cfg: CameraConfig) -> None:
        """Pose, homography and background from `cfg.look_at/distance/tilt_deg/azimuth_deg`."""
        # Camera pose: centre at `distance` from `look_at`, tilted towards world -y by tilt_deg,
        # the whole rig turned by azimuth_deg about world z. Rows of R are the camera axes
        # expressed in the world frame; at tilt 0: x_c = +x, y_c = -y, z_c = -z (det R = +1).
        # Fixed-order arithmetic (rodctl.fixedla, math's scalar functions) instead of BLAS and
        # LAPACK: the homography feeds every pixel of every frame, so its last bits must not
        # depend on the machine's BLAS kernel (docs/reproducibility.md).
        tilt = math.radians(cfg.tilt_deg)
        az = math.radians(cfg.azimuth_deg)
        ca, sa = math.cos(az), math.sin(az)
        rz = np.array([[ca, -sa, 0.0], [sa, ca, 0.0], [0, 0, 1.0]])
        to_camera = fla.matvec(rz, np.array([0.0, -math.sin(tilt), math.cos(tilt)]))
        self.center = np.array([cfg.look_at[0], cfg.look_at[1], 0.0]) + cfg.distance * to_camera
        z_c = -to_camera  # look_at -> centre, reversed
        x_c = rz[:, 0].copy()
        y_c = np.cross(z_c, x_c)
        self.rotation = np.stack([x_c, y_c, z_c])
        self.translation = -fla.matvec(self.rotation, self.center)
        self.homography = fla.matmul(
            self.camera_matrix,
            np.column_stack([self.rotation[:, 0], self.rotation[:, 1], self.translation]),
        )
        self.homography /= self.homography[2, 2]
        self._homography_inv = fla.inv3(self.homography)
        self._background = self._make_background()

    # ------------------------------------------------------------------ mid-run changes
    def _with(self, **changes: object) -> CameraConfig:
        """A validated copy of the camera config with `changes` (the caller's config object is
        left alone: it may be shared with the experiment's config)."""
        data = self.cfg.model_dump()
        render = changes.pop("render", None)
        data.update(changes)
        if render is not None:
            data["render"] = {**data["render"], **render}  # type: ignore[dict-item]
        return type(self.cfg).model_validate(data)

    def set_pose(
        self,
        look_at: tuple[float, float] | None = None,
        distance: float | None = None,
        tilt_deg: float | None = None,
        azimuth_deg: float | None = None,
    ) -> None:
        """Move the camera (a bump): new extrinsics, same intrinsics. None keeps a value.

        Everything derived from the pose (rotation, translation, homography, a checkerboard
        background) is recomputed. A `CenterlineExtractor` built on this camera calibrated its
        clamp pixel from the old pose: rebuild it.
        """
        changes = {
            k: v
            for k, v in (
                ("look_at", look_at),
                ("distance", distance),
                ("tilt_deg", tilt_deg),
                ("azimuth_deg", azimuth_deg),
            )
            if v is not None
        }
        self.cfg = self._with(**changes)
        self._set_extrinsics(self.cfg)

    def set_noise(self, noise_std: float, blur_sigma: float | None = None) -> None:
        """New pixel noise σ (and blur σ unless None) for the following frames."""
        render: dict[str, float] = {"noise_std": float(noise_std)}
        if blur_sigma is not None:
            render["blur_sigma"] = float(blur_sigma)
        self.cfg = self._with(render=render)

    def add_occlusion(self, box: tuple[float, float, float, float]) -> None:
        """An occluder [u0, v0, u1, v1] (px) appears in the following frames."""
        boxes = [tuple(b) for b in self.cfg.render.occlusions]
        self.cfg = self._with(render={"occlusions": [*boxes, tuple(float(v) for v in box)]})

    def remove_occlusion(self, box: tuple[float, float, float, float]) -> None:
        """Remove the occluder [u0, v0, u1, v1] (px).

        Raises:
            ValueError: no such occluder.
        """
        boxes = [tuple(float(v) for v in b) for b in self.cfg.render.occlusions]
        key = tuple(float(v) for v in box)
        if key not in boxes:
            raise ValueError(f"no occluder {list(key)} to remove (present: {boxes})")
        boxes.remove(key)
        self.cfg = self._with(render={"occlusions": boxes})

    # ------------------------------------------------------------------ geometry
    @property
    def rvec(self) -> np.ndarray:
        """(3,) Rodrigues vector of `rotation`, as `cv2.projectPoints` takes it."""
        rvec, _ = cv2.Rodrigues(self.rotation)
        return rvec.ravel()

    @property
    def tvec(self) -> np.ndarray:
        """(3,) translation, as `cv2.projectPoints` takes it."""
        return self.translation.copy()

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Project points of the plane z = 0 into the image.

        Args:
            points_world: (M, 2) world points (x, y) in metres.

        Returns:
            (M, 2) float64 pixel coordinates (u, v); NaN for points behind the camera.
        """
        pts = _as_points(points_world, "points_world")
        h = self.homography
        w = pts[:, 0] * h[2, 0] + pts[:, 1] * h[2, 1] + h[2, 2]
        u = (pts[:, 0] * h[0, 0] + pts[:, 1] * h[0, 1] + h[0, 2]) / w
        v = (pts[:, 0] * h[1, 0] + pts[:, 1] * h[1, 1] + h[1, 2]) / w
        out = np.column_stack([u, v])
        out[w <= 0] = np.nan
        return out

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Intersect the viewing rays of pixels with the plane z = 0 (the inverse of `project`).

        Args:
            pixels: (M, 2) pixel coordinates (u, v).

        Returns:
            (M, 2) float64 world points (x, y) in metres; NaN for rays that miss the plane
            (pixels above the horizon).
        """
        pix = _as_points(pixels, "pixels")
        g = self._homography_inv
        w = pix[:, 0] * g[2, 0] + pix[:, 1] * g[2, 1] + g[2, 2]
        x = (pix[:, 0] * g[0, 0] + pix[:, 1] * g[0, 1] + g[0, 2]) / w
        y = (pix[:, 0] * g[1, 0] + pix[:, 1] * g[1, 1] + g[1, 2]) / w
        out = np.column_stack([x, y])
        out[w <= 0] = np.nan
        return out

    def projection_jacobian(self, points_world: np.ndarray) -> np.ndarray:
        """Derivative of `project` at plane points: d(u, v)/d(x, y), exact for the homography.

        With (a, b, w) = H (x, y, 1): u = a/w, v = b/w, so du/dx = (H00 - u H20)/w, etc.

        Args:
            points_world: (M, 2) world points (x, y) in metres.

        Returns:
            (M, 2, 2) Jacobians, rows (u, v), columns (x, y), in pixels per metre.
        """
        pts = _as_points(points_world, "points_world")
        h = self.homography
        w = pts[:, 0] * h[2, 0] + pts[:, 1] * h[2, 1] + h[2, 2]
        uv = self.project(pts)
        jac = h[None, :2, :2] - uv[:, :, None] * h[None, 2:3, :2]
        return jac / w[:, None, None]

    def project_pose_direction(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel position and unit image direction of a planar pose's tangent.

        Args:
            pose: (3,) world pose [x, y, theta].

        Returns:
            ((2,) pixel position, (2,) unit vector in the image along the projected tangent).
        """
        x, y, th = (float(c) for c in pose)
        eps = 1e-4
        pix = self.project(np.array([[x, y], [x + eps * math.cos(th), y + eps * math.sin(th)]]))
        d = pix[1] - pix[0]
        return pix[0], d / math.hypot(float(d[0]), float(d[1]))

    # ------------------------------------------------------------------ rendering
    def _make_background(self) -> np.ndarray:
        """(H, W, 3) uint8: plain colour, or a checkerboard on the plane (seen in perspective)."""
        r = self.cfg.render
        img = np.empty((self.height, self.width, 3), np.uint8)
        img[:] = r.background_color
        if r.background == "checker":
            vv, uu = np.mgrid[0 : self.height, 0 : self.width]
            world = self.unproject(np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64))
            with np.errstate(invalid="ignore"):
                cell = np.floor(world / r.checker_size)
                odd = ((cell[:, 0] + cell[:, 1]) % 2 == 1).reshape(self.height, self.width)
            img[odd] = r.checker_color
        return img

    def _fill_world_boxes(
        self, img: np.ndarray, pose: np.ndarray, boxes: tuple, color: tuple[int, int, int]
    ) -> None:
        x, y, th = (float(c) for c in pose)
        c, s = math.cos(th), math.sin(th)
        for (a0, a1), (l0, l1) in boxes:
            local = np.array([[a0, l0], [a1, l0], [a1, l1], [a0, l1]])
            world = np.column_stack(
                [x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]]
            )
            pix = self.project(world)
            if not np.isfinite(pix).all():
                continue
            cv2.fillConvexPoly(
                img, np.round(pix * _SCALE).astype(np.int32), color, cv2.LINE_AA, _SHIFT
            )

    def render(
        self, centerline_world: np.ndarray, gripper_pose: np.ndarray, clamp_pose: np.ndarray
    ) -> np.ndarray:
        """Draw what the camera sees: background, clamp, gripper, the rod, then nuisances.

        Args:
            centerline_world: (M, 2) rod centerline on the plane (metres), clamp end first.
            gripper_pose: (3,) gripper pose [x, y, theta] (world).
            clamp_pose: (3,) clamp pose [x, y, theta] (world).

        Returns:
            (H, W, 3) uint8 RGB image.

        Raises:
            ValueError: the centerline has the wrong shape or a point behind the camera.
        """
        r = self.cfg.render
        pts = self.project(_as_points(centerline_world, "centerline_world"))
        if len(pts) < 2 or not np.isfinite(pts).all():
            raise ValueError("centerline_world needs >= 2 points, all in front of the camera")
        img = self._background.copy()
        if r.draw_clamp:
            self._fill_world_boxes(img, np.asarray(clamp_pose), _CLAMP_BOXES, r.fixture_color)
        if r.draw_gripper:
            self._fill_world_boxes(img, np.asarray(gripper_pose), _GRIPPER_BOXES, r.fixture_color)
        # Keep coordinates inside int32 even for absurd inputs; OpenCV clips the drawing itself.
        fixed = np.clip(np.round(pts * _SCALE), -(2**28), 2**28).astype(np.int32)
        cv2.polylines(img, [fixed], False, r.rod_color, int(r.rod_width_px), cv2.LINE_AA, _SHIFT)
        boxes = [tuple(b) for b in r.occlusions]
        if self.rng is not None and r.random_occlusions:
            side = r.occlusion_size_px
            corners = self.rng.uniform(
                [-side / 2, -side / 2],
                [self.width - side / 2, self.height - side / 2],
                size=(r.random_occlusions, 2),
            )
            boxes += [(u, v, u + side, v + side) for u, v in corners]
        for u0, v0, u1, v1 in boxes:
            # A box covers the pixels whose centres lie inside [u0, u1] x [v0, v1].
            cv2.rectangle(
                img,
                (int(np.ceil(u0)), int(np.ceil(v0))),
                (int(np.floor(u1)), int(np.floor(v1))),
                r.occluder_color,
                thickness=-1,
            )
        if r.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), r.blur_sigma)
        if self.rng is not None and r.noise_std > 0:
            # OpenCV's normal generator is ~4x faster than numpy's for a whole frame (2 ms vs
            # 8 ms at 640x480x3); its global state is reseeded from our generator every frame,
            # so frames stay reproducible from the config's seed.
            cv2.setRNGSeed(int(self.rng.integers(2**31 - 1)))
            noise = np.empty(img.shape, np.int16)
            cv2.randn(noise, (0.0,) * 3, (float(r.noise_std),) * 3)  # every channel
            img = cv2.add(img, noise, dtype=cv2.CV_8U)  # saturating add
        return img
