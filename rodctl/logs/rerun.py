"""The Rerun recording of a run (run.rrd): what a person scrubs through after a run.

Why a native recording next to the MCAP: Rerun's MCAP importer does not draw Foxglove scene
updates and leaves JSON channels raw, so the rod, the camera view and the time series are logged
here directly, with the same entity paths as the MCAP topics where they overlap.

Entities (timelines `step` = control step k, `sim_time` = simulated time since t = 0; no
wall-clock `log_time`, so two recordings of the same records compare equal with
`rerun rrd compare --unordered`; the .rrd bytes and chunk order are not reproducible, because
Rerun batches rows into chunks on a background thread):
- `/world/rod` (coloured by phase: probing violet, control blue), `/world/target` (static, a
  wide translucent green band under the rod), `/world/clamp` (static, light grey, labelled),
  `/world/gripper`: the scene in world metres with **y negated**: Rerun's 2D views are y-down
  while the world is y-up, so the stored y is -y_world and the view shows the rod the right way up.
- `/camera/image` (PNG frames chosen by `codec.FrameSchedule`), `/camera/target` (static, the
  widest band, translucent green, under the others), `/camera/projected_truth` (a narrower
  translucent yellow band), `/camera/centerline` (extracted, thin blue on top): pixels, already
  y-down; colours differ from the rendered rod (red) and from each other, and each band is
  narrower than the one under it, so at convergence, with the three lines on one another, the
  target still shows as a green edge around the others. `/camera/legend` (static): one labelled
  dot per overlay in the image's top-left corner, so no label sits on the rod.
- `/control/T1`, `/control/pixel_error`, `/control/u/{x,y,theta}`: scalars;
  `/control/probing/{T1,pixel_error}`: violet markers on the probing steps;
  `/control/jacobian_error` (||J - J_true||_F / ||J_true||_F, the steps that have one,
  `run.jacobian_error`), with a plot of its own in the final layout when the run logged any.
- Dual-arm (q = 6, `rod.arms: 2`): the x0 end's command on `/control/u/x0_end/{x,y,theta}`,
  plotted beside the gripper's (series named "gripper ..." and "x0 end ..."), and its pose as
  the arrow `/world/clamp_arm`; `/world/clamp` is then where the x0 end started.
- `/log`: the same log lines as the MCAP's `/log`.
The blueprint (2D scene, camera with the overlays over the image, T1, pixel error, the command's
translation (m) and rotation (rad) on two plots of their own scale, the log) gives both 2D views
fixed bounds, so nothing refits while scrubbing: the
camera view the image frame, the scene a box around the clamp of one rod length plus the gripper
arrow (sent when the recording starts, so a killed run still has a layout), replaced when the
recording closes by the box around everything the run drew, with a 10 % margin.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from rodctl.logs import codec
from rodctl.logs.base import raise_or_warn
from rodctl.records import RunHeader, RunSummary, StepRecord

if TYPE_CHECKING:  # the writer process (`rodctl.logs.rerun_process`) does without pydantic
    from rodctl.config.logging import LoggingConfig


class RerunSettings(Protocol):
    """What `RerunSink` reads of its config: a `LoggingConfig`, or the plain `RerunOptions` of
    the writer process (`rodctl.logs.rerun_process`, which imports this module, not back)."""

    @property
    def flush_every_steps(self) -> int: ...
    @property
    def image_rate_hz(self) -> float: ...
    @property
    def png_compression(self) -> int: ...


APPLICATION_ID = "rodctl"

# Scene colours, for Rerun's dark background.
_ROD = (70, 150, 255)
_ROD_PROBE = (190, 120, 255)
_TARGET = (40, 200, 90, 150)
_CLAMP = (225, 225, 225)
_GRIPPER = (255, 150, 20)
_CLAMP_ARM = (230, 90, 160)
# Camera overlays: the rendered rod is red on a light background.
_CAM_TARGET = (0, 170, 50, 150)
_EXTRACTED = (20, 70, 255)
_TRUTH = (255, 215, 0, 170)
#: Half-widths (px) of the camera overlays, widest under: target, truth, extracted.
_CAM_RADII = (4.5, 2.5, 0.8)
_PROBE_MARK = _ROD_PROBE
_AXES = ("x", "y", "theta")
_AXIS_COLORS = ((220, 50, 47), (38, 139, 210), (133, 153, 0))
#: The x0 end's axes (dual-arm), lighter shades of the gripper's.
_X0_AXIS_COLORS = ((255, 140, 130), (130, 195, 255), (200, 215, 90))
_AXIS_NAMES = ("Δx (m)", "Δy (m)", "Δθ (rad)")
#: Entity of the x0 end's command components (dual-arm), under `/control/u`.
X0_END = "x0_end"
TOPIC_JACOBIAN_ERROR = "/control/jacobian_error"
#: Arrow length of the gripper, as a fraction of the rod length.
_GRIPPER_SIZE = 0.12
_MARGIN = 0.10
#: Most tasks (column batches, frames, log lines) waiting for the background thread.
_MAX_TASKS = 8


def flip_y(points: np.ndarray) -> np.ndarray:
    """(M, 2) world points (y up) as stored in the recording (y down): (x, -y)."""
    out = np.array(points, dtype=np.float64, copy=True).reshape(-1, 2)
    out[:, 1] *= -1.0
    return out


def dual_arm(header: RunHeader) -> bool:
    """Whether the run moves both ends (q = 6): its header's home pose holds both ends'."""
    return np.asarray(header.home_pose).size == 6


def u_entities(header: RunHeader) -> list[tuple[str, str, tuple[int, int, int]]]:
    """(entity path, series name, colour) of each command component, in the order of `u`: the
    gripper's x, y, theta, then (dual-arm) the x0 end's."""
    if not dual_arm(header):
        return [
            (f"/control/u/{a}", n, c)
            for a, n, c in zip(_AXES, _AXIS_NAMES, _AXIS_COLORS, strict=True)
        ]
    return [
        (f"/control/u/{a}", f"gripper {n}", c)
        for a, n, c in zip(_AXES, _AXIS_NAMES, _AXIS_COLORS, strict=True)
    ] + [
        (f"/control/u/{X0_END}/{a}", f"x0 end {n}", c)
        for a, n, c in zip(_AXES, _AXIS_NAMES, _X0_AXIS_COLORS, strict=True)
    ]


def _gripper_size(header: RunHeader) -> float:
    L = float(header.rod_length)
    return _GRIPPER_SIZE * L if np.isfinite(L) and L > 0 else 0.05


def _box(points: Sequence[np.ndarray], margin: float = _MARGIN) -> rrb.VisualBounds2D:
    """Bounds around every finite stored point, `margin` of the larger side added all round."""
    pts = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in points])
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, 2))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = max(margin * float((hi - lo).max()), 0.02)
    return rrb.VisualBounds2D(
        x_range=[float(lo[0] - pad), float(hi[0] + pad)],
        y_range=[float(lo[1] - pad), float(hi[1] + pad)],
    )


def reach_bounds(header: RunHeader) -> rrb.VisualBounds2D:
    """Scene bounds known before the run: no point of the rod is farther than one rod length
    from the clamp, and the gripper arrow adds its own length; the target is included."""
    reach = float(header.rod_length) + _gripper_size(header)
    if not np.isfinite(reach) or reach <= 0:
        reach = 1.0
    c = flip_y(header.clamp_pose[:2])[0]
    corners = np.array([c - reach, c + reach])
    return _box([corners, flip_y(header.target_centerline)], margin=0.0)


def _series_views(header: RunHeader, jacobian_error: bool) -> list[rrb.TimeSeriesView]:
    """T1, pixel error, the command's translations and rotations (dual-arm: both ends' on the
    same two plots) and, when the run logged one, the Jacobian error."""
    u = [path for path, _, _ in u_entities(header)]
    views = [
        rrb.TimeSeriesView(
            origin="/control",
            contents=["/control/T1", "/control/probing/T1"],
            name="T1 (probing steps marked)",
        ),
        rrb.TimeSeriesView(
            origin="/control",
            contents=["/control/pixel_error", "/control/probing/pixel_error"],
            name="pixel error (px)",
        ),
        rrb.TimeSeriesView(
            origin="/control/u",
            contents=[p for p in u if not p.endswith("theta")],
            name="command: translation Δx, Δy (m per step)",
        ),
        rrb.TimeSeriesView(
            origin="/control/u",
            contents=[p for p in u if p.endswith("theta")],
            name="command: rotation Δθ (rad per step)",
        ),
    ]
    if jacobian_error:
        views.append(
            rrb.TimeSeriesView(
                origin="/control",
                contents=[TOPIC_JACOBIAN_ERROR],
                name="Jacobian error ||J − J_true||_F / ||J_true||_F",
            )
        )
    return views


def blueprint(
    header: RunHeader,
    scene_bounds: rrb.VisualBounds2D | None = None,
    jacobian_error: bool = False,
) -> rrb.Blueprint:
    """The layout: scene and camera on the left, time series and log on the right.

    Both 2D views have fixed bounds (`scene_bounds`, by default `reach_bounds`; the camera view
    the image frame with a small margin) so that they do not refit to the data every step.
    `jacobian_error`: add the Jacobian error's plot (the run logged it).
    """
    w, h = header.image_size
    pad = 0.03 * max(w, h)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(
                    origin="/world",
                    name="scene (world m, y up)",
                    visual_bounds=scene_bounds or reach_bounds(header),
                ),
                rrb.Spatial2DView(
                    origin="/camera",
                    name="camera (px): target green, truth yellow, extracted blue",
                    visual_bounds=rrb.VisualBounds2D(
                        x_range=[-pad, w + pad], y_range=[-pad, h + pad]
                    ),
                ),
            ),
            rrb.Vertical(
                *_series_views(header, jacobian_error),
                rrb.TextLogView(origin="/log", name="log"),
            ),
        ),
        collapse_panels=True,
    )


def _empty_buffer() -> dict[str, list]:
    return {
        key: []
        for key in (
            "step",
            "sim_time",
            "probe",
            "rod",
            "origin",
            "vector",
            "centerline",
            "projected_truth",
            "T1",
            "clamp_origin",
            "clamp_vector",
            "pixel_error",
            "u",
            "jacobian_error",
        )
    }


#: Longest wait for Rerun's file writer to take a flush (s); past it the run goes on or closes.
FLUSH_TIMEOUT_S = 10.0


def _scalars(data: dict[str, Any]) -> dict[str, Any]:
    """The entries of `data` that Rerun's `AnyValues` shows: numbers, strings and booleans."""
    return {k: v for k, v in data.items() if isinstance(v, (int, float, str, bool))}


