"""rodctl without torch (the extra `train` not installed): runs, replays and the Gymnasium env
work; what needs torch says how to install it (exit 2). And a run folder is portable: it
carries its encoder checkpoint (rodctl/portable.py).

torch is installed in the test set-up, so each check runs in a subprocess where an import hook
makes `import torch` fail as it does when torch is absent.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from paths import REPO
from typer.testing import CliRunner

import rodctl
from rodctl.cli import app
from rodctl.features.autoencoder import DEFAULT_CHECKPOINT

BLOCK_TORCH = """
import importlib.abc, sys

class _NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, _NoTorch())
"""

CLI = (
    BLOCK_TORCH
    + """
from rodctl.cli import main
sys.argv = ["rodctl", *sys.argv[1:]]
main()
"""
)


def _rodctl(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", CLI, *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=600,
    )


@pytest.mark.slow
def test_a_run_without_torch_verifies_elsewhere_without_its_checkpoint(tmp_path):
    """The autoencoder feature encoded in numpy, and a portable run folder (rodctl/portable.py):
    copied to another place with its original checkpoint gone, it still verifies."""
    own = tmp_path / "mine" / "encoder-v1.npz"
    own.parent.mkdir()
    shutil.copyfile(DEFAULT_CHECKPOINT, own)
    sim = _rodctl(
        "simulate", str(REPO / "configs/default.yaml"), "--out", str(tmp_path / "runs"), "-q",
        "--set", f"feature.checkpoint={own}", "--set", "run.max_steps=3",
        "--set", "logging.rerun=false", "--set", "logging.figures=false",
        cwd=tmp_path,
    )  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    run_dir = Path(sim.stdout.strip().splitlines()[-1])
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["encoder"] == {
        "file": "encoder.npz",
        "sha256": hashlib.sha256(own.read_bytes()).hexdigest(),
        "source": str(own),
    }
    moved = tmp_path / "colleague" / run_dir.name
    shutil.copytree(run_dir, moved)
    own.rename(own.with_suffix(".gone"))  # the original path no longer exists
    rep = _rodctl("replay", str(moved), "--verify", "--no-figures", cwd=tmp_path)
    assert rep.returncode == 0, rep.stderr
    assert "verify: OK" in rep.stderr
    assert [r.step for r in rodctl.load_run(moved).records] == [0, 1, 2, 3]

    # A copy changed after the run is not what the run used.
    with open(moved / "encoder.npz", "r+b") as fh:
        fh.seek(-1, 2)
        last = fh.read(1)
        fh.seek(-1, 2)
        fh.write(bytes([last[0] ^ 1]))
    res = CliRunner().invoke(app, ["replay", str(moved), "--verify", "--no-figures", "-q"])
    assert res.exit_code == 2, res.output
    assert "SHA-256" in res.output and "encoder.npz" in res.output


@pytest.mark.slow
def test_train_encoder_without_torch_says_how_to_install_it(tmp_path):
    res = _rodctl(
        "train-encoder", str(REPO / "configs/default.yaml"), "--quick", "--out", str(tmp_path),
        cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert "needs torch" in res.stderr and "pip install -e '.[train]'" in res.stderr
    assert "Traceback" not in res.stderr
    assert list(tmp_path.iterdir()) == [], "nothing is collected or written"


@pytest.mark.slow
def test_gymnasium_env_runs_without_torch():
    code = (
        BLOCK_TORCH
        + """
import gymnasium as gym
import numpy as np
import rodctl
from rodctl.config import load_config
cfg = load_config("configs/default.yaml", ["run.max_steps=2", "logging.mcap=false"])
env = gym.make("rodctl/ShapeServo-v0", config=cfg)
obs, _ = env.reset(seed=0)
obs, reward, *_ = env.step(np.zeros(3))
assert np.isfinite(reward)
assert "torch" not in sys.modules
print("ok")
"""
    )
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=600
    )
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr
