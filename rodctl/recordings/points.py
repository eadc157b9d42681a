"""rodctl's points dataset format: per-frame tracked points plus one or two end-effector poses.

docs/recordings.md is the specification. Two encodings of the same content:
- CSV: a header row, then one row per frame. Columns `t` (seconds, strictly increasing),
  `x0, y0, x1, y1, ..., x{N-1}, y{N-1}` (the tracked points, end 0's side first) and
  `e0_x, e0_y, e0_theta` (end effector 0), optionally `e1_x, e1_y, e1_theta` (a second one:
  q = 6). Lines starting with `#` are comments; `# units: px` says the points are pixels
  (default metres). Extra columns are refused (a misspelt name would otherwise be ignored).
- NPZ: arrays `t` (T,), `points` (T, N, 2), `poses` (T, E, 3) with E = 1 or 2, optionally a
  string `units`.
Poses are [x, y, theta] in the world frame, metres and radians (the contract's convention).
"""

from __future__ import annotations

import csv
import re
import zipfile
from pathlib import Path

import numpy as np

from rodctl.errors import UserError
from rodctl.notices import say_once
from rodctl.recordings.synthetic import PointsRecording

__all__ = ["read_points", "write_points_csv", "write_points_npz"]

_POINT = re.compile(r"^([xy])(\d+)$")
_POSE = re.compile(r"^e([01])_(x|y|theta)$")


def _check(path: Path, rec: PointsRecording) -> PointsRecording:
    t, pts, poses = rec.t, rec.points, rec.poses
    n_frames = len(t)
    if n_frames < 3:
        raise UserError(f"{path}: {n_frames} frame(s); a recording needs at least 3")
    if pts.ndim != 3 or pts.shape[0] != n_frames or pts.shape[2] != 2 or pts.shape[1] < 2:
        raise UserError(
            f"{path}: points must be (T, N >= 2, 2) for T = {n_frames}, got {pts.shape}"
        )
    if (
        poses.ndim != 3
        or poses.shape[0] != n_frames
        or poses.shape[1] not in (1, 2)
        or (poses.shape[2] != 3)
    ):
        raise UserError(
            f"{path}: poses must be (T, 1 or 2, 3) for T = {n_frames}, got {poses.shape}"
        )
    for name, arr in (("t", t), ("points", pts), ("poses", poses)):
        bad = np.argwhere(~np.isfinite(arr.reshape(n_frames, -1)))
        if len(bad):
            raise UserError(f"{path}: frame {int(bad[0][0])}: {name} is not a finite number")
    steps = np.diff(t)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        raise UserError(
            f"{path}: frame {k}: t = {float(t[k])!r} does not increase "
            f"(previous {float(t[k - 1])!r})"
        )
    if rec.units not in ("m", "px"):
        raise UserError(f"{path}: units {rec.units!r}: must be m or px")
    return rec


def _read_csv(path: Path) -> PointsRecording:
    units, header, rows = _csv_rows(path)
    points, ends = _csv_columns(path, header)
    data = np.empty((len(rows), len(header)), dtype=float)
    for frame, (line_no, row) in enumerate(rows):
        for col, value in enumerate(row):
            try:
                data[frame, col] = float(value)
            except ValueError:
                raise UserError(
                    f"{path}: line {line_no} (frame {frame}), column {header[col]}: "
                    f"{value.strip()!r} is not a number"
                ) from None
        bad = np.flatnonzero(~np.isfinite(data[frame]))
        if len(bad):  # nan, inf: named by column, as a value that is not a number is
            raise UserError(
                f"{path}: line {line_no} (frame {frame}), column {header[bad[0]]}: "
                f"{row[bad[0]].strip()!r} is not a finite number"
            )
    if data.size == 0:
        raise UserError(f"{path}: no frames after the header")
    t = data[:, header.index("t")]
    pts = np.stack(
        [
            np.stack([data[:, points[k]["x"]], data[:, points[k]["y"]]], axis=-1)
            for k in range(len(points))
        ],
        axis=1,
    )
    poses = np.stack(
        [
            np.stack([data[:, ends[e][f]] for f in ("x", "y", "theta")], axis=-1)
            for e in sorted(ends)
        ],
        axis=1,
    )
    return PointsRecording(t=t, points=pts, poses=poses, units=units)


