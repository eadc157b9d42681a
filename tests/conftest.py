"""Shared test setup: headless plotting, Rerun strict mode, a `repo` fixture."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from paths import REPO

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("RERUN_STRICT", "1")


@pytest.fixture
def repo() -> Path:
    return REPO
