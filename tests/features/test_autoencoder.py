"""Autoencoder feature: training machinery, numpy/torch agreement, checkpoint I/O and checks."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rodctl.config import ExperimentConfig
from rodctl.errors import UserError
from rodctl.features import make_feature_map
from rodctl.features.autoencoder import (
    AutoencoderFeatureMap,
    EncoderCheckpoint,
    encoder_fingerprint,
    torch_encode,
)
from rodctl.training.encoder import fit_autoencoder


def test_tiny_training_learns_the_shape_family(tiny_checkpoint, synthetic_split):
    train, held = synthetic_split
    fmap = tiny_checkpoint.feature_map()
    err = fmap.reconstruction_error(held).mean()
    # Baseline: predicting the mean training shape for every input.
    baseline = np.linalg.norm(held - train.mean(axis=0), axis=-1).mean()
    assert baseline > 40.0  # the shapes really vary (tens of pixels)
    assert err < 0.1 * baseline
    assert err < 2.5  # 1.7 px measured
    m = tiny_checkpoint.metrics
    assert m["validation"]["mean_px"] == pytest.approx(err, rel=1e-6)
    assert m["train_samples"] == 2000 and m["validation_samples"] == 300
    assert m["loss_rms_px"][-1] < 0.2 * m["loss_rms_px"][0]


def test_numpy_inference_matches_torch(tiny_checkpoint, synthetic_split):
    _, held = synthetic_split
    fmap = tiny_checkpoint.feature_map()
    z_np = fmap.encode_batch(held[:50])
    z_t = torch_encode(tiny_checkpoint, held[:50])
    np.testing.assert_allclose(z_np, z_t, rtol=0, atol=1e-4 * np.abs(z_t).max())
    for b in range(3):
        np.testing.assert_allclose(fmap.encode(held[b]), z_np[b], rtol=1e-12, atol=1e-12)
    # decoder too: numpy decode equals the torch decoder on the same latent
    net = tiny_checkpoint.network()
    with torch.no_grad():
        rec = net.decoder(torch.as_tensor(z_np[:5], dtype=torch.float32)).double().numpy()
    rec = rec * tiny_checkpoint.input_scale + tiny_checkpoint.input_mean
    np.testing.assert_allclose(fmap.decode(z_np[:5]).reshape(5, -1), rec, atol=1e-3)


def test_encoding_is_deterministic(tiny_checkpoint, synthetic_split):
    _, held = synthetic_split
    a = tiny_checkpoint.feature_map().encode(held[0])
    b = tiny_checkpoint.feature_map().encode(held[0].copy())
    assert a.shape == (6,) and a.dtype == np.float64
    assert np.array_equal(a, b)


def test_training_is_reproducible_from_the_seed(tiny_cfg, synthetic_split):
    train, held = synthetic_split
    cfg = tiny_cfg.model_copy(deep=True)
    cfg.feature.training.epochs = 3
    runs = [
        fit_autoencoder(train[:500], held[:50], cfg.feature, seed=5, fingerprint={}, progress=False)
        for _ in range(2)
    ]
    for k, v in runs[0].state_dict.items():
        assert np.array_equal(v, runs[1].state_dict[k])
    other = fit_autoencoder(
        train[:500], held[:50], cfg.feature, seed=6, fingerprint={}, progress=False
    )
    assert not all(np.array_equal(v, other.state_dict[k]) for k, v in runs[0].state_dict.items())


def test_latent_scale_is_the_training_spread(tiny_checkpoint, synthetic_split):
    train, _ = synthetic_split
    fmap = tiny_checkpoint.feature_map()
    np.testing.assert_allclose(fmap.scale, fmap.encode_batch(train).std(axis=0), rtol=1e-9)
    assert fmap.units == "latent" and fmap.kind == "autoencoder"


def test_checkpoint_round_trip_with_weights_only(
    tmp_path, tiny_checkpoint, tiny_cfg, synthetic_split
):
    _, held = synthetic_split
    path = tmp_path / "encoder.pt"
    tiny_checkpoint.save(path)
    raw = torch.load(path, map_location="cpu", weights_only=True)  # no pickled code needed
    assert raw["format"] == "rodctl.autoencoder" and raw["fingerprint"]["points"] == 100
    cfg = tiny_cfg.model_copy(deep=True)
    cfg.feature.checkpoint = str(path)
    fmap = make_feature_map(cfg.feature, points=100, experiment=cfg)
    assert isinstance(fmap, AutoencoderFeatureMap)
    np.testing.assert_array_equal(
        fmap.encode_batch(held[:10]), tiny_checkpoint.feature_map().encode_batch(held[:10])
    )
    assert path.stat().st_size < 200_000


@pytest.mark.parametrize(
    "content",
    [b"", b"not a checkpoint at all", b"PK\x03\x04" + bytes(range(200))],
    ids=["empty", "text", "broken-zip"],
)
@pytest.mark.parametrize("suffix", [".pt", ".npz"])
def test_corrupt_file_is_a_user_error_naming_it(tmp_path, content, tiny_cfg, suffix):
    path = tmp_path / f"broken{suffix}"
    path.write_bytes(content)
    cfg = tiny_cfg.model_copy(deep=True)
    cfg.feature.checkpoint = str(path)
    with pytest.raises(UserError, match=f"broken\\{suffix}") as err:
        make_feature_map(cfg.feature, points=100, experiment=cfg)
    assert "checkpoint" in str(err.value)
    # numpy's and torch's own texts advise loading the file unsafely: never passed on
    for advice in ("allow_pickle", "weights_only", "pickle.load", "trust"):
        assert advice not in str(err.value), str(err.value)


def test_truncated_checkpoint_is_a_user_error(tmp_path, tiny_checkpoint):
    path = tmp_path / "encoder.pt"
    tiny_checkpoint.save(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(UserError, match="encoder.pt"):
        EncoderCheckpoint.load(path)


def test_foreign_torch_file_is_a_user_error(tmp_path):
    path = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, path)
    with pytest.raises(UserError, match=r"other\.pt.*format"):
        EncoderCheckpoint.load(path)


def test_missing_file_is_a_user_error(tmp_path, tiny_cfg):
    cfg = tiny_cfg.model_copy(deep=True)
    cfg.feature.checkpoint = str(tmp_path / "nowhere.pt")
    with pytest.raises(UserError, match="nowhere.pt"):
        make_feature_map(cfg.feature, points=100)


@pytest.mark.parametrize(
    "change,field",
    [
        ({"rod": {"length": 0.6}}, "rod.length"),
        ({"rod": {"clamp_pose": [0.0, 0.05, 0.0]}}, "rod.clamp_pose"),
        ({"camera": {"tilt_deg": 10.0}}, "camera.homography"),
        ({"camera": {"width": 800}}, "camera.width"),
        ({"feature": {"latent_dim": 4}}, "architecture.latent_dim"),
        ({"feature": {"hidden": [128, 64]}}, "architecture.hidden"),
    ],
)
def test_checkpoint_for_another_setup_is_a_user_error_naming_the_field(
    tmp_path, tiny_checkpoint, tiny_cfg, change, field
):
    path = tmp_path / "encoder.pt"
    tiny_checkpoint.save(path)
    data = _merge(tiny_cfg.model_dump(mode="json"), change)
    data["feature"]["checkpoint"] = str(path)
    cfg = ExperimentConfig.model_validate(data)
    with pytest.raises(UserError) as err:
        make_feature_map(cfg.feature, points=cfg.camera.points, experiment=cfg)
    msg = str(err.value)
    assert str(path) in msg and field in msg and "train-encoder" in msg


def test_noise_and_training_settings_do_not_invalidate_a_checkpoint(
    tmp_path, tiny_checkpoint, tiny_cfg
):
    path = tmp_path / "encoder.pt"
    tiny_checkpoint.save(path)
    data = _merge(
        tiny_cfg.model_dump(mode="json"),
        {
            "seed": 9,
            "camera": {"render": {"noise_std": 3.0}},
            "feature": {
                "checkpoint": str(path),
                "training": {"epochs": 7},
                "data": {"samples": 50},
            },
        },
    )
    cfg = ExperimentConfig.model_validate(data)
    assert make_feature_map(cfg.feature, points=100, experiment=cfg).dim == 6


def test_points_mismatch_is_caught_without_the_experiment(tmp_path, tiny_checkpoint, tiny_cfg):
    path = tmp_path / "encoder.pt"
    tiny_checkpoint.save(path)
    cfg = tiny_cfg.model_copy(deep=True)
    cfg.feature.checkpoint = str(path)
    with pytest.raises(UserError, match="points"):
        make_feature_map(cfg.feature, points=80)


def test_fingerprint_ignores_what_does_not_change_the_encoding():
    a = ExperimentConfig()
    b = ExperimentConfig.model_validate(
        {
            "seed": 3,
            "camera": {"render": {"noise_std": 2.0, "blur_sigma": 1.0}},
            "feature": {"training": {"epochs": 5}, "data": {"samples": 100}},
        }
    )
    assert encoder_fingerprint(a) == encoder_fingerprint(b)


def _merge(base: dict, change: dict) -> dict:
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    for k, v in change.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def test_npz_checkpoint_round_trip_and_no_torch_on_the_inference_path(
    tmp_path, tiny_checkpoint, synthetic_split
):
    """encoder.npz holds exactly what encoder.pt holds, and loading and encoding with it never
    imports torch (issue #17: torch's import alone took longer than a default run)."""
    import subprocess
    import sys

    _, held = synthetic_split
    tiny_checkpoint.save(tmp_path / "encoder.npz")
    tiny_checkpoint.save(tmp_path / "encoder.pt")
    a = EncoderCheckpoint.load(tmp_path / "encoder.npz")
    b = EncoderCheckpoint.load(tmp_path / "encoder.pt")
    assert a.state_dict.keys() == b.state_dict.keys()
    assert all(np.array_equal(a.state_dict[k], b.state_dict[k]) for k in a.state_dict)
    assert a.fingerprint == b.fingerprint and a.metrics == b.metrics
    np.testing.assert_array_equal(
        a.feature_map().encode_batch(held[:5]), tiny_checkpoint.feature_map().encode_batch(held[:5])
    )
    code = (
        "import sys, numpy as np\n"
        "from rodctl.config import ExperimentConfig\n"
        "from rodctl.features import make_feature_map\n"
        "cfg = ExperimentConfig()\n"
        "fmap = make_feature_map(cfg.feature, points=100, experiment=cfg)\n"
        "fmap.encode(np.column_stack([np.linspace(300, 500, 100), np.full(100, 240.0)]))\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


def test_npz_with_wrong_weights_is_a_user_error(tmp_path, tiny_checkpoint):
    path = tmp_path / "encoder.npz"
    tiny_checkpoint.save(path)
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["w/encoder.0.weight"] = arrays["w/encoder.0.weight"][:, :-1]
    np.savez(path, **arrays)
    with pytest.raises(UserError, match=r"encoder\.npz.*architecture"):
        EncoderCheckpoint.load(path)
