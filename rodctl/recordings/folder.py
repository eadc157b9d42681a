"""An image folder with a CSV of gripper poses: the camera-frame import without ROS 2.

Layout (docs/recordings.md, "An image folder"): the folder holds the frames (any image format
OpenCV reads: PNG, JPEG, ...) and `frames.csv` with columns `file` (a path relative to the
folder) and `t` (seconds); the poses CSV (`--poses`) has columns `t, x, y, theta` (the gripper,
world frame, metres and radians). Images are read one at a time while they are extracted.
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from rodctl.errors import UserError


def _table(path: Path, columns: list[str]) -> list[dict[str, str]]:
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = [r for r in csv.DictReader(row for row in fh if not row.startswith("#"))]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise UserError(f"{path}: cannot read: {exc}") from None
    if not rows:
        raise UserError(f"{path}: no rows")
    for c in columns:
        if c not in rows[0]:
            raise UserError(f"{path}: no column {c} (needs {', '.join(columns)})")
    return rows


def _number(path: Path, row: int, col: str, text: str | None) -> float:
    try:
        v = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v):
        raise UserError(f"{path}: row {row + 1}: {col} = {text!r} is not a number")
    return v


def _loader(path: Path) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise UserError(f"{path}: not an image OpenCV can read")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    return load


def read_folder(
    folder: str | Path, poses_csv: str | Path
) -> tuple[list[tuple[int, Callable[[], np.ndarray]]], list[tuple[int, list[float]]]]:
    """(frames [(t_ns, loader)] in time order, gripper poses [(t_ns, [x, y, theta])]).

    Raises:
        UserError: a missing frames.csv or column, a frame file that does not exist, a time
            that is not a number or does not increase; the message names the file and the row.
    """
    root = Path(folder)
    index = root / "frames.csv"
    frames: list[tuple[int, Callable[[], np.ndarray]]] = []
    for i, row in enumerate(_table(index, ["file", "t"])):
        f = root / row["file"]
        if not f.is_file():
            raise UserError(f"{index}: row {i + 1}: no frame file {f}")
        t = _number(index, i, "t", row["t"])
        _increasing(index, i, t, frames)
        frames.append((int(round(t * 1e9)), _loader(f)))
    p = Path(poses_csv)
    poses: list[tuple[int, list[float]]] = []
    for i, row in enumerate(_table(p, ["t", "x", "y", "theta"])):
        t = _number(p, i, "t", row["t"])
        _increasing(p, i, t, poses)
        vals = [_number(p, i, c, row[c]) for c in ("x", "y", "theta")]
        poses.append((int(round(t * 1e9)), vals))
    return frames, poses


def _increasing(path: Path, i: int, t: float, earlier: list[tuple[int, Any]]) -> None:
    """Row `i`'s time `t` [s] must follow the last of `earlier` (a pose or a frame matched to
    the wrong time would be silently misassigned), as in a points CSV."""
    if earlier and round(t * 1e9) <= earlier[-1][0]:
        previous = earlier[-1][0] / 1e9
        raise UserError(f"{path}: row {i + 1}: t = {t:g} does not increase (previous {previous:g})")