def _bounded(call: Callable[[], object], timeout: float) -> BaseException | None:
    """Run `call()` on a helper thread for at most `timeout` seconds; its error, or a
    TimeoutError when it did not return (Rerun's file writer waits for ever on a full disk).

    A call that does not return is abandoned (a daemon thread), and Rerun's own exit handler,
    which would wait for the same writer, is unregistered so that the process can still end.
    """
    import threading

    box: list[BaseException | None] = [None]

    def run() -> None:
        try:
            call()
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box[0] = exc

    worker = threading.Thread(target=run, name="rodctl-rerun-close", daemon=True)
    worker.start()
    worker.join(timeout)
    if worker.is_alive():
        rr.unregister_shutdown()
        return TimeoutError(f"Rerun's file writer did not finish within {timeout:g} s")
    return box[0]


def _log_static_series(rec: rr.RecordingStream, header: RunHeader) -> None:
    """The time series' names and colours: T1, pixel error, their probing marks, and each
    component of the command (dual-arm: both ends', named by end)."""
    rec.log("/control/T1", rr.SeriesLines(names="T1", colors=[_ROD]), static=True)
    rec.log(
        "/control/pixel_error",
        rr.SeriesLines(names="pixel error", colors=[_ROD]),
        static=True,
    )
    for name in ("T1", "pixel_error"):
        rec.log(
            f"/control/probing/{name}",
            rr.SeriesPoints(
                names="probing", colors=[_PROBE_MARK], markers="diamond", marker_sizes=4.0
            ),
            static=True,
        )
    for entity, name, color in u_entities(header):
        rec.log(entity, rr.SeriesLines(names=name, colors=[color]), static=True)


