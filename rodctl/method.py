"""`Method`: a feature map, a Jacobian estimator and a controller behind one small interface.

Why: the loop must not know which method it runs. Everything that differs between the paper's
method, the baselines and a scripted path happens here, through what each stage declares:

- `start(task)`: the start hook. Builds a fresh estimator and controller (so a method object
  can run many episodes), encodes the target, and plans the probing moves when the estimator
  learns online and the controller needs a Jacobian.
- `act(observation) -> Δr`: folds the new observation in (encode it, update the estimate with
  the move really made) and returns the next gripper pose increment. The first observation of
  an episode goes to the estimator's `prepare` hook instead: the offline ASAP model builds its
  Jacobian from the first image there (and then needs no probing).

Probing (docs/method.md §4): q + 1 small moves and a least-squares
fit give J_0 for the online estimators. A frame whose centerline was not extracted gives no
feature: the moves made since the last good frame are summed, so each Δs is paired with the Δr
that caused it.
"""

from __future__ import annotations

import time
from typing import Any, cast

import numpy as np

from rodctl import fixedla as fla
from rodctl.config import ExperimentConfig
from rodctl.control.base import Controller, OpenLoopController
from rodctl.env import Q, StageTimes, Task
from rodctl.errors import UserError
from rodctl.estimation.base import JacobianEstimator, ObservingEstimator, PreparingEstimator
from rodctl.estimation.probing import fit_jacobian, probe_moves
from rodctl.registry import (
    CONTROLLERS,
    ESTIMATORS,
    FEATURES,
    BuildContext,
    load_plugins,
)

#: Phases of a command: the first observation, a probing move, a move of the control law.
INITIAL, PROBE, CONTROL = "initial", "probe", "control"


