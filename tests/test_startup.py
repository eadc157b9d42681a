"""The start of `rodctl simulate` (issue #24): its helper processes forked from the entry point
(`rodctl._entry`) before the command's own imports, the command line peeked at for which ones,
and the helpers' bounded input (`rodctl.helper_process`)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
from paths import REPO

from rodctl import _entry, figure_worker, helper_process
from rodctl.helper_process import Helper, HelperFailed
from rodctl.logs import rerun_process

SMALL = ["--set", "rod.engine=quasistatic", "--set", "run.max_steps=3", "-q"]


def _wanted(*args: str) -> set[str]:
    return {module for module, _ in _entry.wanted(list(args))}


BOTH = {figure_worker.MODULE, rerun_process.MODULE}


def test_the_peek_names_the_modules_the_sinks_take():
    assert {(m, n) for _, m, n in _entry.JOBS} == {
        (figure_worker.MODULE, figure_worker.NAME),
        (rerun_process.MODULE, rerun_process.NAME),
    }


def test_the_peek_reads_the_config_files_logging_block_and_the_sets(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("run:\n  figures: false\nlogging:\n  mcap: true\n  figures: false  # off\n")
    assert _wanted(str(cfg)) == {rerun_process.MODULE}  # `run.figures` is not `logging.figures`
    assert _wanted(str(cfg), "--set", "logging.figures=yes") == BOTH
    assert _wanted("-o", str(cfg), "missing.yaml") == BOTH  # -o's value is not the config
    assert _wanted(str(cfg), "--set=logging.rerun=off") == set()
    assert _wanted("configs/default.yaml", "--set", "logging.rerun=maybe") == BOTH
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    assert _wanted(str(fifo)) == BOTH  # not opened (it would block): the loader refuses it
    flow = tmp_path / "flow.yaml"
    flow.write_text("logging: {figures: false}\n")
    assert _wanted(str(flow)) == BOTH  # not understood: both, the config then decides


@pytest.mark.parametrize(
    ("argv", "orig", "expected"),
    [
        (["/venv/bin/rodctl", "simulate", "c.yaml"], None, ["simulate", "c.yaml"]),
        (["-m", "simulate", "c"], ["python", "-m", "rodctl", "simulate"], ["simulate", "c"]),
        (["-m", "simulate"], ["python", "-m", "pytest", "simulate"], None),
        (["/usr/bin/pytest", "simulate"], None, None),
    ],
)  # fmt: skip
def test_only_the_rodctl_command_is_peeked_at(monkeypatch, argv, orig, expected):
    monkeypatch.setattr(sys, "argv", argv)
    monkeypatch.setattr(sys, "orig_argv", orig or argv, raising=False)
    assert _entry.command_args() == expected


def _without_stdin() -> None:
    os.close(0)


def test_simulate_forks_its_helpers_before_its_own_imports(tmp_path):
    """Its stdin closed, too (no `sys.stdin` in the command: the forked helpers make their own
    streams on their pipes)."""
    marks = tmp_path / "timeline.txt"
    env = {**os.environ, "RODCTL_TIMELINE": str(marks)}
    res = subprocess.run(
        [sys.executable, "-m", "rodctl", "simulate", str(REPO / "configs/default.yaml"), *SMALL,
         "-o", str(tmp_path / "runs")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
        preexec_fn=_without_stdin,  # noqa: PLW1509 - the child's fd 0 only
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    # each line: pid role event... monotonic cpu
    order = [" ".join(line.split(" ")[1:-2]) for line in marks.read_text().splitlines()]
    assert order.index(f"main started {figure_worker.MODULE}") < order.index("main cli")
    assert order.index(f"main started {rerun_process.MODULE}") < order.index("main cli")
    run = next((tmp_path / "runs").iterdir())
    assert {p.name for p in (run / "figures").iterdir()} == {"shapes.png", "t1.png", "commands.png"}
    assert (run / "run.rrd").stat().st_size > 0


def test_simulate_without_rerun_sdk_fails_before_its_first_step(tmp_path):
    fake = tmp_path / "fake" / "rerun"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('injected: no rerun here')\n")
    path = os.pathsep.join(filter(None, [str(fake.parent), os.environ.get("PYTHONPATH")]))
    res = subprocess.run(
        [sys.executable, "-m", "rodctl", "simulate", str(REPO / "configs/default.yaml"), *SMALL,
         "--set", "logging.figures=false", "-o", str(tmp_path / "runs")],
        cwd=tmp_path, env={**os.environ, "PYTHONPATH": path}, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert res.returncode == 1, res.stderr
    assert "rerun-sdk cannot be imported: injected: no rerun here" in res.stderr
    assert "Traceback" not in res.stderr


def test_a_helper_that_stops_reading_is_given_up_after_a_bounded_wait(tmp_path, monkeypatch):
    (tmp_path / "deaf_helper.py").write_text(
        "import signal\n\ndef helper_main():\n    signal.pause()  # never reads its input\n"
    )
    path = os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))
    monkeypatch.setenv("PYTHONPATH", path)
    monkeypatch.setattr(helper_process, "QUEUE_BYTES", 1 << 20)
    monkeypatch.setattr(helper_process, "QUEUE_WAIT_S", 0.2)
    with Helper.start("deaf_helper", "deaf process") as helper:
        block = b"x" * (256 << 10)
        t0 = time.monotonic()
        for _ in range(64):  # 16 MB: far beyond the pipe (64 kB) and the queue (1 MB)
            helper.send(block)
            if not helper.usable:
                break
        assert time.monotonic() - t0 < 30
        assert helper.failure is not None and "deaf process stopped reading" in helper.failure
        with pytest.raises(HelperFailed, match="stopped reading its input"):
            helper.result(timeout=5)


_INTERRUPTED_WHILE_IMPORTING = """
import os, signal, sys
sys.argv = ["rodctl", "config", "show"]  # the rodctl command, as its console script sets it
import rodctl  # installs the start-up handler
os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C before the CLI took over
print("not reached")
"""


def test_a_ctrl_c_while_rodctl_starts_is_one_line_not_a_traceback():
    res = subprocess.run(
        [sys.executable, "-c", _INTERRUPTED_WHILE_IMPORTING],
        capture_output=True, text=True, timeout=120, cwd=REPO,
    )  # fmt: skip
    assert res.returncode == 1, res.stderr
    assert res.stderr == "error: interrupted by SIGINT while rodctl was starting\n", res.stderr
    assert res.stdout == ""


def test_a_library_import_keeps_pythons_ctrl_c():
    code = (
        "import signal, rodctl; "
        "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO
    )
    assert res.stdout.strip() == "True", res.stdout + res.stderr
