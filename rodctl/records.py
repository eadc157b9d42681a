"""Plain data that flows from the experiment loop to the sinks (MCAP, Rerun, summary, figures).

Sinks see only these dataclasses, so `rodctl replay` can rebuild every output from a log file by
feeding the same records the live loop fed. numpy only: no stage or sink library is imported here.

Timing of one record k (k = 0 is the initial observation, before any move):
    command u_k (pose increment) is applied -> the rod settles -> the camera sees c_k ->
    s_k = f_s(c_k) -> the estimator updates with (Delta s_k, u_k) -> J_k -> T1_k = ||s* - s_k||.
The command computed from record k is the `u` of record k + 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: How the quasi-static engine's snap-through notes begin. They travel with a step's event
#: lines (to /log) but are not mid-run events: `scheduled_events` leaves them out.
SNAP_NOTE = "snap-through:"


def scheduled_events(lines: list[str]) -> list[str]:
    """The lines of a step's `events` that are mid-run events (`run.events`), not engine notes."""
    return [line for line in lines if not line.startswith(SNAP_NOTE)]


@dataclass
class RunHeader:
    """What is fixed for a whole run; sinks receive it once, before the first step.

    Attributes:
        run_id: the run directory's name, also the Rerun recording id.
        method: the method label used in summaries and comparisons.
        config_yaml: the resolved config (every default filled in) as YAML text.
        image_size: (width, height) of camera frames in pixels.
        clamp_pose: (3,) pose of the clamped end, world frame.
        home_pose: (3,) gripper pose at the start of the run, world frame.
        target_centerline: (M, 2) ground-truth target centerline, world metres, clamp first.
        target_pixels: (N, 2) the target centerline as the camera extracted it, pixels.
        target_feature: (p,) s*, the feature of `target_pixels`.
        target_pose: (3,) gripper pose that produced the target, world frame.
        rod_length: rod length L (m).
        numeric_env: the numeric environment the run computed in (CPU model, BLAS vendor,
            numpy/OpenCV builds, ...), JSON-able values; logged in /run/header and read back
            as is, so a `replay --verify` mismatch can be traced to a different machine.
        provenance: {"plugins": ..., "stages": ...}, see `rodctl.registry.plugin_provenance`.
    """

    run_id: str
    method: str
    config_yaml: str
    image_size: tuple[int, int]
    clamp_pose: np.ndarray
    home_pose: np.ndarray
    target_centerline: np.ndarray
    target_pixels: np.ndarray
    target_feature: np.ndarray
    target_pose: np.ndarray
    rod_length: float
    numeric_env: dict[str, Any] = field(default_factory=dict)
    #: The plug-ins loaded and the factory of each stage (`rodctl.registry`): written as the
    #: MCAP metadata record `rodctl.provenance`; empty when read back from a log.
    provenance: dict[str, Any] = field(default_factory=dict)


@dataclass
class StepRecord:
    """Everything one control step produced. Arrays carry their shapes in the field docs.

    Attributes:
        step: control step index k (probing steps included; 0 = initial observation).
        sim_time: simulated time at the end of the step (s).
        phase: "initial", "probe" or "control".
        gripper: (3,) gripper pose [x, y, theta], world frame, after the move.
        centerline: (M, 2) simulator ground truth, world metres, clamp end first.
        extracted: (N, 2) centerline extracted from the camera image, pixels, clamp end first.
        projected_truth: (N, 2) ground truth projected by the camera model, pixels.
        u: (3,) pose increment [dx, dy, dtheta] applied in this step (after saturation/clipping).
        u_raw: (3,) the command the controller asked for, before saturation and workspace clipping.
        s: (p,) shape feature of `extracted`.
        s_target: (p,) target feature s*.
        T1: ||s* - s|| (paper's deformation metric).
        J: (p, q) Jacobian estimate after this step's update.
        J_singular_values: (min(p, q),) singular values of J, largest first.
        pixel_error: mean distance (px) between `extracted` and the target centerline.
        settled: whether the rod came to rest within the settle budget.
        saturated: (3,) per-axis flags, True where the speed limit bit.
        clipped: True when the workspace clipped or refused the commanded pose.
        max_joint_gap: largest pivot-joint separation in the chain (m), a health figure.
        kinetic_energy: rod kinetic energy when the step ended (J).
        extraction_ok: False when the extractor reported a problem (occlusion, lost rod).
        extraction_note: the extractor's message when `extraction_ok` is False, else "".
        estimator_info: scalar diagnostics of the estimator (e.g. AKF alpha, innovation).
        events: one line per mid-run event applied before this step's move (`run.events`).
        jacobian_error: ||J - J_true||_F / ||J_true||_F, the estimate against the simulator's
            true Jacobian of the same feature at this step's shape (`run.jacobian_error`);
            NaN where the method has no estimate or the run did not compute the true one.
        image: (H, W, 3) uint8 RGB camera frame, or None. The sinks choose which frames to log
            by `sim_time` (`rodctl.logs.codec.FrameSchedule`), so the loop may attach one to
            every record; records read back from a log carry one only where it was logged.
        clamp: (3,) the x0 end's pose [x, y, theta] after the move when a second arm moves it
            (`rod.arms: 2`; MCAP topic `/rod/clamp`), else None. Dual-arm, `u`, `u_raw` and
            `saturated` are (6,): the gripper's axes, then the x0 end's.
    """

    step: int
    sim_time: float
    phase: str
    gripper: np.ndarray
    centerline: np.ndarray
    extracted: np.ndarray
    projected_truth: np.ndarray
    u: np.ndarray
    u_raw: np.ndarray
    s: np.ndarray
    s_target: np.ndarray
    T1: float
    J: np.ndarray
    J_singular_values: np.ndarray
    pixel_error: float
    settled: bool = True
    saturated: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=bool))
    clipped: bool = False
    max_joint_gap: float = 0.0
    kinetic_energy: float = 0.0
    extraction_ok: bool = True
    extraction_note: str = ""
    estimator_info: dict[str, float] = field(default_factory=dict)
    events: list[str] = field(default_factory=list)
    jacobian_error: float = float("nan")
    image: np.ndarray | None = None
    clamp: np.ndarray | None = None


