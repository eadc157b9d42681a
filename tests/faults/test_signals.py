"""Signals at several points of the long commands: the run stops at a step boundary, its files
are finalised, meta.json says `interrupted`, the exit code is 1, and the log replays."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from batch_helpers import children, cmdline
from paths import REPO

SCRIPTED = str(REPO / "configs/scripted.yaml")


def _start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "rodctl", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def _wait_for(predicate, timeout: float) -> None:
    t0 = time.monotonic()
    while not predicate():
        if time.monotonic() - t0 > timeout:
            raise TimeoutError("condition not reached")
        time.sleep(0.05)


def _run_dir(out: Path) -> Path:
    _wait_for(lambda: out.exists() and any(out.iterdir()), 60)
    return next(out.iterdir())


def _meta(run_dir: Path) -> dict:
    return json.loads((run_dir / "meta.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
@pytest.mark.parametrize("after_bytes", [1, 40_000])
def test_simulate_stops_cleanly_on_a_signal(tmp_path, sig, after_bytes):
    proc = _start(["simulate", SCRIPTED, "-q", "-o", str(tmp_path), "--set", "logging.rerun=false"])
    run_dir = _run_dir(tmp_path)
    mcap = run_dir / "run.mcap"
    _wait_for(lambda: mcap.exists() and mcap.stat().st_size >= after_bytes, 60)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 1, err
    assert "Traceback" not in err
    meta = _meta(run_dir)
    assert meta["status"] == "interrupted" and sig.name in meta["error"]
    res = subprocess.run(
        [sys.executable, "-m", "rodctl", "replay", str(run_dir), "--verify", "--no-figures"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    assert "verify: OK" in res.stderr


def _importing_worker(pid: int) -> bool:
    """Whether a spawn worker of `pid` has begun its imports (numpy's extension is mapped: the
    interpreter is up, its handlers set) and has not finished them (no stop handler yet: rodctl
    takes a second more)."""
    for p in children(pid):
        if "spawn_main" in cmdline(p):
            try:
                if "_multiarray_umath" in Path(f"/proc/{p}/maps").read_text():
                    return True
            except OSError:
                continue
    return False


def _start_at_a_terminal(args: list[str]) -> subprocess.Popen:
    """The `rodctl` console script as a user starts it: SIGINT at its default action. (A test
    runner started in the background inherits SIGINT ignored, and so would every worker, which
    hides what a Ctrl-C at a terminal does to them.)"""
    script = Path(sys.executable).with_name("rodctl")
    return subprocess.Popen(
        [str(script), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # noqa: PLW1509
    )


_STARTING_WORKERS = {
    "compare": (["compare", str(REPO / "configs/compare-smoke.yaml")], "interrupted by SIGINT"),
    "train-encoder": (
        ["train-encoder", str(REPO / "configs/default.yaml"), "--set", "feature.data.workers=2"],
        "error: interrupted",
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("command", sorted(_STARTING_WORKERS))
def test_ctrl_c_while_the_workers_start_prints_no_traceback(tmp_path, command):
    """A Ctrl-C goes to the terminal's whole process group: the spawn workers get it too, while
    they are still importing (a second or more, before their stop handler exists). They used
    to print a KeyboardInterrupt traceback each, or 'interrupted while rodctl was starting'.
    Now they start with SIGINT held (the compare workers until their handler is in place, the
    collection workers for good); the command reports the stop once."""
    args, stopped = _STARTING_WORKERS[command]
    proc = _start_at_a_terminal([*args, "-o", str(tmp_path)])
    _wait_for(lambda: _importing_worker(proc.pid) or proc.poll() is not None, 120)
    assert proc.poll() is None, proc.communicate()
    os.killpg(proc.pid, signal.SIGINT)  # a worker is importing: numpy is in, rodctl not yet
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert "while rodctl was starting" not in err, err
    assert err.count(stopped) == 1, err


def _live_processes(session: int) -> list[str]:
    """The processes of a session still running (a killed child that init has not reaped yet,
    a zombie, is not running)."""
    ps = subprocess.run(["ps", "-s", str(session), "-o", "pid=,stat=,args="],
                        capture_output=True, text=True)  # fmt: skip
    return [line for line in ps.stdout.splitlines() if line.split()[1][0] != "Z"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("sig", "to_group"),
    [(signal.SIGTERM, False), (signal.SIGINT, True)],
    ids=["SIGTERM to the command", "SIGINT to its process group (Ctrl-C)"],
)
def test_simulate_stopped_by_a_signal_keeps_its_figures_and_leaves_no_process(
    tmp_path, sig, to_group
):
    """The figures are drawn by a helper process: a stopped run still gets them (as when they
    were drawn in-process), a Ctrl-C at the terminal does not kill the helper, and nothing of
    the command is left when it returns."""
    proc = _start(["simulate", SCRIPTED, "-q", "-o", str(tmp_path), "--set", "logging.rerun=false"])
    run_dir = _run_dir(tmp_path)
    mcap = run_dir / "run.mcap"
    _wait_for(lambda: mcap.exists() and mcap.stat().st_size >= 40_000, 60)
    (os.killpg if to_group else os.kill)(proc.pid, sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    assert _live_processes(proc.pid) == []
    meta = _meta(run_dir)
    assert meta["status"] == "interrupted" and meta["error"] == f"interrupted by {sig.name}"
    assert {p.name for p in (run_dir / "figures").iterdir()} == {
        "shapes.png", "t1.png", "commands.png"
    }  # fmt: skip


@pytest.mark.slow
def test_simulate_stopped_by_a_signal_finishes_its_rerun_recording(tmp_path):
    """run.rrd is written by a helper process too: a Ctrl-C at the terminal (to the group)
    reaches only the command, which has the helper end the recording with the run's status;
    nothing is left when it returns."""
    from rerun.chunk import RrdReader

    proc = _start(["simulate", SCRIPTED, "-q", "-o", str(tmp_path)])
    run_dir = _run_dir(tmp_path)
    mcap = run_dir / "run.mcap"
    _wait_for(lambda: mcap.exists() and mcap.stat().st_size >= 40_000, 60)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    assert _live_processes(proc.pid) == []
    assert _meta(run_dir)["status"] == "interrupted"
    lines = [
        text
        for chunk in RrdReader(run_dir / "run.rrd").stream()
        if chunk.entity_path == "/log"
        for text in chunk.to_record_batch().column("TextLog:text").to_pylist()
    ]
    assert lines[0][0].startswith("run started: method ")
    assert any(line[0].startswith("run interrupted") for line in lines), lines[-3:]


@pytest.mark.slow
def test_a_killed_simulate_leaves_no_figure_process(tmp_path):
    """SIGKILL to the command alone: its figure process, which nothing told, ends too."""
    proc = _start(["simulate", SCRIPTED, "-q", "-o", str(tmp_path), "--set", "logging.rerun=false"])
    run_dir = _run_dir(tmp_path)
    mcap = run_dir / "run.mcap"
    _wait_for(lambda: mcap.exists() and mcap.stat().st_size >= 40_000, 60)
    assert len(_live_processes(proc.pid)) >= 2, "the command and its figure process"
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    _wait_for(lambda: _live_processes(proc.pid) == [], 10)


@pytest.mark.slow
def test_sigkill_then_replay_recover_reads_the_whole_steps(tmp_path):
    proc = _start(["simulate", SCRIPTED, "-q", "-o", str(tmp_path), "--set", "logging.rerun=false",
                   "--set", "logging.flush_every_steps=2"])  # fmt: skip
    run_dir = _run_dir(tmp_path)
    mcap = run_dir / "run.mcap"
    _wait_for(lambda: mcap.exists() and mcap.stat().st_size > 60_000, 60)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    assert _meta(run_dir)["status"] == "running"  # nothing could record the kill
    plain = subprocess.run(
        [sys.executable, "-m", "rodctl", "replay", str(run_dir), "--no-figures"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert plain.returncode == 2 and "--recover" in plain.stderr
    res = subprocess.run(
        [sys.executable, "-m", "rodctl", "replay", str(run_dir), "--recover", "--no-figures"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    assert "recovered" in res.stderr


@pytest.mark.slow
def test_train_encoder_records_sigterm_as_interrupted_and_keeps_the_data(tmp_path):
    """SIGTERM while collecting: `interrupted`, exit 1, no worker left, and the chunks collected
    so far saved as the run's dataset.npz, which `--dataset` trains on."""
    import re
    import threading

    proc = _start(
        ["train-encoder", str(REPO / "configs/default.yaml"), "-o", str(tmp_path),
         "--set", "feature.data.samples=20000", "--set", "feature.data.chunk=40",
         "--set", "feature.data.workers=2", "--set", "feature.training.epochs=2",
         "--set", "feature.training.batch_size=100"]
    )  # fmt: skip
    run_dir = _run_dir(tmp_path)
    # Off a terminal the collection prints "collecting: 120/20,000 samples (…)" every few
    # seconds: wait until two chunks of 40 are done (a condition, not a guess of the time).
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()

    def collected() -> int:
        found = [re.search(r"collecting: ([\d,]+)/", line) for line in list(lines)]
        return max((int(m.group(1).replace(",", "")) for m in found if m), default=0)

    _wait_for(lambda: collected() >= 80 or proc.poll() is not None, 600)
    assert proc.poll() is None, "".join(lines)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=60)
    reader.join(timeout=60)
    err = "".join(lines)
    assert proc.returncode == 1, err
    assert "Traceback" not in err
    meta = _meta(run_dir)
    assert meta["status"] == "interrupted"

    # No worker process of the command is left behind (the multiprocessing resource tracker
    # notices its parent is gone within a moment).
    def gone() -> bool:
        left = subprocess.run(["pgrep", "-s", str(proc.pid)], capture_output=True, text=True)
        return left.stdout.strip() == ""

    _wait_for(gone, 10)
    dataset = run_dir / "dataset.npz"
    assert dataset.is_file(), "the chunks collected before the signal are kept"
    res = subprocess.run(
        [sys.executable, "-m", "rodctl", "train-encoder", str(REPO / "configs/default.yaml"),
         "-q", "-o", str(tmp_path / "again"), "--dataset", str(dataset),
         "--set", "feature.training.epochs=2", "--set", "feature.training.batch_size=100"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
