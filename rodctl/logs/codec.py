"""Step records <-> JSON messages, shared by the MCAP writer, its reader and the Rerun sink.

Why a separate module: the MCAP file is the run's source of truth (`rodctl replay` rebuilds the
Rerun recording and the figures from it, and `replay --verify` compares every logged step bit for
bit with a fresh simulation), so encoding and decoding must be exact inverses and must live side by
side. Nothing here imports `mcap` or `rerun`.

Exactness: JSON numbers are written with Python's float `repr`, which round-trips every finite
float64 exactly. JSON has no NaN or infinity, so a non-finite value is written as `null` (NaN) or
the strings "Infinity" / "-Infinity"; `decode_real` maps them back. Camera frames travel as
lossless PNG, so a decoded frame equals the logged one byte for byte.

The contract fields of the three per-step topics (shared/design/architecture.md, "MCAP topics") are
written exactly as named there; fields beyond the contract (phase, health flags, estimator
diagnostics…) are extra JSON keys on the same messages, which a JSON-schema consumer ignores.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rodctl.records import RunHeader, RunSummary, StepRecord

#: Version of the message layout below; bumped when a field changes meaning.
FORMAT_VERSION = "1"

# Contract topics (architecture.md), one message per control step.
TOPIC_ROD_STATE = "/rod/state"
TOPIC_CAMERA_CENTERLINE = "/camera/centerline"
TOPIC_CONTROL = "/control"
# Foxglove well-known topics; the names double as Rerun entity paths.
TOPIC_ROD_SCENE = "/world/rod"
TOPIC_TARGET_SCENE = "/world/target"
TOPIC_GRIPPER_SCENE = "/world/gripper"
TOPIC_IMAGE = "/camera/image"
TOPIC_LOG = "/log"
# rodctl bookkeeping: one message each, what replay needs beyond the per-step topics.
TOPIC_HEADER = "/run/header"
TOPIC_SUMMARY = "/run/summary"

#: Units of every contract field, also written as MCAP channel metadata.
UNITS: dict[str, dict[str, str]] = {
    TOPIC_ROD_STATE: {
        "step": "1",
        "sim_time": "s",
        "gripper": "m, m, rad (world frame, y up)",
        "centerline": "m (world frame, y up; clamp end first)",
    },
    TOPIC_CAMERA_CENTERLINE: {
        "step": "1",
        "extracted": "px (u right, v down)",
        "projected_truth": "px (u right, v down)",
    },
    TOPIC_CONTROL: {
        "step": "1",
        "u": "m, m, rad (pose increment dx, dy, dtheta)",
        "s": "feature units",
        "s_target": "feature units",
        "T1": "feature units",
        "J": "feature units per (m, m, rad); row-major p x q",
        "pixel_error": "px",
    },
}

#: Log levels shared by foxglove.Log (numbers) and Rerun's TextLog (names).
LOG_LEVELS = {"DEBUG": 1, "INFO": 2, "WARN": 3, "ERROR": 4}


# ------------------------------------------------------------------------------------- numbers
def encode_real(x: float) -> float | str | None:
    """One float as a JSON value: itself when finite, else None (NaN) or "±Infinity"."""
    x = float(x)
    if math.isfinite(x):
        return x
    if math.isnan(x):
        return None
    return "Infinity" if x > 0 else "-Infinity"


def decode_real(v: Any) -> float:
    """Inverse of `encode_real`."""
    if v is None:
        return math.nan
    if isinstance(v, str):
        if v == "Infinity":
            return math.inf
        if v == "-Infinity":
            return -math.inf
        raise ValueError(f"not a number: {v!r}")
    if isinstance(v, bool):
        raise ValueError(f"not a number: {v!r}")
    return float(v)


def encode_array(a: np.ndarray) -> list[Any]:
    """A float array as nested JSON lists, exactly (fast path when every value is finite)."""
    a = np.asarray(a, dtype=np.float64)
    if np.isfinite(a).all():
        return a.tolist()
    flat = [encode_real(x) for x in a.ravel().tolist()]
    return np.array(flat, dtype=object).reshape(a.shape).tolist()


def decode_array(v: Any, ndim: int) -> np.ndarray:
    """Inverse of `encode_array` for an array of `ndim` dimensions (float64)."""
    try:
        out = np.array(v, dtype=np.float64)
    except (TypeError, ValueError):
        out = _decode_nested(v)
    if out.ndim != ndim and not (out.size == 0 and ndim == 2):
        raise ValueError(f"expected a {ndim}-D array, got shape {out.shape}")
    if out.size == 0 and ndim == 2:
        out = out.reshape(0, 2)
    return out


def _decode_nested(v: Any) -> np.ndarray:
    if isinstance(v, list):
        return np.array([_decode_nested(x) for x in v], dtype=np.float64)
    return np.float64(decode_real(v))


def time_ns(sim_time: float) -> int:
    """Simulated time (s) as MCAP log_time (ns, never negative)."""
    if not math.isfinite(sim_time):
        return 0
    return max(0, round(sim_time * 1e9))


def foxglove_time(t_ns: int) -> dict[str, int]:
    """A Foxglove `time` {sec, nsec} from nanoseconds."""
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


# -------------------------------------------------------------------------------------- images
class PngCache:
    """PNG bytes of the most recent frame, so the MCAP and Rerun sinks encode it only once.

    The cache holds a reference to the array it encoded, so its `id` cannot be reused by another
    array while cached. A frame mutated in place after being handed to a sink would be served
    stale; the loop hands each step a fresh frame.
    """

    def __init__(self) -> None:
        self._image: np.ndarray | None = None
        self._level = -1
        self._png = b""

    def encode(self, image: np.ndarray, level: int) -> bytes:
        """PNG bytes of an (H, W, 3) RGB or (H, W) grey uint8 frame."""
        if image is self._image and level == self._level:
            return self._png
        png = encode_png(image, level)
        self._image, self._level, self._png = image, level, png
        return png


#: Shared between sinks in one process (the loop writes them one after the other, same thread).
PNG_CACHE = PngCache()


def encode_png(image: np.ndarray, level: int = 1) -> bytes:
    """Lossless PNG of an (H, W, 3) RGB or (H, W) grey uint8 frame."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"a frame must be (H, W, 3) or (H, W) uint8, got {img.shape} {img.dtype}")
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
def header_to_json(h: RunHeader) -> dict[str, Any]:
    """The RunHeader as a JSON object (exact), less the run id.

    The run id names the run directory and carries its start time; leaving it out of the log
    keeps two runs of one config byte-identical. Readers take it from the file's folder.
    """
    return {
        "format_version": FORMAT_VERSION,
        "method": h.method,
        "config_yaml": h.config_yaml,
        "image_size": [int(h.image_size[0]), int(h.image_size[1])],
        "clamp_pose": encode_array(h.clamp_pose),
        "home_pose": encode_array(h.home_pose),
        "target_centerline": encode_array(h.target_centerline),
        "target_pixels": encode_array(h.target_pixels),
        "target_feature": encode_array(h.target_feature),
        "target_pose": encode_array(h.target_pose),
        "rod_length": encode_real(h.rod_length),
    }


