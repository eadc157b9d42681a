"""Executors: the local pool and Ray run the same episodes to the same results, retry a lost
worker a bounded number of times, and stop within seconds on a signal to any process.

The Ray tests start one local Ray for the module (2 CPUs, every service on 127.0.0.1, no
dashboard) and shut it down at the end with a timeout.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import pytest
from batch_helpers import alive, interrupt, journal, rows
from paths import REPO

from rodctl.bench import compare as compare_module
from rodctl.bench import journal as journal_module
from rodctl.bench import sweep as sweep_module
from rodctl.bench.compare import run_compare
from rodctl.bench.sweep import run_sweep
from rodctl.errors import UserError
from rodctl.executors import Done, clear_stop, make_executor, request_stop, stop_reason
from rodctl.executors.local import CANCELLED, LocalExecutor

SMOKE = REPO / "configs" / "compare-smoke.yaml"
SWEEP_SMOKE = REPO / "configs" / "sweep-smoke.yaml"


@pytest.fixture(autouse=True)
def _fresh_stop_flag():
    clear_stop()
    yield
    clear_stop()


# --- task functions (module level: the pool pickles them by reference, Ray by value) ---------


def square(task):
    return task * task


def fail(task):
    raise ValueError(f"bad task {task}")


def crash_once(task):
    """Kill this worker process the first time (a lost worker), succeed when run again."""
    marker = Path(task["marker"])
    if not marker.exists():
        marker.write_text("crashed")
        os._exit(1)
    return "ok"


def crash_always(_task):
    os._exit(1)


def wait_for_stop(task):
    """Sleep in short steps until the stop flag is set (an episode polls it between steps)."""
    Path(task["dir"], f"started-{os.getpid()}").touch()
    end = time.monotonic() + task["seconds"]
    while time.monotonic() < end:
        if stop_reason() is not None:
            return {"pid": os.getpid(), "stopped": stop_reason()}
        time.sleep(0.05)
    return {"pid": os.getpid(), "stopped": None}


# --- local ------------------------------------------------------------------------------------


def test_in_process_runs_in_task_order_and_stops_between_tasks():
    with LocalExecutor(1) as ex:
        assert [d.value for d in ex.map(square, [1, 2, 3])] == [1, 4, 9]

    def stop_after_two(task):
        if task == 2:
            request_stop("test")
        return task

    with LocalExecutor(1) as ex:
        done = ex.map(stop_after_two, [1, 2, 3, 4])
    assert [d.value for d in done[:2]] == [1, 2]
    assert all(d.error in (CANCELLED, "not run") for d in done[2:])


@pytest.mark.slow
def test_a_stop_after_the_last_episode_leaves_the_run_completed_and_the_stop_standing(
    tmp_path, monkeypatch
):
    """A Ctrl-C in the moment between a study's last episode and the end of its episode phase:
    nothing was left to stop, so the run is completed (its report whole, not marked partial);
    the stop still stands, so a suite running this study stops before its next scenario."""
    append = journal_module.ResultsLog.append
    count = []

    def append_then_stop_at_the_last(self, row):
        count.append(row)
        if len(count) == 12:  # compare-smoke: 2 targets x 6 methods
            request_stop("SIGINT")
        return append(self, row)

    monkeypatch.setattr(journal_module.ResultsLog, "append", append_then_stop_at_the_last)
    folder = run_compare(str(SMOKE), [], str(tmp_path), progress=False, workers=1)
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["status"] == "completed", meta
    assert meta["episodes"] == {"finished": 12, "total": 12}
    assert "PARTIAL" not in (folder / "summary.md").read_text()
    assert stop_reason() == "SIGINT"


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["compare", "sweep"])
def test_a_signal_during_the_report_lets_it_finish_and_the_run_is_completed(
    tmp_path, monkeypatch, kind
):
    """Found by a new-user trial: a Ctrl-C while the report was being written (every episode
    done) cut it short and said 'interrupted: 36 of 36 episodes finished; partial results
    kept'; docs/reliability.md promises such a run stays completed."""
    module = compare_module if kind == "compare" else sweep_module
    real = module.write_results_csv

    def write_then_signal(*args):
        os.kill(os.getpid(), signal.SIGINT)  # as a Ctrl-C at the terminal, mid-report
        return real(*args)

    monkeypatch.setattr(module, "write_results_csv", write_then_signal)
    if kind == "compare":
        folder = run_compare(str(SMOKE), [], str(tmp_path), progress=False, workers=1)
    else:
        folder = run_sweep(str(SWEEP_SMOKE), [], str(tmp_path), progress=False, workers=1)
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["status"] == "completed", meta
    assert (folder / "results.csv").is_file() and (folder / "summary.md").is_file()
    assert "PARTIAL" not in (folder / "summary.md").read_text()
    assert stop_reason() == "SIGINT"  # still standing: a suite stops before its next scenario


