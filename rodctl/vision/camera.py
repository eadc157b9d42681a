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
#: Points of the rod's polyline per dirty box (the region a frame's blur must recompute).
_CHUNK = 16
#: Side (px) of the tiles in which `Camera._blur` recomputes the blur.
_TILE = 32
#: Frames' worth of pixel noise drawn once per camera (`Camera._noise_parts`).
_NOISE_POOL_FRAMES = 2
#: Backgrounds kept across cameras (`Camera._make_background`), oldest dropped first.
_BACKGROUNDS_KEPT = 4
_BACKGROUNDS: dict[tuple, np.ndarray] = {}

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


def _box_corners(boxes: tuple) -> np.ndarray:
    """(4 K, 2) corners of K boxes ((a0, a1), (l0, l1)) in the frame of their pose."""
    return np.array(
        [[[a0, l0], [a1, l0], [a1, l1], [a0, l1]] for (a0, a1), (l0, l1) in boxes]
    ).reshape(-1, 2)


#: `_box_corners` of the fixtures, per boxes tuple (do not modify).
_CORNERS = {boxes: _box_corners(boxes) for boxes in (_CLAMP_BOXES, _GRIPPER_BOXES)}
#: The same corners as Python floats, box by box ((along, lateral) of each corner).
_CORNER_FLOATS = {
    boxes: tuple(tuple(map(tuple, box)) for box in corners.reshape(-1, 4, 2).tolist())
    for boxes, corners in _CORNERS.items()
}