def header_from_json(d: dict[str, Any], run_id: str) -> RunHeader:
    """Inverse of `header_to_json`; `run_id` is the name of the run's folder."""
    w, h = d["image_size"]
    return RunHeader(
        run_id=run_id,
        method=str(d["method"]),
        config_yaml=str(d["config_yaml"]),
        image_size=(int(w), int(h)),
        clamp_pose=decode_array(d["clamp_pose"], 1),
        home_pose=decode_array(d["home_pose"], 1),
        target_centerline=decode_array(d["target_centerline"], 2),
        target_pixels=decode_array(d["target_pixels"], 2),
        target_feature=decode_array(d["target_feature"], 1),
        target_pose=decode_array(d["target_pose"], 1),
        rod_length=decode_real(d["rod_length"]),
    )


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
def rod_state_message(r: StepRecord) -> dict[str, Any]:
    """/rod/state: contract fields `step, sim_time, gripper, centerline`, then extras."""
    return {
        "step": int(r.step),
        "sim_time": encode_real(r.sim_time),
        "gripper": encode_array(r.gripper),
        "centerline": encode_array(r.centerline),
        "phase": r.phase,
        "settled": bool(r.settled),
        "clipped": bool(r.clipped),
        "max_joint_gap": encode_real(r.max_joint_gap),
        "kinetic_energy": encode_real(r.kinetic_energy),
    }


