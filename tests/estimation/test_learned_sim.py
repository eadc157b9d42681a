"""The learned Jacobian trained on the simulated rod: against the AKF, a stiffness change, online.

One small model for the module (a 20-segment heavy rod seen with N = 30 points: random-motion
data, camera pipeline included). The rod hangs in a vertical plane so that its stiffness
changes its shapes: a weightless rod's quasi-static shapes do not depend on EI at all.
"""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.config import load_config
from rodctl.estimation import AdaptiveKalmanJacobian
from rodctl.estimation.learned import LearnedJacobian
from rodctl.registry import FEATURES, BuildContext, load_plugins
from rodctl.training.learned import (
    collect_walk,
    collect_walks,
    one_step_errors,
    train_model_from_walks,
)
from rodctl.vision import Camera

SMALL = [
    "estimator.checkpoint=null",  # the model is trained here
    "rod.material={name: silicone_tube}",
    "rod.gravity=[0.0, -9.81]",
    "rod.segments=20",
    "camera.points=30",
    "camera.width=320",
    "camera.height=240",
    "camera.fx=280",
    "camera.fy=280",
]
DATA = [
    "estimator.data.samples=480",
    "estimator.data.chunk=120",
    "estimator.data.workers=1",
    "estimator.training.centres=24",
]


@pytest.fixture(scope="module")
def setup():
    load_plugins()
    cfg = load_config("configs/yu2023.yaml", SMALL + DATA)
    walks = collect_walks(cfg, progress=False)
    model = train_model_from_walks(cfg, walks)
    soft = load_config("configs/yu2023.yaml", [*SMALL, "rod.material.modulus=0.75e6"])
    seed = np.random.SeedSequence(2024)
    held = collect_walk(cfg.model_dump_json(), 40, seed)
    held_soft = collect_walk(soft.model_dump_json(), 40, seed)
    feature = FEATURES.build(cfg.feature, BuildContext(points=cfg.camera.points, experiment=cfg))
    small = train_model_from_walks(cfg, walks[:2])  # 60 training pairs: an under-trained model
    return cfg, model, held, held_soft, feature.encode_batch, Camera(cfg.camera, None), small


def learned(setup, walk, eta: float, model=None) -> LearnedJacobian:
    cfg, trained, *_, camera, _ = setup
    model = trained if model is None else model
    est = cfg.estimator
    return LearnedJacobian(
        model.p, model.q, model, camera=camera, home_pose=walk["poses"][0], learning_rate=eta,
        window=est.window,
    )  # fmt: skip


@pytest.mark.slow
def test_the_learned_one_step_prediction_beats_the_akf_on_held_out_motion(setup):
    _, model, held, _, encode, *_ = setup
    akf = one_step_errors(AdaptiveKalmanJacobian(model.p, model.q), held, encode)
    eta = setup[0].estimator.learning_rate  # the configured method: offline model + online steps
    mine = one_step_errors(learned(setup, held, eta), held, encode, skip=model.q + 1)
    assert len(mine) == len(akf) > 10  # the same moves scored
    assert np.mean(mine) < 0.8 * np.mean(akf)


@pytest.mark.slow
def test_the_learned_prior_still_beats_the_akf_after_a_stiffness_change(setup):
    _, model, held, held_soft, encode, *_ = setup
    # the same moves from the same start: the softer rod sags to other shapes
    n = min(len(held["pixels"]), len(held_soft["pixels"]))
    assert np.linalg.norm(held["pixels"][:n] - held_soft["pixels"][:n], axis=-1).mean() > 2.0
    akf = one_step_errors(AdaptiveKalmanJacobian(model.p, model.q), held_soft, encode)
    offline = one_step_errors(learned(setup, held_soft, 0.0), held_soft, encode, skip=4)
    # J as a function of the seen shape barely depends on EI: the offline model transfers
    # (docs/learned.md: online steps did not measurably help here)
    assert np.mean(offline) < np.mean(akf)


@pytest.mark.slow
def test_online_updates_reduce_the_error_of_an_under_trained_model(setup):
    _, _, held, _, encode, _, small = setup
    offline = one_step_errors(learned(setup, held, 0.0, small), held, encode)
    online = one_step_errors(learned(setup, held, 0.5, small), held, encode)
    late = slice(len(online) // 3, None)  # once the online steps have had moves to learn from
    assert np.mean(online[late]) < 0.9 * np.mean(offline[late])  # measured: 0.84