def _pixel_box(fixed: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """Pixel box [u0, u1) x [v0, v1) holding everything OpenCV draws through the points `fixed`
    (1/16 px units) grown by `margin` px (half a line's thickness): two more pixels on each side
    for the anti-aliased fringe and the rounding of the coordinates."""
    lo, hi = fixed.min(axis=0) >> _SHIFT, fixed.max(axis=0) >> _SHIFT
    grow = margin + 2
    return int(lo[0]) - grow, int(lo[1]) - grow, int(hi[0]) + grow + 1, int(hi[1]) + grow + 1


def _dirty_boxes(
    drawn: list[tuple[np.ndarray, int]], rects: list[tuple[int, int, int, int]]
) -> list[tuple[int, int, int, int]]:
    """Pixel boxes [u0, u1) x [v0, v1) holding everything drawn: the rectangles `rects`, and
    per (points in 1/16 px, half-thickness) of `drawn` its `_pixel_box`, a long polyline in
    chunks of `_CHUNK` segments so that the boxes hug the curve."""
    dirty = list(rects)
    for fixed, margin in drawn:
        if len(fixed) <= _CHUNK + 1:
            dirty.append(_pixel_box(fixed, margin))
            continue
        lo = np.minimum(fixed[:-1], fixed[1:])
        hi = np.maximum(fixed[:-1], fixed[1:])
        starts = np.arange(0, len(lo), _CHUNK)
        lo = (np.minimum.reduceat(lo, starts) >> _SHIFT) - (margin + 2)
        hi = (np.maximum.reduceat(hi, starts) >> _SHIFT) + (margin + 3)
        dirty.extend(zip(*lo.T.tolist(), *hi.T.tolist(), strict=True))
    return dirty


def _as_points(points: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (M, 2), got {arr.shape}")
    return arr


def _apply_homography(pts: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(M, 2) points mapped by the 3x3 homography h, NaN where the scale w <= 0. Written out in
    a fixed order of operations (no matmul: its BLAS kernel would change the last bits), each
    coordinate divided straight into its column of the output."""
    (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = h.tolist()
    x, y = pts[:, 0], pts[:, 1]
    w = x * h20 + y * h21 + h22
    out = np.empty((len(pts), 2))
    np.divide(x * h00 + y * h01 + h02, w, out=out[:, 0])
    np.divide(x * h10 + y * h11 + h12, w, out=out[:, 1])
    behind = w <= 0
    if np.count_nonzero(behind):
        out[behind] = np.nan
    return out


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
        self._noise_key: tuple[float, int] | None = None
        # The noise pool as its saturated positive and negative parts (`_noise_parts`).
        self._noise_up = self._noise_down = np.empty(0, np.uint8)
        self._scratch = np.empty(0, np.uint8)  # the frame drawn before a blur or noise, reused
        # The base the scratch frame equals but for the boxes drawn over it (None: stale)
        self._scratch_base: np.ndarray | None = None
        self._scratch_dirty: list[tuple[int, int, int, int]] = []
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
        # The background with the clamp drawn (`_base`), for a clamp that stays put.
        self._base: np.ndarray | None = None
        self._base_key: tuple | None = None
        self._clamp_seen: tuple | None = None
        self._blurred_key: tuple | None = None  # the blurred base is stale
        self._blurred = self._background
        self._blurred_base: np.ndarray | None = None

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
        return _apply_homography(_as_points(points_world, "points_world"), self.homography)

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Intersect the viewing rays of pixels with the plane z = 0 (the inverse of `project`).

        Args:
            pixels: (M, 2) pixel coordinates (u, v).

        Returns:
            (M, 2) float64 world points (x, y) in metres; NaN for rays that miss the plane
            (pixels above the horizon).
        """
        return _apply_homography(_as_points(pixels, "pixels"), self._homography_inv)

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
        x1, y1 = x + eps * math.cos(th), y + eps * math.sin(th)
        # `project` of the two points in scalar arithmetic (the same operations), for the
        # usual case of both in front of the camera
        (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = self.homography.tolist()
        w0, w1 = x * h20 + y * h21 + h22, x1 * h20 + y1 * h21 + h22
        if not (w0 > 0 and w1 > 0):
            pix = self.project(np.array([[x, y], [x1, y1]]))
            d = pix[1] - pix[0]
            return pix[0], d / math.hypot(float(d[0]), float(d[1]))
        u0, v0 = (x * h00 + y * h01 + h02) / w0, (x * h10 + y * h11 + h12) / w0
        du = (x1 * h00 + y1 * h01 + h02) / w1 - u0
        dv = (x1 * h10 + y1 * h11 + h12) / w1 - v0
        return np.array([u0, v0]), np.array([du, dv]) / math.hypot(du, dv)

    # ------------------------------------------------------------------ rendering
    def _make_background(self) -> np.ndarray:
        """(H, W, 3) uint8, read-only: plain colour, or a checkerboard on the plane (seen in
        perspective). A checkerboard costs ~30 ms (every pixel unprojected), and every episode
        makes two cameras with the same scene (rodctl/env.py), so the last few are kept, keyed
        by everything they depend on (the exact bits of the inverse homography included)."""
        r = self.cfg.render
        key = (
            self.width,
            self.height,
            r.background,
            tuple(r.background_color),
            tuple(r.checker_color),
            r.checker_size,
            self._homography_inv.tobytes() if r.background == "checker" else b"",
        )
        img = _BACKGROUNDS.get(key)
        if img is None:
            img = self._draw_background()
            img.flags.writeable = False
            if len(_BACKGROUNDS) >= _BACKGROUNDS_KEPT:
                del _BACKGROUNDS[next(iter(_BACKGROUNDS))]  # the oldest
            _BACKGROUNDS[key] = img
        return img

    def _draw_background(self) -> np.ndarray:
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
        self,
        img: np.ndarray,
        pose: np.ndarray,
        boxes: tuple,
        color: tuple[int, int, int],
        drawn: list[tuple[np.ndarray, int]],
    ) -> None:
        """Fill fixture boxes given in the frame of `pose`; append their corners to `drawn`.

        Corners in scalar arithmetic (a dozen points: numpy's per-call cost would dominate),
        the operations of `project` and of `np.rint` (round half to even, as Python's round)
        in the same order; anything unusual (a corner behind the camera or absurdly far out
        of the image) goes through the array code below, which handles it."""
        x, y, th = (float(c) for c in np.asarray(pose, dtype=float).tolist())
        c, s = math.cos(th), math.sin(th)
        corner_floats = _CORNER_FLOATS.get(boxes)
        if corner_floats is not None:
            (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = self.homography.tolist()
            fixed_boxes = []
            for box in corner_floats:
                pts = []
                for a, lat in box:
                    wx = x + c * a - s * lat
                    wy = y + s * a + c * lat
                    w = wx * h20 + wy * h21 + h22
                    if not w > 0:
                        break
                    u = (wx * h00 + wy * h01 + h02) / w * _SCALE
                    v = (wx * h10 + wy * h11 + h12) / w * _SCALE
                    if not (abs(u) < 2.0**30 and abs(v) < 2.0**30):
                        break
                    pts.append((round(u), round(v)))
                else:
                    fixed_boxes.append(np.array(pts, np.int32))
                    continue
                break
            else:
                for corners in fixed_boxes:
                    cv2.fillConvexPoly(img, corners, color, cv2.LINE_AA, _SHIFT)
                    drawn.append((corners, 0))
                return
        # every box's four corners in one projection (element-wise: the same bits box by box)
        local = _CORNERS.get(boxes)
        if local is None:
            local = _box_corners(boxes)
        world = np.empty_like(local)
        world[:, 0] = x + c * local[:, 0] - s * local[:, 1]
        world[:, 1] = y + s * local[:, 0] + c * local[:, 1]
        pix = self.project(world).reshape(-1, 4, 2)
        finite = np.isfinite(pix).all(axis=(1, 2))
        if not finite.all():
            pix = np.where(finite[:, None, None], pix, 0.0)
        fixed = np.rint(pix * _SCALE).astype(np.int32)  # np.round with 0 decimals is rint
        for corners, ok in zip(fixed, finite.tolist(), strict=True):
            if ok:
                cv2.fillConvexPoly(img, corners, color, cv2.LINE_AA, _SHIFT)
                drawn.append((corners, 0))

    def render(
        self,
        centerline_world: np.ndarray,
        gripper_pose: np.ndarray,
        clamp_pose: np.ndarray,
        *,
        transient: bool = False,
    ) -> np.ndarray:
        """Draw what the camera sees: background, clamp, gripper, the rod, then nuisances.

        Args:
            centerline_world: (M, 2) rod centerline on the plane (metres), clamp end first.
            gripper_pose: (3,) gripper pose [x, y, theta] (world).
            clamp_pose: (3,) clamp pose [x, y, theta] (world).
            transient: a frame that is used before the next `render` and then dropped (a
                collection walk extracts each frame at once): without blur or noise it is the
                camera's scratch frame, which the next call draws over, instead of a fresh copy
                of the 640 x 480 base (a walk: ~0.1 ms of CPU a shape less). The same pixels.

        Returns:
            (H, W, 3) uint8 RGB image.

        Raises:
            ValueError: the centerline has the wrong shape or a point behind the camera.
        """
        r = self.cfg.render
        pts = self.project(_as_points(centerline_world, "centerline_world"))
        if len(pts) < 2 or not np.isfinite(pts).all():
            raise ValueError("centerline_world needs >= 2 points, all in front of the camera")
        base = self._base_with_clamp(np.asarray(clamp_pose), r)
        noisy = self.rng is not None and r.noise_std > 0
        # With blur or noise the frame is drawn on a kept scratch frame (only what the last
        # frame drew over the base is restored) and the returned frame is made by the blur or
        # the noise; a transient plain frame is the scratch frame; otherwise it is drawn on a
        # copy of the base.
        scratch = r.blur_sigma > 0 or noisy or transient
        img = self._scratch_on(base) if scratch else base.copy()
        # What was drawn over the base, for the blur: (points in 1/16 px, half-thickness)
        # and pixel boxes [u0, u1) x [v0, v1).
        drawn: list[tuple[np.ndarray, int]] = []
        rects: list[tuple[int, int, int, int]] = []
        if r.draw_clamp and base is self._background:
            self._fill_world_boxes(
                img, np.asarray(clamp_pose), _CLAMP_BOXES, r.fixture_color, drawn
            )
        if r.draw_gripper:
            self._fill_world_boxes(
                img, np.asarray(gripper_pose), _GRIPPER_BOXES, r.fixture_color, drawn
            )
        # Keep coordinates inside int32 even for absurd inputs; OpenCV clips the drawing itself.
        # np.clip(np.round(...)) of finite values, in fewer calls
        fixed = np.minimum(np.maximum(np.rint(pts * _SCALE), -(2**28)), 2**28).astype(np.int32)
        width = int(r.rod_width_px)
        cv2.polylines(img, [fixed], False, r.rod_color, width, cv2.LINE_AA, _SHIFT)
        drawn.append((fixed, width // 2 + 1))
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
            c0, c1 = (int(np.ceil(u0)), int(np.ceil(v0))), (int(np.floor(u1)), int(np.floor(v1)))
            cv2.rectangle(img, c0, c1, r.occluder_color, thickness=-1)
            rects.append((c0[0], c0[1], c1[0] + 1, c1[1] + 1))
        if not scratch:
            return img
        dirty = _dirty_boxes(drawn, rects)
        self._scratch_dirty, self._scratch_base = dirty, base  # what to restore next time
        noise = self._noise_parts(float(r.noise_std), img.shape) if noisy else None
        if r.blur_sigma > 0:
            return self._blur(img, base, dirty, float(r.blur_sigma), noise)
        if noise is None:  # transient: the scratch frame itself
            return img
        out = cv2.add(img, noise[0])  # saturating; the new frame
        return cv2.subtract(out, noise[1], dst=out)

    def _scratch_on(self, base: np.ndarray) -> np.ndarray:
        """The scratch frame, equal to `base`: copied whole when the base changed, otherwise
        only the boxes the last frame drew over it are copied back (those boxes hold every
        pixel OpenCV drew, see `_pixel_box`). Marked stale until the frame's drawing is
        recorded, so that a frame that fails half-drawn leaves no trace in the next one."""
        img = self._scratch
        if img.shape != base.shape:
            img = self._scratch = np.empty_like(base)
            self._scratch_base = None
        if self._scratch_base is not base:
            np.copyto(img, base)
        else:
            h, w = base.shape[:2]
            for u0, v0, u1, v1 in self._scratch_dirty:
                u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w), min(v1, h)
                if u0 < u1 and v0 < v1:
                    img[v0:v1, u0:u1] = base[v0:v1, u0:u1]
        self._scratch_base = None
        return img

    def _base_with_clamp(self, clamp_pose: np.ndarray, r: object) -> np.ndarray:
        """What a frame is drawn on: the background, or, for a clamp seen at the same pose in
        the frame before, the background with the clamp already drawn (read-only, kept until
        the pose, the colour or the background changes). The clamp is drawn first either way,
        so the frame is the same; a clamp that moves every frame (dual-arm) never pays for
        building a base it cannot reuse."""
        if not r.draw_clamp:  # type: ignore[attr-defined]
            return self._background
        key = (clamp_pose.tobytes(), tuple(r.fixture_color))  # type: ignore[attr-defined]
        if self._base is not None and self._base_key == key:
            return self._base
        if self._clamp_seen != key:
            self._clamp_seen = key
            return self._background
        base = self._background.copy()
        self._fill_world_boxes(base, clamp_pose, _CLAMP_BOXES, key[1], [])
        base.flags.writeable = False
        self._base, self._base_key = base, key
        return base

    def _blur(
        self,
        img: np.ndarray,
        base: np.ndarray,
        dirty: list[tuple[int, int, int, int]],
        sigma: float,
        noise: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """`cv2.GaussianBlur(img, (0, 0), sigma)`, bit for bit, computed only near what was drawn
        over `base` (the background, or the background with the clamp).

        The base is blurred once (per base and sigma) and copied; only the tiles within the
        kernel's reach of a drawn box are blurred again, each from a source window one kernel
        radius larger on every side (clipped at the image's edge, where the window's own border
        reflection is the full image's). OpenCV's 8-bit Gaussian is fixed-point integer
        arithmetic, so a pixel's value depends only on its neighbourhood, never on the window it
        was computed in (tests/vision/test_camera.py compares with the whole-frame blur).

        `dirty`: the pixel boxes drawn over the base (`_dirty_boxes`). `noise`: the frame's
        (up, down) noise parts (`_noise_parts`), added on the way: the blurred base plus `up`
        makes the new frame in one pass (no copy), each re-blurred tile gets its `up`, then
        `down` is taken off the whole frame; the bits of blurring, then adding the noise.
        """
        # OpenCV's own kernel size for 8-bit images and ksize (0, 0) (cv::createGaussianKernels)
        ksize = int(round(sigma * 3 * 2 + 1)) | 1
        rad = ksize // 2
        key = (sigma, ksize, id(base))
        if self._blurred_key != key or self._blurred_base is not base:
            self._blurred = cv2.GaussianBlur(base, (ksize, ksize), sigma)
            self._blurred_key = key
            self._blurred_base = base
        out = self._blurred.copy() if noise is None else cv2.add(self._blurred, noise[0])
        h, w = self.height, self.width
        rows, cols = -(-h // _TILE), -(-w // _TILE)
        tiles = np.zeros((rows, cols), bool)
        for u0, v0, u1, v1 in dirty:
            u0, v0 = max(u0 - rad, 0), max(v0 - rad, 0)
            u1, v1 = min(u1 + rad, w), min(v1 + rad, h)
            if u0 < u1 and v0 < v1:
                tiles[v0 // _TILE : (v1 - 1) // _TILE + 1, u0 // _TILE : (u1 - 1) // _TILE + 1] = 1
        for row, line in enumerate(tiles.tolist()):
            if not any(line):
                continue
            # runs of dirty tiles in this row: [start, end) in tiles
            runs, start = [], None
            for col, on in enumerate([*line, False]):
                if on and start is None:
                    start = col
                elif not on and start is not None:
                    runs.append((start, col))
                    start = None
            y0, y1 = row * _TILE, min((row + 1) * _TILE, h)
            sy0, sy1 = max(y0 - rad, 0), min(y1 + rad, h)
            for start, end in runs:
                x0, x1 = start * _TILE, min(end * _TILE, w)
                sx0, sx1 = max(x0 - rad, 0), min(x1 + rad, w)
                part = cv2.GaussianBlur(img[sy0:sy1, sx0:sx1], (ksize, ksize), sigma)
                part = part[y0 - sy0 : y1 - sy0, x0 - sx0 : x1 - sx0]
                if noise is None:
                    out[y0:y1, x0:x1] = part
                else:
                    cv2.add(part, noise[0][y0:y1, x0:x1], dst=out[y0:y1, x0:x1])
        if noise is not None:
            cv2.subtract(out, noise[1], dst=out)
        return out

    def _noise_parts(self, std: float, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """This frame's seeded Gaussian pixel noise of σ `std` (grey levels, every channel) for
        a frame of `shape`, as (up, down) uint8 frames: the noisy frame is
        saturate(saturate(frame + up) - down), i.e. frame + noise saturated.

        Drawing 921,600 normal values per 640x480 frame costs about 3 ms, more than all the rest
        of a frame. So the camera draws a pool of `_NOISE_POOL_FRAMES` frames' worth of rounded
        N(0, σ²) values once (seeded from its generator's draw for the first noisy frame), and each
        frame adds the pool's slice at an offset drawn from the generator: every frame's noise is
        a contiguous run of i.i.d. values, so within a frame it is i.i.d. N(0, σ²) rounded as
        before; two frames share values only at shifted positions (identical only when two
        offsets coincide, about one chance in a million per pair). One draw per frame, as
        before, so the generator's other draws (random occluders) are unchanged; the values
        themselves differ from the per-frame `cv2.randn` stream of earlier versions.
        """
        draw = int(self.rng.integers(2**31 - 1))  # type: ignore[union-attr]
        size = math.prod(shape)
        if self._noise_key != (std, size):
            cv2.setRNGSeed(draw)
            pool = np.empty((_NOISE_POOL_FRAMES * size, 1), np.int16)
            # cv2's stubs type mean and stddev as arrays; scalars are what it takes
            cv2.randn(pool, 0.0, std)  # type: ignore[call-overload]
            flat = pool.ravel()
            # Kept as two uint8 parts, up = min(max(n, 0), 255) and down = min(max(-n, 0), 255):
            # for a uint8 pixel p, saturate(p + n) = saturate(saturate(p + up) - down) (one of
            # the two is 0), and two 8-bit saturating passes cost less than a third of one
            # mixed 8/16-bit one.
            self._noise_up = np.clip(flat, 0, 255).astype(np.uint8)
            self._noise_down = (-np.clip(flat, -255, 0)).astype(np.uint8)
            self._noise_key = (std, size)
        offset = draw % (len(self._noise_up) - size + 1)
        up = self._noise_up[offset : offset + size].reshape(shape)
        return up, self._noise_down[offset : offset + size].reshape(shape)
