"""The paper's shape feature (section VI-A): the latent code of a centerline autoencoder.

Architecture: an MLP encoder 2N -> hidden... -> p with ReLU after every hidden layer and a linear
latent, and a mirrored decoder (the paper: "RELU function is adopted in the Encoder and Decoder";
layer widths are not printed; we use 128/64, docs/baselines.md).

Input normalisation is stored with the weights: a per-coordinate mean (2N,) and ONE scalar scale
(the pooled standard deviation). A single scale, rather than one per coordinate, keeps the
reconstruction loss proportional to the squared pixel error (so training minimises what is
reported), and does not blow up the clamp-end coordinates, which barely vary.

Inference runs in numpy with float64 copies of the weights, the normalisation folded into the
first and last layers: a 200-128-64-6 forward pass is three small mat-vecs, a few microseconds,
where one torch call costs tens of microseconds of overhead alone. `torch_encode` runs the same
checkpoint through torch, and the tests check the two agree.

A checkpoint comes in two files with the same content: `encoder.npz` (numpy arrays and one JSON
text, read with `numpy.load(..., allow_pickle=False)`), which is what experiments load, without
importing torch (torch takes about a second to import, longer than a whole default run: issue
#17); and `encoder.pt`, a plain dict of tensors, numbers and strings written by `torch.save` and
loadable with `torch.load(..., weights_only=True)`, kept for training tools. `EncoderCheckpoint.
load` reads either, by suffix. A checkpoint carries a *fingerprint* of what the learned feature
depends on: the rod geometry (length, clamp pose) and, when present, its in-plane gravity load
per stiffness, the camera geometry, N and the architecture, but not noise levels, seeds, table
friction or training settings. Loading it for a config whose fingerprint
differs is a `UserError` naming the file and the config keys to change.

torch is imported only inside the functions that need it (`AutoencoderNet`, `torch_encode`,
`.pt` files), never at module import. It is an optional dependency (the extra `train`):
`require_torch` says how to install it when it is missing.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeGuard

import numpy as np
import yaml

from rodctl import fixedla as fla
from rodctl.config.loading import safe_load  # size, nesting and alias bombs refused
from rodctl.errors import UserError
from rodctl.features.geometry import check_centerlines

if TYPE_CHECKING:
    import torch

    from rodctl.config.experiment import ExperimentConfig

#: Identifies our checkpoints; bump VERSION when the layout changes.
FORMAT = "rodctl.autoencoder"
VERSION = 1

#: The checkpoint packaged with rodctl and used when `feature.checkpoint` is None.
DEFAULT_CHECKPOINT = Path(__file__).resolve().parent.parent / "assets" / "encoder.npz"


def require_torch(purpose: str) -> Any:
    """Import and return torch, or raise a `UserError` saying how to install it.

    Args:
        purpose: what needs torch, e.g. "train-encoder" (starts the message).
    """
    try:
        import torch
    except ImportError:
        raise UserError(
            f"{purpose} needs torch, which rodctl installs only for training: "
            "pip install -e '.[train]' (on a machine without a GPU, install the CPU build of "
            "torch first: docs/install.md)"
        ) from None
    return torch


def AutoencoderNet(inputs: int, hidden: list[int], latent_dim: int) -> torch.nn.Module:  # noqa: N802
    """The torch module: encoder 2N -> hidden -> p (linear latent), mirrored decoder, ReLU in
    between; `forward` maps (B, 2N) normalised inputs to their reconstruction.

    A factory rather than a module-level class so that importing this module never imports
    torch. Parameter names: encoder.{0,2,..}.weight/bias, decoder.{0,2,..}.weight/bias.

    Args:
        inputs: 2N.
        hidden: encoder hidden widths, e.g. [128, 64]; the decoder uses them reversed.
        latent_dim: p.
    """
    from torch import nn

    class _Net(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.encoder = _mlp(nn, [inputs, *hidden, latent_dim])
            self.decoder = _mlp(nn, [latent_dim, *reversed(hidden), inputs])

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return self.decoder(self.encoder(x))

    return _Net()


def _mlp(nn: Any, widths: list[int]) -> Any:
    layers: list[Any] = []
    for i, (a, b) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if i < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def parameter_shapes(arch: dict[str, Any]) -> dict[str, tuple[int, ...]]:
    """{parameter name: shape} of the network an architecture record describes (no torch)."""
    inputs, latent = int(arch["inputs"]), int(arch["latent_dim"])
    hidden = [int(h) for h in arch["hidden"]]
    out: dict[str, tuple[int, ...]] = {}
    for part, widths in (
        ("encoder", [inputs, *hidden, latent]),
        ("decoder", [latent, *reversed(hidden), inputs]),
    ):
        for i, (a, b) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
            out[f"{part}.{2 * i}.weight"] = (b, a)
            out[f"{part}.{2 * i}.bias"] = (b,)
    return out


class Architecture(Protocol):
    """What the network's shape is read from: an autoencoder feature config
    (`rodctl.features.autoencoder_config.AutoencoderFeatureConfig`, which imports this module,
    not the other way round)."""

    hidden: list[int]
    latent_dim: int


class _BatchSize(Protocol):
    batch_size: int


class _DataSpec(Protocol):
    samples: int
    chunk: int
    workers: int


class AutoencoderSpec(Architecture, Protocol):
    """What the cache and the fingerprint read of an autoencoder feature config (its `type` is
    "autoencoder")."""

    type: str
    checkpoint: str | None
    training: _BatchSize
    data: _DataSpec


def is_autoencoder(feature: object) -> TypeGuard[AutoencoderSpec]:
    """`feature` is an autoencoder feature config (its `type` says so)."""
    return getattr(feature, "type", None) == "autoencoder"


def architecture_of(feature: Architecture, points: int) -> dict[str, Any]:
    """The architecture record of a checkpoint for `feature` on N = `points` centerlines."""
    return {
        "inputs": 2 * points,
        "hidden": list(feature.hidden),
        "latent_dim": feature.latent_dim,
        "activation": "relu",
    }


def encoder_fingerprint(cfg: ExperimentConfig) -> dict[str, Any]:
    """What a trained encoder depends on, as plain JSON-able values.

    Rod geometry (length, clamp pose); camera geometry as the image size, the plane-to-pixel
    homography (which folds intrinsics and camera pose into 9 numbers, normalised so h33 = 1) and
    how the extractor spaces its points; N; the architecture. Seeds, noise, rendering appearance,
    data and training settings are left out: they change how good the encoder is, not what it
    encodes.

    Args:
        cfg: an experiment config whose `feature` is an autoencoder.
    """
    # The camera model defines the geometry. Lazy: it imports OpenCV, which a config command
    # (that loads every feature's registration) does not need.
    from rodctl.vision.camera import Camera  # noqa: PLC0415

    if not is_autoencoder(cfg.feature):
        raise ValueError(f"feature.type is {cfg.feature.type!r}, not 'autoencoder'")
    camera = Camera(cfg.camera, None)
    return {
        "points": cfg.camera.points,
        "architecture": architecture_of(cfg.feature, cfg.camera.points),
        "rod": _rod_fingerprint(cfg),
        "camera": {
            "width": cfg.camera.width,
            "height": cfg.camera.height,
            "homography": [float(v) for v in np.asarray(camera.homography).ravel()],
            "arc_length": cfg.camera.extract.arc_length,
        },
    }


def _rod_fingerprint(cfg: ExperimentConfig) -> dict[str, Any]:
    """The rod's part of the fingerprint: geometry, plus in-plane gravity when there is some.

    A weightless rod's settled shapes depend only on L and the end poses. Gravity in the plane
    changes the family of shapes: it adds the distributed load per stiffness ρA·g/EI (1/m³, the
    only combination the heavy elastica depends on), so a checkpoint is refused when that
    differs. Measured with `benchmarks/bench_encoder_fit.py` (300 fresh shapes each): the
    packaged weightless encoder reconstructs 0.41 px mean on its own rod, 0.62 px with gravity
    at q L³/EI = 19 and 1.59 px at 85 — the error grows with the load, so it is refused.

    Table friction is left out on purpose: it only makes the shapes path-dependent within a
    band of a few millimetres around the weightless equilibria (same family), and the packaged
    encoder reconstructs table shapes (μ = 0.5) at 0.50 px mean, within its 1 px goal.

    The gravity key is present only when gravity is on, so checkpoints of the weightless rod
    (the packaged one included) keep their fingerprint.
    """
    rod = cfg.rod
    out: dict[str, Any] = {"length": rod.length, "clamp_pose": list(rod.clamp_pose)}
    if rod.arms == 2:  # both ends move: a wider family of shapes (docs/dual-arm.md)
        out["arms"] = 2
    if tuple(rod.gravity) != (0.0, 0.0):
        scale = rod.mass_per_length / rod.bending_stiffness
        out["gravity_load_per_stiffness"] = [scale * g for g in rod.gravity]
    return out


def fingerprint_differences(stored: Any, expected: Any, prefix: str = "") -> list[str]:
    """Human-readable differences between two fingerprints ('field: checkpoint X, config Y').

    Numbers compare with a relative tolerance of 1e-9 (they went through JSON and YAML).
    """
    if isinstance(stored, dict) and isinstance(expected, dict):
        out: list[str] = []
        for key in sorted(set(stored) | set(expected), key=str):
            name = f"{prefix}.{key}" if prefix else str(key)
            if key not in stored:
                out.append(f"{name}: absent from the checkpoint, config has {expected[key]!r}")
            elif key not in expected:
                out.append(f"{name}: checkpoint has {stored[key]!r}, absent from the config")
            else:
                out.extend(fingerprint_differences(stored[key], expected[key], name))
        return out
    if isinstance(stored, list | tuple) and isinstance(expected, list | tuple):
        same = len(stored) == len(expected) and all(
            not fingerprint_differences(a, b) for a, b in zip(stored, expected, strict=False)
        )
        numeric = all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in [*stored, *expected]
        )
        if not same and numeric and len(stored) == len(expected) and len(stored) > 4:
            gap = max(abs(a - b) for a, b in zip(stored, expected, strict=True))
            return [f"{prefix}: checkpoint and config differ (by up to {gap:.4g})"]
    elif isinstance(stored, bool | str | None) or isinstance(expected, bool | str | None):
        same = stored == expected
    elif isinstance(stored, int | float) and isinstance(expected, int | float):
        same = math.isclose(stored, expected, rel_tol=1e-9, abs_tol=1e-12)
    else:
        same = stored == expected
    return [] if same else [f"{prefix}: checkpoint has {stored!r}, config has {expected!r}"]


#: Fingerprint fields -> the config keys a user sets to change them.
_FINGERPRINT_KEYS = {
    "points": ["camera.points"],
    "architecture.inputs": ["camera.points"],
    "architecture.hidden": ["feature.hidden"],
    "architecture.latent_dim": ["feature.latent_dim"],
    "architecture.activation": ["feature.type"],
    "rod.length": ["rod.length"],
    "rod.clamp_pose": ["rod.clamp_pose"],
    "camera.width": ["camera.width"],
    "camera.height": ["camera.height"],
    "camera.arc_length": ["camera.extract.arc_length"],
    "camera.homography": [
        "camera.fx",
        "camera.fy",
        "camera.cx",
        "camera.cy",
        "camera.look_at",
        "camera.distance",
        "camera.tilt_deg",
        "camera.azimuth_deg",
        "camera.width",
        "camera.height",
    ],
}


def _lookup(data: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        if not isinstance(data, dict) or part not in data:
            return None
        data = data[part]
    return data


def config_key_differences(
    checkpoint: EncoderCheckpoint, experiment: ExperimentConfig | None, diffs: list[str]
) -> list[str]:
    """The fingerprint differences `diffs` restated as the config keys that cause them.

    Each differing fingerprint field is mapped to the config keys it derives from, and those
    keys are compared between the config the checkpoint was trained with (`config_yaml`) and
    `experiment`: "camera.tilt_deg: the encoder's 25.0, this config's 35.0". A field whose keys
    cannot be compared (no experiment, an old checkpoint without its config) stays as it is,
    with the keys that may cause it.
    """
    try:
        trained = safe_load(checkpoint.config_yaml) if checkpoint.config_yaml else None
    except (yaml.YAMLError, RecursionError):
        trained = None
    current = experiment.model_dump(mode="json") if experiment is not None else None
    out: list[str] = []
    for diff in diffs:
        field_name = diff.split(":", 1)[0]
        keys = _FINGERPRINT_KEYS.get(field_name, [])
        named = []
        if isinstance(trained, dict) and current is not None:
            for key in keys:
                a, b = _lookup(trained, key), _lookup(current, key)
                if a != b:
                    named.append(f"{key}: the encoder's {a!r}, this config's {b!r}")
        if named:
            out.extend(n for n in named if n not in out)
        elif keys:
            out.append(f"{diff} (set by {', '.join(keys)})")
        else:
            out.append(diff)
    return out


#: The entries every serialised checkpoint has (`EncoderCheckpoint.from_dict`).
_CHECKPOINT_KEYS = (
    "state_dict",
    "architecture",
    "input_mean",
    "input_scale",
    "latent_scale",
    "fingerprint",
)


def _checked_weights(
    arch: Any, state_dict: Any, bad: Callable[[str], UserError]
) -> tuple[int, int, list[int], dict[str, tuple[int, ...]], dict[str, np.ndarray]]:
    """(inputs, latent_dim, hidden sizes, parameter shapes, weights) of a serialised checkpoint,
    the weights checked to have the architecture's names and shapes; `bad(why)` is raised."""
    try:
        inputs, latent = int(arch["inputs"]), int(arch["latent_dim"])
        hidden = [int(h) for h in arch["hidden"]]
        shapes = parameter_shapes(arch)
        weights = {k: _as_numpy(v) for k, v in dict(state_dict).items()}
    except (KeyError, TypeError, ValueError) as exc:
        raise bad(f"unreadable architecture or weights ({exc})") from None
    if set(weights) != set(shapes) or any(weights[k].shape != shape for k, shape in shapes.items()):
        raise bad("weights do not match the recorded architecture")
    return inputs, latent, hidden, shapes, weights