class RerunSink:
    """Writes a run as a Rerun recording (see the module docstring for the entities).

    Args:
        path: the .rrd file to write.
        cfg: the logging config (flush interval, PNG level of frames).
    """

    def __init__(
        self,
        path: str | Path | None,
        cfg: LoggingConfig | RerunSettings | None = None,
        *,
        url: str | None = None,
    ) -> None:
        if (path is None) == (url is None):
            raise ValueError("RerunSink: give a file path or a viewer url, not both")
        self.path = Path(path) if path is not None else None
        self.url = url  # live: the same recording streamed to a Rerun viewer (`simulate --live`)
        if cfg is None:
            from rodctl.config.logging import LoggingConfig  # noqa: PLC0415 (TYPE_CHECKING above)

            cfg = LoggingConfig()
        #: `flush_every_steps`, `image_rate_hz`, `png_compression` (a `LoggingConfig`, or the
        #: `RerunOptions` of the writer process)
        self.cfg = cfg
        self._rec: rr.RecordingStream | None = None
        self._header: RunHeader | None = None
        self._prev: StepRecord | None = None
        self._steps = 0
        self._last_step = 0
        self._last_time: np.timedelta64 = np.timedelta64(0, "ns")
        self._closed = False
        self._jacobian_error = False  # a step with a Jacobian error was sent (its plot, style)
        self._buf = _empty_buffer()
        self._frames = codec.FrameSchedule(self.cfg.image_rate_hz)
        self._worker: ThreadPoolExecutor | None = None
        self._tasks: deque[Future[None]] = deque()
        # Box of everything drawn in the scene so far (stored coordinates), for the final bounds.
        self._lo = np.full(2, np.inf)
        self._hi = np.full(2, -np.inf)

    # ---------------------------------------------------------------------------- Sink protocol
    def open(self, header: RunHeader) -> None:
        """Start the recording (id = run id), send the blueprint and the static scene."""
        if self._rec is not None or self._closed:
            raise RuntimeError("RerunSink.open called twice")
        self._header = header
        # No time-based batching: rows logged one by one (frames, log lines) are cut into chunks
        # only where `_send` flushes, every `flush_every_steps` steps, so two runs of one config
        # give the same chunks (rrd compare matches chunks) however busy the machine is.
        rec = rr.RecordingStream(
            APPLICATION_ID,
            recording_id=header.run_id,
            batcher_config=rr.ChunkBatcherConfig.NEVER(),
        )
        rec.set_log_time_enabled(False)
        # Rerun reports a file it cannot create as `RuntimeError: Failed to create file`, with
        # no path or reason: open it first, so a read-only or full disk is an OSError that
        # names both (one line from the CLI).
        if self.path is not None:
            open(self.path, "ab").close()
            rec.save(self.path, default_blueprint=blueprint(header))
        else:
            rec.set_sinks(rr.GrpcSink(self.url), default_blueprint=blueprint(header))
        self._rec = rec
        # No recording name: it would only repeat the id, and the id (which carries the start
        # time) is the one thing allowed to differ between two runs of one config.
        rec.send_property(
            "rodctl",
            rr.AnyValues(
                method=header.method,
                config_yaml=header.config_yaml,
                rod_length_m=float(header.rod_length),
                image_size=np.asarray(header.image_size, dtype=np.int64),
                numeric_env=json.dumps(codec.sanitize(header.numeric_env), sort_keys=True),
            ),
        )
        self._log_static_scene(rec, header)
        rec.set_time("step", sequence=0)
        rec.set_time("sim_time", duration=np.timedelta64(0, "ns"))
        level, text = codec.open_log_line(header)
        rec.log("/log", rr.TextLog(text, level=level))

    def _log_static_scene(self, rec: rr.RecordingStream, header: RunHeader) -> None:
        """What does not change during the run: the target, the clamp, and each entity's style
        (colours, radii, draw order, series names), so the per-step batches carry data only."""
        self._log_static_world(rec, header)
        self._log_static_camera(rec, header)
        _log_static_series(rec, header)

    def _log_static_world(self, rec: rr.RecordingStream, header: RunHeader) -> None:
        """The scene's target and clamp, and the style of the rod and the moved ends' arrows."""
        target = flip_y(header.target_centerline)
        clamp = flip_y(header.clamp_pose[:2])
        self._extend(target)
        self._extend(clamp)
        L = float(header.rod_length) if np.isfinite(header.rod_length) else 0.5
        dual = dual_arm(header)
        rec.log(
            "/world/target",
            rr.LineStrips2D([target], colors=[_TARGET], radii=0.012 * L, draw_order=10.0),
            static=True,
        )
        rec.log(
            "/world/clamp",
            rr.Points2D(
                clamp,
                colors=[_CLAMP],
                radii=0.025 * L,
                labels=["x0 end at start" if dual else "clamp"],
                draw_order=40.0,
            ),
            static=True,
        )
        rec.log(
            "/world/rod",
            rr.LineStrips2D.from_fields(colors=[_ROD], radii=0.005 * L, draw_order=20.0),
            static=True,
        )
        # Dual-arm: both ends are arrows, labelled so that a user sees which is which.
        ends = [("/world/gripper", _GRIPPER, "gripper")]
        if dual:
            ends.append(("/world/clamp_arm", _CLAMP_ARM, "x0 end"))
        for entity, color, label in ends:
            rec.log(
                entity,
                rr.Arrows2D.from_fields(
                    colors=[color],
                    radii=0.006 * L,
                    draw_order=30.0,
                    labels=[label] if dual else None,
                    show_labels=True if dual else None,
                ),
                static=True,
            )

    def _log_static_camera(self, rec: rr.RecordingStream, header: RunHeader) -> None:
        """The camera's target, its legend, and the style of the per-step overlays."""
        rec.log(
            "/camera/target",
            rr.LineStrips2D(
                [header.target_pixels], colors=[_CAM_TARGET], radii=_CAM_RADII[0], draw_order=20.0
            ),
            static=True,
        )
        # The overlays' names as a legend in the image's corner: a label on a line sits at its
        # middle, on the rod.
        w, h = header.image_size
        step = max(14.0, 0.04 * h)
        rec.log(
            "/camera/legend",
            rr.Points2D(
                [(step, step * (i + 1)) for i in range(3)],
                colors=[_CAM_TARGET[:3], _TRUTH[:3], _EXTRACTED],
                radii=4.0,
                labels=["target", "truth (projected)", "extracted"],
                show_labels=True,
                draw_order=50.0,
            ),
            static=True,
        )
        rec.log(
            "/camera/centerline",
            rr.LineStrips2D.from_fields(colors=[_EXTRACTED], radii=_CAM_RADII[2], draw_order=30.0),
            static=True,
        )
        rec.log(
            "/camera/projected_truth",
            rr.LineStrips2D.from_fields(colors=[_TRUTH], radii=_CAM_RADII[1], draw_order=25.0),
            static=True,
        )

    def write(self, record: StepRecord) -> None:
        """Buffer one step; every `flush_every_steps` steps the buffer is sent as columns.

        Sending columns (one call per entity per batch instead of one per entity per step) cuts
        the Python-side cost of Rerun logging about fivefold. Batches, frames (PNG-encoded by
        `codec.FRAMES`) and log lines go to the recording through the sink's FIFO thread
        (`_in_order`); what they need of the record is copied first, so the loop may reuse its
        arrays.
        """
        frame = None
        if record.image is not None and self._frames.due(record):
            frame = codec.FRAMES.submit(record.image, self.cfg.png_compression)
            self._frames.take(record)
        self.write_step(record, frame)

    def write_step(self, record: StepRecord, frame: Future[bytes] | None) -> None:
        """`write` with the frame chosen and encoded already: `frame` is the PNG of the step's
        camera frame (a future, or None: no frame this step; `record.image` is not read).
        The writer process (`rodctl.logs.rerun_process`) gets the frames the command chose."""
        rec, header = self._rec, self._header
        if rec is None or header is None:
            raise RuntimeError("RerunSink.write called before open (or after close)")
        r = record
        k = int(r.step)
        # Integer nanoseconds, as the MCAP's log_time (Rerun truncates float seconds).
        t = np.timedelta64(codec.time_ns(r.sim_time), "ns")
        self._last_step, self._last_time = k, t
        lines = codec.step_log_lines(self._prev, r)
        if frame is not None:
            self._in_order(self._log_frame, k, t, frame)
        if lines:
            self._in_order(self._log_lines, k, t, lines)
        g = np.asarray(r.gripper, dtype=np.float64)
        size = _gripper_size(header)
        rod = flip_y(r.centerline)
        origin = (g[0], -g[1])
        vector = (size * np.cos(g[2]), -size * np.sin(g[2]))
        self._extend(rod)
        self._extend(np.array([origin, (origin[0] + vector[0], origin[1] + vector[1])]))
        b = self._buf
        b["step"].append(k)
        b["sim_time"].append(t)
        b["probe"].append(r.phase == "probe")
        b["rod"].append(rod)
        b["origin"].append(origin)
        b["vector"].append(vector)
        # Copies: the FIFO thread reads them later, and the loop may reuse its arrays.
        b["centerline"].append(np.array(r.extracted, dtype=np.float64))
        b["projected_truth"].append(np.array(r.projected_truth, dtype=np.float64))
        b["T1"].append(float(r.T1))
        b["pixel_error"].append(float(r.pixel_error))
        b["u"].append(np.array(r.u, dtype=np.float64))  # q values: dual-arm, both ends'
        b["jacobian_error"].append(float(r.jacobian_error))
        if r.clamp is not None:  # dual-arm: the second arm's end, an arrow into the rod
            c = np.asarray(r.clamp, dtype=np.float64)
            c_origin = (c[0], -c[1])
            c_vector = (size * np.cos(c[2]), -size * np.sin(c[2]))
            self._extend(np.array([c_origin, np.add(c_origin, c_vector)]))
            b["clamp_origin"].append(c_origin)
            b["clamp_vector"].append(c_vector)
        self._prev = r
        self._steps += 1
        if len(b["step"]) >= self.cfg.flush_every_steps:
            buf, self._buf = self._buf, _empty_buffer()
            self._in_order(self._send, buf)

    def _in_order(self, fn, *args) -> None:
        """Run `fn(*args)` on the sink's background thread, after everything handed over before.

        Why: building Rerun's columns, and logging frames (which waits for their PNG), cost the
        loop ~1 ms a step on its own thread. Every call to the recording after `open` goes
        through this one FIFO thread, so the file's chunks are cut where `_send` flushes whatever
        the timing (two runs of one config still compare equal). At most `_MAX_TASKS` tasks
        wait; beyond that the loop waits for the oldest. A failure surfaces there or at close.
        """
        if self._worker is None:
            self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rodctl-rerun")
        while self._tasks and self._tasks[0].done():
            self._tasks.popleft().result()
        while len(self._tasks) >= _MAX_TASKS:
            self._tasks.popleft().result()
        self._tasks.append(self._worker.submit(fn, *args))

    def _log_frame(self, k: int, t: np.timedelta64, future: Future[bytes]) -> None:
        rec = self._rec
        png = future.result()
        if rec is not None:
            rec.set_time("step", sequence=k)
            rec.set_time("sim_time", duration=t)
            rec.log("/camera/image", rr.EncodedImage(contents=png, media_type="image/png"))

    def _log_lines(self, k: int, t: np.timedelta64, lines: list[tuple[str, str]]) -> None:
        rec = self._rec
        if rec is not None:
            rec.set_time("step", sequence=k)
            rec.set_time("sim_time", duration=t)
            for level, text in lines:
                rec.log("/log", rr.TextLog(text, level=level))

    def _extend(self, points: np.ndarray) -> None:
        """Grow the scene box by (M, 2) stored points (non-finite ones ignored)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if not np.isfinite(pts).all():
            pts = pts[np.isfinite(pts).all(axis=1)]
            if len(pts) == 0:
                return
        np.minimum(self._lo, pts.min(axis=0), out=self._lo)
        np.maximum(self._hi, pts.max(axis=0), out=self._hi)

    def _send(self, b: dict[str, list] | None = None) -> None:
        """Send buffered steps (`b`, default the current buffer) as one column batch per entity."""
        rec = self._rec
        if b is None:
            b, self._buf = self._buf, _empty_buffer()
        n = len(b["step"])
        if rec is None or n == 0:
            return
        idx = [
            rr.TimeColumn("step", sequence=np.asarray(b["step"], dtype=np.int64)),
            rr.TimeColumn("sim_time", duration=np.asarray(b["sim_time"], dtype="timedelta64[ns]")),
        ]
        ones = [1] * n
        probe = np.asarray(b["probe"], dtype=bool)
        colors = [_ROD_PROBE if p else _ROD for p in probe]
        rec.send_columns(
            "/world/rod",
            idx,
            rr.LineStrips2D.columns(strips=b["rod"], colors=colors).partition(ones),
        )
        rec.send_columns(
            "/world/gripper",
            idx,
            rr.Arrows2D.columns(
                origins=np.asarray(b["origin"]), vectors=np.asarray(b["vector"])
            ).partition(ones),
        )
        if len(b["clamp_origin"]) == n:  # dual-arm
            rec.send_columns(
                "/world/clamp_arm",
                idx,
                rr.Arrows2D.columns(
                    origins=np.asarray(b["clamp_origin"]), vectors=np.asarray(b["clamp_vector"])
                ).partition(ones),
            )
        for name in ("centerline", "projected_truth"):
            rec.send_columns(
                f"/camera/{name}", idx, rr.LineStrips2D.columns(strips=b[name]).partition(ones)
            )
        rec.send_columns("/control/T1", idx, rr.Scalars.columns(scalars=b["T1"]))
        rec.send_columns("/control/pixel_error", idx, rr.Scalars.columns(scalars=b["pixel_error"]))
        self._send_commands(rec, idx, b["u"])
        if probe.any():
            pidx = _time_columns(b, probe)
            for name in ("T1", "pixel_error"):
                values = np.asarray(b[name], dtype=np.float64)[probe]
                rec.send_columns(
                    f"/control/probing/{name}", pidx, rr.Scalars.columns(scalars=values)
                )
        self._send_jacobian_error(rec, b)
        # The batched rows become chunks here, and reach the file. Bounded: a full disk can make
        # the file writer stop accepting data, and an unbounded flush then waits for ever.
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)

    def _send_commands(self, rec: rr.RecordingStream, idx: list, u_rows: list) -> None:
        """Each component of the applied command u, on its entity (`u_entities`)."""
        assert self._header is not None
        entities = u_entities(self._header)
        u = np.asarray(u_rows, dtype=np.float64).reshape(len(u_rows), -1)
        if u.shape[1] != len(entities):
            raise ValueError(
                f"u has {u.shape[1]} values a step, but the run's header is for q = {len(entities)}"
            )
        for i, (entity, _, _) in enumerate(entities):
            rec.send_columns(entity, idx, rr.Scalars.columns(scalars=u[:, i]))

    def _send_jacobian_error(self, rec: rr.RecordingStream, b: dict[str, list]) -> None:
        """The Jacobian error of the steps that have one (NaN: none, `StepRecord`); its style
        with the first."""
        values = np.asarray(b["jacobian_error"], dtype=np.float64)
        have = np.isfinite(values)
        if not have.any():
            return
        if not self._jacobian_error:
            self._jacobian_error = True
            rec.log(
                TOPIC_JACOBIAN_ERROR,
                rr.SeriesLines(names="||J − J_true||_F / ||J_true||_F", colors=[_GRIPPER]),
                static=True,
            )
        rec.send_columns(
            TOPIC_JACOBIAN_ERROR, _time_columns(b, have), rr.Scalars.columns(scalars=values[have])
        )

    def close(self, summary: RunSummary | None, status: str) -> None:
        """Log the closing line and finish the file (footer). Idempotent.

        Errors are raised for a completed run and become warnings otherwise, so they never mask
        the exception that ended the run.
        """
        if self._closed:
            return
        self._closed = True
        rec = self._rec
        if rec is None:
            return
        errors: list[BaseException] = []
        while self._tasks:  # everything handed to the background thread, in order
            try:
                self._tasks.popleft().result()
            except Exception as exc:  # noqa: BLE001 - collected, see docstring
                errors.append(exc)
        if self._worker is not None:
            self._worker.shutdown(wait=True)
        try:
            self._send()
        except Exception as exc:  # noqa: BLE001 - collected, see docstring
            errors.append(exc)
        self._rec = None
        try:
            rec.set_time("step", sequence=self._last_step)
            rec.set_time("sim_time", duration=self._last_time)
            level, text = codec.close_log_line(summary, status, self._steps)
            rec.log("/log", rr.TextLog(text, level=level))
            if summary is not None:
                rec.send_property(
                    "summary",
                    rr.AnyValues(**_scalars(codec.sanitize(summary.to_log_json()))),
                )
        except Exception as exc:  # noqa: BLE001 - collected, see docstring
            errors.append(exc)
        try:
            # The whole run is known now: fix the scene's bounds around everything it drew.
            if self._header is not None and np.isfinite(self._lo).all():
                bounds = _box([np.array([self._lo, self._hi])])
                rec.send_blueprint(
                    blueprint(self._header, bounds, jacobian_error=self._jacobian_error),
                    make_active=True,
                    make_default=True,
                )
        except Exception as exc:  # noqa: BLE001 - collected, see docstring
            errors.append(exc)
        try:
            rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except Exception as exc:  # noqa: BLE001
            errors.append(exc)
        error = _bounded(rec.disconnect, FLUSH_TIMEOUT_S)
        if error is not None:
            errors.append(error)
        where = self.path if self.path is not None else self.url
        raise_or_warn(errors, status, f"{where}: closing the Rerun recording failed")


def _time_columns(b: dict[str, list], mask: np.ndarray) -> list[rr.TimeColumn]:
    """The `step` and `sim_time` columns of the buffered steps where `mask` holds."""
    return [
        rr.TimeColumn("step", sequence=np.asarray(b["step"], dtype=np.int64)[mask]),
        rr.TimeColumn(
            "sim_time", duration=np.asarray(b["sim_time"], dtype="timedelta64[ns]")[mask]
        ),
    ]


def check_viewer(url: str, timeout: float = 3.0) -> None:
    """Raise `UserError` unless something listens at the Rerun gRPC `url` (rerun+http://host:port
    /proxy): Rerun's client would otherwise buffer the run for a viewer that never comes."""
    import socket
    from urllib.parse import urlsplit

    from rodctl.errors import UserError

    parts = urlsplit(url)
    if parts.scheme not in ("rerun", "rerun+http", "rerun+https") or parts.path != "/proxy":
        raise UserError(
            f"--live-rerun {url}: expected a Rerun gRPC url such as "
            "rerun+http://127.0.0.1:9876/proxy"
        )
    host, port = parts.hostname or "127.0.0.1", parts.port or 9876
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise UserError(
            f"--live-rerun {url}: no Rerun viewer listens there ({exc.strerror or exc}); start "
            f"one first with `rerun --port {port}`"
        ) from None
