"""Failures say what happened: a diverged run names the quantity and the step, every write error
is one line with the path, and the exit code follows one rule (2: what the user gave cannot be
used, nothing is created; 1: the run could not go on or failed, what it wrote is kept)."""

from __future__ import annotations

import json
from pathlib import Path

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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_run_that_loses_the_rod_says_so_in_the_terminal_meta_and_error_txt(tmp_path):
    """Found by a new-user trial: a lost_tracking run exited 1 with no `error:` line, no
    `error` in meta.json and no error.txt, which the failure table promises."""
    blind = "run.events=[{at_step: 6, type: occluder, action: add, box: [0, 0, 640, 480]}]"
    res = _run("simulate", SCRIPTED, "-q", "-o", tmp_path, "--set", blind, *QUICK)
    assert res.exit_code == 1, res.output
    said = "lost the rod at step 8: the extractor found no rod in 3 frames in a row"
    assert f"error: {said}" in res.output
    (run_dir,) = tmp_path.iterdir()
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "failed" and meta["outcome"] == "lost_tracking"
    assert said in meta["error"]
    assert said in (run_dir / "error.txt").read_text()


# --------------------------------------------------------------------------- exit codes
def _simulate_out(out):
    return _run("simulate", SCRIPTED, "-q", "-o", out, "--set", "run.max_steps=5", *QUICK)


def test_a_disk_without_inodes_or_read_only_is_exit_1_and_a_wrong_path_exit_2(tmp_path, small_disk):
    """The rule: 2 = what the user gave cannot be used; 1 = the system refused (full disk, no
    inodes, read-only, permissions) or the run failed. One line with the path either way."""
    full = small_disk("1m,nr_inodes=2", "noinodes")  # the root takes one inode
    ro = small_disk("1m", "ro", read_only=True)
    for out, says in ((full, "No space left on device"), (ro, "Read-only file system"),
                      (ro / "sub", "Read-only file system")):  # fmt: skip
        res = _simulate_out(out)
        assert res.exit_code == 1, res.output
        lines = res.output.strip().splitlines()
        assert len(lines) == 1 and says in lines[0] and str(out) in lines[0], res.output
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    res = _simulate_out(a_file)
    assert res.exit_code == 2 and str(a_file) in res.output, res.output


@pytest.mark.slow
def test_replay_on_a_read_only_disk_is_one_line_with_the_path(small_disk):
    """A run folder on a read-only disk (an archive), replayed plainly, without figures, with
    --verify, or with -o into an existing read-only folder."""
    import subprocess

    disk = small_disk("8m", "archive")
    res = _simulate_out(disk)
    assert res.exit_code == 0, res.output
    run_dir = Path(res.output.strip().splitlines()[-1])
    (disk / "empty").mkdir()
    subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True, timeout=10)
    for extra in ([], ["--no-figures"], ["--verify", "--no-figures"],
                  ["-o", str(disk / "empty"), "--no-figures"]):  # fmt: skip
        res = _run("replay", run_dir, *extra)
        assert res.exit_code == 1, (extra, res.output)
        assert res.output.count("error:") == 1 and "Failed to create file" not in res.output
        folder = disk / "empty" if "-o" in extra else run_dir
        assert f"error: Read-only file system: {folder}/run.rrd" in res.output, res.output


def test_a_compare_whose_disk_fills_records_why_in_meta_json(tmp_path, monkeypatch):
    import errno

    import rodctl.bench.compare as compare_module

    def full(*args, **kwargs):  # what PIL and file objects raise: no file name
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(compare_module, "write_targets", full)
    cfg = tmp_path / "one.yaml"
    cfg.write_text(
        "name: one\nbase: {run: {max_steps: 5}, logging: {mcap: false, rerun: false, figures: "
        "false}}\nmethods: {pinv: {feature: {type: nodes, positions: [0.5, 1.0]}, estimator: "
        "{type: broyden}, controller: {type: pinv}}}\ntargets: {count: 1, max_offset: 0.2}\n"
        "workers: 1\n"
    )
    res = _run("compare", cfg, "-q", "-o", tmp_path / "runs")
    assert res.exit_code == 1, res.output
    (run_dir,) = (tmp_path / "runs").iterdir()
    said = f"No space left on device: while writing in {run_dir}"
    assert res.output.strip() == f"error: {said}"
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "failed" and meta["error"] == said


@pytest.mark.slow
def test_bad_input_found_after_the_run_folder_was_made_leaves_nothing(tmp_path):
    not_npz = tmp_path / "data.npz"
    not_npz.write_text("centerlines, but as text\n")
    res = _run("train-encoder", DEFAULT, "-q", "-o", tmp_path / "a", "--dataset", not_npz)
    assert res.exit_code == 2 and "not a NumPy .npz archive" in res.output, res.output
    res = _run("simulate", SCRIPTED, "-q", "-o", tmp_path / "b", *QUICK,
               "--set", "run.target.pose=[5.0, 0.0, 0.0]")  # fmt: skip
    assert res.exit_code == 2 and "run.target.pose" in res.output, res.output
    for out in (tmp_path / "a", tmp_path / "b"):
        assert not out.exists() or not any(out.iterdir()), list(out.iterdir())


# --------------------------------------------------------------------------- every --out, one rule
@pytest.fixture(scope="module")
def a_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    res = _simulate_out(out)
    assert res.exit_code == 0, res.output
    return Path(res.output.strip().splitlines()[-1])


def _write_somewhere(run: Path, out: str, tmp: Path) -> list[tuple[str, object]]:
    """Every command that writes a folder, told to write it at `out`."""
    from rodctl.recordings.points import write_points_csv
    from rodctl.recordings.synthetic import dual_arm_recording

    points = write_points_csv(dual_arm_recording(5, seed=1, points=4), tmp / "points.csv")
    return [
        ("simulate", _simulate_out(out)),
        ("replay", _run("replay", run, "-q", "--no-figures", "-o", out)),
        ("estimate", _run("estimate", run, "--init", "3", "--no-plots", "--out", out)),
        ("import", _run("import", points, "--out", out)),
        ("export", _run("export", run, "--ros2", out)),
    ]


@pytest.mark.parametrize(
    "where, says",
    [
        ("file", "a-file is a file, not a folder"),  # a file in the way
        ("under-file", "a-file is a file, not a folder"),
        ("", "empty; give a folder's path"),  # Path("") would silently be the current folder
        ("too-long", "File name too long"),  # an OSError of the check itself (Python 3.11)
    ],
)
def test_every_command_refuses_an_unusable_output_path_alike(a_run, tmp_path, where, says):
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    out = {
        "file": str(a_file),
        "under-file": str(a_file / "sub"),
        "": "",
        "too-long": str(tmp_path / ("x" * 300) / "sub"),
    }[where]
    for command, res in _write_somewhere(a_run, out, tmp_path):
        assert res.exit_code == 2, (command, res.output)
        lines = res.output.strip().splitlines()
        option = "--ros2" if command == "export" else "--out"
        assert len(lines) == 1 and lines[0].startswith("error: --"), (command, res.output)
        assert says in lines[0] and f"{option} {out}".strip() in lines[0], (command, res.output)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file", "points.csv"]
