"""A learned, state-dependent Jacobian updated online: our Yu et al. 2023 baseline (`learned`).

A re-implementation from published descriptions and the authors' public code (docs/learned.md,
docs/baselines.md "yu2023"), not the authors' code: M. Yu et al., "Global Model Learning for
Large Deformation Control of Elastic Deformable Linear Objects" (T-RO 2023, arXiv 2205.04004),
after "Shape Control of Deformable Linear Objects with Offline and Online Learning of Local
Linear Deformation Models" (ICRA 2022, arXiv 2109.11091). Their body text was not available to
us, so no equation numbers are cited; the forms below are named by what they compute.

The model. A radial-basis-function network maps the normalised state x of the rod to its local
Jacobian J(x) (p x q), so that Delta s ~ J(x) Delta r:

    J(x) = S Jn(x) C,   vec Jn(x) = W^T phi(x),   phi(x) = [1, exp(-|x - c_h|^2 / (2 sigma_h^2))]_h

with S = diag(s_scale) the feature scale, C = diag(c) the command scale (1 / max_step per
axis; the angle columns also times L / L_train, the rod length against the trained one: the
length normalisation of the authors' code), c_h, sigma_h the centres and widths (k-means on the
training states) and W ((H + 1) x pq) the output weights. The leading constant basis function
(our addition) makes a state far from every centre fall back to the average Jacobian instead
of to J = 0.

The state x (`state_vector`) is the authors' relative representation, in the plane: the unit
directions of the K - 1 chords between K points equally spaced along the centerline (world
frame when the camera is calibrated, else pixels), the unit direction from the clamped end to
the gripped end, and (cos, sin) of each end's angle. It is invariant to the rod's length.

Offline training (`rodctl.training.learned`) fits W in closed form (ridge least
squares; the loss is linear in W) on random-motion data. Online, every informative move takes
one normalised gradient step on 1/2 ||Delta s_n - Jn(x) Delta r_n||^2 (feature and command
normalised as above), summed over a window of the last moves:

    W <- W + eta * sum_i phi_i (e_i Delta r_n,i^T) / sum_i |phi_i|^2 |Delta r_n,i|^2,
    e_i = Delta s_n,i - Jn(x_i) Delta r_n,i,

so with one move and eta = 1 the updated model reproduces that move exactly at its state (the
secant condition, as Broyden's update does for a constant J). Only W adapts, as in the authors'
code (their online optimiser updates the output layer only).

Inference is numpy (no torch); the per-step products are fixed-order (`rodctl.fixedla`).
"""

from __future__ import annotations

import hashlib
import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from rodctl import fixedla as fla
from rodctl.config.base import StrictModel
from rodctl.errors import UserError
from rodctl.estimation.base import DEAD_ZONE_DOC, checked_jacobian
from rodctl.geometry import resample_polyline
from rodctl.notices import say_once
from rodctl.registry import ESTIMATORS, BuildContext

#: Identifies our checkpoints; bump VERSION when the layout changes.
FORMAT = "rodctl.learned_jacobian"
VERSION = 1


def rotation_columns(q: int) -> list[int]:
    """The angle columns of a q-DoF command: [dx, dy, dtheta] per gripped end (q = 3 or 6)."""
    return [j for j in range(q) if j % 3 == 2]


def state_vector(
    points: np.ndarray, end_angles: np.ndarray, state_points: int
) -> tuple[np.ndarray, float]:
    """The normalised state x of a rod and its length (module docstring).

    Args:
        points: (M, 2) centerline, clamp end first (world metres, or pixels without a camera).
        end_angles: angles of the rod's ends [rad], e.g. [theta_gripper] or [theta_clamp,
            theta_gripper].
        state_points: K, the centerline points the chords join (>= 2).

    Returns:
        x (2 (K - 1) + 2 + 2 len(end_angles),) and the polyline length of `points`.
    """
    pts = resample_polyline(np.asarray(points, dtype=float), state_points)
    chords = np.diff(pts, axis=0)
    norms = np.sqrt(chords[:, 0] ** 2 + chords[:, 1] ** 2)
    length_all = np.diff(np.asarray(points, dtype=float), axis=0)
    length = float(np.sum(np.sqrt(length_all[:, 0] ** 2 + length_all[:, 1] ** 2)))
    dirs = chords / np.maximum(norms, 1e-12)[:, None]
    span = pts[-1] - pts[0]
    span = span / max(math.hypot(float(span[0]), float(span[1])), 1e-12)
    angles = np.asarray(end_angles, dtype=float).reshape(-1)
    trig = np.stack([np.cos(angles), np.sin(angles)], axis=1).reshape(-1)
    return np.concatenate([dirs.reshape(-1), span, trig]), length


