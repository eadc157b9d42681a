"""Portable runs: a run folder carries the encoder checkpoint it used, with its hash.

Why: a run's config names its encoder by path (`feature.checkpoint`: a file, the packaged
default, or `auto`'s cache). Copied to a colleague's machine, that path is gone or holds another
file, and `replay --verify` could not re-run the run. So `rodctl simulate` copies the checkpoint
file it loaded into the run folder (`encoder.npz`, or `encoder.pt` for a torch checkpoint;
~350 KB for the default network) and records in meta.json under `encoder` its file name,
SHA-256 and original path. `replay --verify` re-runs with that copy after checking its hash,
whatever the original path holds now; a run folder without one (older runs) uses the config's
path as before.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

from rodctl.errors import UserError
from rodctl.features.auto import cache_path
from rodctl.features.autoencoder import DEFAULT_CHECKPOINT
from rodctl.features.autoencoder_config import AutoencoderFeatureConfig, _resolve


def checkpoint_file(cfg: Any) -> Path | None:
    """The encoder checkpoint file `cfg` loads (None: its feature has none).

    Call it after the method was built: for `checkpoint: auto` the cached file exists then.
    """
    feature = getattr(cfg, "feature", None)
    if not isinstance(feature, AutoencoderFeatureConfig):
        return None
    if feature.checkpoint is None:
        return DEFAULT_CHECKPOINT
    if feature.checkpoint == "auto":
        return cache_path(cfg)  # trained before the method was built (rodctl.training.auto)
    return _resolve(feature.checkpoint)


def sha256_of(path: Path) -> str:
    """The SHA-256 of a file, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def embed_checkpoint(cfg: Any, run_dir: Path) -> dict[str, str] | None:
    """Copy the checkpoint `cfg` uses into `run_dir`; the meta.json record of it, or None.

    Returns:
        {"file": "encoder.npz", "sha256": ..., "source": the original path}.
    """
    source = checkpoint_file(cfg)
    if source is None or not source.is_file():
        return None
    name = "encoder.pt" if source.suffix == ".pt" else "encoder.npz"
    target = run_dir / name
    tmp = target.with_name(name + ".tmp")
    try:
        shutil.copyfile(source, tmp)
        tmp.replace(target)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    return {"file": name, "sha256": sha256_of(target), "source": str(source)}


def with_embedded_checkpoint(data: dict[str, Any], run_dir: Path) -> dict[str, Any]:
    """The config mapping `data` of the run in `run_dir`, its `feature.checkpoint` pointed at
    the copy in the folder when meta.json records one.

    Raises:
        UserError: the copy is missing or its hash is not the recorded one.
    """
    try:
        meta = json.loads((run_dir / "meta.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return data  # no meta.json beside the log (an MCAP file on its own): the config's path
    record = meta.get("encoder") if isinstance(meta, dict) else None
    if not isinstance(record, dict) or not isinstance(data.get("feature"), dict):
        return data
    copy = run_dir / str(record.get("file", ""))
    if not copy.is_file():
        raise UserError(
            f"{copy}: the encoder checkpoint this run used (meta.json `encoder`) is missing; "
            "copy the whole run folder"
        )
    found = sha256_of(copy)
    if found != record.get("sha256"):
        raise UserError(
            f"{copy}: SHA-256 {found[:16]}... is not the {str(record.get('sha256'))[:16]}... "
            "recorded in meta.json: the file was changed after the run"
        )
    feature = dict(data["feature"])
    feature["checkpoint"] = str(copy.resolve())
    return {**data, "feature": feature}
