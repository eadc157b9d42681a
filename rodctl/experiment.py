"""The experiment loop: observe -> feature -> estimate -> command -> move, one step at a time.

One control step flows one way (shared/design/architecture.md):

    RodSim.apply(u_k) -> settle -> ground-truth centerline (world, metres)
    Camera.render -> image -> CenterlineExtractor -> c_k (N = 100 pixels)
    FeatureMap.encode(c_k) -> s_k
    JacobianEstimator.update(Delta s_k, Delta r_k) -> J_k
    Controller.command(s_k, s*, J_k, r_k) -> u_{k+1}
    StepRecord -> sinks (MCAP, Rerun), summary, figures

Stages never see each other or the sinks; this module is the only place that wires them. The
loop is free of user interface: progress is reported through an `on_step` callback.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from rodctl.config import ExperimentConfig, dump_config
from rodctl.control import make_controller
from rodctl.errors import UserError
from rodctl.estimation import make_estimator
from rodctl.estimation.asap import asap_from_centerline
from rodctl.estimation.probing import fit_jacobian, probe_moves
from rodctl.features import make_feature_map
from rodctl.geometry import resample_polyline
from rodctl.logs.base import Sink
from rodctl.records import RunHeader, RunSummary, StepRecord
from rodctl.runs import rng
from rodctl.sim import RodSim
from rodctl.targets import difficulty, sample_target_pose
from rodctl.vision import Camera, CenterlineExtractor

Q = 3  # gripper degrees of freedom: x, y, theta


def method_label(cfg: ExperimentConfig) -> str:
    """A method's name in summaries and comparisons: feature/estimator/controller."""
    return f"{cfg.feature.type}/{cfg.estimator.type}/{cfg.controller.type}"


def pixel_error(extracted: np.ndarray, target: np.ndarray) -> float:
    """Mean distance (px) between corresponding points of two (N, 2) clamp-first centerlines."""
    return float(np.mean(np.linalg.norm(extracted - target, axis=1)))


@dataclass
class Observation:
    """What one look at the rod gives: ground truth, the camera frame and what was extracted."""

    centerline: np.ndarray  # (M, 2) world, simulator joints
    projected_truth: np.ndarray  # (N, 2) px
    image: np.ndarray  # (H, W, 3) uint8
    extracted: np.ndarray  # (N, 2) px
    ok: bool
    note: str


@dataclass
class Target:
    """A reachable target: the gripper pose that produces it and what the camera saw there."""

    pose: np.ndarray
    centerline: np.ndarray
    pixels: np.ndarray
    feature: np.ndarray
    difficulty: float


@dataclass
class StepTimes:
    """Wall time spent per stage, summed over the run (seconds)."""

    sim: float = 0.0
    vision: float = 0.0
    feature: float = 0.0
    control: float = 0.0
    logging: float = 0.0

    def per_step_ms(self, steps: int) -> dict[str, float]:
        n = max(steps, 1)
        return {k: round(1e3 * v / n, 4) for k, v in self.__dict__.items()}


class Interrupted(Exception):
    """Raised inside the loop when the user (Ctrl-C) or the system (SIGTERM) stops a run."""


