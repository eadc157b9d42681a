"""A run folder carries its encoder checkpoint (rodctl/portable.py): copied to another place,
with the original checkpoint gone, `replay --verify` still re-runs it; a changed copy is refused."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

from paths import REPO
from typer.testing import CliRunner

import rodctl
from rodctl.cli import app
from rodctl.features.autoencoder import DEFAULT_CHECKPOINT

runner = CliRunner()


def test_a_copied_run_folder_verifies_without_the_original_checkpoint(tmp_path):
    own = tmp_path / "mine" / "encoder-v1.npz"
    own.parent.mkdir()
    shutil.copyfile(DEFAULT_CHECKPOINT, own)
    res = runner.invoke(
        app,
        [
            "simulate", str(REPO / "configs/default.yaml"), "-q", "-o", str(tmp_path / "runs"),
            "--set", f"feature.checkpoint={own}", "--set", "run.max_steps=3",
            "--set", "logging.rerun=false", "--set", "logging.figures=false",
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    run_dir = Path(res.stdout.strip().splitlines()[-1])
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["encoder"] == {
        "file": "encoder.npz",
        "sha256": hashlib.sha256(own.read_bytes()).hexdigest(),
        "source": str(own),
    }

    moved = tmp_path / "colleague" / run_dir.name
    shutil.copytree(run_dir, moved)
    own.rename(own.with_suffix(".gone"))  # the original path no longer exists
    res = runner.invoke(app, ["replay", str(moved), "--verify", "--no-figures"])
    assert res.exit_code == 0, res.output
    assert "verify: OK" in res.output
    assert [r.step for r in rodctl.load_run(moved).records] == [0, 1, 2, 3]

    # A copy changed after the run is not what the run used.
    with open(moved / "encoder.npz", "r+b") as fh:
        fh.seek(-1, 2)
        last = fh.read(1)
        fh.seek(-1, 2)
        fh.write(bytes([last[0] ^ 1]))
    res = runner.invoke(app, ["replay", str(moved), "--verify", "--no-figures"])
    assert res.exit_code == 2, res.output
    assert "SHA-256" in res.output and "encoder.npz" in res.output
