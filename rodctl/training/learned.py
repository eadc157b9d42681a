"""Offline training of the learned Jacobian (`rodctl train-model`): random motion, then a fit.

Data, as the authors collect theirs (random end motions in simulation, docs/learned.md): the
gripper walks one control step at a time; each step is `1 - jitter` of the way (at most
`rod.max_step` per axis) towards a goal pose drawn uniformly from the workspace plus a uniform
random part of `jitter * rod.max_step` per axis, so moves at one state point in many directions
(a straight walk would excite one direction only). Every settled step goes through the camera
pipeline (render, extract) exactly as in an experiment; a frame that fails is skipped, and the
moves are then summed until the next good frame. The work is cut into independently seeded
walks (`SeedSequence.spawn` of the config's "model-data" stream), so the data do not depend on
the number of worker processes, and whole walks are held out for validation.

Fit: k-means (Lloyd, k-means++ start, seeded) of the training states gives the centres; each
width is `width` times its cluster's RMS radius (the median radius for a cluster of one); the
output weights W solve a ridge least squares in closed form, since Delta s = Jn(x) Delta r is
linear in W: each pair gives the row kron(phi(x), Delta r_n) for each feature component.
No torch.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from rodctl.config import ExperimentConfig, dump_config
from rodctl.display import task_progress
from rodctl.errors import UserError
from rodctl.estimation.learned import (
    LearnedEstimatorConfig,
    RbfJacobianModel,
    model_fingerprint,
    rbf_features,
    state_vector,
)
from rodctl.estimation.probing import fit_jacobian
from rodctl.notices import say_once
from rodctl.registry import FEATURES, BuildContext, load_plugins
from rodctl.runs import RunDir, rng, seed_sequence, write_json_atomic
from rodctl.sim import RodSim
from rodctl.training.collection import (
    chunk_sizes,
    map_chunks,
    random_walk_start,
    sample_end_goals,
    sample_goal,
)
from rodctl.vision import Camera, CenterlineExtractor

_MAX_ATTEMPTS_PER_SAMPLE = 20


def collect_walk(cfg_json: str, count: int, seed: np.random.SeedSequence) -> dict[str, Any]:
    """One seeded random walk with `count` + 1 good frames (runs in a worker process).

    Returns:
        {"pixels": (F, N, 2), "poses": (F, q) (q = 6 dual-arm: both ends), "segment": (F,) int
        (a new segment after the simulator was rebuilt: no pair spans two), "attempts": int}.
    """
    walk = _Walk(cfg_json, seed)
    walk.look()
    attempts = 0
    while len(walk.frames) < count + 1:
        attempts += 1
        if attempts > _MAX_ATTEMPTS_PER_SAMPLE * count + 100:
            raise RuntimeError(
                f"model data: {attempts} control steps gave only {len(walk.frames)} usable "
                "frames; the simulator or the extractor fails on most shapes"
            )
        walk.step()
    return {
        "pixels": np.array(walk.frames),
        "poses": np.array(walk.poses),
        "segment": np.array(walk.segments, dtype=np.int64),
        "attempts": attempts,
    }


class _Walk:
    """One model-data walk (see the module docstring): the simulator, the goal pose, and the
    good frames seen so far with their poses and segments."""

    def __init__(self, cfg_json: str, seed: np.random.SeedSequence) -> None:
        cfg, gen, camera, extractor, max_step, sim, goal = random_walk_start(cfg_json, seed)
        self.cfg, self.gen, self.camera, self.extractor, self.sim = cfg, gen, camera, extractor, sim
        self.clamp = np.asarray(cfg.rod.clamp_pose, dtype=float)
        self.jitter = float(cfg.estimator.data.jitter)
        self.frames: list[np.ndarray] = []
        self.poses: list[np.ndarray] = []
        self.segments: list[int] = []
        self.segment = 0
        self.dual = cfg.rod.arms == 2  # dual-arm: both ends walk, poses and moves are (6,)
        if self.dual:
            max_step = sim.max_steps
            goal = sample_end_goals(gen, sim, cfg, goal)
        self.max_step, self.goal = max_step, goal

    def look(self) -> bool:
        """Render and extract the rod; a good frame is kept with its pose (both ends' dual-arm)."""
        sim, camera = self.sim, self.camera
        if self.dual:
            grip, at = sim.gripper_pose, sim.clamp_pose
            extractor = CenterlineExtractor(self.cfg.camera, camera, at)
            ext = extractor.extract(camera.render(sim.centerline(), grip, at, transient=True), grip)
            pose = sim.end_poses
        else:
            pose = np.asarray(sim.gripper_pose, dtype=float)
            frame = camera.render(sim.centerline(), pose, self.clamp, transient=True)
            ext = self.extractor.extract(frame, pose)
        if ext.ok:
            self.frames.append(np.asarray(ext.points, dtype=np.float32))
            self.poses.append(pose)
            self.segments.append(self.segment)
        return bool(ext.ok)

    def new_goal(self) -> None:
        goal = sample_goal(self.gen, self.sim, self.cfg)
        self.goal = sample_end_goals(self.gen, self.sim, self.cfg, goal) if self.dual else goal

    def step(self) -> None:
        """One control step towards the goal (a new goal once it is reached, refused, or the
        simulator diverged and was rebuilt: a new segment); a settled step is looked at."""
        sim, max_step, jitter = self.sim, self.max_step, self.jitter
        pose = np.asarray(sim.end_poses if self.dual else sim.gripper_pose, dtype=float)
        delta = self.goal - pose
        if np.max(np.abs(delta) / max_step) < 0.5:
            self.new_goal()
            return
        move = (1.0 - jitter) * np.clip(delta, -max_step, max_step)
        move = np.clip(move + jitter * self.gen.uniform(-max_step, max_step), -max_step, max_step)
        res = sim.apply(move)
        if res.diverged:
            self.sim = RodSim(self.cfg.rod)
            self.segment += 1
            self.new_goal()
            self.look()
        elif res.refused:
            self.new_goal()
        elif res.settled:
            self.look()


def _collect_task(args: tuple[str, int, np.random.SeedSequence]) -> dict[str, Any]:
    return collect_walk(*args)


def collect_walks(cfg: ExperimentConfig, *, progress: bool = True) -> list[dict[str, Any]]:
    """The random walks `cfg.estimator.data` describes, in order (see the module docstring)."""
    assert isinstance(cfg.estimator, LearnedEstimatorConfig), "the learned Jacobian's walks"
    data = cfg.estimator.data
    sizes = chunk_sizes(data.samples, data.chunk)
    seeds = seed_sequence(cfg.seed, "model-data").spawn(len(sizes))
    cfg_json = cfg.model_dump_json()
    tasks = [(cfg_json, n, s) for n, s in zip(sizes, seeds, strict=True)]
    walks: list[dict[str, Any]] = []
    with task_progress("collecting", data.samples, progress) as advance:
        for task, res in map_chunks(_collect_task, tasks, data.workers):
            walks.append(res)
            advance(n=task[1])
    return walks


def walk_pairs(
    walk: dict[str, Any], encode: Any, camera: Any, state_points: int
) -> dict[str, np.ndarray]:
    """(state, move, feature change) pairs of consecutive good frames of one walk.

    Args:
        walk: a `collect_walk` result.
        encode: the feature map's batch encoder, (B, N, 2) pixels -> (B, p).
        camera: the calibrated camera (`unproject`), or None to use pixels.
        state_points: K.

    Returns:
        {"X": (M, d) states before each move, "dR": (M, q), "dS": (M, p), "length": (M,),
        "S": (M + ..., p) the features of every frame}.
    """
    pixels = np.asarray(walk["pixels"], dtype=float)
    poses = np.asarray(walk["poses"], dtype=float)
    seg = np.asarray(walk["segment"])
    S = np.asarray(encode(pixels), dtype=float)
    keep = np.flatnonzero(seg[1:] == seg[:-1])
    X, L = [], []
    for i in keep:
        pts = camera.unproject(pixels[i]) if camera is not None else pixels[i]
        x, length = state_vector(pts, poses[i, 2:3], state_points)
        X.append(x)
        L.append(length)
    return {
        "X": np.array(X),
        "dR": poses[keep + 1] - poses[keep],
        "dS": S[keep + 1] - S[keep],
        "length": np.array(L),
    }


def kmeans(X: np.ndarray, k: int, gen: np.random.Generator, iterations: int = 30) -> np.ndarray:
    """Lloyd's k-means with a k-means++ start: (k, d) centres (k capped at the distinct rows)."""
    X = np.asarray(X, dtype=float)
    k = min(k, len(np.unique(X, axis=0)))
    centres = [X[gen.integers(len(X))]]
    d2 = np.sum((X - centres[0]) ** 2, axis=1)
    for _ in range(1, k):
        prob = d2 / d2.sum() if d2.sum() > 0 else np.full(len(X), 1.0 / len(X))
        centres.append(X[gen.choice(len(X), p=prob)])
        d2 = np.minimum(d2, np.sum((X - centres[-1]) ** 2, axis=1))
    C = np.array(centres)
    for _ in range(iterations):
        dist = (X**2).sum(1)[:, None] - 2.0 * X @ C.T + (C**2).sum(1)[None, :]
        label = np.argmin(dist, axis=1)
        new = np.array(
            [X[label == h].mean(axis=0) if np.any(label == h) else C[h] for h in range(k)]
        )
        if np.allclose(new, C):
            break
        C = new
    return C


def fit_rbf(
    X: np.ndarray,
    dR: np.ndarray,
    dS: np.ndarray,
    *,
    centres: int,
    width: float,
    ridge: float,
    r_scale: np.ndarray,
    seed: int = 0,
) -> RbfJacobianModel:
    """Fit the RBF Jacobian network to pairs Delta s_i ~ J(x_i) Delta r_i.

    Args:
        X: (M, d) states; dR: (M, q) moves; dS: (M, p) feature changes.
        centres: H; width: sigma_h / cluster RMS radius; ridge: relative ridge weight.
        r_scale: (q,) command scale (rod.max_step).
        seed: k-means seed.

    Returns:
        The model (train_length 1, no fingerprint: the caller fills them in).
    """
    X, dR, dS = (np.asarray(a, dtype=float) for a in (X, dR, dS))
    if X.ndim != 2 or len(X) != len(dR) or len(X) != len(dS) or len(X) < 2:
        raise UserError(f"training needs at least 2 consistent pairs, got {len(X)}")
    gen = np.random.Generator(np.random.PCG64(seed))
    C = kmeans(X, centres, gen)
    dist = (X**2).sum(1)[:, None] - 2.0 * X @ C.T + (C**2).sum(1)[None, :]
    label = np.argmin(dist, axis=1)
    radius = np.array(
        [
            np.sqrt(np.maximum(dist[label == h, h], 0.0).mean()) if np.sum(label == h) > 1 else 0.0
            for h in range(len(C))
        ]
    )
    positive = radius[radius > 0]
    floor = float(np.median(positive)) if positive.size else 1.0
    widths = width * np.where(radius > 0, np.maximum(radius, 0.1 * floor), floor)
    s_scale = np.maximum(dS.std(axis=0), 1e-12)
    r_scale = np.asarray(r_scale, dtype=float)
    phi = rbf_features(X, C, widths)  # (M, H + 1)
    drn = dR / r_scale
    dsn = dS / s_scale
    A = (phi[:, :, None] * drn[:, None, :]).reshape(len(X), -1)  # rows kron(phi, dr_n)
    G = A.T @ A
    lam = ridge * float(np.trace(G)) / G.shape[0]
    w = np.linalg.solve(G + lam * np.eye(G.shape[0]), A.T @ dsn)  # ((H + 1) q, p)
    weights = w.reshape(phi.shape[1], dR.shape[1], dS.shape[1]).transpose(0, 2, 1)
    return RbfJacobianModel(
        centres=C, widths=widths, weights=np.ascontiguousarray(weights), s_scale=s_scale,
        r_scale=r_scale,
    )  # fmt: skip


def prediction_errors(model: RbfJacobianModel, pairs: dict[str, np.ndarray]) -> dict[str, float]:
    """One-step prediction error of the offline model: mean ||ds - J(x) dr|| and its share of
    mean ||ds|| (feature units)."""
    if len(pairs["X"]) == 0:
        return {"mean_error": float("nan"), "relative_error": float("nan")}
    length = pairs["length"] if model.length_scaling else None
    errs = []
    for i in range(len(pairs["X"])):
        L = None if length is None else float(length[i])
        J = model.predict(pairs["X"][i : i + 1], L)[0]
        errs.append(np.linalg.norm(pairs["dS"][i] - J @ pairs["dR"][i]))
    mean = float(np.mean(errs))
    return {
        "mean_error": mean,
        "relative_error": mean / max(float(np.mean(np.linalg.norm(pairs["dS"], axis=1))), 1e-12),
    }


def _stack(pairs: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([p[k] for p in pairs]) for k in ("X", "dR", "dS", "length")}


def train_model_from_walks(cfg: ExperimentConfig, walks: list[dict[str, Any]]) -> RbfJacobianModel:
    """Encode the walks with the experiment's feature, hold out walks, fit, measure."""
    load_plugins()
    est: LearnedEstimatorConfig = cfg.estimator  # type: ignore[assignment]
    tcfg = est.training
    feature = FEATURES.build(cfg.feature, BuildContext(points=cfg.camera.points, experiment=cfg))
    camera = Camera(cfg.camera, None)
    pairs = [walk_pairs(w, feature.encode_batch, camera, tcfg.state_points) for w in walks]
    order = rng(cfg.seed, "model-data").permutation(len(pairs))
    n_val = min(max(int(round(tcfg.validation_fraction * len(pairs))), 1), len(pairs) - 1)
    val = [pairs[i] for i in order[:n_val]] if len(pairs) > 1 else []
    train = [pairs[i] for i in order[n_val:]] if len(pairs) > 1 else pairs
    data = _stack(train)
    t0 = time.perf_counter()
    model = fit_rbf(
        data["X"], data["dR"], data["dS"], centres=tcfg.centres, width=tcfg.width,
        ridge=tcfg.ridge, r_scale=_r_scale(cfg), seed=cfg.seed,
    )  # fmt: skip
    fit_time = time.perf_counter() - t0
    model.train_length = float(np.median(data["length"]))
    model.state_points = tcfg.state_points
    model.length_scaling = tcfg.length_scaling
    model.fingerprint = model_fingerprint(cfg)
    model.config_yaml = dump_config(cfg)
    _warn_small_data(est, len(pairs), n_val if val else 0, len(model.centres))
    model.metrics = {
        "train": prediction_errors(model, data),
        "validation": prediction_errors(model, _stack(val)) if val else None,
        "train_pairs": int(len(data["X"])),
        "validation_pairs": int(sum(len(v["X"]) for v in val)),
        "walks": len(walks),
        "fit_time_s": fit_time,
        "feature_units": getattr(feature, "units", ""),
    }
    return model


def _warn_small_data(est: LearnedEstimatorConfig, walks: int, held: int, centres: int) -> None:
    """Say what a small collection changed: no validation (one walk), a held-out share far from
    `validation_fraction` (whole walks are held out), fewer centres than asked for (k-means
    keeps at most one per distinct training state)."""
    data, tcfg = est.data, est.training
    said = []
    if held == 0:
        said.append("no walk is held out: metrics.json's validation is null")
    elif held / walks > 1.5 * tcfg.validation_fraction:
        said.append(
            f"{held} of {walks} walks ({100 * held / walks:.0f} %) are held out for validation, "
            f"not the {100 * tcfg.validation_fraction:.0f} % of "
            "estimator.training.validation_fraction (whole walks are held out)"
        )
    if centres < tcfg.centres:
        said.append(
            f"the model has {centres} centres, not the {tcfg.centres} of "
            f"estimator.training.centres (only {centres} distinct training states)"
        )
    if said:
        text = (
            f"warning: {data.samples} samples in {walks} walk(s) of estimator.data.chunk = "
            f"{data.chunk}: {'; '.join(said)}. Collect more (estimator.data.samples) to avoid this."
        )
        say_once(text, text)


def _r_scale(cfg: ExperimentConfig) -> np.ndarray:
    """(q,) the command scale: `rod.max_step`, then (dual-arm) `rod.clamp_arm.max_step`."""
    scale = np.asarray(cfg.rod.max_step, dtype=float)
    if cfg.rod.arms == 2:
        scale = np.concatenate([scale, np.asarray(cfg.rod.clamp_arm.max_step, dtype=float)])
    return scale


def train_model(cfg: ExperimentConfig, run: RunDir, *, progress: bool = True) -> dict[str, Any]:
    """The body of `rodctl train-model`: collect, fit, write model.npz and metrics.json.

    Raises:
        UserError: the config's estimator is not `learned`.
    """
    if not isinstance(cfg.estimator, LearnedEstimatorConfig):
        raise UserError(
            f"train-model trains the learned Jacobian, but estimator.type is "
            f"{cfg.estimator.type!r}; set estimator.type=learned"
        )
    t0 = time.perf_counter()
    walks = collect_walks(cfg, progress=progress)
    collect_time = time.perf_counter() - t0
    model = train_model_from_walks(cfg, walks)
    path = Path(run.path) / "model.npz"
    model.metrics.update(
        collection_time_s=collect_time,
        collection_attempts=int(sum(w["attempts"] for w in walks)),
    )
    model.save(path)
    metrics = {
        **model.metrics,
        "checkpoint": str(path),
        "sha256": model.digest(),
        "fingerprint": model.fingerprint,
    }
    write_json_atomic(Path(run.path) / "metrics.json", metrics)
    return metrics


def one_step_errors(
    estimator: Any, walk: dict[str, Any], encode: Any, *, skip: int = 0
) -> np.ndarray:
    """||ds_k - J_k dr_k|| along one walk: J_k is the estimate before move k, then updated.

    How a method meets the walk's moves in the loop: the estimate made from everything seen
    so far predicts the next feature change; then the estimator folds that move in (the state
    hooks first, for the learned model). An estimator with a `prepare` hook starts there, any
    other from the least-squares fit of the first q + 1 moves (the probing of docs/method.md
    §4), which are then not scored.

    Args:
        estimator: a `JacobianEstimator` for the walk's feature.
        walk: a `collect_walk` result (one segment is used: the first).
        encode: the feature map's batch encoder.
        skip: further leading moves not scored.

    Returns:
        (M,) errors in feature units.
    """
    seg = np.asarray(walk["segment"])
    n = int(np.sum(seg == seg[0]))
    pixels = np.asarray(walk["pixels"], dtype=float)[:n]
    poses = np.asarray(walk["poses"], dtype=float)[:n]
    S = np.asarray(encode(pixels), dtype=float)
    dS, dR = np.diff(S, axis=0), np.diff(poses, axis=0)
    prepare = getattr(estimator, "prepare", None)
    observe = getattr(estimator, "observe", None)
    start = 0
    if prepare is not None:
        J = prepare(pixels[0])
    else:
        start = dR.shape[1] + 1
        J = fit_jacobian(dS[:start], dR[:start])
        estimator.reset(J)
    errs = []
    for k in range(start, len(dR)):
        errs.append(float(np.linalg.norm(dS[k] - J @ dR[k])))
        if observe is not None:
            observe(pixels[k + 1], poses[k + 1])
        J = estimator.update(dS[k], dR[k])
    return np.array(errs[skip:])
