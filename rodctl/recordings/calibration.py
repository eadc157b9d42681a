"""Camera calibration from data: a given extrinsic R|t, or a plane homography from marked points.

rodctl's camera model (`rodctl.vision.camera`) is a pinhole over the rod's plane z = 0, so all
it needs of a calibration is the plane -> pixel homography H (pixel ~ H (x, y, 1)):
- **extrinsic**: the world -> camera rotation R (a matrix or a Rodrigues vector) and
  translation t (metres, OpenCV's camera frame: x right, y down, z along the optical axis)
  with the intrinsics K (CameraInfo's, or the camera config's): H = K [r1 r2 t], the same
  product `Camera` forms from its own pose;
- **plane_points**: four or more marked points, each a pixel (u, v) of the recorded frames
  and its plane coordinates (x, y) in metres: H by least squares over all of them
  (`cv2.findHomography`, method 0). With a distortion D the marked pixels are undistorted
  first (`cv2.undistortPoints` onto K), since the frames are undistorted before extraction.
docs/recordings.md ("Calibration") gives the file format.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from rodctl import fixedla as fla
from rodctl.config.loading import format_validation_error, read_yaml
from rodctl.errors import UserError
from rodctl.recordings.mapping import _tidy
from rodctl.vision.camera import Camera


class _Extrinsic(BaseModel):
    model_config = ConfigDict(extra="forbid")

    rotation: list[list[float]] | None = Field(
        None, description="3 x 3 world -> camera rotation matrix (rows)."
    )
    rvec: list[float] | None = Field(None, description="Rodrigues vector of the rotation.")
    translation: list[float] = Field(description="World -> camera translation (m).")

    @field_validator("rotation")
    @classmethod
    def _rotation(cls, v: list[list[float]] | None) -> list[list[float]] | None:
        if v is None:
            return v
        R = np.asarray(v, dtype=float)
        if R.shape != (3, 3):
            raise ValueError(f"a 3 x 3 matrix is needed, got shape {R.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("not a rotation (R Rᵀ = I and det R = +1, to 1e-6)")
        return v

    @field_validator("rvec", "translation")
    @classmethod
    def _three(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and (len(v) != 3 or not all(math.isfinite(x) for x in v)):
            raise ValueError("three finite numbers are needed")
        return v

    @model_validator(mode="after")
    def _one_rotation(self) -> _Extrinsic:
        if (self.rotation is None) == (self.rvec is None):
            raise ValueError("give exactly one of rotation (3 x 3) or rvec (3)")
        return self


class _Mark(BaseModel):
    model_config = ConfigDict(extra="forbid")

    pixel: tuple[float, float] = Field(description="u, v of the marked point (px).")
    plane: tuple[float, float] = Field(description="x, y of the same point on the plane (m).")


class CalibrationFile(BaseModel):
    """A calibration YAML file: exactly one of `extrinsic` or `plane_points`."""

    model_config = ConfigDict(extra="forbid")

    extrinsic: _Extrinsic | None = None
    plane_points: list[_Mark] | None = Field(None, min_length=4)

    @model_validator(mode="after")
    def _exactly_one(self) -> CalibrationFile:
        if (self.extrinsic is None) == (self.plane_points is None):
            raise ValueError("give exactly one of extrinsic or plane_points")
        return self


class PlaneCamera(Camera):
    """rodctl's camera with its plane -> pixel homography given (from a calibration) instead of
    derived from the config's look_at/distance/tilt/azimuth. Rendering, projection and the
    extractor work as on any `Camera`; `set_pose` does not apply."""

    def __init__(
        self,
        cfg: Any,
        homography: np.ndarray,
        rotation: np.ndarray | None = None,
        translation: np.ndarray | None = None,
    ) -> None:
        self._given = (np.asarray(homography, dtype=float), rotation, translation)
        super().__init__(cfg)

    def _set_extrinsics(self, cfg: Any) -> None:
        H, R, t = self._given
        self.homography = H / H[2, 2]
        self._homography_inv = fla.inv3(self.homography)
        if R is not None and t is not None:
            self.rotation = np.asarray(R, dtype=float)
            self.translation = np.asarray(t, dtype=float)
            self.center = -self.rotation.T @ self.translation
        self._background = self._make_background()

    def set_pose(self, *args: Any, **kwargs: Any) -> None:
        """Refused: a calibrated camera's pose is its homography's (a camera-bump event or a
        replayed bump cannot move it)."""
        raise TypeError("a calibrated PlaneCamera's pose comes from its homography: set_pose")


@dataclass
class Calibration:
    """A camera's pose over the plane from data: `rotation` and `translation` (an extrinsic),
    or `pixels` (M, 2) and `plane` (M, 2) marked points (M >= 4)."""

    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    pixels: np.ndarray | None = None
    plane: np.ndarray | None = None
    source: str = "flags"

    def homography(
        self, K: np.ndarray, D: np.ndarray, model: str = "plumb_bob"
    ) -> tuple[np.ndarray, float | None]:
        """(H plane -> undistorted pixel, normalised to H[2, 2] = 1; the RMS reprojection error
        of the marked points in px, None for an extrinsic).

        Raises:
            UserError: marked points that give no homography (collinear, repeated).
        """
        if self.rotation is not None:
            R, t = self.rotation, self.translation
            assert t is not None  # an extrinsic has both
            H = np.asarray(K, float) @ np.column_stack([R[:, 0], R[:, 1], t])
            if abs(H[2, 2]) < 1e-12:
                raise UserError(f"{self.source}: the extrinsic puts the plane's origin at infinity")
            return H / H[2, 2], None
        px = np.asarray(self.pixels, dtype=float)
        if np.any(np.asarray(D, float) != 0.0):
            if model == "equidistant":  # fisheye: cv2.fisheye's model
                px = cv2.fisheye.undistortPoints(
                    px.reshape(-1, 1, 2), K, np.asarray(D, float).reshape(4, 1), P=K
                ).reshape(-1, 2)
            else:
                px = cv2.undistortPoints(px.reshape(-1, 1, 2), K, D, P=K).reshape(-1, 2)
        H, _ = cv2.findHomography(np.asarray(self.plane, float), px, 0)
        if H is None or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
            raise UserError(
                f"{self.source}: plane_points give no homography (four or more points, no three "
                "on a line, are needed)"
            )
        H = H / H[2, 2]
        w = np.c_[self.plane, np.ones(len(px))] @ H.T
        rms = float(np.sqrt(np.mean(np.sum((w[:, :2] / w[:, 2:] - px) ** 2, axis=1))))
        return H, rms

    def camera(
        self, cfg: Any, K: np.ndarray, D: np.ndarray, model: str = "plumb_bob"
    ) -> tuple[PlaneCamera, str]:
        """The calibrated camera for `cfg` (size, intrinsics, rendering, extraction) and a note
        (`model`: the CameraInfo distortion model of D)."""
        H, rms = self.homography(K, D, model)
        cam = PlaneCamera(cfg, H, self.rotation, self.translation)
        if rms is None:
            return cam, f"camera pose from the extrinsic of {self.source}"
        assert self.plane is not None  # not an extrinsic: marked points
        return cam, (
            f"camera pose from {len(self.plane)} marked points of {self.source} (homography, "
            f"RMS reprojection {rms:.3f} px)"
        )

    def describe(self) -> dict:
        """The calibration as written into an imported run's config.yaml `source`."""
        if self.rotation is not None:
            return {
                "kind": "extrinsic",
                "from": self.source,
                "rotation": np.asarray(self.rotation).tolist(),
                "translation": np.asarray(self.translation).tolist(),
            }
        assert self.pixels is not None and self.plane is not None  # not an extrinsic
        return {
            "kind": "plane_points",
            "from": self.source,
            "plane_points": [
                {"pixel": [float(a), float(b)], "plane": [float(c), float(d)]}
                for (a, b), (c, d) in zip(self.pixels, self.plane, strict=True)
            ],
        }


def _rotation(rvec: list[float]) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3, 1))
    return R


def load_calibration(path: str | Path) -> Calibration:
    """The calibration YAML at `path` (docs/recordings.md, "Calibration").

    Raises:
        UserError: an unreadable file, an unknown or missing key, a matrix that is not a
            rotation, fewer than 4 marked points; exit 2 naming the key.
    """
    p = Path(path)
    data = read_yaml(p, "calibration")
    try:
        f = CalibrationFile.model_validate(data)
    except ValidationError as exc:
        msg = format_validation_error(exc, data, f"--calibration {p}")
        raise UserError(_tidy(msg, "invalid calibration")) from None
    where = f"--calibration {p}"
    if f.extrinsic is not None:
        e = f.extrinsic
        R = np.asarray(e.rotation, float) if e.rotation is not None else _rotation(e.rvec or [])
        return Calibration(rotation=R, translation=np.asarray(e.translation, float), source=where)
    marks = f.plane_points or []
    return Calibration(
        pixels=np.array([m.pixel for m in marks], dtype=float),
        plane=np.array([m.plane for m in marks], dtype=float),
        source=where,
    )


def extrinsic_from_flag(values: list[float]) -> Calibration:
    """`--extrinsic RX,RY,RZ,TX,TY,TZ`: a Rodrigues vector and a translation (world -> camera).

    Raises:
        UserError: a value that is not finite.
    """
    v = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(v)):
        bad = ", ".join(f"{float(x):g}" for x in v)
        raise UserError(f"--extrinsic: the values must be finite numbers, got {bad}")
    return Calibration(
        rotation=_rotation(values[:3]),
        translation=np.asarray(values[3:], dtype=float),
        source="--extrinsic",
    )
