"""Shared test setup: headless plotting, Rerun strict mode, a `repo` fixture."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from paths import REPO

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("RERUN_STRICT", "1")
# Before anything imports Ray: Ray reads this when it is imported, and without it a one-node
# Ray advertises the machine's network address (found by routing towards a public address)
# instead of the loopback one once the machine has a default route.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")


@pytest.fixture
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def compare_smoke_run(tmp_path_factory) -> Path:
    """configs/compare-smoke.yaml run once per session on the local pool (2 spawned workers),
    as a user types it; shared by the compare and executor tests (it takes ~30 s)."""
    from typer.testing import CliRunner

    from rodctl.cli import app

    out = tmp_path_factory.mktemp("compare")
    smoke = REPO / "configs" / "compare-smoke.yaml"
    result = CliRunner().invoke(app, ["compare", str(smoke), "--out", str(out), "-q"])
    assert result.exit_code == 0, result.output
    folder = Path(result.stdout.strip().splitlines()[-1])  # the output folder is the last line
    assert folder.parent == out
    return folder
