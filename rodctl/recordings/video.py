"""A video file (OpenCV `VideoCapture`: .mp4, .avi, ...) with a CSV of gripper poses.

The camera-frame import of an image folder (`folder.py`) with the frames decoded from a video
one at a time while they are extracted (docs/recordings.md, "A video"). Frame k's time is
row k's `t` of a frame-times CSV (`--frame-times`, column `t` in seconds, one row per frame in
the video's order), or k / fps with fps from `--fps` or, without it, the video's own. The
poses CSV is the image folder's (`t, x, y, theta`), on the same clock.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rodctl.errors import UserError
from rodctl.recordings.folder import _number, _table

if TYPE_CHECKING:
    import cv2

#: File suffixes `rodctl import` treats as a video.
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm", ".mjpeg", ".mjpg")


class _Decoder:
    """Sequential frame access to a video: frame k decoded by reading forward (re-opening the
    file to go back), the last frame kept, so the import's in-order reads decode each once."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.cap: cv2.VideoCapture | None = None
        self.pos = 0
        self.last: tuple[int, np.ndarray] | None = None

    def _open(self) -> cv2.VideoCapture:
        # Lazy: `rodctl import` loads this module for VIDEO_SUFFIXES whatever it imports; only
        # a video needs OpenCV.
        import cv2  # noqa: PLC0415

        # FFmpeg's own log (e.g. "[mov,mp4,...] moov atom not found" for a file that is not a
        # video) goes to stderr past rodctl's one-line error; quiet unless the user set it.
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
        if self.cap is not None:
            self.cap.release()
        cap = self.cap = cv2.VideoCapture(str(self.path))
        self.pos = 0
        if not cap.isOpened():
            raise UserError(f"{self.path}: not a video OpenCV can read")
        return cap

    def frame(self, k: int) -> np.ndarray:
        import cv2  # noqa: PLC0415 (lazy, as in `_open`)

        if self.last is not None and self.last[0] == k:
            return self.last[1]
        cap = self._open() if self.cap is None or k < self.pos else self.cap
        while self.pos < k:
            if not cap.grab():
                raise UserError(f"{self.path}: frame {k}: the video ends at frame {self.pos}")
            self.pos += 1
        ok, img = cap.read()
        if not ok or img is None:
            raise UserError(f"{self.path}: frame {k} does not decode")
        self.pos += 1
        rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        self.last = (k, rgb)
        return rgb

    def count(self) -> tuple[int, float]:
        """(frames, the container's fps) by decoding through the video once."""
        import cv2  # noqa: PLC0415 (lazy, as in `_open`)

        cap = self._open()
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        n = 0
        while cap.grab():
            n += 1
        self._open()
        return n, fps

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()
            self.cap = None


def read_video(
    video: str | Path,
    poses_csv: str | Path,
    *,
    fps: float | None = None,
    frame_times: str | Path | None = None,
) -> tuple[list[tuple[int, Callable[[], np.ndarray]]], list[tuple[int, list[float]]], dict]:
    """(frames [(t_ns, loader)], gripper poses [(t_ns, [x, y, theta])], what was used).

    Raises:
        UserError: a file that is missing or not a video OpenCV decodes, a video without
            frames, no fps (neither the flag nor the container), a frame-times CSV whose row
            count differs from the frame count or whose times do not increase, the poses CSV's
            errors (`folder.read_folder`).
    """
    path = Path(video)
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    dec = _Decoder(path)
    n, container_fps = dec.count()
    if n == 0:
        raise UserError(f"{path}: not a video OpenCV can read (no frame decodes)")
    used: dict = {"frames": n}
    if frame_times is not None:
        ftp = Path(frame_times)
        rows = _table(ftp, ["t"])
        if len(rows) != n:
            raise UserError(f"{ftp}: {len(rows)} rows for the {n} frames of {path}")
        t = np.array([_number(ftp, i, "t", r["t"]) for i, r in enumerate(rows)])
        used["frame_times"] = str(ftp)
    else:
        rate = fps if fps is not None else container_fps
        if not rate or not np.isfinite(rate) or rate <= 0:
            raise UserError(f"{path}: the video has no frame rate; give --fps or --frame-times")
        t = np.arange(n) / float(rate)
        used["fps"] = float(rate)
    steps = np.diff(t)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        raise UserError(f"{frame_times}: row {k + 1}: t = {float(t[k])!r} does not increase")
    p = Path(poses_csv)
    poses = []
    for i, row in enumerate(_table(p, ["t", "x", "y", "theta"])):
        vals = [_number(p, i, c, row[c]) for c in ("t", "x", "y", "theta")]
        poses.append((int(round(vals[0] * 1e9)), vals[1:]))
    frames = [(int(round(float(tk) * 1e9)), _loader(dec, k)) for k, tk in enumerate(t)]
    return frames, poses, used


def _loader(dec: _Decoder, k: int) -> Callable[[], np.ndarray]:
    return lambda: dec.frame(k)
