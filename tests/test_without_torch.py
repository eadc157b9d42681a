"""rodctl without torch (the extra `train` not installed): runs, replays and the Gymnasium env
work; what needs torch says how to install it (exit 2).

torch is installed in the test set-up, so each check runs in a subprocess where an import hook
makes `import torch` fail as it does when torch is absent.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from paths import REPO

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


def test_simulate_and_replay_verify_run_without_torch(tmp_path):
    # The default feature: the packaged autoencoder, encoded in numpy.
    sim = _rodctl(
        "simulate", str(REPO / "configs/default.yaml"), "--out", str(tmp_path), "-q",
        "--set", "run.max_steps=3", "--set", "logging.rerun=false",
        "--set", "logging.figures=false",
        cwd=tmp_path,
    )  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    run_dir = sim.stdout.strip().splitlines()[-1]
    assert (Path(run_dir) / "run.mcap").is_file()
    rep = _rodctl("replay", run_dir, "--verify", "--no-figures", cwd=tmp_path)
    assert rep.returncode == 0, rep.stderr
    assert "verify: OK" in rep.stderr


def test_train_encoder_without_torch_says_how_to_install_it(tmp_path):
    res = _rodctl(
        "train-encoder", str(REPO / "configs/default.yaml"), "--quick", "--out", str(tmp_path),
        cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert "needs torch" in res.stderr and "pip install -e '.[train]'" in res.stderr
    assert "Traceback" not in res.stderr
    assert list(tmp_path.iterdir()) == [], "nothing is collected or written"


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