@pytest.mark.slow
def test_pool_retries_a_lost_worker_and_passes_task_exceptions_on(tmp_path):
    with LocalExecutor(2) as ex:
        done = ex.map(crash_once, [{"marker": str(tmp_path / "m")}])
        assert done[0].value == "ok" and done[0].attempts == 2
        with pytest.raises(ValueError, match="bad task 7"):
            ex.map(fail, [7])


@pytest.mark.slow
def test_a_signal_to_one_pool_worker_stops_the_whole_run_and_no_process_is_left(tmp_path):
    ex = LocalExecutor(2)
    ex.start()

    def signal_a_worker_once_both_run():
        while len(list(tmp_path.glob("started-*"))) < 2:
            time.sleep(0.05)
        pid = int(sorted(tmp_path.glob("started-*"))[0].name.split("-")[1])
        os.kill(pid, signal.SIGTERM)

    try:
        for i in range(4):
            ex.submit(wait_for_stop, {"seconds": 60, "dir": str(tmp_path)}, i)
        threading.Thread(target=signal_a_worker_once_both_run, daemon=True).start()
        t0 = time.monotonic()
        done = list(ex.results())
        took = time.monotonic() - t0
        procs = ex._procs
    finally:
        ex.shutdown(10)
    assert stop_reason() is not None  # the parent learnt of it
    stopped = [d.value for d in done if d.value is not None]
    assert stopped and all(v["stopped"] == "SIGTERM" for v in stopped)
    assert len({v["pid"] for v in stopped}) == 2  # the other worker was stopped too
    assert took < 45, took  # before the tasks' own end (60 s; spawning takes a while)
    assert not any(alive(p.pid) for p in procs)


def test_unknown_executor_and_address_without_ray_are_user_errors():
    with pytest.raises(UserError, match="--executor 'dask'"):
        make_executor("dask", 1)
    with pytest.raises(UserError, match="--address needs --executor ray"):
        make_executor("local", 1, "127.0.0.1:6379")


def test_missing_ray_is_a_user_error_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(UserError, match=r"rodctl\[ray\]"):
        make_executor("ray", 1)  # when the command line is read, before any run folder


# --- Ray --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ray_address():
    """A local Ray for this module: 2 CPUs, loopback only, no dashboard; shut down after."""
    if os.environ.get("CI"):
        import ray  # the test extra installs it: in CI its absence is a failure
    else:
        ray = pytest.importorskip("ray")
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # node address 127.0.0.1
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report leaves the machine
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        _node_ip_address="127.0.0.1",
        object_store_memory=128 * 2**20,
        log_to_driver=False,
        logging_level="warning",
    )
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        t = threading.Thread(target=ray.shutdown, daemon=True)
        t.start()
        t.join(30)
        assert not t.is_alive(), "ray.shutdown() hung"


@pytest.mark.slow
def test_ray_is_local_and_loopback_only(ray_address):
    import ray

    assert ray_address.startswith("127.0.0.1:")
    assert ray.cluster_resources()["CPU"] == 2
    assert all(n["NodeManagerAddress"] == "127.0.0.1" for n in ray.nodes())


