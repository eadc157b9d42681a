"""One journal per run folder (issue 29, Data): a run holds an OS lock on its folder, so a second
`--resume` of it is refused (exit 2, naming the holder) while the first runs; a resumed run
writes each episode's final row once (an interrupted row is superseded, not duplicated); every
reader of results.jsonl dedupes the same way (the last final row per key wins)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter

import pytest
import yaml
from batch_helpers import journal, send_self_after
from paths import REPO
from typer.testing import CliRunner

from rodctl.bench.compare import run_compare
from rodctl.bench.journal import ResultsLog
from rodctl.bench.runner import RunInterrupted
from rodctl.bench.sweep import run_sweep
from rodctl.bench.tasks import row_key
from rodctl.cli import app
from rodctl.executors import clear_stop
from rodctl.method import Method
from rodctl.runlock import LOCK_NAME


@pytest.fixture(autouse=True)
def _fresh_stop_flag():
    clear_stop()
    yield
    clear_stop()


def _tiny_compare(tmp_path):
    """Two methods of the smoke benchmark on two easy targets, in this process."""
    smoke = yaml.safe_load((REPO / "configs/compare-smoke.yaml").read_text())
    keep = ("paper-bezier", "ma2022")
    smoke["methods"] = {k: v for k, v in smoke["methods"].items() if k in keep}
    smoke["workers"] = 1
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(smoke, sort_keys=False))
    return path


def _wait_for(predicate, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError("condition not reached")
        time.sleep(0.05)


def _holder(folder) -> int | None:
    try:
        return json.loads((folder / LOCK_NAME).read_text())["pid"]
    except (OSError, ValueError, KeyError):
        return None


def _resumed(folder) -> int:
    """How many resumes meta.json records (0 while it is being replaced)."""
    try:
        return len(json.loads((folder / "meta.json").read_text()).get("resumed", []))
    except (OSError, ValueError):
        return 0


def _once_per_key(folder) -> None:
    keys = Counter(row_key(r) for r in journal(folder))
    assert keys and all(n == 1 for n in keys.values()), keys
    assert all(r["outcome"] != "interrupted" for r in journal(folder))


@pytest.mark.slow
def test_compare_resume_is_one_journal_a_second_resume_is_refused_and_rows_are_not_duplicated(
    tmp_path,
):
    config = _tiny_compare(tmp_path)
    out = tmp_path / "runs"
    out.mkdir()
    send_self_after(out, after_rows=1, sig=signal.SIGINT)
    with pytest.raises(RunInterrupted) as info:
        run_compare(str(config), [], str(out), progress=False, workers=1)
    folder = info.value.folder
    clear_stop()
    assert 1 <= len([r for r in journal(folder) if r["outcome"] != "interrupted"]) < 4

    first = subprocess.Popen(
        [sys.executable, "-m", "rodctl", "compare", str(config), "-q", "--resume", str(folder)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # It holds the lock, then records its resume in meta.json: wait for both.
        _wait_for(
            lambda: _resumed(folder) and _holder(folder) == first.pid or first.poll() is not None
        )
        assert first.poll() is None, first.communicate()
        resumed = _resumed(folder)
        second = CliRunner().invoke(app, ["compare", str(config), "-q", "--resume", str(folder)])
        assert second.exit_code == 2, second.output
        assert f"pid {first.pid}" in second.output and "in use" in second.output
        assert "started" in second.output
        meta = json.loads((folder / "meta.json").read_text())
        assert len(meta["resumed"]) == resumed == 1, "the refused one touched nothing"
        _, err = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
            first.communicate()
    assert first.returncode == 0, err
    _once_per_key(folder)
    assert len(journal(folder)) == 4
    assert json.loads((folder / "meta.json").read_text())["status"] == "completed"


@pytest.mark.slow
def test_sweep_resume_after_an_interrupt_leaves_one_row_per_key(tmp_path, monkeypatch):
    # The SIGINT is sent from inside an episode's step (the in-process worker, workers=1), once
    # the journal has a row: it always lands in a running episode. A watcher thread sending it
    # on seeing the row could land between two episodes (seen on a loaded machine).
    smoke = str(REPO / "configs/sweep-smoke.yaml")
    real_act, sent = Method.act, []

    def act(self, obs):
        if not sent:
            found = sorted(p for p in tmp_path.iterdir() if p.is_dir())
            if found and journal(found[-1]):
                sent.append(True)
                os.kill(os.getpid(), signal.SIGINT)
        return real_act(self, obs)

    monkeypatch.setattr(Method, "act", act)
    with pytest.raises(RunInterrupted) as info:
        run_sweep(smoke, ["targets.count=8"], str(tmp_path), progress=False, workers=1)
    folder = info.value.folder
    clear_stop()
    cut = [r for r in journal(folder) if r["outcome"] == "interrupted"]
    run_sweep(
        smoke, ["targets.count=8"], str(tmp_path), progress=False, workers=1, resume=str(folder)
    )
    assert cut, "the signal should have cut the running episode"
    _once_per_key(folder)
    assert len(journal(folder)) == 16  # two points on eight targets


def test_every_reader_takes_the_last_final_row_of_a_key(tmp_path):
    """A journal with duplicates (as older versions wrote them): `ResultsLog.read`, and so
    `--resume`, sees one row per key, the last final one; a key cut and never finished keeps
    its interrupted row; appending a final row for a key that has one writes nothing."""
    path = tmp_path / "results.jsonl"
    rows = [
        {"method": "a", "target": 0, "outcome": "converged", "steps": 1},
        {"method": "a", "target": 1, "outcome": "interrupted"},
        {"method": "a", "target": 0, "outcome": "stalled", "steps": 2},
        {"method": "a", "target": 1, "outcome": "converged", "steps": 3},
        {"method": "a", "target": 0, "outcome": "interrupted"},
        {"method": "b", "target": 0, "outcome": "interrupted"},
    ]
    path.write_text("".join(json.dumps(r) + "\n" for r in rows) + '{"method": "torn')
    log = ResultsLog(path)
    got = {row_key(r): r for r in log.read()}
    assert len(log.read()) == 3
    assert got[("a", 0, None, None)]["steps"] == 2
    assert got[("a", 1, None, None)]["steps"] == 3
    assert got[("b", 0, None, None)]["outcome"] == "interrupted"
    kept = log.append({"method": "a", "target": 1, "outcome": "converged", "steps": 9})
    assert kept["steps"] == 3
    assert len(path.read_text().splitlines()) == len(rows) + 1  # nothing appended
    log.append({"method": "b", "target": 1, "outcome": "converged", "steps": 4})
    assert {row_key(r): r for r in log.read()}[("b", 1, None, None)]["steps"] == 4  # not torn