def _csv_rows(path: Path) -> tuple[str, list[str], list[tuple[int, list[str]]]]:
    """(units (a `# units: px` comment, else m), the header's column names, the data rows as
    (line number, values as text)) of a points CSV; blank lines and other comments are
    skipped."""
    units = "m"
    rows: list[tuple[int, list[str]]] = []
    header: list[str] | None = None
    try:
        # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark, read as part of `t`
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            for row in reader:
                line_no = reader.line_num  # the record's last line (a quoted field may span)
                if not row or not "".join(row).strip():
                    continue
                if row[0].lstrip().startswith("#"):
                    text = ",".join(row).strip()
                    m = re.match(r"#\s*(units?)\s*:\s*(\S+)", text, re.IGNORECASE)
                    if m and m.group(1) != "units":  # a misspelt key would read px as metres
                        raise UserError(
                            f"{path}: line {line_no}: {text!r}: the units comment is "
                            "'# units: px' (or m)"
                        )
                    if m:
                        units = m.group(2)
                    continue
                if header is None:
                    header = [c.strip() for c in row]
                    if len(header) == 1 and ";" in header[0]:
                        raise UserError(
                            f"{path}: line {line_no}: the columns are separated by ';'; a "
                            "points CSV is comma-separated (t,x0,y0,...)"
                        )
                    twice = sorted({c for c in header if header.count(c) > 1})
                    if twice:  # which of the two would be read is nobody's guess
                        raise UserError(f"{path}: line {line_no}: column {twice[0]} is named twice")
                    continue
                if len(row) != len(header):
                    raise UserError(
                        f"{path}: line {line_no}: {len(row)} values for {len(header)} columns"
                    )
                rows.append((line_no, row))
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read: {exc}") from None
    if header is None:
        raise UserError(f"{path}: empty file (no header row)")
    return units, header, rows


def _csv_columns(
    path: Path, header: list[str]
) -> tuple[dict[int, dict[str, int]], dict[int, dict[str, int]]]:
    """The column index of each point's x and y ({i: {"x": col, "y": col}}) and of each end
    effector's pose ({e: {"x": col, "y": col, "theta": col}}), every one checked present."""
    if "t" not in header:
        raise UserError(f"{path}: no column t (the frame time in seconds)")
    points: dict[int, dict[str, int]] = {}
    ends: dict[int, dict[str, int]] = {}
    for i, name in enumerate(header):
        if name == "t":
            continue
        m, e = _POINT.match(name), _POSE.match(name)
        if m:
            points.setdefault(int(m.group(2)), {})[m.group(1)] = i
        elif e:
            ends.setdefault(int(e.group(1)), {})[e.group(2)] = i
        else:
            raise UserError(
                f"{path}: column {name!r}: not t, x<i>/y<i> (a point) or e<0|1>_x/_y/_theta"
            )
    n = len(points)
    for k in range(n):
        for axis in "xy":
            if axis not in points.get(k, {}):
                raise UserError(f"{path}: no column {axis}{k} (points are numbered 0..{n - 1})")
    if 0 not in ends:
        raise UserError(f"{path}: no columns e0_x, e0_y, e0_theta (end effector 0's pose)")
    for end, cols in ends.items():
        for f in ("x", "y", "theta"):
            if f not in cols:
                raise UserError(f"{path}: no column e{end}_{f}")
    return points, ends


#: The arrays of a points NPZ file: `units` is optional (m).
NPZ_ARRAYS = ("t", "points", "poses", "units")


