"""Reading run.mcap back: exact records, and clear errors for files that are not whole runs."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from mcap.reader import make_reader

from rodctl.config.logging import LoggingConfig
from rodctl.errors import UserError
from rodctl.logs.mcap import McapSink, read_mcap
from rodctl.logs.synthetic import SyntheticRun
from rodctl.replay import compare_records


def test_records_and_header_read_back_bit_for_bit(mcap_file, synthetic):
    header, records = synthetic
    run = read_mcap(mcap_file)
    assert run.complete and run.status == "completed" and run.warnings == []
    assert compare_records(run.records, records, images=True) == []
    assert [r.image is not None for r in run.records] == [r.image is not None for r in records]
    for name in (
        "clamp_pose",
        "home_pose",
        "target_centerline",
        "target_pixels",
        "target_feature",
        "target_pose",
    ):
        got, want = getattr(run.header, name), getattr(header, name)
        assert got.dtype == np.float64 and np.array_equal(got, want), name
    assert (run.header.method, run.header.config_yaml) == (header.method, header.config_yaml)
    # The run id is not logged (it carries the start time); it is the run folder's name.
    assert run.header.run_id == mcap_file.resolve().parent.name
    assert run.header.image_size == header.image_size
    assert run.header.rod_length == header.rod_length
    assert run.summary["final_T1"] == records[-1].T1 and run.summary["note"] == "synthetic"


def test_a_log_out_of_its_run_folder_is_named_by_its_own_stem(mcap_file, tmp_path):
    """A `run.mcap` copied elsewhere under another name is not the run of its new folder."""
    copy = tmp_path / "lab-copy.mcap"
    copy.write_bytes(mcap_file.read_bytes())
    assert read_mcap(copy).header.run_id == "lab-copy"
    cut = tmp_path / "cut.mcap"  # a killed run's file, read with --recover: the same rule
    cut.write_bytes(mcap_file.read_bytes()[: mcap_file.stat().st_size // 2])
    assert read_mcap(cut, recover=True).header.run_id == "cut"


def test_compare_records_sees_one_ulp(synthetic):
    _, records = synthetic
    other = [SyntheticRun(seed=3, image_every=5).records(30)][0]
    assert compare_records(records, other) == []  # same seed, same numbers
    other[4].gripper = other[4].gripper.copy()
    other[4].gripper[2] = np.nextafter(other[4].gripper[2], np.inf)
    other[9].estimator_info = {**other[9].estimator_info, "alpha": 0.5}
    assert compare_records(records, other) == [
        "step 4: gripper differs",
        "step 9: estimator_info differs",
    ]
    assert compare_records(records, other[:-1])[0].startswith("step count differs")


def test_non_finite_values_round_trip(tmp_path, synthetic, helpers):
    header, records = synthetic
    recs = SyntheticRun(seed=3, image_every=0).records(3)
    recs[1].T1 = math.nan
    recs[1].pixel_error = math.inf
    recs[2].s = recs[2].s.copy()
    recs[2].s[[0, 3]] = [-math.inf, math.nan]
    recs[2].J = recs[2].J.copy()
    recs[2].J[5, 2] = math.nan
    recs[2].estimator_info = {"alpha": -math.inf}
    summary = helpers.summary_of(recs, "failed")
    summary.final_T1 = math.nan
    path = helpers.write_run(McapSink, tmp_path / "nan.mcap", header, recs, summary, "failed")
    run = read_mcap(path)
    assert compare_records(run.records, recs) == []
    assert math.isinf(run.records[1].pixel_error) and math.isnan(run.records[1].T1)
    assert run.records[2].s[0] == -math.inf and math.isnan(run.records[2].s[3])
    assert run.status == "failed" and run.summary["final_T1"] is None


def test_non_finite_points_and_header_round_trip(tmp_path, helpers):
    """Points ({x, y} objects) and header arrays carry NaN and infinities exactly too."""
    run0 = SyntheticRun(seed=5, image_every=0)
    header = run0.header
    header.target_pixels = header.target_pixels.copy()
    header.target_pixels[7, 1] = math.inf
    header.rod_length = math.nan
    header.numeric_env = {"cpu": "Test CPU 9000", "blas": {"vendor": "openblas", "threads": 1}}
    recs = run0.records(3)
    recs[1].centerline = recs[1].centerline.copy()
    recs[1].centerline[4] = [math.nan, -math.inf]
    recs[2].extracted = recs[2].extracted.copy()
    recs[2].extracted[99, 0] = math.inf
    path = helpers.write_run(McapSink, tmp_path / "nan.mcap", header, recs, None, "failed")
    run = read_mcap(path)
    assert compare_records(run.records, recs) == []
    assert math.isnan(run.records[1].centerline[4, 0]) and run.records[1].centerline[4, 1] < 0
    assert run.header.target_pixels[7, 1] == math.inf and math.isnan(run.header.rod_length)
    assert np.array_equal(run.header.target_pixels, header.target_pixels, equal_nan=True)
    assert run.header.numeric_env == header.numeric_env


def test_a_null_without_its_nonfinite_entry_is_malformed(tmp_path, helpers):
    from rodctl.logs import codec

    rec = SyntheticRun(seed=1, image_every=0).records(1)[0]
    rod = codec.rod_state_message(rec)
    rod["centerline"][2]["x"] = None  # a null that `nonfinite` does not explain
    with pytest.raises(ValueError, match="nonfinite"):
        codec.record_from_messages(rod, codec.camera_message(rec), codec.control_message(rec), None)
    ctl = codec.control_message(rec)
    ctl["nonfinite"] = [{"path": "T1", "value": "NaN"}]  # T1 is a number, not null
    with pytest.raises(ValueError, match="null"):
        codec.record_from_messages(
            codec.rod_state_message(rec), codec.camera_message(rec), ctl, None
        )


def test_older_format_is_refused_naming_its_version(tmp_path, helpers, monkeypatch):
    from rodctl.logs import codec

    run0 = SyntheticRun(seed=2, image_every=0)
    monkeypatch.setattr(codec, "FORMAT_VERSION", "1")
    path = helpers.write_run(McapSink, tmp_path / "old.mcap", run0.header, run0.records(2), None)
    monkeypatch.undo()
    with pytest.raises(UserError, match="format version '1'.*reads format versions '2' and '3'"):
        read_mcap(path)


def test_format_2_logs_are_still_read_and_new_ones_are_format_3(tmp_path, helpers, monkeypatch):
    """Format 3 (dual-arm: q = 6 values) is what rodctl writes; a format-2 log (one arm, before
    dual-arm) reads back to the same records."""
    from rodctl.logs import codec

    run = SyntheticRun(seed=2, image_every=0)
    records = run.records(3)
    new = helpers.write_run(McapSink, tmp_path / "new.mcap", run.header, records, None)
    monkeypatch.setattr(codec, "FORMAT_VERSION", "2")
    old = helpers.write_run(McapSink, tmp_path / "old.mcap", run.header, records, None)
    monkeypatch.undo()
    assert codec.FORMAT_VERSION == "3"
    for path, version in ((new, "3"), (old, "2")):
        with path.open("rb") as fh:
            meta = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
        assert meta["rodctl.run"]["format_version"] == version
        back = read_mcap(path).records
        assert [r.step for r in back] == [r.step for r in records]
        assert all(np.array_equal(a.u, b.u) for a, b in zip(back, records, strict=True))
    dual = SyntheticRun(seed=2, image_every=0, arms=2)  # what format 3 adds: q = 6, /rod/clamp
    records = dual.records(3)
    path = helpers.write_run(McapSink, tmp_path / "dual.mcap", dual.header, records, None)
    read = read_mcap(path)
    assert read.header.home_pose.shape == (6,)
    for a, b in zip(read.records, records, strict=True):
        assert np.array_equal(a.u, b.u) and a.u.shape == (6,) and np.array_equal(a.clamp, b.clamp)


@pytest.mark.parametrize(
    "content",
    [b"", b"hello", os.urandom(4096), b"\x89MCAP0\r\n" + os.urandom(3000)],
    ids=["empty", "text", "random", "magic-then-random"],
)
def test_garbage_raises_user_error(tmp_path, content):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    for recover in (False, True):
        with pytest.raises(UserError, match="bad.mcap"):
            read_mcap(path, recover=recover)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(UserError, match="no such file"):
        read_mcap(tmp_path / "nope.mcap")
    with pytest.raises(UserError, match="not a file"):
        read_mcap(tmp_path)


def test_mcap_that_is_not_a_rodctl_run(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "other.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/x", "json", sid)
        w.add_message(cid, 0, b"{}", 0)
        w.finish()
    with pytest.raises(UserError, match="not a rodctl run log"):
        read_mcap(path)


@pytest.mark.parametrize("keep", [0.97, 0.6, 0.2])
def test_truncated_file_is_refused_then_recovered(tmp_path, mcap_file, synthetic, keep):
    _, records = synthetic
    data = mcap_file.read_bytes()
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(UserError, match="incomplete MCAP file.*writer never finished"):
        read_mcap(path)
    run = read_mcap(path, recover=True)
    assert not run.complete and "incomplete" in run.warnings[0]
    n = len(run.records)
    # Complete steps only, a prefix of the run, exact; chunks are closed every 10 steps.
    assert compare_records(run.records, records[:n], images=True) == []
    if keep > 0.9:
        # Only the summary section (indexes, footer) is cut: every step and the closing
        # status survive, yet the file is still reported as incomplete.
        assert n == len(records) and run.status == "completed"
    else:
        assert n % 10 == 0 and n < len(records)
        assert run.status is None and run.summary is None


_KILLED = textwrap.dedent("""
    import os, signal, sys
    from rodctl.config.logging import LoggingConfig
    from rodctl.logs.mcap import McapSink
    from rodctl.logs.rerun import RerunSink
    from rodctl.logs.synthetic import SyntheticRun
    run = SyntheticRun(seed=3, image_every=5)
    cfg = LoggingConfig(flush_every_steps=5)
    sinks = [McapSink(sys.argv[1] + "/run.mcap", cfg), RerunSink(sys.argv[1] + "/run.rrd", cfg)]
    mode = sys.argv[2]

    class Stop(Exception):
        pass

    def on_term(signum, frame):
        raise Stop(signal.Signals(signum).name)

    signal.signal(signal.SIGTERM, on_term)
    status = "completed"
    try:
        for s in sinks:
            s.open(run.header)
        for rec in run.records(40):
            for s in sinks:
                s.write(rec)
            if rec.step == 27:
                if mode == "kill":
                    os.kill(os.getpid(), signal.SIGKILL)
                if mode == "term":
                    os.kill(os.getpid(), signal.SIGTERM)
                if mode == "error":
                    raise RuntimeError("boom")
    except Stop:
        status = "interrupted"
    except RuntimeError:
        status = "failed"
    finally:
        for s in sinks:
            s.close(None, status)
