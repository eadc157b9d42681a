"""Nothing written outside `--out` (issue 29): the git query of a run leaves the user's checkout
alone, torch's compile cache and Ray's session folder do not stay behind in the temp folder."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from paths import REPO

from rodctl.runs import git_sha


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
        cwd=repo, capture_output=True, text=True, check=True, timeout=30,
    ).stdout  # fmt: skip


def test_the_dirty_check_does_not_write_the_index_of_the_users_checkout(tmp_path):
    """`git status` refreshes a stale index (taking .git/index.lock and rewriting .git/index),
    racing with the user's own git commands; the run's query must only read."""
    _git(tmp_path, "init", "-q")
    (tmp_path / "a.py").write_text("x = 1\n")
    _git(tmp_path, "add", "a.py")
    _git(tmp_path, "commit", "-q", "-m", "one")
    index = tmp_path / ".git" / "index"

    def stale() -> bytes:
        """Touch the file (same content): the index's stat data no longer matches."""
        st = (tmp_path / "a.py").stat()
        os.utime(tmp_path / "a.py", ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))
        return index.read_bytes()

    before = stale()
    _git(tmp_path, "status", "--porcelain")
    assert index.read_bytes() != before, "premise: a plain git status rewrites a stale index"

    before = stale()
    mtime = index.stat().st_mtime_ns
    sha = git_sha(tmp_path)
    assert sha is not None and not sha.endswith("-dirty")
    assert index.read_bytes() == before and index.stat().st_mtime_ns == mtime
    assert not (tmp_path / ".git" / "index.lock").exists()


@pytest.mark.slow
def test_training_leaves_nothing_in_the_temp_folder(tmp_path):
    """torch.optim imports torch._dynamo, which makes `torchinductor_<user>` in TMPDIR."""
    from rodctl.config import ExperimentConfig
    from rodctl.features.autoencoder import encoder_fingerprint
    from rodctl.training.collection import CenterlineDataset

    cfg = ExperimentConfig()
    n = cfg.camera.points
    rng = np.random.default_rng(0)
    u = np.linspace(100.0, 500.0, n)
    bend = rng.uniform(-50.0, 50.0, size=(40, 1))
    lines = np.stack([np.broadcast_to(u, (40, n)), 240.0 + bend * np.sin(u / 400.0)], axis=2)
    dataset = tmp_path / "dataset.npz"
    CenterlineDataset(centerlines=lines, poses=np.zeros((40, 3)), chunk=np.arange(40) // 10).save(
        dataset, fingerprint=encoder_fingerprint(cfg)
    )
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    res = subprocess.run(
        [sys.executable, "-m", "rodctl", "train-encoder", str(REPO / "configs/default.yaml"),
         "-q", "-o", str(tmp_path / "runs"), "--dataset", str(dataset),
         "--set", "feature.training.epochs=1", "--set", "feature.training.batch_size=40"],
        capture_output=True, text=True, timeout=300,
        env={**{k: v for k, v in os.environ.items() if k != "TORCHINDUCTOR_CACHE_DIR"},
             "TMPDIR": str(tmp)},
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in tmp.iterdir()) == []


@pytest.mark.slow
def test_a_ray_started_for_the_run_leaves_no_session_folder_in_the_temp_folder():
    pytest.importorskip("ray")
    # Short: Ray's socket paths (under its session folder) must stay below 108 bytes.
    tmp = Path(tempfile.mkdtemp(prefix="rt", dir="/tmp"))
    code = (
        "from rodctl.executors.ray import RayExecutor\n"
        "with RayExecutor(1) as ex:\n"
        "    assert [d.value for d in ex.map(abs, [-1, -2])] == [1, 2]\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_TMPDIR", "RAY_ADDRESS")}
    try:
        res = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True, text=True, timeout=300, env={**env, "TMPDIR": str(tmp)},
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        assert sorted(p.name for p in tmp.iterdir()) == []
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