class Method:
    """One shape-servoing method: feature map + Jacobian estimator + controller.

    Args:
        feature, estimator, controller: registered stage configs (their `type` picks each).
        experiment: the whole experiment config, for stages that check it (an encoder
            checkpoint is checked against the rod and camera).
        points: N, the centerline points (default: the experiment's camera.points).

    Attributes (valid after `act`):
        s: (p,) the feature of the last good frame.
        s_target: (p,) the target feature s*.
        J: (p, q) the current Jacobian estimate.
        phase: the phase of the command `act` returned last (probe / control).
        failure: an outcome the method itself ended on (e.g. "lost_tracking" when probing saw
            too few frames), else None.
    """

    def __init__(
        self,
        feature: Any,
        estimator: Any,
        controller: Any,
        *,
        experiment: ExperimentConfig | None = None,
        points: int | None = None,
    ) -> None:
        load_plugins()
        if points is None:
            if experiment is None:
                raise TypeError("Method: give `points` or the `experiment` config")
            points = experiment.camera.points
        self.configs = {"feature": feature, "estimator": estimator, "controller": controller}
        self.label = f"{feature.type}/{estimator.type}/{controller.type}"
        self.points = int(points)
        self.feature = FEATURES.build(
            feature, BuildContext(points=self.points, experiment=experiment)
        )
        #: Which registered factory builds each stage (module:attr, file, built-in or plug-in),
        #: looked up once: a lookup resolves the factory's file (~60 us), and `start` builds
        #: the estimator and controller of these same types every episode.
        self.stages: dict[str, Any] = {
            kind: registry.provenance(self.configs[kind].type)
            for kind, registry in (
                ("feature", FEATURES),
                ("estimator", ESTIMATORS),
                ("controller", CONTROLLERS),
            )
        }
        self.times = StageTimes()
        self.task: Task | None = None

    @classmethod
    def from_config(cls, cfg: ExperimentConfig) -> Method:
        """The method an `ExperimentConfig` describes (its feature, estimator, controller)."""
        return cls(cfg.feature, cfg.estimator, cfg.controller, experiment=cfg)

    # --- the start hook ------------------------------------------------------------------------

    def start(self, task: Task) -> None:
        """Begin an episode: fresh estimator and controller, target feature, probing plan."""
        self.task = task
        self.times = StageTimes()
        self._target_pixels = np.array(task.target_pixels, dtype=float)
        self.s_target = self._encode(self._target_pixels)
        self.p = int(self.s_target.shape[0])
        # q: 3 (the gripper's x, y, theta) or 6 (both ends moved), as the task's home pose has it
        self.q = (
            int(np.asarray(task.home_pose).reshape(-1).shape[0])
            if task.home_pose is not None
            else Q
        )
        ctx = BuildContext(
            points=self.points,
            p=self.p,
            q=self.q,
            home_pose=task.home_pose,
            max_step=task.max_step,
            camera=task.camera,
            oracle=(
                (lambda: task.true_jacobian(self.feature.encode))
                if task.true_jacobian is not None
                else None
            ),
        )
        self.estimator: JacobianEstimator = ESTIMATORS.build(self.configs["estimator"], ctx)
        self.controller: Controller = CONTROLLERS.build(self.configs["controller"], ctx)
        if getattr(self.controller, "open_loop", False) and not isinstance(
            self.controller, OpenLoopController
        ):
            # an open-loop controller without `done` would silently run closed-loop (probed)
            raise UserError(
                f"controller {self.configs['controller'].type!r} says open_loop but is not an "
                "OpenLoopController: it needs `done` too (rodctl/control/base.py)"
            )
        # Which optional hooks the stages have, looked up once per episode: a runtime-protocol
        # isinstance costs ~10 us on Python 3.11, and the loop asks several times a step.
        self._open_loop_hooks = isinstance(self.controller, OpenLoopController)
        self._observes = isinstance(self.estimator, ObservingEstimator)
        self.J = np.zeros((self.p, self.q))
        self.s: np.ndarray | None = None
        self.phase = INITIAL
        self.failure: str | None = None
        self._unseen = np.zeros(self.q)  # gripper motion since the last good frame
        self._probes: list[np.ndarray] = []
        self._probe_pairs: tuple[list, list] = ([], [])
        self._probing_left = 0

    def release(self) -> None:
        """Let go of the last episode: its task, whose true-Jacobian closure holds that
        episode's env (rod, camera, frames), and the estimator and controller built for it
        (the oracle's holds the same closure). For a method kept for later episodes
        (`rodctl.bench.episodes`, `rodctl.diagnosis`); `start` builds them again."""
        self.task = None
        for name in ("estimator", "controller"):
            self.__dict__.pop(name, None)

    @property
    def open_loop(self) -> bool:
        """The controller ignores the feature and J (a scripted path): nothing to converge."""
        return self._open_loop_hooks and bool(cast(OpenLoopController, self.controller).open_loop)

    @property
    def finished(self) -> bool:
        """The controller has nothing left to do (the end of a scripted path)."""
        return self._open_loop_hooks and bool(cast(OpenLoopController, self.controller).done)

    @property
    def T1(self) -> float:
        """||s* - s||, the paper's deformation metric (feature units)."""
        return fla.norm(self.s_target - self.s)

    def estimator_info(self) -> dict[str, float]:
        """The estimator's scalar diagnostics for the log."""
        return self.estimator.info()

    # --- one step ------------------------------------------------------------------------------

    def act(self, observation: dict[str, Any]) -> np.ndarray:
        """Fold in an observation and return the next pose increment (3,) [dx, dy, dtheta].

        Args:
            observation: the environment's observation (`ShapeServoEnv`): `centerline`,
                `extraction_ok`, `gripper` and `applied` (the move really made last step).
        """
        target = observation.get("target")
        if target is not None and not np.array_equal(target, self._target_pixels):
            # The target's pixels move only when the camera was bumped: the goal, re-encoded.
            self._target_pixels = np.array(target, dtype=float)
            self.s_target = self._encode(self._target_pixels)
        if self.s is None:
            self._first(observation)
        else:
            self._fold(observation)
        return self._command(observation)

    def _first(self, obs: dict[str, Any]) -> None:
        pixels = np.asarray(obs["centerline"])
        self.s = self._encode(pixels)
        est = self.estimator
        model = est.prepare(pixels) if isinstance(est, PreparingEstimator) else None
        if model is not None:
            self.J = np.array(model, dtype=float)
        elif not self.open_loop:
            assert self.task is not None  # start() set it
            self._probes = list(probe_moves(self.q, self.task.probe_size))
            self._probing_left = len(self._probes)

    def _fold(self, obs: dict[str, Any]) -> None:
        """Pair the new feature with the moves since the last good frame; update J."""
        self._unseen += np.asarray(obs["applied"], dtype=float)
        ok = bool(obs["extraction_ok"])
        if self.phase == PROBE:
            self._probing_left -= 1
            if ok:
                s_new = self._encode(obs["centerline"])
                self._probe_pairs[0].append(s_new - self.s)
                self._probe_pairs[1].append(self._unseen.copy())
                self._unseen[:] = 0.0
                self.s = s_new
            if self._probing_left == 0:
                self._fit_initial_jacobian()
            return
        if ok:
            s_new = self._encode(obs["centerline"])
            t = time.perf_counter()
            if self._observes:  # a state-dependent model (ObservingEstimator)
                cast(ObservingEstimator, self.estimator).observe(
                    np.asarray(obs["centerline"]), np.asarray(obs["gripper"], dtype=float)
                )
            self.J = self.estimator.update(s_new - self.s, self._unseen)
            self.times.control += time.perf_counter() - t
            self._unseen[:] = 0.0
            self.s = s_new

    def _fit_initial_jacobian(self) -> None:
        """J_0 from the probing moves (least squares); too few good frames end the episode."""
        dS, dR = self._probe_pairs
        if len(dR) < self.q:
            self.failure = "lost_tracking"
            return
        t = time.perf_counter()
        try:
            self.J = fit_jacobian(np.array(dS), np.array(dR))
        except ValueError as exc:
            if len(dR) < self.q + 1:
                # A lost frame merged two probing moves (the last one undoes the others, so
                # e.g. +x with -(x+y+theta) leaves only 2 axes): the camera, not the set-up.
                self.failure = "lost_tracking"
                return
            raise UserError(
                f"probing: {exc}. The workspace clipped or refused the probing moves; make "
                "run.probe_size smaller or start further inside rod.workspace"
            ) from None
        self.estimator.reset(self.J)
        self.times.control += time.perf_counter() - t

    def _command(self, obs: dict[str, Any]) -> np.ndarray:
        if self._probes:
            self.phase = PROBE
            return np.array(self._probes.pop(0), dtype=float)
        self.phase = CONTROL
        t = time.perf_counter()
        assert self.task is not None and self.s is not None  # start() and _first() set them
        r = np.asarray(obs["gripper"], dtype=float) - self.task.home_pose
        raw = self.controller.command(self.s, self.s_target, self.J, r)
        u = np.asarray(raw if raw is not None else np.nan, dtype=float)
        if raw is None or u.shape != (self.q,):  # a plug-in's bug, not a divergence
            got = "None" if raw is None else f"an array of shape {u.shape}"
            raise ValueError(
                f"controller {self.configs['controller'].type!r}: command(s, s*, J, r) returned "
                f"{got}, not a ({self.q},) command"
            )
        self.times.control += time.perf_counter() - t
        return u

    def _encode(self, pixels: np.ndarray) -> np.ndarray:
        t = time.perf_counter()
        s = self.feature.encode(np.asarray(pixels))
        self.times.feature += time.perf_counter() - t
        return s
