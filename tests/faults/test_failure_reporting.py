"""Failures say what happened: a diverged run names the quantity and the step, every write error
is one line with the path, and the exit code follows one rule (2: what the user gave cannot be
used, nothing is created; 1: the run could not go on or failed, what it wrote is kept)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from paths import REPO
from typer.testing import CliRunner

import rodctl.env as env_module
import rodctl.method as method_module
from rodctl.cli import app

SCRIPTED = str(REPO / "configs/scripted.yaml")
DEFAULT = str(REPO / "configs/default.yaml")
QUICK = ["--set", "logging.figures=false", "--set", "logging.rerun=false"]


def _run(*args: str):
    res = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    return res


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_non_finite_command_ends_the_run_diverged_saying_what_and_when(
    tmp_path, monkeypatch, bad
):
    real = method_module.Method.act
    calls = {"n": 0}

    def act(self, obs):
        u = real(self, obs)
        calls["n"] += 1
        return np.array([bad, 0.0, 0.0]) if calls["n"] == 4 else u

    monkeypatch.setattr(method_module.Method, "act", act)
    res = _run("simulate", SCRIPTED, "-q", "-o", tmp_path, *QUICK)
    assert res.exit_code == 1, res.output
    said = f"diverged at step 4: the controller's command u = [{bad}, 0, 0] is not finite"
    assert said in res.output
    (run_dir,) = tmp_path.iterdir()
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "failed" and meta["outcome"] == "diverged"
    assert said in meta["error"]
    assert said in (run_dir / "error.txt").read_text()


def test_a_simulation_that_breaks_down_says_so_with_the_step(tmp_path, monkeypatch):
    real = env_module.ShapeServoEnv.step

    def step(self, action):
        out = real(self, action)
        if self.steps == 3:
            out[4]["diverged"] = True
        return out

    monkeypatch.setattr(env_module.ShapeServoEnv, "step", step)
    res = _run("simulate", SCRIPTED, "-q", "-o", tmp_path, *QUICK)
    assert res.exit_code == 1, res.output
    assert "diverged at step 3: the rod simulation broke down" in res.output
    (run_dir,) = tmp_path.iterdir()
    meta = json.loads((run_dir / "meta.json").read_text())
    assert "diverged at step 3" in meta["error"]
    assert "rod.gap_limit" in (run_dir / "error.txt").read_text()
