"""The per-step Jacobian error ||Ĵ - J||_F / ||J||_F (`run.jacobian_error`, docs/engines.md):
zero for the oracle, falling for an AKF that starts from a wrong Jacobian, absent where there is
no estimate or no cheap true Jacobian, carried through the MCAP log and into results.csv."""

from __future__ import annotations

import csv
import math
from types import SimpleNamespace

import numpy as np
import yaml

from rodctl.bench.compare import CSV_COLUMNS, run_compare
from rodctl.config import validate_config
from rodctl.env import ShapeServoEnv
from rodctl.episode import _jacobian_error_summary, run_episode
from rodctl.estimation.akf import AdaptiveKalmanJacobian
from rodctl.logs.codec import control_message, record_from_messages
from rodctl.method import Method

TARGET = [0.38, 0.05, 0.8]


def _cfg(estimator: dict, engine: str = "quasistatic", **run) -> object:
    return validate_config(
        {
            "rod": {"segments": 20, "engine": engine},
            "camera": {"points": 30},
            "feature": {"type": "bezier", "degree": 3},
            "estimator": estimator,
            "controller": {"type": "mfac"},
            "run": {"max_steps": 10, "target": {"pose": TARGET}, **run},
        },
        "test config",
    )


def test_the_oracle_scores_zero_and_probing_has_no_estimate() -> None:
    cfg = _cfg({"type": "oracle"})
    res = run_episode(ShapeServoEnv(cfg), Method.from_config(cfg))
    errors = [r.jacobian_error for r in res.records]
    assert errors and all(e == 0.0 for e in errors), errors  # the oracle's J is the true one
    assert res.summary.extra["jacobian_error_median"] == 0.0

    cfg = _cfg({"type": "akf"})
    res = run_episode(ShapeServoEnv(cfg), Method.from_config(cfg))
    before = [r.jacobian_error for r in res.records if r.phase != "control"]
    after = [r.jacobian_error for r in res.records if r.phase == "control"]
    assert math.isnan(before[0]) and after  # no Ĵ before probing has fitted J_0
    assert all(np.isfinite(after)) and all(e > 0 for e in after)
    assert res.summary.extra["jacobian_error_final"] == after[-1]

    # The MCAP /control message carries it and reads back bit for bit; NaN is left out.
    for rec in (res.records[0], res.records[-1]):
        msg = control_message(rec)
        assert ("jacobian_error" in msg) == np.isfinite(rec.jacobian_error)
        back = record_from_messages(
            {"step": 0, "sim_time": 0.0, "phase": rec.phase, "gripper": [0.0] * 3,
             "centerline": [], "settled": True, "clipped": False, "max_joint_gap": 0.0,
             "kinetic_energy": 0.0},
            {"extracted": [], "projected_truth": [], "extraction_ok": True,
             "extraction_note": ""},
            msg,
            None,
        )  # fmt: skip
        assert back.jacobian_error == rec.jacobian_error or (
            math.isnan(back.jacobian_error) and math.isnan(rec.jacobian_error)
        )


def test_pymunk_scores_only_when_asked() -> None:
    cfg = _cfg({"type": "broyden"}, engine="pymunk", max_steps=6)
    env = ShapeServoEnv(cfg)
    res = run_episode(env, Method.from_config(cfg))
    assert all(math.isnan(r.jacobian_error) for r in res.records)  # auto: six settles, not cheap
    assert res.summary.extra["jacobian_error_median"] is None
    cfg = _cfg({"type": "broyden"}, engine="pymunk", max_steps=6, jacobian_error="always")
    res = run_episode(ShapeServoEnv(cfg), Method.from_config(cfg))
    control = [r.jacobian_error for r in res.records if r.phase == "control"]
    assert control and all(0 < e < 1 for e in control), control


def test_the_akf_error_falls_from_a_wrong_start() -> None:
    """The AKF started from half the true Jacobian, fed small random moves of the rod: the
    error the env scores it with falls from 0.5 to well below."""
    cfg = _cfg({"type": "akf"})
    env = ShapeServoEnv(cfg)
    obs, _ = env.reset()
    encode = Method.from_config(cfg).feature.encode
    true = env.jacobian_error_reference(encode)
    akf = AdaptiveKalmanJacobian(true.shape[0], 3)
    akf.reset(0.5 * true)
    s = encode(obs["centerline"])
    gen = np.random.default_rng(0)
    errors = []
    for _ in range(16):
        obs, *_ = env.step(gen.uniform(-1, 1, 3) * np.array([0.004, 0.004, 0.02]))
        s_new = encode(obs["centerline"])
        J = akf.update(s_new - s, obs["applied"])
        s = s_new
        true = env.jacobian_error_reference(encode)
        errors.append(np.linalg.norm(J - true) / np.linalg.norm(true))
    assert np.all(np.isfinite(errors))
    assert errors[-1] < 0.5 * errors[0], np.round(errors, 3)


def test_compare_results_have_the_jacobian_error_columns(tmp_path) -> None:
    config = {
        "name": "jerr",
        "base": {
            "rod": {"segments": 20, "engine": "quasistatic"},
            "camera": {"points": 30},
            "run": {"max_steps": 8},
            "logging": {"mcap": False, "rerun": False, "figures": False},
        },
        "methods": {
            "akf": {
                "feature": {"type": "bezier", "degree": 3},
                "estimator": {"type": "akf"},
                "controller": {"type": "mfac"},
            },
        },
        "targets": {"count": 1, "min_offset": 0.1, "max_offset": 0.3},
        "workers": 1,
    }
    path = tmp_path / "jerr.yaml"
    path.write_text(yaml.safe_dump(config), encoding="utf-8")
    folder = run_compare(str(path), [], str(tmp_path / "out"), progress=False, workers=1)
    assert {"jacobian_error_median", "jacobian_error_final"} <= set(CSV_COLUMNS)
    with (folder / "results.csv").open() as fh:
        rows = {r["method"]: r for r in csv.DictReader(fh)}
    assert 0.0 < float(rows["akf"]["jacobian_error_median"]) < 10.0
    assert 0.0 < float(rows["akf"]["jacobian_error_final"]) < 10.0


def test_the_summary_median_is_numpys() -> None:
    """The episode summary's median Jacobian error is np.median's, bit for bit (it is computed
    without numpy so that an episode does not import numpy.ma), NaN steps left out."""
    rng = np.random.default_rng(9)
    for n in range(1, 30):
        errors = list(rng.lognormal(-2.0, 1.5, n))
        errors[:: max(2, n // 3)] = [math.nan] * len(errors[:: max(2, n // 3)])
        got = _jacobian_error_summary([SimpleNamespace(jacobian_error=e) for e in errors])
        finite = np.array([e for e in errors if math.isfinite(e)])
        want = float(np.median(finite)) if finite.size else None
        assert got["jacobian_error_median"] == want, n
        assert got["jacobian_error_final"] == (None if math.isnan(errors[-1]) else errors[-1])
    assert _jacobian_error_summary([]) == {
        "jacobian_error_median": None,
        "jacobian_error_final": None,
    }
