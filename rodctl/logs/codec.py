"""Step records <-> JSON messages, shared by the MCAP writer, its reader and the Rerun sink.

Why a separate module: the MCAP file is the run's source of truth (`rodctl replay` rebuilds the
Rerun recording and the figures from it, and `replay --verify` compares every logged step bit for
bit with a fresh simulation), so encoding and decoding must be exact inverses and must live side by
side. Nothing here imports `mcap` or `rerun`.

Exactness: JSON numbers are written with Python's float `repr`, which round-trips every finite
float64 exactly. JSON has no NaN or infinity, so a non-finite value is written as `null` and
listed with its exact value in the message's `nonfinite` array (`Encoder`, `restore_nonfinite`).
Camera frames travel as lossless PNG, so a decoded frame equals the logged one byte for byte.

Layout (format version 3, `FORMAT_VERSION`): points are arrays of `{x, y}` objects, the
Jacobian a flat row-major array with its shape beside it, maps arrays of `{key, value}` /
`{name, value}` objects, so that every schema loads in Foxglove's JSON-schema parser (see
`schemas`). The contract fields of the three per-step topics (docs/outputs.md, "The MCAP log")
come first, exactly as named there; fields beyond the contract (phase, health flags, estimator
diagnostics...) follow on the same messages.

Clock: MCAP log_time = `LOG_EPOCH_NS` + simulated time; `FrameSchedule` picks the camera frames
by simulated time, so their rate holds in log time.
"""

from __future__ import annotations

import base64
import json
import math
import re
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from rodctl.records import FIELD_UNITS, RunHeader, RunSummary, StepRecord

#: Version of the message layout below; bumped when a field changes meaning.
#: 3 (2026-12-02, dual-arm): `u`, `u_raw`, `saturated` and the header's `home_pose` and
#: `target_pose` hold q = 3 or 6 values (version 2: exactly 3; a version-2 reader refuses a
#: dual-arm log), J is p x 6 at q = 6, and dual-arm runs add `/rod/clamp`. A version-2 log is
#: a version-3 log of one arm: read as is.
FORMAT_VERSION = "3"
#: The versions this rodctl reads (`check_format_version`).
READABLE_VERSIONS = ("2", FORMAT_VERSION)

# Contract topics (docs/outputs.md, "The MCAP log"), one message per control step.
TOPIC_ROD_STATE = "/rod/state"
TOPIC_CAMERA_CENTERLINE = "/camera/centerline"
TOPIC_CONTROL = "/control"
#: Dual-arm runs only (rod.arms: 2): the x0 end's pose per step (added, not in single-arm logs).
TOPIC_CLAMP_STATE = "/rod/clamp"
#: The unit metadata of /rod/clamp's channel (run.mcap and the live view).
CLAMP_UNITS = {"clamp": FIELD_UNITS["clamp"].described}
# Foxglove well-known topics; the names double as Rerun entity paths.
TOPIC_ROD_SCENE = "/world/rod"
TOPIC_TARGET_SCENE = "/world/target"
TOPIC_GRIPPER_SCENE = "/world/gripper"
TOPIC_IMAGE = "/camera/image"
TOPIC_ANNOTATIONS = "/camera/annotations"
TOPIC_LOG = "/log"
# rodctl bookkeeping: one message each, what replay needs beyond the per-step topics.
TOPIC_HEADER = "/run/header"
TOPIC_SUMMARY = "/run/summary"

#: The contract fields of each per-step topic that carry a unit (`rodctl.records.FIELD_UNITS`).
_UNIT_FIELDS = {
    TOPIC_ROD_STATE: ("step", "sim_time", "gripper", "centerline"),
    TOPIC_CAMERA_CENTERLINE: ("step", "extracted", "projected_truth"),
    TOPIC_CONTROL: ("step", "u", "s", "s_target", "T1", "J", "pixel_error", "jacobian_error"),
}
#: Units of every contract field, also written as MCAP channel metadata.
UNITS: dict[str, dict[str, str]] = {
    topic: {name: FIELD_UNITS[name].described for name in names}
    for topic, names in _UNIT_FIELDS.items()
}

