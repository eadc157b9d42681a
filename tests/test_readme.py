"""The README's examples run as written (the long ones with small overrides), and so do the
Python examples of docs/python-api.md and docs/plugins.md: a documented command that fails is a
bug a new user meets first."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app

README = (REPO / "README.md").read_text(encoding="utf-8")
#: The Python examples moved from the README to these pages (issue 23): section -> page.
PAGES = {
    "## The environment, the method and the loop": "docs/python-api.md",
    "# Write a plug-in": "docs/plugins.md",
}
PLACEHOLDER = "runs/20261123-225358_default"
#: Extra arguments that keep the long examples short; the command itself is run as written.
SHORTEN = {
    "compare": ["--set", "targets.count=2", "--set", "base.run.max_steps=40", "--workers", "1"],
    "train-encoder": [
        "--set", "feature.data.samples=200", "--set", "feature.data.chunk=100",
        "--set", "feature.data.workers=1", "--set", "feature.training.epochs=2",
        "--set", "feature.training.batch_size=100",
    ],
    "simulate": ["--set", "logging.rerun=false", "--set", "logging.figures=false"],
    "sweep": ["--workers", "1"],
}  # fmt: skip


def _block_after(marker: str, lang: str, text: str = README) -> str:
    start = text.index(marker)
    m = re.compile(rf"```{lang}\n(.*?)```", re.S).search(text, start)
    assert m, f"no ```{lang} block after {marker!r}"
    return m.group(1)


def _examples() -> list[list[str]]:
    out = []
    for line in _block_after("Examples:", "bash").splitlines():
        code = line.split("  #")[0].strip()
        if code.startswith("rodctl "):
            out.append(shlex.split(code.split(">")[0])[1:])
    return out


def test_the_examples_block_lists_every_command():
    commands = {args[0] for args in _examples()}
    assert {"simulate", "replay", "compare", "train-encoder", "config", "plugins"} <= commands


@pytest.mark.slow
def test_every_command_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    runner = CliRunner()
    run_dir = None
    for args in _examples():
        args = [a.replace(PLACEHOLDER, str(run_dir)) if run_dir else a for a in args]
        if args[0] in ("simulate", "compare", "sweep", "train-encoder") and "-o" not in args:
            args += ["-o", str(tmp_path)]
        if args[0] == "replay":
            assert run_dir is not None, "a simulate example must come before replay"
            args += ["-o", str(tmp_path / "replay")]
        res = runner.invoke(app, args + SHORTEN.get(args[0], []))
        assert res.exit_code == 0, (args, res.output)
        if args[0] == "simulate" and "--json" not in args and run_dir is None:
            run_dir = res.output.strip().splitlines()[-1]


@pytest.mark.slow
@pytest.mark.parametrize("section", list(PAGES))
def test_python_examples_run(section, tmp_path):
    code = _block_after(section, "python", (REPO / PAGES[section]).read_text(encoding="utf-8"))
    if section == "# Write a plug-in":
        code += (
            "\nfrom rodctl.registry import CONTROLLERS\n"
            "assert 'gradient' in CONTROLLERS\n"
            "from rodctl.config import load_config\n"
            "cfg = load_config('configs/default.yaml', ['controller.type=gradient'])\n"
            "assert cfg.controller.gain == 1e-4\n"
        )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