@pytest.mark.slow
def test_ray_runs_the_smoke_benchmark_to_the_local_pools_results(
    ray_address, compare_smoke_run, tmp_path
):
    folder = run_compare(str(SMOKE), [], str(tmp_path), progress=False, workers=2, executor="ray")
    assert rows(folder) == rows(compare_smoke_run)
    data = json.loads((folder / "results.json").read_text())
    assert data["executor"] == "ray" and data["partial"] is False
    assert len(journal(folder)) == len(rows(folder))


@pytest.mark.slow
def test_ray_retries_a_lost_worker_then_records_an_error(ray_address, tmp_path):
    with make_executor("ray", 2) as ex:
        done = ex.map(crash_once, [{"marker": str(tmp_path / "m")}])
        assert done[0].value == "ok"
        lost = ex.map(crash_always, [0])
    assert lost[0].value is None and "worker lost 3 time(s)" in lost[0].error


@pytest.mark.slow
def test_ray_runs_a_sweep(ray_address, tmp_path):
    from rodctl.bench.sweep import run_sweep

    folder = run_sweep(
        str(SWEEP_SMOKE), [], str(tmp_path), progress=False, workers=2, executor="ray"
    )
    got = rows(folder)
    assert len(got) == 4 and {r["estimator.p0"] for r in got} == {"10.0", "1000.0"}
    summary = json.loads((folder / "summary.json").read_text())
    assert [g["rank"] for g in summary["ranking"]] == [1, 2]


@pytest.mark.slow
def test_ray_run_interrupted_by_sigterm_keeps_results_and_resumes(
    ray_address, compare_smoke_run, tmp_path
):
    """SIGTERM to a compare driving an existing Ray: stopped within seconds, finished episodes
    kept (partial), the cut episodes' logs replayable; --resume finishes it to the same table."""
    from rodctl.replay import rebuild

    sets = [
        "--set",
        "figure_target=1",
        "--set",
        "keep_logs=true",
        "--set",
        "base.logging.mcap=true",
    ]
    args = ["compare", str(SMOKE), *sets, "--executor", "ray", "--address", ray_address]
    out = tmp_path / "runs"
    out.mkdir()
    run = interrupt(args, out, after_rows=2, sig=signal.SIGTERM)
    assert run.returncode == 1, run.stderr
    assert run.stop_seconds < 30, run.stop_seconds
    meta = json.loads((run.folder / "meta.json").read_text())
    assert meta["status"] == "interrupted" and "SIGTERM" in meta["error"]
    kept = rows(run.folder)
    assert 2 <= len(kept) < 12
    assert json.loads((run.folder / "results.json").read_text())["partial"] is True
    assert (run.folder / "summary.md").read_text().startswith("**PARTIAL**")
    for row in journal(run.folder):
        if row["outcome"] == "interrupted":
            log = run.folder / "episodes" / row["method"] / f"t{row['target']:03d}"
            assert rebuild(log, tmp_path / "replay", figures=False).run.records
    resumed = run_compare(
        str(SMOKE),
        [s for s in sets if s != "--set"],
        str(out),
        progress=False,
        workers=2,
        executor="ray",
        resume=str(run.folder),
    )
    assert resumed == run.folder
    assert rows(resumed) == rows(compare_smoke_run)
    # The episodes the stop cut are journaled as `interrupted` (whichever target they were on:
    # that depends on timing) and run again; every finished one is kept, not run again.
    finished_before = [r for r in journal(run.folder)[: len(kept)] if r["outcome"] != "interrupted"]
    for r in finished_before:
        same = [
            j
            for j in journal(run.folder)
            if (j["method"], j["target"]) == (r["method"], r["target"])
        ]
        assert len(same) == 1, same
    assert json.loads((run.folder / "meta.json").read_text())["status"] == "completed"


def test_done_defaults():
    assert Done(3).error is None and Done(3).attempts == 1
