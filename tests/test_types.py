"""`mypy rodctl` with the pydantic plugin ([tool.mypy] in pyproject.toml) reports nothing: the
package ships `py.typed`, so its annotations are part of its interface. Run in the suite so that
CI (`make test`) checks it as `make lint` does."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from paths import REPO


def _mypy(*args: str, cwd=REPO, timeout: float = 900) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mypy", "--no-error-summary", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.slow
def test_mypy_finds_no_error_in_rodctl(tmp_path):
    # The cache lives in the test's folder: a fresh clone's cold run, never a stale cache.
    res = _mypy("--cache-dir", str(tmp_path / "mypy-cache"))
    assert res.returncode == 0, res.stdout + res.stderr


def test_the_configuration_catches_a_type_error(tmp_path):
    """The check can fail: the same settings on a module that passes None where a str goes."""
    (tmp_path / "probe.py").write_text(
        textwrap.dedent(
            """
            def shout(text: str) -> str:
                return text.upper()

            shout(None)
            """
        )
    )
    res = _mypy(
        "--config-file",
        str(REPO / "pyproject.toml"),
        "--cache-dir",
        str(tmp_path / "mypy-cache"),
        str(tmp_path / "probe.py"),
        cwd=tmp_path,
        timeout=300,
    )
    assert res.returncode == 1, res.stdout + res.stderr
    assert 'Argument 1 to "shout" has incompatible type "None"' in res.stdout
