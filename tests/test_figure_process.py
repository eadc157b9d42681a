"""The figures of `simulate` and `replay`, drawn by a helper process (`rodctl.figure_worker`).

What must hold whatever draws them: the figures exist when the command returns and are the ones
the records give; a drawing that fails, is killed or hangs costs the figures only (the run is
marked failed with the reason, like a figure that could not be written, and every log is kept);
and no helper is left behind.

Failures are injected into the helper alone: a fake `matplotlib` package first on PYTHONPATH,
which only the helper imports (the command itself never imports matplotlib), fails, kills
itself or hangs.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl import figure_worker, plots
from rodctl.cli import app
from rodctl.config import load_config
from rodctl.replay import read_run
from rodctl.simulate import simulate

runner = CliRunner()
FAST = ["feature.type=bezier", "run.max_steps=40", "logging.rerun=false"]
FIGURES = {"shapes.png", "t1.png", "commands.png"}

#: Bodies of the fake matplotlib/__init__.py; each first writes its pid to PID_FILE.
FAKES = {
    "fails": "raise RuntimeError('injected figure failure')\n",
    "is killed": "import signal\nos.kill(os.getpid(), signal.SIGKILL)\n",
    "hangs": "import time\ntime.sleep(3600)\n",
}
PID_FILE = "helper.pid"


@pytest.fixture
def broken_helper(tmp_path, monkeypatch):
    """broken_helper(kind): the next figure process meets `FAKES[kind]`; returns the pid file."""

    def install(kind: str) -> Path:
        fake = tmp_path / "fake" / "matplotlib"
        fake.mkdir(parents=True)
        pid_file = tmp_path / PID_FILE
        (fake / "__init__.py").write_text(
            f"import os\nopen({str(pid_file)!r}, 'w').write(str(os.getpid()))\n" + FAKES[kind]
        )
        path = os.pathsep.join(filter(None, [str(fake.parent), os.environ.get("PYTHONPATH")]))
        monkeypatch.setenv("PYTHONPATH", path)
        return pid_file

    return install


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def _run(tmp_path: Path, *sets: str):
    cfg = load_config(REPO / "configs/default.yaml", [*FAST, *sets])
    return simulate(cfg, tmp_path / "runs")


@pytest.mark.slow
def test_figures_exist_when_simulate_returns_and_match_the_records(tmp_path):
    res = _run(tmp_path)
    assert res.exit_code == 0 and res.error is None
    folder = res.run.path / "figures"
    assert {p.name for p in folder.iterdir()} == FIGURES
    # The same bytes as drawing in this process from the records the log holds.
    run = read_run(res.run.path)
    for name, data in plots.render_figures(run.header, run.records).items():
        assert (folder / name).read_bytes() == data, name


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "reason"),
    [
        ("fails", "the figure process failed: RuntimeError: injected figure failure"),
        ("is killed", "the figure process was killed by SIGKILL"),
        ("hangs", "the figure process did not finish within 3 s"),
    ],
)
def test_a_figure_process_that_fails_costs_the_figures_only(
    tmp_path, monkeypatch, broken_helper, kind, reason
):
    pid_file = broken_helper(kind)
    monkeypatch.setattr(figure_worker, "TIMEOUT_S", 3.0)
    res = _run(tmp_path)
    run_dir = res.run.path
    message = f"figures not written: {reason}"
    assert res.exit_code == 1 and res.error == message
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["status"] == "failed" and meta["error"] == message
    assert meta["outcome"] == "converged"  # the run itself was fine
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "completed"
    assert read_run(run_dir).complete
    assert not (run_dir / "figures").exists()
    assert _gone(int(pid_file.read_text())), "the figure process outlived the command"


@pytest.mark.slow
def test_a_figure_process_that_cannot_start_costs_the_figures_only(tmp_path, monkeypatch):
    missing = tmp_path / "no-python"
    monkeypatch.setattr("sys.executable", str(missing))
    res = _run(tmp_path)
    message = (
        "figures not written: could not start the figure process: "
        f"No such file or directory: {missing}"
    )
    assert res.exit_code == 1 and res.error == message
    meta = json.loads((res.run.path / "meta.json").read_text())
    assert meta["status"] == "failed" and meta["error"] == message
    assert read_run(res.run.path).complete


@pytest.mark.slow
def test_no_figure_process_when_figures_are_off(tmp_path, broken_helper):
    pid_file = broken_helper("fails")
    res = _run(tmp_path, "logging.figures=false")
    assert res.exit_code == 0 and res.error is None
    assert not (res.run.path / "figures").exists()
    assert not pid_file.exists(), "a figure process was started"


@pytest.mark.slow
def test_a_figures_folder_that_cannot_be_made_fails_the_run_with_the_reason(tmp_path):
    """A write error is the command's own, as when it drew in-process: here `figures` is a
    file (made during the run), so the folder cannot be created."""
    out = tmp_path / "runs"

    def block_figures(_rec) -> None:
        (run_dir,) = out.iterdir()
        (run_dir / "figures").touch()

    cfg = load_config(REPO / "configs/default.yaml", FAST)
    res = simulate(cfg, out, on_step=block_figures)
    message = f"File exists: {res.run.path / 'figures'}"
    assert res.exit_code == 1 and res.error == message
    meta = json.loads((res.run.path / "meta.json").read_text())
    assert meta["status"] == "failed" and meta["error"] == message


@pytest.mark.slow
def test_replay_reports_a_failed_figure_process_and_keeps_run_rrd(tmp_path, broken_helper):
    res = _run(tmp_path)
    broken_helper("fails")
    out = tmp_path / "replayed"
    result = runner.invoke(app, ["replay", str(res.run.path), "--out", str(out)])
    assert result.exit_code == 1, result.output
    assert (
        "error: figures not written: the figure process failed: RuntimeError: injected "
        "figure failure" in result.output
    )
    assert "Traceback" not in result.output
    assert (out / "run.rrd").is_file() and not (out / "figures").exists()


@pytest.mark.slow
def test_replay_draws_the_same_figures(tmp_path):
    res = _run(tmp_path)
    out = tmp_path / "replayed"
    result = runner.invoke(app, ["replay", str(res.run.path), "--out", str(out)])
    assert result.exit_code == 0, result.output
    for name in FIGURES:
        assert (out / "figures" / name).read_bytes() == (
            res.run.path / "figures" / name
        ).read_bytes()


@pytest.mark.slow
def test_the_summary_is_shown_before_the_figures_are_waited_for(tmp_path):
    """`on_summary` (the CLI's table) comes as soon as summary.json is written; a display that
    fails (a closed pipe) is raised only once meta.json is final."""
    out = tmp_path / "runs"
    seen = []

    def show(summary) -> None:
        (run_dir,) = out.iterdir()
        seen.append((summary.status, (run_dir / "summary.json").exists()))
        seen.append((run_dir / "figures").exists())
        raise BrokenPipeError("stderr closed")

    cfg = load_config(REPO / "configs/default.yaml", FAST)
    with pytest.raises(BrokenPipeError):
        simulate(cfg, out, on_summary=show)
    assert seen == [("completed", True), False]
    (run_dir,) = out.iterdir()
    assert json.loads((run_dir / "meta.json").read_text())["status"] == "completed"
    assert {p.name for p in (run_dir / "figures").iterdir()} == FIGURES


class _ChildFails:
    """RunFigures whose `FORKED` figure raises in any process but this one (a forked child)."""

    def __init__(self) -> None:
        self.figures = plots.RunFigures()
        self.pid = os.getpid()

    def render_one(self, name, header, records):
        if name == figure_worker.FORKED and os.getpid() != self.pid:
            raise RuntimeError("injected failure in the forked child")
        return self.figures.render_one(name, header, records)


def test_figures_drawn_on_two_cores_are_the_bytes_of_one_and_a_failed_child_costs_time_only(
    monkeypatch,
):
    """The figure process draws `FORKED` in a forked child where it has two cores: the same
    bytes as drawing all three in one process, in the same order; a child that fails has its
    figure drawn by the figure process instead; on one core nothing is forked."""
    from rodctl.logs.synthetic import SyntheticRun  # noqa: PLC0415

    run = SyntheticRun(seed=3, image_every=0)
    header, records = run.header, run.records(12)
    expected = plots.render_figures(header, records)
    monkeypatch.setattr(figure_worker, "_cores", lambda: 2)
    got = figure_worker._render(plots.RunFigures(), header, records)
    assert list(got) == list(expected) and got == expected
    assert figure_worker._render(_ChildFails(), header, records) == expected

    monkeypatch.setattr(figure_worker, "_cores", lambda: 1)
    monkeypatch.setattr(figure_worker, "_fork_figure", None)  # called: a TypeError
    assert figure_worker._render(plots.RunFigures(), header, records) == expected