def rbf_features(X: np.ndarray, centres: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """phi(x) for a batch: (B, d) states -> (B, H + 1), a constant 1 first."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    diff = X[:, None, :] - centres[None, :, :]
    d2 = np.einsum("bhd,bhd->bh", diff, diff)
    phi = np.exp(-0.5 * d2 / (widths[None, :] ** 2))
    return np.concatenate([np.ones((X.shape[0], 1)), phi], axis=1)


@dataclass
class RbfJacobianModel:
    """The trained network and what it was trained for (module docstring for the symbols).

    Attributes:
        centres: (H, d) RBF centres.
        widths: (H,) RBF widths sigma_h.
        weights: (H + 1, p, q) output weights W (normalised units).
        s_scale: (p,) feature scale S.
        r_scale: (q,) command scale (max_step at training); C = 1 / r_scale.
        train_length: L_train, the rod length in the training data (m; 1 without a camera).
        state_points: K.
        end_angles: how many end angles the state holds (1: the gripper; 2: both ends).
        length_scaling: scale the angle columns by L / L_train.
        fingerprint: the set-up it was trained for (`model_fingerprint`).
        config_yaml: the resolved config that trained it.
        metrics: training figures.
    """

    centres: np.ndarray
    widths: np.ndarray
    weights: np.ndarray
    s_scale: np.ndarray
    r_scale: np.ndarray
    train_length: float = 1.0
    state_points: int = 10
    end_angles: int = 1
    length_scaling: bool = True
    fingerprint: dict[str, Any] = field(default_factory=dict)
    config_yaml: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def p(self) -> int:
        return int(self.weights.shape[1])

    @property
    def q(self) -> int:
        return int(self.weights.shape[2])

    def column_scale(self, length: float | None = None) -> np.ndarray:
        """c (q,): 1 / r_scale, the angle columns times L / L_train when length-scaled."""
        c = 1.0 / np.asarray(self.r_scale, dtype=float)
        if self.length_scaling and length is not None and self.train_length > 0.0:
            for j in rotation_columns(self.q):
                c[j] *= length / self.train_length
        return c

    def normalised_jacobians(
        self, phi: np.ndarray, weights: np.ndarray | None = None
    ) -> np.ndarray:
        """Jn for a batch of features phi (B, H + 1) -> (B, p, q)."""
        W = self.weights if weights is None else weights
        return np.einsum("bh,hpq->bpq", phi, W)

    def predict(self, X: np.ndarray, length: float | None = None) -> np.ndarray:
        """J(x) in feature per command units for states X (B, d) -> (B, p, q)."""
        Jn = self.normalised_jacobians(rbf_features(X, self.centres, self.widths))
        return self.s_scale[None, :, None] * Jn * self.column_scale(length)[None, None, :]

    def digest(self) -> str:
        """sha256 of the weights and the meta data: names one trained model exactly."""
        h = hashlib.sha256()
        for a in (self.centres, self.widths, self.weights, self.s_scale, self.r_scale):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        h.update(json.dumps(self._meta(with_metrics=False), sort_keys=True).encode())
        return h.hexdigest()

    def _meta(self, with_metrics: bool = True) -> dict[str, Any]:
        meta = {
            "format": FORMAT,
            "version": VERSION,
            "train_length": float(self.train_length),
            "state_points": int(self.state_points),
            "end_angles": int(self.end_angles),
            "length_scaling": bool(self.length_scaling),
            "fingerprint": self.fingerprint,
            "config_yaml": self.config_yaml,
        }
        if with_metrics:
            meta["metrics"] = self.metrics
        return meta

    def save(self, path: str | Path) -> None:
        """Write an .npz (numpy arrays and one JSON text; no pickles) atomically."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as f:
            np.savez(
                f,
                meta=np.array(json.dumps(self._meta(), sort_keys=True)),
                centres=np.asarray(self.centres, dtype=np.float64),
                widths=np.asarray(self.widths, dtype=np.float64),
                weights=np.asarray(self.weights, dtype=np.float64),
                s_scale=np.asarray(self.s_scale, dtype=np.float64),
                r_scale=np.asarray(self.r_scale, dtype=np.float64),
            )
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path) -> RbfJacobianModel:
        """Read and validate a model written by `save` (never unpickles).

        Raises:
            UserError: missing, unreadable, not a rodctl learned model, another version, or
                inconsistent arrays; the message names the file.
        """
        path = Path(path)

        def bad(why: str) -> UserError:
            return UserError(
                f"{path}: not a valid rodctl learned Jacobian model: {why}; "
                "re-create it with `rodctl train-model`"
            )

        if not path.is_file():
            raise UserError(f"{path}: learned Jacobian model not found")
        if not zipfile.is_zipfile(path):  # numpy would read it as a pickle and suggest that
            raise bad("not an .npz archive (the model.npz `rodctl train-model` writes)")
        try:
            with np.load(path, allow_pickle=False) as npz:
                meta = json.loads(str(npz["meta"]))
                arrays = {
                    k: np.array(npz[k], dtype=np.float64)
                    for k in ("centres", "widths", "weights", "s_scale", "r_scale")
                }
        except Exception as exc:  # noqa: BLE001 - numpy raises many types on a corrupt file
            raise bad(f"{type(exc).__name__}: {str(exc)[:200]}") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise bad(f"expected format {FORMAT!r}")
        if meta.get("version") != VERSION:
            raise bad(f"format version {meta.get('version')!r}, this rodctl reads {VERSION}")
        c, w, W = arrays["centres"], arrays["widths"], arrays["weights"]
        if c.ndim != 2 or w.shape != (c.shape[0],) or W.ndim != 3 or W.shape[0] != c.shape[0] + 1:
            raise bad("centres, widths and weights do not fit together")
        if arrays["s_scale"].shape != (W.shape[1],) or arrays["r_scale"].shape != (W.shape[2],):
            raise bad("scales do not match the weights")
        if not all(np.all(np.isfinite(a)) for a in arrays.values()):
            raise bad("non-finite values")
        if np.any(w <= 0.0) or np.any(arrays["s_scale"] <= 0.0) or np.any(arrays["r_scale"] <= 0):
            raise bad("widths and scales must be positive")
        try:
            model = cls(
                **arrays,
                train_length=float(meta["train_length"]),
                state_points=int(meta["state_points"]),
                end_angles=int(meta["end_angles"]),
                length_scaling=bool(meta["length_scaling"]),
                fingerprint=dict(meta.get("fingerprint", {})),
                config_yaml=str(meta.get("config_yaml", "")),
                metrics=dict(meta.get("metrics", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise bad(f"unreadable meta data ({exc})") from None
        expected_d = 2 * (model.state_points - 1) + 2 + 2 * model.end_angles
        if c.shape[1] != expected_d:
            raise bad(f"centres have {c.shape[1]} dimensions, the state has {expected_d}")
        return model


# --- what a model depends on ------------------------------------------------------------


def model_fingerprint(cfg: Any) -> dict[str, Any]:
    """What a trained model is for: feature, camera geometry, N and the rod, as JSON values.

    The learned J is of one feature seen by one camera on one rod, so all of these enter:
    the feature config (an encoder checkpoint by the sha256 of its file), the camera's
    plane-to-pixel homography and image size, N, the rod's length, clamp pose, stiffness,
    weight and gravity. Seeds, noise and the training settings are left out.
    """
    from rodctl.vision.camera import Camera

    feature = cfg.feature.model_dump(mode="json", exclude={"data", "training", "other_setup"})
    if feature.get("type") == "autoencoder":
        from rodctl.features.autoencoder import DEFAULT_CHECKPOINT
        from rodctl.features.autoencoder_config import _resolve

        ck = feature.get("checkpoint")
        path = DEFAULT_CHECKPOINT if ck is None else _resolve(ck)
        if ck == "auto":
            feature["checkpoint"] = "auto"
        else:
            feature["checkpoint"] = (
                "sha256:" + hashlib.sha256(Path(path).read_bytes()).hexdigest()
                if Path(path).is_file()
                else str(ck)
            )
    camera = Camera(cfg.camera, None)
    rod = cfg.rod
    return {
        "feature": feature,
        "points": cfg.camera.points,
        "camera": {
            "width": cfg.camera.width,
            "height": cfg.camera.height,
            "homography": [float(v) for v in np.asarray(camera.homography).ravel()],
        },
        "rod": {
            "length": rod.length,
            "clamp_pose": list(rod.clamp_pose),
            "bending_stiffness": rod.bending_stiffness,
            "mass_per_length": rod.mass_per_length,
            "gravity": list(rod.gravity),
        },
    }


def _resolve_path(checkpoint: str) -> Path:
    from rodctl.features.autoencoder_config import _resolve

    return _resolve(checkpoint)


# --- the estimator ----------------------------------------------------------------------


class LearnedJacobian:
    """J from the learned model at the current state, its weights adapted online.

    The loop hands it the state through two hooks besides the protocol: `prepare(pixels)` at
    the first frame (the gripper is at `home_pose`) returns J(x_0), so no probing is needed;
    `observe(pixels, gripper)` before each `update` gives the new state. `update(ds, dr)`
    then takes the gradient step for the move from the previous state and returns J at the new
    one.
    """

    def __init__(
        self,
        p: int,
        q: int,
        model: RbfJacobianModel,
        *,
        camera: Any = None,
        home_pose: np.ndarray | None = None,
        learning_rate: float = 0.2,
        window: int = 10,
        dead_zone: float = 1e-4,
    ) -> None:
        self.p, self.q = int(p), int(q)
        if (model.p, model.q) != (self.p, self.q):
            raise UserError(
                f"estimator.checkpoint: the model gives a {model.p} x {model.q} Jacobian, this "
                f"method needs {self.p} x {self.q} (another feature, or another number of arms)"
            )
        self.model = model
        self._camera = camera
        self._home = None if home_pose is None else np.asarray(home_pose, dtype=float)
        self._eta = float(learning_rate)
        self._window = int(window)
        self._dead_zone = float(dead_zone)
        self._W0 = np.array(model.weights, dtype=float)
        self._Wt0 = self._W0.reshape(self._W0.shape[0], -1).T.copy()  # (pq, H + 1)
        self._length: float | None = None
        self._phi: np.ndarray | None = None
        self._phi_new: np.ndarray | None = None
        self.reset(np.zeros((self.p, self.q)))

    # --- state -------------------------------------------------------------------------

    def _state(self, pixels: np.ndarray, gripper: np.ndarray) -> tuple[np.ndarray, float]:
        pts = np.asarray(pixels, dtype=float)
        if self._camera is not None:
            pts = self._camera.unproject(pts)
        angles = [float(np.asarray(gripper, dtype=float)[2])]
        if self.model.end_angles == 2:
            tangent = pts[1] - pts[0]
            angles.insert(0, math.atan2(float(tangent[1]), float(tangent[0])))
        return state_vector(pts, np.array(angles), self.model.state_points)

    def _features(self, x: np.ndarray) -> np.ndarray:
        return rbf_features(x, self.model.centres, self.model.widths)[0]

    def _jacobian(self, phi: np.ndarray) -> np.ndarray:
        Jn = fla.matvec(self._Wt, phi).reshape(self.p, self.q)  # fixed order (rodctl.fixedla)
        return self.model.s_scale[:, None] * Jn * self._c[None, :]

    # --- protocol ------------------------------------------------------------------------

    @property
    def J(self) -> np.ndarray:
        """(p, q) the current estimate (a copy)."""
        return self._J.copy()

    def reset(self, J0: np.ndarray) -> None:
        """Back to the offline weights, an empty window, and J0 (p, q) until the next update."""
        self._J = checked_jacobian(J0, self.p, self.q)
        self._W = self._W0.copy()
        self._Wt = self._Wt0.copy()
        self._pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._c = self.model.column_scale(self._length)
        self._info = {"skipped": 0.0, "residual": 0.0, "weight_change": 0.0}

    def prepare(self, pixels: np.ndarray) -> np.ndarray:
        """The start hook: J(x_0) from the first frame, the gripper at the home pose."""
        if self._home is None:
            raise UserError("estimator.type=learned needs the home pose (the loop gives it)")
        x, length = self._state(pixels, self._home)
        self._length = length if self._camera is not None else None
        self.reset(np.zeros((self.p, self.q)))
        self._phi = self._features(x)
        self._J = self._jacobian(self._phi)
        return self.J

    def observe(self, pixels: np.ndarray, gripper: np.ndarray) -> None:
        """The state after the latest move (its centerline and the gripper pose)."""
        x, _ = self._state(pixels, gripper)
        self._phi_new = self._features(x)

    def update(self, ds: np.ndarray, dr: np.ndarray) -> np.ndarray:
        """One normalised gradient step for (ds, dr) at the previous state; J at the new one."""
        ds = np.asarray(ds, dtype=float)
        dr = np.asarray(dr, dtype=float)
        phi_old, phi_new = self._phi, self._phi_new
        if phi_old is None:  # no state given yet: nothing to learn from
            self._info = {"skipped": 1.0, "residual": 0.0, "weight_change": 0.0}
            return self.J
        if phi_new is None:
            phi_new = phi_old
        resid = ds - fla.matvec(self._jacobian(phi_old), dr)
        skipped = fla.norm(dr) < self._dead_zone
        change = 0.0
        if not skipped and self._eta > 0.0:
            self._pairs.append((phi_old, ds / self.model.s_scale, dr * self._c))
            self._pairs = self._pairs[-self._window :]
            grad = np.zeros_like(self._Wt)
            norm = 0.0
            for phi, dsn, drn in self._pairs:
                e = dsn - fla.matvec(fla.matvec(self._Wt, phi).reshape(self.p, self.q), drn)
                grad += np.outer(np.outer(e, drn).reshape(-1), phi)
                norm += fla.dot(phi, phi) * fla.dot(drn, drn)
            if norm > 0.0:
                step = (self._eta / norm) * grad
                self._Wt = self._Wt + step
                change = float(np.sqrt(np.sum(step**2)))
        self._phi = phi_new
        self._phi_new = None
        self._J = self._jacobian(phi_new)
        self._info = {
            "skipped": float(skipped),
            "residual": fla.norm(resid),
            "weight_change": change,
        }
        return self.J

    def info(self) -> dict[str, float]:
        """skipped (1.0 in the dead zone), residual ||ds - J dr|| before the update and the
        size of the weight step."""
        return dict(self._info)


# --- config and registration ------------------------------------------------------------


class LearnedDataConfig(StrictModel):
    """How `rodctl train-model` collects random-motion data (docs/learned.md)."""

    samples: int = Field(
        3000, ge=10, le=10_000_000, description="(state, move, feature change) pairs to collect."
    )
    chunk: int = Field(
        300, ge=5, le=1_000_000, description="Pairs per independently seeded random walk."
    )
    workers: int = Field(2, ge=1, le=256, description="Collection processes (1 = in-process).")
    jitter: float = Field(
        0.5,
        ge=0.0,
        le=1.0,
        description="Random part of each move, as a fraction of rod.max_step per axis; the "
        "rest walks towards a random goal pose (1: pure random motion).",
    )


class LearnedTrainingConfig(StrictModel):
    """The network `rodctl train-model` fits (ignored when the model is used)."""

    centres: int = Field(128, ge=1, le=4096, description="RBF centres H (k-means clusters).")
    state_points: int = Field(
        10, ge=3, le=200, description="K: centerline points of the state (the authors use 10)."
    )
    width: float = Field(
        4.0,
        gt=0.0,
        le=100.0,
        description="RBF width sigma_h as a multiple of cluster h's RMS radius.",
    )
    ridge: float = Field(
        0.1,
        ge=0.0,
        le=1e3,
        description="Ridge weight of the output-layer least squares, relative to the mean "
        "diagonal of the normal matrix.",
    )
    length_scaling: bool = Field(
        True,
        description="Scale the angle columns by the measured rod length over the trained one "
        "(the authors' length normalisation; needs the calibrated camera).",
    )
    validation_fraction: float = Field(
        0.2, gt=0.0, lt=1.0, description="Share of the walks held out for validation."
    )


class LearnedEstimatorConfig(StrictModel):
    """A learned state-to-Jacobian RBF network, updated online (our Yu et al. 2023 baseline).

    Trained offline by `rodctl train-model` on random-motion data; `checkpoint` names the
    model.npz it wrote. No probing: the model gives J at the first frame.
    """

    type: Literal["learned"] = "learned"
    checkpoint: str | None = Field(
        ...,
        description="The trained model (model.npz from `rodctl train-model`; "
        "rodctl/assets/learned-yu2023.npz is one for configs/yu2023.yaml). null: not trained "
        "yet (only `rodctl train-model` accepts that).",
    )
    learning_rate: float = Field(
        0.2,
        ge=0.0,
        le=1.0,
        description="eta of the online normalised gradient step (0: no online updates; 1: "
        "each step reproduces the last move exactly).",
    )
    window: int = Field(10, ge=1, le=1000, description="Moves the online gradient sums over.")
    dead_zone: float = Field(1e-4, le=1.0, ge=0.0, description=DEAD_ZONE_DOC)
    other_setup: Literal["refuse", "accept"] = Field(
        "refuse",
        description="A model trained for another rod, camera or feature: 'refuse' it (exit 2) "
        "or 'accept' it for a transfer experiment (the differences are printed once).",
    )
    data: LearnedDataConfig = Field(
        LearnedDataConfig(), description="How `rodctl train-model` collects data."
    )
    training: LearnedTrainingConfig = Field(
        LearnedTrainingConfig(), description="How `rodctl train-model` fits the network."
    )

    def check_experiment(self, experiment: Any) -> None:
        """A trained model must fit this feature, camera and rod (or be accepted as transfer)."""
        if self.checkpoint is None:
            return
        try:
            model = RbfJacobianModel.load(_resolve_path(self.checkpoint))
        except UserError as exc:
            raise ValueError(f"estimator.checkpoint: {exc}") from None
        from rodctl.features.autoencoder import fingerprint_differences

        diffs = fingerprint_differences(model.fingerprint, model_fingerprint(experiment))
        if not diffs:
            return
        feature_diffs = [d for d in diffs if d.startswith(("feature", "points"))]
        if self.other_setup == "refuse" or feature_diffs:
            raise ValueError(
                f"estimator.checkpoint {self.checkpoint}: this model was trained for another "
                "set-up:\n  "
                + "\n  ".join(diffs)
                + "\nTrain one for this config with `rodctl train-model CONFIG`"
                + (
                    ""
                    if feature_diffs
                    else ", or set estimator.other_setup=accept for a transfer experiment"
                )
            )
        say_once(  # once per run, not in each worker process again (`rodctl.notices`)
            f"estimator transfer {self.checkpoint}: {diffs}",
            f"estimator.other_setup=accept: {self.checkpoint} was trained for another "
            "set-up:\n  " + "\n  ".join(diffs),
        )


@ESTIMATORS.register(LearnedEstimatorConfig)
def _build(cfg: LearnedEstimatorConfig, ctx: BuildContext) -> LearnedJacobian:
    if cfg.checkpoint is None:
        raise UserError(
            "estimator.checkpoint: no learned model set; train one with `rodctl train-model "
            "CONFIG` and set estimator.checkpoint to its model.npz"
        )
    model = RbfJacobianModel.load(_resolve_path(cfg.checkpoint))
    return LearnedJacobian(
        ctx.p,
        ctx.q,
        model,
        camera=ctx.camera,
        home_pose=ctx.home_pose,
        learning_rate=cfg.learning_rate,
        window=cfg.window,
        dead_zone=cfg.dead_zone,
    )