#: Log levels shared by foxglove.Log (numbers) and Rerun's TextLog (names).
LOG_LEVELS = {"DEBUG": 1, "INFO": 2, "WARN": 3, "ERROR": 4}


# ------------------------------------------------------------------------------------- numbers
#: The non-finite values by their JSON name (`nonfinite` entries of a message).
_NONFINITE_VALUES = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


def _nonfinite_name(x: float) -> str:
    return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")


class Encoder:
    """Encodes the numbers of one message exactly, collecting its non-finite values.

    Finite floats are written as themselves (shortest round-trip repr, exact). A non-finite value
    is written as `null` and listed in `nonfinite` as `{"path", "value"}` (e.g.
    `{"path": "centerline[3].x", "value": "NaN"}`), which `restore_nonfinite` puts back. Why not
    `null` alone: it cannot tell NaN from an infinity, and why not the strings "NaN"/"Infinity"
    in place: the field's schema must be a plain `number` for Foxglove's parser (see `schemas`).
    """

    __slots__ = ("nonfinite",)

    def __init__(self) -> None:
        self.nonfinite: list[dict[str, str]] = []

    def _note(self, path: str, x: float) -> None:
        self.nonfinite.append({"path": path, "value": _nonfinite_name(x)})

    def real(self, path: str, x: float) -> float | None:
        """One float: itself when finite, else None (noted)."""
        x = float(x)
        if math.isfinite(x):
            return x
        self._note(path, x)
        return None

    def vec(self, path: str, a: np.ndarray) -> list[float | None]:
        """A float array as a flat list (row-major), non-finite entries None (noted)."""
        a = np.asarray(a, dtype=np.float64).ravel()
        out: list[Any] = a.tolist()
        if not np.isfinite(a).all():
            for i in np.flatnonzero(~np.isfinite(a)).tolist():
                self._note(f"{path}[{i}]", out[i])
                out[i] = None
        return out

    def points(self, path: str, a: np.ndarray) -> list[dict[str, float | None]]:
        """(M, 2) points as `[{"x": .., "y": ..}, ...]`, non-finite coordinates None (noted)."""
        a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
        rows: list[Any] = a.tolist()
        if not np.isfinite(a).all():
            for i, j in zip(*np.nonzero(~np.isfinite(a)), strict=True):
                i, j = int(i), int(j)
                self._note(f"{path}[{i}].{'xy'[j]}", rows[i][j])
                rows[i][j] = None
        return [{"x": x, "y": y} for x, y in rows]


_PATH_TOKEN = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]|\.([A-Za-z_][A-Za-z0-9_]*)")


def restore_nonfinite(msg: dict[str, Any]) -> dict[str, Any]:
    """Put the values listed in `msg["nonfinite"]` back in place (as Python floats); in place.

    Raises:
        ValueError: an entry whose path does not lead to a `null` of the message.
    """
    for entry in msg.get("nonfinite") or ():
        path, name = entry.get("path"), entry.get("value")
        if not isinstance(path, str) or name not in _NONFINITE_VALUES:
            raise ValueError(f"bad nonfinite entry {entry!r}")
        keys: list[Any] = []
        pos = 0
        while pos < len(path):
            m = _PATH_TOKEN.match(path, pos)
            if m is None or (pos == 0) != (m.group(1) is not None):
                raise ValueError(f"bad nonfinite path {path!r}")
            keys.append(int(m.group(2)) if m.group(2) is not None else (m.group(1) or m.group(3)))
            pos = m.end()
        node: Any = msg
        try:
            for key in keys[:-1]:
                node = node[key]
            if node[keys[-1]] is not None:
                raise ValueError(f"nonfinite path {path!r} does not hold null")
            node[keys[-1]] = _NONFINITE_VALUES[name]
        except (KeyError, IndexError, TypeError):
            raise ValueError(f"nonfinite path {path!r} is not in the message") from None
    return msg


def encode_real(x: float) -> float | str | None:
    """One float as a free-form JSON value (summary, numeric environment): itself when finite,
    else None (NaN) or "Infinity" / "-Infinity"."""
    x = float(x)
    if math.isfinite(x):
        return x
    if math.isnan(x):
        return None
    return "Infinity" if x > 0 else "-Infinity"