@dataclass(frozen=True)
class Unit:
    """The unit of a StepRecord field.

    Attributes:
        symbol: the unit itself, as `replay --verify` reports deviations in it.
        detail: what the MCAP channel metadata adds to it (frame, order, layout).
    """

    symbol: str
    detail: str = ""

    @property
    def described(self) -> str:
        """The unit with its detail: the MCAP channels' `unit.<field>` metadata."""
        return self.symbol + self.detail


_POSE = "m, m, rad"
_FEATURE = "feature units"
_JACOBIAN = "feature units per (m, m, rad)"
_PIXELS = "px"

#: The unit of each StepRecord field that has one: the one table that the MCAP channel metadata
#: (`rodctl.logs.codec.UNITS`) and `replay --verify` reports read.
FIELD_UNITS: dict[str, Unit] = {
    "step": Unit("1"),
    "sim_time": Unit("s"),
    "gripper": Unit(_POSE, " (world frame, y up)"),
    "clamp": Unit(_POSE, " (world frame, y up)"),
    "centerline": Unit("m", " (world frame, y up; clamp end first)"),
    "extracted": Unit(_PIXELS, " (u right, v down)"),
    "projected_truth": Unit(_PIXELS, " (u right, v down)"),
    "u": Unit(_POSE, " (pose increment dx, dy, dtheta)"),
    "u_raw": Unit(_POSE),
    "s": Unit(_FEATURE),
    "s_target": Unit(_FEATURE),
    "T1": Unit(_FEATURE),
    "J": Unit(_JACOBIAN, "; row-major p x q"),
    "J_singular_values": Unit(_JACOBIAN),
    "pixel_error": Unit(_PIXELS),
    "jacobian_error": Unit("1", " (||J - J_true||_F / ||J_true||_F)"),
    "max_joint_gap": Unit("m"),
    "kinetic_energy": Unit("J"),
    "estimator_info": Unit("estimator units"),
    "image": Unit("8-bit levels"),
}


def summary_text(value: Any) -> str:
    """One summary value as the tables of `simulate` and `replay` show it: a float to 6
    significant digits, None (a run that never converged has no steps_to_converge) as —, a
    mapping as `key=value, …`."""
    if isinstance(value, float):
        return f"{value:.6g}"
    if value is None:
        return "—"
    if isinstance(value, dict):
        return ", ".join(f"{k}={summary_text(v)}" for k, v in value.items())
    return str(value)


@dataclass
class RunSummary:
    """The run's outcome; written as summary.json (keys in docs/outputs.md).

    `outcome` is one of "converged", "stalled", "step_limit", "diverged", "interrupted", "failed".
    """

    status: str
    outcome: str
    method: str
    steps: int
    converged: bool
    steps_to_converge: int | None
    final_T1: float
    final_pixel_error: float
    wall_time_s: float
    steps_per_s: float
    extra: dict[str, Any] = field(default_factory=dict)

    #: Keys that describe this invocation rather than the simulated run: wall-clock figures and
    #: the run id (which carries the start time). Logs leave them out, so that two runs of the
    #: same config write byte-identical MCAP files; summary.json keeps them.
    INVOCATION_KEYS = ("run_id", "wall_time_s", "steps_per_s", "setup_time_s", "time_per_step_ms")

    def to_log_json(self) -> dict[str, Any]:
        """`to_json` without the `INVOCATION_KEYS`: what the simulation alone determines."""
        return {k: v for k, v in self.to_json().items() if k not in self.INVOCATION_KEYS}

    def to_json(self) -> dict[str, Any]:
        """The summary.json mapping: contract keys first, then `extra` merged in."""
        out = {
            "status": self.status,
            "outcome": self.outcome,
            "method": self.method,
            "steps": self.steps,
            "converged": self.converged,
            "steps_to_converge": self.steps_to_converge,
            "final_T1": self.final_T1,
            "final_pixel_error": self.final_pixel_error,
            "wall_time_s": self.wall_time_s,
            "steps_per_s": self.steps_per_s,
        }
        out.update(self.extra)
        return out
