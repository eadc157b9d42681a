"""The import rules of docs/development.md, as import-linter contracts (pyproject.toml), run in
the suite so that CI (`make test`) enforces them as `make lint` does."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from paths import REPO

LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"


def _lint(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(LINT_IMPORTS), "--no-cache", "--no-logo", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_the_import_contracts_hold():
    res = _lint()
    assert res.returncode == 0, res.stdout + res.stderr
    assert "0 broken" in res.stdout


def test_a_feature_map_that_imported_training_would_break_them(tmp_path):
    """The contracts can fail: a package laid out like rodctl with features -> training."""
    pkg = tmp_path / "rodctl_probe"
    for mod, body in {
        "__init__.py": "",
        "features/__init__.py": "",
        "features/autoencoder.py": "",
        "features/auto.py": "from rodctl_probe.features import autoencoder\n",
        "features/autoencoder_config.py": "from rodctl_probe.training import auto\n",
        "training/__init__.py": "",
        "training/auto.py": "from rodctl_probe.features import autoencoder_config\n",
    }.items():
        (pkg / mod).parent.mkdir(parents=True, exist_ok=True)
        (pkg / mod).write_text(body)
    config = tmp_path / "contracts.toml"
    config.write_text(
        textwrap.dedent(
            """
            [tool.importlinter]
            root_package = "rodctl_probe"
            [[tool.importlinter.contracts]]
            name = "training above features"
            type = "layers"
            layers = ["rodctl_probe.training", "rodctl_probe.features"]
            [[tool.importlinter.contracts]]
            name = "no circles"
            type = "acyclic_siblings"
            ancestors = ["rodctl_probe"]
            """
        )
    )
    res = subprocess.run(
        [str(LINT_IMPORTS), "--no-cache", "--no-logo", "--config", str(config)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env={"PYTHONPATH": str(tmp_path), "PATH": ""},
    )
    assert res.returncode == 1, res.stdout + res.stderr
    assert "2 broken" in res.stdout
    assert "rodctl_probe.features.autoencoder_config -> rodctl_probe.training.auto" in res.stdout