def camera_message(r: StepRecord) -> dict[str, Any]:
    """/camera/centerline: contract fields `step, extracted, projected_truth`, then extras."""
    return {
        "step": int(r.step),
        "extracted": encode_array(r.extracted),
        "projected_truth": encode_array(r.projected_truth),
        "extraction_ok": bool(r.extraction_ok),
        "extraction_note": r.extraction_note,
    }


def control_message(r: StepRecord) -> dict[str, Any]:
    """/control: contract fields `step, u, s, s_target, T1, J (row-major), pixel_error`, extras."""
    J = np.asarray(r.J, dtype=np.float64)
    if J.ndim != 2:
        raise ValueError(f"step {r.step}: J must be (p, q), got shape {J.shape}")
    return {
        "step": int(r.step),
        "u": encode_array(r.u),
        "s": encode_array(r.s),
        "s_target": encode_array(r.s_target),
        "T1": encode_real(r.T1),
        "J": encode_array(J.ravel()),
        "pixel_error": encode_real(r.pixel_error),
        "J_shape": [int(J.shape[0]), int(J.shape[1])],
        "J_singular_values": encode_array(r.J_singular_values),
        "u_raw": encode_array(r.u_raw),
        "saturated": [bool(x) for x in np.asarray(r.saturated).ravel()],
        "phase": r.phase,
        "estimator_info": {str(k): encode_real(v) for k, v in r.estimator_info.items()},
    }


def record_from_messages(
    rod: dict[str, Any], cam: dict[str, Any], ctl: dict[str, Any], image: np.ndarray | None
) -> StepRecord:
    """Rebuild one StepRecord from its three per-step messages (and its frame, if logged)."""
    p, q = (int(n) for n in ctl["J_shape"])
    return StepRecord(
        step=int(rod["step"]),
        sim_time=decode_real(rod["sim_time"]),
        phase=str(rod["phase"]),
        gripper=decode_array(rod["gripper"], 1),
        centerline=decode_array(rod["centerline"], 2),
        extracted=decode_array(cam["extracted"], 2),
        projected_truth=decode_array(cam["projected_truth"], 2),
        u=decode_array(ctl["u"], 1),
        u_raw=decode_array(ctl["u_raw"], 1),
        s=decode_array(ctl["s"], 1),
        s_target=decode_array(ctl["s_target"], 1),
        T1=decode_real(ctl["T1"]),
        J=decode_array(ctl["J"], 1).reshape(p, q),
        J_singular_values=decode_array(ctl["J_singular_values"], 1),
        pixel_error=decode_real(ctl["pixel_error"]),
        settled=bool(rod["settled"]),
        saturated=np.array(ctl["saturated"], dtype=bool),
        clipped=bool(rod["clipped"]),
        max_joint_gap=decode_real(rod["max_joint_gap"]),
        kinetic_energy=decode_real(rod["kinetic_energy"]),
        extraction_ok=bool(cam["extraction_ok"]),
        extraction_note=str(cam["extraction_note"]),
        estimator_info={str(k): decode_real(v) for k, v in ctl["estimator_info"].items()},
        image=image,
    )


# ---------------------------------------------------------------------------------------- logs
def _saturated_axes(r: StepRecord) -> list[str]:
    return [axis for axis, bit in zip(("x", "y", "theta"), r.saturated, strict=True) if bit]


def step_log_lines(prev: StepRecord | None, r: StepRecord) -> list[tuple[str, str]]:
    """The human-readable events of one step as (level, text): phase changes and problems.

    Both sinks log exactly these lines (foxglove.Log on /log, Rerun TextLog at /log).
    """
    lines: list[tuple[str, str]] = []
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