@dataclass
class Experiment:
    """One shape-servoing experiment, built from a validated config.

    Attributes:
        cfg: the experiment config.
        run_id: the run's id (run directory name); recorded in the log header.
        records: every step record of the last `run()`, without camera images.
    """

    cfg: ExperimentConfig
    run_id: str = "adhoc"
    records: list[StepRecord] = field(default_factory=list)
    times: StepTimes = field(default_factory=StepTimes)

    def __post_init__(self) -> None:
        cfg = self.cfg
        self.clamp_pose = np.asarray(cfg.rod.clamp_pose, dtype=float)
        self.max_step = np.asarray(cfg.rod.max_step, dtype=float)
        self.camera = Camera(cfg.camera, rng(cfg.seed, "camera"))
        self.extractor = CenterlineExtractor(
            cfg.camera, self.camera, self.clamp_pose, rod_length=cfg.rod.length
        )
        self.features = make_feature_map(cfg.feature, points=cfg.camera.points, experiment=cfg)
        self.method = method_label(cfg)

    # --- observation -------------------------------------------------------------------------

    def observe(self, sim: RodSim) -> Observation:
        """Render the rod as the camera sees it and extract its centerline."""
        t = time.perf_counter()
        truth = sim.centerline()
        gripper = sim.gripper_pose
        image = self.camera.render(truth, gripper, self.clamp_pose)
        ext = self.extractor.extract(image, gripper)
        projected = self.camera.project(resample_polyline(truth, self.cfg.camera.points))
        self.times.vision += time.perf_counter() - t
        return Observation(truth, projected, image, ext.points, ext.ok, ext.note)

    def encode(self, pixels: np.ndarray) -> np.ndarray:
        t = time.perf_counter()
        s = self.features.encode(pixels)
        self.times.feature += time.perf_counter() - t
        return s

    # --- target ------------------------------------------------------------------------------

    def make_target(self) -> Target:
        """Drive a fresh rod to the target gripper pose (given or sampled) and look at it."""
        cfg = self.cfg
        sim = RodSim(cfg.rod)
        home = sim.home_pose
        tcfg = cfg.run.target
        if tcfg.pose is not None:
            pose, clipped = sim.clip_pose(np.asarray(tcfg.pose, dtype=float))
            if clipped:
                raise UserError(
                    f"run.target.pose {list(tcfg.pose)} is outside the workspace or out of reach "
                    f"(nearest allowed pose: {[round(float(v), 4) for v in pose]})"
                )
            candidates = [pose]
        else:
            gen = rng(cfg.seed, "targets")
            candidates = (
                sample_target_pose(
                    gen,
                    home,
                    cfg.rod.length,
                    lambda p: not sim.clip_pose(p)[1],
                    tcfg.min_offset,
                    tcfg.max_offset,
                )
                for _ in range(20)
            )
        for pose in candidates:
            res = sim.move_to(pose)
            obs = self.observe(sim)
            if res.diverged or not res.settled or not obs.ok:
                why = obs.note or ("diverged" if res.diverged else "did not settle")
                if tcfg.pose is not None:
                    raise UserError(f"run.target.pose {list(tcfg.pose)}: unusable target ({why})")
                sim = RodSim(cfg.rod)
                continue
            return Target(
                pose=sim.gripper_pose,
                centerline=obs.centerline,
                pixels=obs.extracted,
                feature=self.encode(obs.extracted),
                difficulty=difficulty(sim.gripper_pose, home, cfg.rod.length),
            )
        raise UserError("run.target: 20 sampled targets in a row were unusable; check the config")

    def offline_jacobian(self, rest_pixels: np.ndarray) -> np.ndarray:
        """The ASAP model Jacobian of the servoed nodes' pixels w.r.t. the gripper pose.

        The rest shape is what the camera sees at the start, mapped onto the rod's plane with
        the calibrated camera (the method knows no more about the rod than its image); the
        model gives d(node positions)/d(gripper pose) in world units, and the camera's
        projection Jacobian at each node turns it into pixels (the `nodes` feature's units).
        """
        est = self.cfg.estimator
        rest = self.camera.unproject(rest_pixels)
        J_world, nodes = asap_from_centerline(rest, est.nodes, est.servoed)
        proj = self.camera.projection_jacobian(nodes)  # (n, 2, 2)
        n = nodes.shape[0]
        return np.einsum("nij,njq->niq", proj, J_world.reshape(n, 2, Q)).reshape(2 * n, Q)

    # --- the loop ----------------------------------------------------------------------------

    def run(
        self,
        sinks: Sequence[Sink] = (),
        on_step: Callable[[StepRecord], None] | None = None,
        stop_requested: Callable[[], str | None] | None = None,
    ) -> RunSummary:
        """Run the experiment to its end and return the summary.

        Sinks are opened here and receive every record as it is made; closing them is the
        caller's job (so that it happens whatever way the run ends).

        Args:
            sinks: outputs that receive the header and every step record.
            on_step: called with each record after the sinks have it (progress display).
            stop_requested: polled before each step; a non-empty reason (e.g. "SIGINT") ends
                the run there by raising `Interrupted`, so a stop never cuts a step in half:
                every record made so far is complete and in every sink.
        """
        cfg = self.cfg
        wall0 = time.perf_counter()
        self.records = []
        self.times = StepTimes()
        target = self.make_target()
        sim = RodSim(cfg.rod)
        home = sim.home_pose
        scripted = cfg.controller.type == "scripted"
        controller = make_controller(cfg.controller, home_pose=home, max_step=self.max_step)
        header = RunHeader(
            run_id=self.run_id,
            method=self.method,
            config_yaml=dump_config(cfg),
            image_size=(cfg.camera.width, cfg.camera.height),
            clamp_pose=self.clamp_pose,
            home_pose=home,
            target_centerline=target.centerline,
            target_pixels=target.pixels,
            target_feature=target.feature,
            target_pose=target.pose,
            rod_length=cfg.rod.length,
        )
        self.header = header
        for sink in sinks:
            sink.open(header)

        image_every = _image_every(cfg.logging.image_rate_hz, cfg.rod.control_period)
        s_star = target.feature
        p = s_star.shape[0]
        J = np.zeros((p, Q))
        estimator = make_estimator(cfg.estimator, p, Q)

        def emit(rec: StepRecord, obs: Observation) -> None:
            if image_every and rec.step % image_every == 0:
                rec.image = obs.image
            t = time.perf_counter()
            for sink in sinks:
                sink.write(rec)
            self.times.logging += time.perf_counter() - t
            rec.image = None
            self.records.append(rec)
            if on_step is not None:
                on_step(rec)

        def make_record(k, phase, obs, s, u, u_raw, res=None, sat=None) -> StepRecord:
            """The record of step k; saturation flags come from the move when not given."""
            if sat is None:
                sat = res.saturated if res is not None else np.zeros(Q, dtype=bool)
            health = sim.health()
            return StepRecord(
                step=k,
                sim_time=float(sim.sim_time),
                phase=phase,
                gripper=sim.gripper_pose,
                centerline=obs.centerline,
                extracted=obs.extracted,
                projected_truth=obs.projected_truth,
                u=np.asarray(u, dtype=float),
                u_raw=np.asarray(u_raw, dtype=float),
                s=s,
                s_target=s_star,
                T1=float(np.linalg.norm(s_star - s)),
                J=J.copy(),
                J_singular_values=np.linalg.svd(J, compute_uv=False),
                pixel_error=pixel_error(obs.extracted, target.pixels),
                settled=True if res is None else bool(res.settled),
                saturated=np.asarray(sat, dtype=bool),
                clipped=False if res is None else bool(res.clipped or res.refused),
                max_joint_gap=float(health.max_joint_gap),
                kinetic_energy=float(health.kinetic_energy),
                extraction_ok=obs.ok,
                extraction_note=obs.note,
                estimator_info=estimator.info(),
            )

        def move(u: np.ndarray):
            t = time.perf_counter()
            res = sim.apply(u)
            self.times.sim += time.perf_counter() - t
            return res

        setup_time = time.perf_counter() - wall0  # target, rod at home, stages

        def check_stop() -> None:
            reason = stop_requested() if stop_requested is not None else None
            if reason:
                raise Interrupted(reason)

        # Step 0: the initial observation.
        obs = self.observe(sim)
        if not obs.ok:
            raise UserError(
                f"initial frame: the rod's centerline could not be extracted ({obs.note})"
            )
        s = self.encode(obs.extracted)
        offline = cfg.estimator.type == "offline"
        if offline:
            J = self.offline_jacobian(obs.extracted)
            estimator.reset(J)
        zero = np.zeros(Q)
        emit(make_record(0, "initial", obs, s, zero, zero, sat=np.zeros(Q, dtype=bool)), obs)
        k = 0
        outcome = None
        steps_to_converge = None
        probe_steps = 0

        # Probing: q + 1 small moves and a least-squares fit give J_0 (method-notes section 1).
        # J_0 is fitted before the last probe's record is made: a record never changes once a
        # sink has it (replay --verify compares the log with a rerun bit for bit).
        # A frame whose centerline was not extracted gives no feature: the moves made since the
        # last good frame are summed, so each Delta s is paired with the Delta r that caused it.
        unseen = np.zeros(Q)  # gripper motion since the last good frame
        if not (scripted or offline):
            moves = probe_moves(Q, np.asarray(cfg.run.probe_size))
            dS, dR = [], []
            for i, du in enumerate(moves):
                if k >= cfg.run.max_steps:
                    break
                check_stop()
                k += 1
                res = move(du)
                obs = self.observe(sim)
                unseen += res.u_applied
                if res.diverged:
                    outcome = "diverged"
                elif obs.ok:
                    s_new = self.encode(obs.extracted)
                    dS.append(s_new - s)
                    dR.append(unseen.copy())
                    unseen[:] = 0.0
                    s = s_new
                if outcome is None and i == len(moves) - 1:
                    if len(dR) < Q:
                        outcome = "lost_tracking"
                    else:
                        t = time.perf_counter()
                        J = _initial_jacobian(np.array(dS), np.array(dR))
                        estimator.reset(J)
                        self.times.control += time.perf_counter() - t
                emit(make_record(k, "probe", obs, s, res.u_applied, du, res), obs)
                if outcome is not None:
                    break
            probe_steps = k

        # Control.
        lost = 0
        # Pixel errors of the last stall_window + 1 good frames: progress over stall_window steps.
        window: deque[float] = deque(maxlen=cfg.run.stall_window + 1)
        while outcome is None and k < cfg.run.max_steps:
            check_stop()
            k += 1
            t = time.perf_counter()
            r_rel = sim.gripper_pose - home
            u_raw = np.asarray(controller.command(s, s_star, J, r_rel), dtype=float)
            self.times.control += time.perf_counter() - t
            if not np.all(np.isfinite(u_raw)):
                # A NaN estimate or feature: the method has broken down; do not move the robot.
                emit(make_record(k, "control", obs, s, np.zeros(Q), u_raw), obs)
                outcome = "diverged"
                break
            res = move(u_raw)  # the robot saturates per axis (rod.max_step) and reports it
            obs = self.observe(sim)
            unseen += res.u_applied
            if obs.ok:
                lost = 0
                s_new = self.encode(obs.extracted)
                t = time.perf_counter()
                J = estimator.update(s_new - s, unseen)
                self.times.control += time.perf_counter() - t
                unseen[:] = 0.0
                s = s_new
            else:
                lost += 1
            rec = make_record(k, "control", obs, s, res.u_applied, u_raw, res, res.saturated)
            emit(rec, obs)

            if res.diverged or not np.isfinite(rec.T1):
                outcome = "diverged"
            elif lost >= cfg.run.max_lost_frames:
                outcome = "lost_tracking"
            elif not obs.ok:
                continue  # a bridged or failed frame decides nothing
            elif scripted:
                if getattr(controller, "done", False) and res.settled:
                    outcome = "completed"
            elif rec.pixel_error < cfg.run.pixel_tolerance and (
                cfg.run.t1_tolerance is None or rec.T1 < cfg.run.t1_tolerance
            ):
                outcome = "converged"
                steps_to_converge = k
            else:
                window.append(rec.pixel_error)
                if len(window) == window.maxlen and _stalled(list(window), J, s_star - s, cfg):
                    outcome = "stalled"
        if outcome is None:
            outcome = "step_limit"

        last = self.records[-1]
        wall = time.perf_counter() - wall0
        us = np.array([r.u for r in self.records[1:]]).reshape(-1, Q)
        status = "failed" if outcome in ("diverged", "lost_tracking") else "completed"
        return RunSummary(
            status=status,
            outcome=outcome,
            method=self.method,
            steps=k,
            converged=outcome == "converged",
            steps_to_converge=steps_to_converge,
            final_T1=float(last.T1),
            final_pixel_error=float(last.pixel_error),
            wall_time_s=round(wall, 4),
            steps_per_s=round(k / (wall - setup_time), 3) if wall > setup_time else 0.0,
            extra={
                "run_id": self.run_id,
                "setup_time_s": round(setup_time, 4),
                "probe_steps": probe_steps,
                "target_pose": [float(v) for v in target.pose],
                "target_difficulty": round(target.difficulty, 6),
                "home_pose": [float(v) for v in home],
                "final_gripper": [float(v) for v in last.gripper],
                "final_J_singular_values": [float(v) for v in last.J_singular_values],
                "path_length": float(np.sum(np.linalg.norm(us[:, :2], axis=1))),
                "rotation_length": float(np.sum(np.abs(us[:, 2]))),
                "smoothness": float(np.sum(np.linalg.norm(np.diff(us, axis=0), axis=1))),
                "saturated_steps": int(sum(bool(np.any(r.saturated)) for r in self.records)),
                "clipped_steps": int(sum(r.clipped for r in self.records)),
                "unsettled_steps": int(sum(not r.settled for r in self.records)),
                "lost_frames": int(sum(not r.extraction_ok for r in self.records)),
                "time_per_step_ms": self.times.per_step_ms(len(self.records)),
            },
        )