def _checked_normalisation(
    data: dict[str, Any], inputs: int, latent: int, bad: Callable[[str], UserError]
) -> tuple[np.ndarray, float, np.ndarray]:
    """(input mean (inputs,), input scale > 0, latent scale (latent,)) of a serialised
    checkpoint, finite and of the architecture's sizes; `bad(why)` is raised."""
    try:
        mean = _as_numpy(data["input_mean"]).astype(np.float64)
        lat = _as_numpy(data["latent_scale"]).astype(np.float64)
        scale = float(data["input_scale"])
    except (TypeError, ValueError) as exc:
        raise bad(f"unreadable normalisation ({exc})") from None
    if mean.shape != (inputs,) or lat.shape != (latent,) or not scale > 0.0:
        raise bad("normalisation does not match the architecture")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(lat)) and math.isfinite(scale)):
        raise bad("normalisation holds non-finite values")
    return mean, scale, lat


@dataclass
class EncoderCheckpoint:
    """A trained autoencoder with everything needed to use and to trust it.

    Attributes:
        state_dict: `AutoencoderNet` parameters as float32 numpy arrays.
        architecture: {"inputs": 2N, "hidden": [...], "latent_dim": p, "activation": "relu"}.
        input_mean: (2N,) per-coordinate mean of the training centerlines, pixels.
        input_scale: pooled standard deviation of the training centerlines, pixels.
        latent_scale: (p,) standard deviation of each latent over the training set.
        fingerprint: `encoder_fingerprint` of the config it was trained for.
        config_yaml: the resolved config that trained it.
        metrics: training figures (reconstruction errors in pixels, sizes, times).
    """

    state_dict: dict[str, np.ndarray]
    architecture: dict[str, Any]
    input_mean: np.ndarray
    input_scale: float
    latent_scale: np.ndarray
    fingerprint: dict[str, Any]
    config_yaml: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def points(self) -> int:
        """N, the centerline points the encoder takes."""
        return int(self.architecture["inputs"]) // 2

    def network(self) -> torch.nn.Module:
        """The torch module with these weights, in eval mode (imports torch)."""
        import torch

        arch = self.architecture
        net = AutoencoderNet(int(arch["inputs"]), list(arch["hidden"]), int(arch["latent_dim"]))
        net.load_state_dict({k: torch.from_numpy(np.array(v)) for k, v in self.state_dict.items()})
        return net.eval()

    def feature_map(self, source: str = "") -> AutoencoderFeatureMap:
        """The numpy inference map of this checkpoint; `source` names it in messages."""
        return AutoencoderFeatureMap(self, source=source)

    def _meta(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "architecture": self.architecture,
            "input_scale": float(self.input_scale),
            "fingerprint": self.fingerprint,
            "config_yaml": self.config_yaml,
            "metrics": self.metrics,
        }

    def to_dict(self) -> dict[str, Any]:
        """The serialised form of `encoder.pt` (tensors, numbers, strings; imports torch)."""
        import torch

        meta = self._meta()
        return {
            "format": meta.pop("format"),
            "version": meta.pop("version"),
            "state_dict": {
                k: torch.from_numpy(np.asarray(v, dtype=np.float32).copy())
                for k, v in self.state_dict.items()
            },
            "input_mean": torch.as_tensor(self.input_mean, dtype=torch.float64),
            "latent_scale": torch.as_tensor(self.latent_scale, dtype=torch.float64),
            **meta,
        }

    def save(self, path: str | Path) -> None:
        """Write the checkpoint atomically (temporary file, then rename): numpy's `.npz` when
        `path` ends in .npz, `torch.save` otherwise."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        if path.suffix == ".npz":
            arrays: dict[str, Any] = {
                f"w/{k}": np.asarray(v, dtype=np.float32) for k, v in self.state_dict.items()
            }
            with open(tmp, "wb") as f:
                np.savez(
                    f,
                    meta=np.array(json.dumps(self._meta(), sort_keys=True)),
                    input_mean=np.asarray(self.input_mean, dtype=np.float64),
                    latent_scale=np.asarray(self.latent_scale, dtype=np.float64),
                    **arrays,
                )
        else:
            import torch

            torch.save(self.to_dict(), tmp)
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path) -> EncoderCheckpoint:
        """Read and validate a checkpoint written by `save` (.npz without torch, else torch).

        Raises:
            UserError: the file is missing, unreadable, not a rodctl encoder checkpoint, of
                another format version, or internally inconsistent; the message names the file.
        """
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path}: encoder checkpoint not found")
        if path.suffix not in (".npz", ".pt"):
            raise UserError(
                f"{path}: not an encoder checkpoint (an encoder.npz, or the encoder.pt that "
                "`rodctl train-encoder` writes beside it)"
            )
        if path.suffix == ".pt":
            torch = require_torch(f"{path}: reading a .pt checkpoint (or use its .npz twin)")
        try:
            if path.suffix == ".npz":
                data = _read_npz(path)
            else:
                data = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - torch/numpy raise many types on a corrupt file
            # The libraries' own texts advise loading the file unsafely (allow_pickle,
            # weights_only=False): never passed on for a file that may not be trusted.
            kind = "a NumPy .npz archive" if path.suffix == ".npz" else "a torch checkpoint"
            what = (
                f"not {kind}"
                if not zipfile.is_zipfile(path)
                else "an archive without an encoder's plain arrays and tensors"
            )
            raise UserError(
                f"{path}: not a readable encoder checkpoint ({what}; {type(exc).__name__}); "
                "re-create it with `rodctl train-encoder`"
            ) from None
        return cls.from_dict(data, source=str(path))

    @classmethod
    def from_dict(cls, data: Any, source: str) -> EncoderCheckpoint:
        """Validate the serialised form; `source` names it in errors (raises `UserError`)."""

        def bad(why: str) -> UserError:
            return UserError(
                f"{source}: not a valid rodctl encoder checkpoint: {why}; "
                "re-create it with `rodctl train-encoder`"
            )

        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise bad(f"expected a mapping with format={FORMAT!r}")
        if data.get("version") != VERSION:
            raise bad(f"format version {data.get('version')!r}, this rodctl reads {VERSION}")
        missing = [k for k in _CHECKPOINT_KEYS if k not in data]
        if missing:
            raise bad(f"missing {', '.join(missing)}")
        arch = data["architecture"]
        inputs, latent, hidden, shapes, weights = _checked_weights(arch, data["state_dict"], bad)
        mean, scale, lat = _checked_normalisation(data, inputs, latent, bad)
        for name, w in weights.items():
            if not np.all(np.isfinite(w)):
                raise bad(f"weight {name} holds non-finite values")
        fingerprint, metrics = data["fingerprint"], data.get("metrics", {})
        if not isinstance(fingerprint, dict) or not isinstance(metrics, dict):
            raise bad("fingerprint and metrics must be mappings")
        return cls(
            state_dict={k: weights[k].astype(np.float32) for k in shapes},
            architecture={
                "inputs": inputs,
                "hidden": hidden,
                "latent_dim": latent,
                "activation": str(arch.get("activation", "relu")),
            },
            input_mean=mean,
            input_scale=scale,
            latent_scale=lat,
            fingerprint=fingerprint,
            config_yaml=str(data.get("config_yaml", "")),
            metrics=metrics,
        )

    def mismatches(
        self, expected: dict[str, Any], experiment: ExperimentConfig | None = None
    ) -> list[str]:
        """Where the set-up it was trained for differs from `expected` (empty: it fits), as
        config keys when `experiment` is given (see `check_compatible`)."""
        diffs = fingerprint_differences(self.fingerprint, expected)
        return config_key_differences(self, experiment, diffs) if diffs else []

    def check_compatible(
        self,
        expected: dict[str, Any],
        source: str,
        experiment: ExperimentConfig | None = None,
    ) -> None:
        """Raise `UserError` naming `source` and every config key where the setups differ.

        Args:
            expected: the fingerprint of the config it is to be used with.
            source: the checkpoint's path, for the message.
            experiment: that config; with it, the message names the user's config keys (e.g.
                `camera.tilt_deg`) instead of the fingerprint's derived quantities (the camera
                homography), by comparing the config the checkpoint was trained with.
        """
        lines = self.mismatches(expected, experiment)
        if not lines:
            return
        raise UserError(
            f"{source}: this encoder was trained for another rod or camera:\n  "
            + "\n  ".join(lines)
            + "\nTrain a quick encoder for this config (3,000 samples, 300 epochs: about 30 s "
            "on 2 cores) with `rodctl train-encoder CONFIG --quick` (same --set options) and "
            "set feature.checkpoint to its encoder.npz, or set feature.checkpoint=auto to "
            "train one once and reuse it. `rodctl train-encoder CONFIG` trains the paper's "
            "full-size encoder (about 15 minutes). To run it on this set-up anyway (a transfer "
            "experiment), set feature.other_setup=accept."
        )


def _as_numpy(value: Any) -> np.ndarray:
    """A numpy copy of an array or a (CPU) torch tensor, without importing torch."""
    if hasattr(value, "detach"):  # a torch.Tensor
        value = value.detach().cpu().numpy()
    return np.array(value)


def _read_npz(path: Path) -> dict[str, Any]:
    """The serialised form (as `EncoderCheckpoint.from_dict` takes it) of an .npz checkpoint."""
    with np.load(path, allow_pickle=False) as npz:
        meta = json.loads(str(npz["meta"]))
        if not isinstance(meta, dict):
            raise ValueError("meta is not a mapping")
        meta["state_dict"] = {k[2:]: npz[k] for k in npz.files if k.startswith("w/")}
        meta["input_mean"] = npz["input_mean"]
        meta["latent_scale"] = npz["latent_scale"]
    return meta


def _numpy_layers(state_dict: dict[str, np.ndarray], prefix: str) -> list[list[np.ndarray]]:
    """[[W (out, in), b (out,)], ...] float64 copies of the Linear layers under `prefix`."""
    layers: dict[int, list[np.ndarray]] = {}
    for name, array in state_dict.items():
        if not name.startswith(prefix + "."):
            continue
        _, index, kind = name.split(".")
        slot = layers.setdefault(int(index), [np.empty(0), np.empty(0)])
        slot[0 if kind == "weight" else 1] = _as_numpy(array).astype(np.float64)
    return [layers[i] for i in sorted(layers)]


class AutoencoderFeatureMap:
    """s = encoder(normalise(c)): the autoencoder latent, computed in numpy (float64).

    Args:
        checkpoint: the trained encoder.
        source: where it came from (a path), for messages.

    Attributes:
        dim: latent dimension p.
        points: N.
        kind: "autoencoder".
        units: "latent" (the latent has no physical unit).
        scale: (p,) standard deviation of each latent over the training set; divide by it to
            compare components or set thresholds in a unit-free way.
        source: the checkpoint path.
        checkpoint: the `EncoderCheckpoint` it was built from.
    """

    kind = "autoencoder"
    units = "latent"

    def __init__(self, checkpoint: EncoderCheckpoint, source: str = "") -> None:
        self.checkpoint = checkpoint
        self.source = source
        self.points = checkpoint.points
        self.dim = int(checkpoint.architecture["latent_dim"])
        self.scale = np.asarray(checkpoint.latent_scale, dtype=np.float64).copy()
        mean, s = checkpoint.input_mean, checkpoint.input_scale
        enc = _numpy_layers(checkpoint.state_dict, "encoder")
        dec = _numpy_layers(checkpoint.state_dict, "decoder")
        # Fold x_n = (x - mean) / s into the first encoder layer:
        # W x_n + b = (W/s) x + (b - W mean / s)
        w0, b0 = enc[0]
        enc[0] = [w0 / s, b0 - fla.matvec(w0 / s, mean)]
        # ... and x = s x_n + mean into the last decoder layer.
        wl, bl = dec[-1]
        dec[-1] = [wl * s, bl * s + mean]
        self._enc = [(np.ascontiguousarray(w), np.ascontiguousarray(b)) for w, b in enc]
        self._dec = [(np.ascontiguousarray(w), np.ascontiguousarray(b)) for w, b in dec]
        self._enc_t = [(np.ascontiguousarray(w.T), b) for w, b in self._enc]
        self._dec_t = [(np.ascontiguousarray(w.T), b) for w, b in self._dec]

    def encode(self, centerline_px: np.ndarray) -> np.ndarray:
        """(N, 2) pixels, clamp end first -> (p,) float64 latent. Deterministic."""
        x = np.asarray(centerline_px, dtype=np.float64)
        if x.shape != (self.points, 2):
            check_centerlines(x, self.points, batch=False)  # raises with a clear message
        x = x.reshape(-1)
        last = len(self._enc) - 1
        for i, (w, b) in enumerate(self._enc):
            # Fixed-order mat-vec, not `w @ x`: BLAS dgemv's sums differ between CPU kernels,
            # and s feeds the closed loop (docs/reproducibility.md).
            x = fla.matvec(w, x) + b
            if i < last:
                np.maximum(x, 0.0, out=x)
        return x

    def encode_rows(self, centerlines_px: np.ndarray) -> np.ndarray:
        """(B, N, 2) pixels -> (B, p): `encode` of each shape, the same bits, in one pass.

        Each latent is the same fixed-order `einsum` sum as in `encode` (the reduction over a
        layer's inputs is the innermost loop either way, so numpy runs the same kernel on the
        same products; tests/features/test_autoencoder_rows.py checks it), not a BLAS product
        like `encode_batch`. For the few shapes a step's true Jacobian perturbs
        (`ShapeServoEnv.true_jacobian`): half the calls' overhead.
        """
        x = np.asarray(centerlines_px, dtype=np.float64)
        if x.ndim != 3 or x.shape[1:] != (self.points, 2):
            check_centerlines(x, self.points, batch=True)  # raises with a clear message
        x = x.reshape(x.shape[0], -1)
        last = len(self._enc) - 1
        for i, (w, b) in enumerate(self._enc):
            x = fla.einsum("ok,bk->bo", w, x) + b
            if i < last:
                np.maximum(x, 0.0, out=x)
        return x

    def encode_batch(self, centerlines_px: np.ndarray) -> np.ndarray:
        """(B, N, 2) pixels -> (B, p)."""
        arr = check_centerlines(centerlines_px, self.points, batch=True)
        return _forward(arr.reshape(arr.shape[0], -1), self._enc_t)

    def decode(self, s: np.ndarray) -> np.ndarray:
        """Latent (p,) or (B, p) -> reconstructed centerline (N, 2) or (B, N, 2), pixels."""
        s = np.asarray(s, dtype=np.float64)
        flat = _forward(s.reshape(-1, self.dim), self._dec_t)
        return flat.reshape(*s.shape[:-1], self.points, 2)

    def reconstruction_error(self, centerlines_px: np.ndarray) -> np.ndarray:
        """(B, N, 2) pixels -> (B, N) pixel distance of each point from its reconstruction."""
        arr = check_centerlines(centerlines_px, self.points, batch=True)
        return np.linalg.norm(self.decode(self.encode_batch(arr)) - arr, axis=-1)


def _forward(x: np.ndarray, layers: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Batched MLP pass with ReLU between layers; `layers` hold transposed weights (in, out)."""
    last = len(layers) - 1
    for i, (wt, b) in enumerate(layers):
        x = x @ wt + b  # BLAS: batches (training figures, datasets) are not in the loop
        if i < last:
            np.maximum(x, 0.0, out=x)
    return x


def torch_encode(checkpoint: EncoderCheckpoint, centerlines_px: np.ndarray) -> np.ndarray:
    """The same encoding through torch (float32), as training computes it.

    Args:
        checkpoint: the trained encoder.
        centerlines_px: (B, N, 2) pixels.

    Returns:
        (B, p) float64 latents.
    """
    import torch

    arr = check_centerlines(centerlines_px, checkpoint.points, batch=True)
    x = (arr.reshape(arr.shape[0], -1) - checkpoint.input_mean) / checkpoint.input_scale
    net = checkpoint.network()
    with torch.no_grad():
        z = net.get_submodule("encoder")(torch.as_tensor(x, dtype=torch.float32))
    return z.double().numpy()