def decode_real(v: Any) -> float:
    """A number of a message whose `nonfinite` entries are restored."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f"not a number: {v!r}")
    return float(v)


def decode_vec(v: Any, n: int | None = None) -> np.ndarray:
    """A flat number list as a (len,) float64 array (`n`: the length it must have)."""
    if not isinstance(v, list):
        raise ValueError(f"expected a list of numbers, got {type(v).__name__}")
    if any(x is None or isinstance(x, (bool, str, list, dict)) for x in v):
        raise ValueError("expected a list of numbers (a null not listed in `nonfinite`?)")
    out = np.array(v, dtype=np.float64).reshape(-1)
    if n is not None and out.shape != (n,):
        raise ValueError(f"expected {n} numbers, got {out.shape[0]}")
    return out


def decode_points(v: Any) -> np.ndarray:
    """`[{"x": .., "y": ..}, ...]` as an (M, 2) float64 array."""
    if not isinstance(v, list):
        raise ValueError(f"expected a list of points, got {type(v).__name__}")
    try:
        flat = [c for p in v for c in (p["x"], p["y"])]
    except (KeyError, TypeError):
        raise ValueError("expected a list of {x, y} points") from None
    return decode_vec(flat).reshape(-1, 2)


#: MCAP log times are simulated time plus this fixed offset: 2000-01-01T00:00:00Z in ns since
#: the Unix epoch. Why an offset: viewers read log times as dates, and 0 ns shows as 1970-01-01;
#: why fixed rather than the wall clock: reruns of one config must write identical bytes.
LOG_EPOCH_NS = 946_684_800 * 1_000_000_000


def time_ns(sim_time: float) -> int:
    """Simulated time (s) in integer ns (never negative); the Rerun `sim_time` timeline."""
    if not math.isfinite(sim_time):
        return 0
    return max(0, round(sim_time * 1e9))


def log_time_ns(sim_time: float) -> int:
    """Simulated time (s) as MCAP log_time: `LOG_EPOCH_NS` + simulated ns."""
    return LOG_EPOCH_NS + time_ns(sim_time)


def foxglove_time(t_ns: int) -> dict[str, int]:
    """A Foxglove `time` {sec, nsec} from nanoseconds."""
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


class _Frame(Protocol):
    """What the schedule reads of a step: its camera frame and its time."""

    @property
    def image(self) -> np.ndarray | None: ...

    @property
    def sim_time(self) -> float: ...


class FrameSchedule:
    """Which camera frames a sink logs: at most `rate_hz` frames per second of simulated time.

    Why in the sinks and by `sim_time`: log time is simulated time, and a control step's simulated
    time is its move plus however long the rod takes to settle, so a rate counted in control
    periods drifts from the rate a viewer sees. Simulated time is cut into slots of 1 / rate_hz
    from t = 0, and the first record of a slot that carries a frame is taken: one frame per slot,
    so the rate holds on average even when steps do not divide the period evenly, and never more
    than one frame per control step (steps slower than the period give one frame each). A record
    without a frame leaves its slot open for the next record that has one, so the schedule works
    whether the loop attaches a frame to every record or to some. The decision depends on the
    records alone: both sinks and a replay take the same frames.
    """

    def __init__(self, rate_hz: float) -> None:
        self.period_ns = round(1e9 / rate_hz) if rate_hz > 0 else 0
        self._next_ns = 0

    def due(self, record: StepRecord) -> bool:
        """Whether `take` would take this record's frame (nothing changes)."""
        if record.image is None or self.period_ns <= 0:
            return False
        return time_ns(record.sim_time) >= self._next_ns

    def take(self, record: _Frame) -> bool:
        """Whether to log `record.image`; advances the schedule when it does."""
        if record.image is None or self.period_ns <= 0:
            return False
        t = time_ns(record.sim_time)
        if t < self._next_ns:
            return False
        self._next_ns = (t // self.period_ns + 1) * self.period_ns
        return True


# -------------------------------------------------------------------------------------- images
class FrameEncoder:
    """PNG encoding of camera frames on one bounded background thread, shared by the sinks.

    Why: a lossless PNG of a 640 x 480 frame costs 1.3-2.5 ms, most of what logging costs the
    loop. OpenCV releases the GIL while encoding, so a worker thread encodes frame k while the
    loop simulates step k + 1, and the sinks write frame k one step later (`LAG`, a fixed number
    of steps, so what lands in which MCAP chunk never depends on timing: reruns stay
    byte-identical). At most `max_pending` frames wait for the worker; a sink that gets ahead
    blocks until the oldest is done, so memory stays bounded.

    `submit` returns a future of the PNG bytes. Submitting the same array again (the next sink,
    same step) returns the same future, so each frame is encoded once. The encoder keeps a
    reference to the last array it was given, so its `id` cannot be reused while cached; a frame
    mutated in place after being handed to a sink would be served stale (the loop hands each step
    a fresh frame).
    """

    def __init__(self, max_pending: int = 4) -> None:
        self.max_pending = max_pending
        self._pool: ThreadPoolExecutor | None = None
        self._last: tuple[np.ndarray | None, int, Future[bytes] | None] = (None, -1, None)
        self._pending: deque[Future[bytes]] = deque()

    def submit(self, image: np.ndarray, level: int) -> Future[bytes]:
        """Start encoding an (H, W, 3) RGB or (H, W) grey uint8 frame; a bad frame raises here."""
        last_image, last_level, last_future = self._last
        if image is last_image and level == last_level and last_future is not None:
            return last_future
        check_frame(image)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rodctl-png")
        while self._pending and self._pending[0].done():
            self._pending.popleft()
        while len(self._pending) >= self.max_pending:
            self._pending.popleft().exception()  # wait for the oldest; errors go to its sink
        future = self._pool.submit(encode_png, image, level)
        self._pending.append(future)
        self._last = (image, level, future)
        return future

    def reset(self) -> None:
        """Forget the cached frame (benchmarks: no frame carried over from the previous run)."""
        self._last = (None, -1, None)


#: Shared between the sinks of one process (the loop writes them one after the other).
FRAMES = FrameEncoder()
#: Steps by which the sinks delay writing a frame (and, in the MCAP, the whole step with it).
LAG = 1


def check_frame(image: np.ndarray) -> None:
    """Raise ValueError unless `image` is an (H, W, 3) or (H, W) uint8 frame."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"a frame must be (H, W, 3) or (H, W) uint8, got {img.shape} {img.dtype}")


def encode_png(image: np.ndarray, level: int = 1) -> bytes:
    """Lossless PNG of an (H, W, 3) RGB or (H, W) grey uint8 frame."""
    import cv2  # noqa: PLC0415 (here: the Rerun writer process imports this module, never cv2)

    check_frame(image)
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)  # OpenCV writes BGR
    # No filter + run-length zlib strategy: 1.3 ms for a plain 640 x 480 render (6 kB) and 1.5 ms
    # on the checker background (20 kB), against 1.6-1.9 ms with the Sub filter and 4-8 ms with
    # OpenCV's adaptive filtering (measured with opencv-python-headless 5.0.0.93).
    params = [
        cv2.IMWRITE_PNG_COMPRESSION,
        level,
        cv2.IMWRITE_PNG_FILTER,
        cv2.IMWRITE_PNG_FILTER_NONE,
        cv2.IMWRITE_PNG_STRATEGY,
        cv2.IMWRITE_PNG_STRATEGY_RLE,
    ]
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img), params)
    if not ok:  # pragma: no cover - OpenCV fails only on invalid input, checked above
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def decode_png(data: bytes) -> np.ndarray:
    """Inverse of `encode_png`: (H, W, 3) RGB or (H, W) grey uint8."""
    import cv2  # noqa: PLC0415 (as in `encode_png`)

    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError("not a PNG image")
    if img.ndim == 3:
        img = np.ascontiguousarray(img[:, :, ::-1])
    return img


def b64(data: bytes) -> str:
    """Base64 text, how JSON-encoded Foxglove messages carry bytes."""
    return base64.b64encode(data).decode("ascii")


# -------------------------------------------------------------------------------------- header
class FormatVersionError(ValueError):
    """A log written in a message layout this version of rodctl does not read."""


def check_format_version(d: dict[str, Any]) -> None:
    """Refuse a /run/header of a layout this rodctl does not read (version 1 logs had nested
    point arrays); versions 2 and 3 are read alike (`FORMAT_VERSION`)."""
    version = d.get("format_version")
    if version not in READABLE_VERSIONS:
        readable = " and ".join(repr(v) for v in READABLE_VERSIONS)
        raise FormatVersionError(
            f"log format version {version!r}, but this rodctl reads format versions "
            f"{readable} only (version 1 logs, written before the Foxglove-loadable "
            f"schemas, nested their point arrays); run the config again to get a new log"
        )


def header_to_json(h: RunHeader) -> dict[str, Any]:
    """The RunHeader as a JSON object (exact), less the run id.

    The run id names the run directory and carries its start time; leaving it out of the log
    keeps two runs of one config byte-identical. Readers take it from the file's folder.
    `numeric_env` travels as `[{key, value}]` with each value as JSON text (the schema parser
    Foxglove uses admits no free-form maps); its values must be JSON-able.
    """
    e = Encoder()
    out = {
        "format_version": FORMAT_VERSION,
        "method": h.method,
        "config_yaml": h.config_yaml,
        "image_size": [int(h.image_size[0]), int(h.image_size[1])],
        "clamp_pose": e.vec("clamp_pose", h.clamp_pose),
        "home_pose": e.vec("home_pose", h.home_pose),
        "target_centerline": e.points("target_centerline", h.target_centerline),
        "target_pixels": e.points("target_pixels", h.target_pixels),
        "target_feature": e.vec("target_feature", h.target_feature),
        "target_pose": e.vec("target_pose", h.target_pose),
        "rod_length": e.real("rod_length", h.rod_length),
        "numeric_env": [
            {"key": str(k), "value": json.dumps(sanitize(v), ensure_ascii=False)}
            for k, v in h.numeric_env.items()
        ],
    }
    out["nonfinite"] = e.nonfinite
    return out


def header_from_json(d: dict[str, Any], run_id: str) -> RunHeader:
    """Inverse of `header_to_json`; `run_id` is the name of the run's folder (`run_id_of`).

    Raises:
        FormatVersionError: the header is of another format version.
        ValueError, KeyError, TypeError: a malformed header.
    """
    check_format_version(d)
    d = restore_nonfinite(d)
    w, h = d["image_size"]
    return RunHeader(
        run_id=run_id,
        method=str(d["method"]),
        config_yaml=str(d["config_yaml"]),
        image_size=(int(w), int(h)),
        clamp_pose=decode_vec(d["clamp_pose"], 3),
        home_pose=_decode_q(d["home_pose"]),
        target_centerline=decode_points(d["target_centerline"]),
        target_pixels=decode_points(d["target_pixels"]),
        target_feature=decode_vec(d["target_feature"]),
        target_pose=_decode_q(d["target_pose"]),
        rod_length=decode_real(d["rod_length"]),
        numeric_env={str(kv["key"]): json.loads(kv["value"]) for kv in d["numeric_env"]},
    )


def _decode_q(v: Any) -> np.ndarray:
    """A pose vector of q = 3 (one moved end) or 6 (dual-arm) numbers."""
    out = decode_vec(v)
    if out.shape not in ((3,), (6,)):
        raise ValueError(f"expected 3 or 6 numbers, got {out.shape[0]}")
    return out


def sanitize(v: Any) -> Any:
    """A JSON-safe copy of nested dicts/lists/numpy values, non-finite floats as `encode_real`."""
    if isinstance(v, dict):
        return {str(k): sanitize(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [sanitize(x) for x in v]
    if isinstance(v, np.ndarray):
        return sanitize(v.tolist())
    if isinstance(v, np.generic):
        return sanitize(v.item())
    if isinstance(v, float):
        return encode_real(v)
    if v is None or isinstance(v, (str, int, bool)):
        return v
    return str(v)


def summary_to_json(summary: RunSummary | None, status: str) -> dict[str, Any]:
    """The /run/summary message: summary.json's mapping plus the sink's closing status."""
    out: dict[str, Any] = {"closing_status": status}
    if summary is not None:
        out.update(sanitize(summary.to_log_json()))
    return out


# --------------------------------------------------------------------------------------- steps
# Each per-step message starts with its contract fields (shared design contract: `step` and the
# names below, exactly), then extras, then `nonfinite`. Points are [{x, y}, ...] and J is flat
# row-major with `J_shape`: Foxglove's JSON-schema parser admits no arrays of arrays.
def rod_state_message(r: StepRecord) -> dict[str, Any]:
    """/rod/state: contract fields `step, sim_time, gripper, centerline`, then extras."""
    e = Encoder()
    return {
        "step": int(r.step),
        "sim_time": e.real("sim_time", r.sim_time),
        "gripper": e.vec("gripper", r.gripper),
        "centerline": e.points("centerline", r.centerline),
        "phase": r.phase,
        "settled": bool(r.settled),
        "clipped": bool(r.clipped),
        "max_joint_gap": e.real("max_joint_gap", r.max_joint_gap),
        "kinetic_energy": e.real("kinetic_energy", r.kinetic_energy),
        "events": [str(line) for line in r.events],
        "nonfinite": e.nonfinite,
    }


def clamp_state_message(r: StepRecord) -> dict[str, Any]:
    """/rod/clamp (dual-arm): `step, sim_time, clamp` (the x0 end's pose)."""
    assert r.clamp is not None, "a dual-arm step has the x0 end's pose"
    e = Encoder()
    return {
        "step": int(r.step),
        "sim_time": e.real("sim_time", r.sim_time),
        "clamp": e.vec("clamp", r.clamp),
        "nonfinite": e.nonfinite,
    }


def camera_message(r: StepRecord) -> dict[str, Any]:
    """/camera/centerline: contract fields `step, extracted, projected_truth`, then extras."""
    e = Encoder()
    return {
        "step": int(r.step),
        "extracted": e.points("extracted", r.extracted),
        "projected_truth": e.points("projected_truth", r.projected_truth),
        "extraction_ok": bool(r.extraction_ok),
        "extraction_note": r.extraction_note,
        "nonfinite": e.nonfinite,
    }


def control_message(r: StepRecord) -> dict[str, Any]:
    """/control: contract fields `step, u, s, s_target, T1, J (row-major), pixel_error`, extras."""
    J = np.asarray(r.J, dtype=np.float64)
    if J.ndim != 2:
        raise ValueError(f"step {r.step}: J must be (p, q), got shape {J.shape}")
    e = Encoder()
    msg = {
        "step": int(r.step),
        "u": e.vec("u", r.u),
        "s": e.vec("s", r.s),
        "s_target": e.vec("s_target", r.s_target),
        "T1": e.real("T1", r.T1),
        "J": e.vec("J", J),
        "pixel_error": e.real("pixel_error", r.pixel_error),
        "J_shape": [int(J.shape[0]), int(J.shape[1])],
        "J_singular_values": e.vec("J_singular_values", r.J_singular_values),
        "u_raw": e.vec("u_raw", r.u_raw),
        "saturated": [bool(x) for x in np.asarray(r.saturated).ravel()],
        "phase": r.phase,
        "estimator_info": [
            {"name": str(k), "value": e.real(f"estimator_info[{i}].value", v)}
            for i, (k, v) in enumerate(r.estimator_info.items())
        ],
        "nonfinite": e.nonfinite,
    }
    if not math.isnan(r.jacobian_error):  # absent where the step has none (NaN)
        msg["jacobian_error"] = e.real("jacobian_error", r.jacobian_error)
    return msg


def record_from_messages(
    rod: dict[str, Any], cam: dict[str, Any], ctl: dict[str, Any], image: np.ndarray | None
) -> StepRecord:
    """Rebuild one StepRecord from its three per-step messages (and its frame, if logged).

    The messages' `nonfinite` values are restored in place first.
    """
    rod, cam, ctl = (restore_nonfinite(m) for m in (rod, cam, ctl))
    p, q = (int(n) for n in ctl["J_shape"])
    return StepRecord(
        step=int(rod["step"]),
        sim_time=decode_real(rod["sim_time"]),
        phase=str(rod["phase"]),
        gripper=decode_vec(rod["gripper"]),
        centerline=decode_points(rod["centerline"]),
        extracted=decode_points(cam["extracted"]),
        projected_truth=decode_points(cam["projected_truth"]),
        u=decode_vec(ctl["u"]),
        u_raw=decode_vec(ctl["u_raw"]),
        s=decode_vec(ctl["s"]),
        s_target=decode_vec(ctl["s_target"]),
        T1=decode_real(ctl["T1"]),
        J=decode_vec(ctl["J"], p * q).reshape(p, q),
        J_singular_values=decode_vec(ctl["J_singular_values"]),
        pixel_error=decode_real(ctl["pixel_error"]),
        settled=bool(rod["settled"]),
        saturated=np.array(ctl["saturated"], dtype=bool),
        clipped=bool(rod["clipped"]),
        max_joint_gap=decode_real(rod["max_joint_gap"]),
        kinetic_energy=decode_real(rod["kinetic_energy"]),
        extraction_ok=bool(cam["extraction_ok"]),
        extraction_note=str(cam["extraction_note"]),
        estimator_info={str(kv["name"]): decode_real(kv["value"]) for kv in ctl["estimator_info"]},
        events=[str(line) for line in rod.get("events", [])],
        jacobian_error=decode_real(ctl["jacobian_error"]) if "jacobian_error" in ctl else math.nan,
        image=image,
    )


# ---------------------------------------------------------------------------------------- logs
_AXES = ("x", "y", "theta", "x0-end x", "x0-end y", "x0-end theta")


def _saturated_axes(r: StepRecord) -> list[str]:
    bits = np.asarray(r.saturated).ravel()
    return [axis for axis, bit in zip(_AXES[: len(bits)], bits, strict=True) if bit]


def step_log_lines(prev: StepRecord | None, r: StepRecord) -> list[tuple[str, str]]:
    """The human-readable events of one step as (level, text): phase changes and problems.

    Both sinks log exactly these lines (foxglove.Log on /log, Rerun TextLog at /log).
    """
    lines: list[tuple[str, str]] = [("WARN", f"step {r.step}: {line}") for line in r.events]
    if prev is None or prev.phase != r.phase:
        lines.append(("INFO", f"step {r.step}: phase {r.phase}"))
    if not r.extraction_ok:
        note = r.extraction_note or "no detail"
        lines.append(("WARN", f"step {r.step}: centerline extraction problem: {note}"))
    if not r.settled:
        lines.append(("WARN", f"step {r.step}: rod did not settle within the budget"))
    if r.clipped:
        lines.append(("INFO", f"step {r.step}: workspace clipped the commanded pose"))
    sat = _saturated_axes(r)
    if sat and (prev is None or sat != _saturated_axes(prev)):  # when it starts or changes
        lines.append(("INFO", f"step {r.step}: speed limit bit on {', '.join(sat)}"))
    if not math.isfinite(r.T1):
        lines.append(("ERROR", f"step {r.step}: T1 is not finite ({r.T1})"))
    return lines


def open_log_line(h: RunHeader) -> tuple[str, str]:
    """The first log line of a run."""
    return ("INFO", f"run started: method {h.method}")


def close_log_line(summary: RunSummary | None, status: str, steps: int) -> tuple[str, str]:
    """The last log line of a run."""
    level = "INFO" if status == "completed" else "ERROR"
    if summary is None:
        return (level, f"run {status} after {steps} logged steps (no summary)")
    return (
        level,
        f"run {status} ({summary.outcome}) after {summary.steps} steps: "
        f"final T1 {summary.final_T1:.6g}, final pixel error {summary.final_pixel_error:.4g} px",
    )


# ----------------------------------------------------------------------------------- read back
@dataclass
class ReadRun:
    """A run read back from its MCAP log.

    Attributes:
        path: the MCAP file read.
        header: the run's header.
        records: every complete step, in step order; `image` set on the logged frames.
        summary: summary.json's mapping as logged at close, or None (crashed before close).
        status: the status the writer closed with ("completed", "failed", "interrupted"), or
            None when the writer never closed.
        complete: True when the writer finished the file (footer and summary section present).
        warnings: what the reader noticed and skipped (incomplete file, missing messages…).
    """

    path: Path
    header: RunHeader
    records: list[StepRecord]
    summary: dict[str, Any] | None
    status: str | None
    complete: bool
    warnings: list[str] = field(default_factory=list)