def _initial_jacobian(dS: np.ndarray, dR: np.ndarray) -> np.ndarray:
    """J_0 from the probing moves; probes the workspace refused cannot span every axis."""
    try:
        return fit_jacobian(dS, dR)
    except ValueError as exc:
        raise UserError(
            f"probing: {exc}. The workspace clipped or refused the probing moves; make "
            "run.probe_size smaller or start further inside rod.workspace"
        ) from None


def _image_every(rate_hz: float, control_period: float) -> int:
    """Log a camera frame every this many steps (0: never) for a rate in simulated time."""
    if rate_hz <= 0:
        return 0
    return max(1, round(1.0 / (rate_hz * control_period)))


def _stalled(window: list[float], J: np.ndarray, e: np.ndarray, cfg: ExperimentConfig) -> bool:
    """No progress over the window while the descent direction J^T e has vanished.

    method-notes section 3: with p = 6 > q = 3 any law descending ||e||^2 along J can rest where
    J^T e = 0 but e != 0; that is a stall, not a slow convergence.
    """
    start, best = window[0], min(window[1:])
    no_progress = best > start * (1.0 - cfg.run.stall_improvement)
    denom = np.linalg.norm(J) * np.linalg.norm(e)
    grad = np.linalg.norm(J.T @ e) / denom if denom > 0 else 0.0
    return bool(no_progress and grad < cfg.run.stall_gradient)