def _read_npz(path: Path) -> PointsRecording:
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("t", "points", "poses") if k not in z.files]
            if missing:
                raise UserError(f"{path}: no array {missing[0]!r} (needs t, points, poses)")
            extra = [k for k in z.files if k not in NPZ_ARRAYS]
            if extra:  # a misspelt `units` would read pixels as metres
                raise UserError(
                    f"{path}: array {extra[0]!r} is not one a points file has "
                    f"({', '.join(NPZ_ARRAYS)})"
                )
            units = str(z["units"]) if "units" in z.files else "m"
            arrays = {k: z[k] for k in ("t", "points", "poses")}
    except UserError:
        raise
    except Exception as exc:  # noqa: BLE001 - not a zip, a pickled object array, ...
        # numpy's own text advises loading the file unsafely (allow_pickle): never passed on
        # for a file that may not be trusted.
        what = "not a NumPy .npz archive" if not zipfile.is_zipfile(path) else "object arrays"
        raise UserError(
            f"{path}: not a points NPZ file ({what}; {type(exc).__name__}): it needs plain "
            "numeric arrays t, points, poses"
        ) from None
    for name, a in arrays.items():
        if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
            raise UserError(f"{path}: array {name!r} is {a.dtype}, not real numbers")
    if arrays["t"].ndim != 1:
        shape = arrays["t"].shape
        raise UserError(f"{path}: array 't' has shape {shape}; one time per frame, (T,)")
    return PointsRecording(
        t=arrays["t"].astype(float),
        points=arrays["points"].astype(float),
        poses=arrays["poses"].astype(float),
        units=units,
    )


def read_points(path: str | Path) -> PointsRecording:
    """Read a points recording (CSV or NPZ by its suffix), checked; angles unwrapped.

    Raises:
        UserError: missing file, column or array, a non-number, a time that does not increase,
            fewer than 3 frames; the message names the file and the column or frame.
    """
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: {'not a regular file' if p.exists() else 'no such file'}")
    if p.suffix.lower() == ".npz":
        rec = _read_npz(p)
    elif p.suffix.lower() == ".csv":
        rec = _read_csv(p)
    else:
        raise UserError(f"{p}: a points recording is a .csv or .npz file (docs/recordings.md)")
    rec = _check(p, rec)
    _warn_unlikely_units(p, rec)
    rec.poses[:, :, 2] = np.unwrap(rec.poses[:, :, 2], axis=0)
    return rec


#: A tracked rod longer than this many metres, or shorter than this many pixels, is more
#: likely in the other unit (a lab's rods are 0.1-2 m long and span tens to hundreds of px).
_LONGEST_M, _SHORTEST_PX = 20.0, 2.0


def _warn_unlikely_units(path: Path, rec: PointsRecording) -> None:
    """Say so when the points' size fits the other unit better: a file of pixels without its
    `# units: px` is read as metres, and every figure downstream is then 1000x off."""
    length = float(np.median(np.hypot(*np.diff(rec.points, axis=1).transpose(2, 0, 1)).sum(1)))
    if rec.units == "m" and length > _LONGEST_M:
        said = f"the tracked rod is {length:.4g} m long (median over frames), read as metres"
        fix = "if they are pixels, add a `# units: px` line (CSV) or a `units` array 'px' (NPZ)"
    elif rec.units == "px" and length < _SHORTEST_PX:
        said = f"the tracked rod is {length:.3g} px long (median over frames), read as pixels"
        fix = "if they are metres, say `# units: m` (CSV) or `units` 'm' (NPZ)"
    else:
        return
    say_once(f"points-units:{path}", f"warning: {path}: {said}; {fix} (docs/recordings.md)")


def write_points_csv(rec: PointsRecording, path: str | Path) -> Path:
    """Write `rec` as a points CSV (repr floats: reading it back gives the same bits)."""
    p = Path(path)
    n, e = rec.points.shape[1], rec.poses.shape[1]
    header = ["t"] + [f"{a}{k}" for k in range(n) for a in "xy"]
    header += [f"e{j}_{f}" for j in range(e) for f in ("x", "y", "theta")]
    with p.open("w", newline="", encoding="utf-8") as fh:
        fh.write(f"# units: {rec.units}\n")
        w = csv.writer(fh)
        w.writerow(header)
        for k in range(len(rec.t)):
            vals = [rec.t[k], *rec.points[k].reshape(-1), *rec.poses[k].reshape(-1)]
            w.writerow([repr(float(v)) for v in vals])
    return p


def write_points_npz(rec: PointsRecording, path: str | Path) -> Path:
    """Write `rec` as a points NPZ."""
    p = Path(path)
    np.savez(p, t=rec.t, points=rec.points, poses=rec.poses, units=np.array(rec.units))
    return p