""")


def _run_child(tmp_path, mode):
    return subprocess.run(
        [sys.executable, "-c", _KILLED, str(tmp_path), mode],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.slow
def test_sigkilled_run_leaves_a_recoverable_file(tmp_path):
    res = _run_child(tmp_path, "kill")
    assert res.returncode == -signal.SIGKILL
    with pytest.raises(UserError, match="incomplete"):
        read_mcap(tmp_path / "run.mcap")
    run = read_mcap(tmp_path / "run.mcap", recover=True)
    # Flushed every 5 steps: steps 0..24 are on disk, 25..27 were in the open chunk.
    assert [r.step for r in run.records] == list(range(25))
    want = SyntheticRun(seed=3, image_every=5).records(25)
    assert compare_records(run.records, want, images=True) == []


@pytest.mark.slow
@pytest.mark.parametrize("mode,status", [("term", "interrupted"), ("error", "failed")])
def test_sigterm_and_exception_finalise_both_files(tmp_path, rerun_exe, mode, status):
    res = _run_child(tmp_path, mode)
    assert res.returncode == 0, res.stderr
    run = read_mcap(tmp_path / "run.mcap")
    assert run.complete and run.status == status
    assert [r.step for r in run.records] == list(range(28))  # nothing logged is lost
    for cmd in (
        ["mcap", "check", str(tmp_path / "run.mcap")],
        ["rrd", "verify", str(tmp_path / "run.rrd")],
    ):
        check = subprocess.run([rerun_exe, *cmd], capture_output=True, text=True, timeout=60)
        assert check.returncode == 0, check.stdout + check.stderr


def test_close_is_idempotent_and_safe_before_open(tmp_path, synthetic):
    header, records = synthetic
    never = McapSink(tmp_path / "never.mcap", LoggingConfig())
    never.close(None, "failed")
    never.close(None, "failed")
    assert not (tmp_path / "never.mcap").exists()
    sink = McapSink(tmp_path / "twice.mcap", LoggingConfig())
    sink.open(header)
    sink.write(records[0])
    sink.close(None, "completed")
    size = (tmp_path / "twice.mcap").stat().st_size
    sink.close(None, "failed")
    assert (tmp_path / "twice.mcap").stat().st_size == size
    assert read_mcap(tmp_path / "twice.mcap").status == "completed"
    with pytest.raises(RuntimeError):
        sink.write(records[1])


def test_signals_arriving_during_a_step_are_delivered_after_it():
    from rodctl.logs.mcap import signals_deferred

    class Stop(Exception):
        pass

    def on_term(signum, frame):
        raise Stop

    old = signal.signal(signal.SIGTERM, on_term)
    reached = []
    try:
        with pytest.raises(Stop):
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                reached.append("rest of the step")
            reached.append("after the step")  # pragma: no cover - the signal lands first
    finally:
        signal.signal(signal.SIGTERM, old)
    assert reached == ["rest of the step"]
