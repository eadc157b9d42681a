"""Fixtures of the fault-injection suite: small filesystems that fill up or are read-only.

Real tmpfs mounts need root (CI and the development machines run as root); where mounting is
not allowed the tests that need one are skipped with the reason, and the injected-error tests
still cover the same promises.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest


def _mount(target: Path, options: str) -> bool:
    target.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)],
        capture_output=True,
        text=True,
        timeout=10,
    )
    return proc.returncode == 0


def _umount(target: Path) -> None:
    subprocess.run(["umount", "-l", str(target)], capture_output=True, timeout=10)


@pytest.fixture
def small_disk(tmp_path) -> Iterator[callable]:
    """A factory: small_disk(size) mounts a tmpfs of that size and returns its path."""
    mounted: list[Path] = []

    def make(size: str, name: str = "disk", *, read_only: bool = False) -> Path:
        target = tmp_path / name
        opts = f"size={size}" + (",ro" if read_only else "")
        if not _mount(target, opts):
            pytest.skip("cannot mount a tmpfs here (needs root)")
        mounted.append(target)
        return target

    yield make
    for target in mounted:
        _umount(target)
