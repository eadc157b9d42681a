"""One log clock: camera frames are chosen by simulated time, so their rate holds in log time."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from rerun.chunk import RrdReader

from rodctl.config.logging import LoggingConfig
from rodctl.logs import codec
from rodctl.logs.mcap import McapSink, read_mcap
from rodctl.logs.rerun import RerunSink
from rodctl.logs.synthetic import SyntheticRun


def _records(n: int, dt: float, every: int = 1):
    """n synthetic steps `dt` simulated seconds apart, a frame on every `every`-th."""
    run = SyntheticRun(seed=7, image_every=1)
    recs = run.records(n)
    for k, r in enumerate(recs):
        r.sim_time = round(3.0 + k * dt, 9)
        if k % every:
            r.image = None
    return run.header, recs


def _taken(rate: float, recs) -> list[int]:
    sched = codec.FrameSchedule(rate)
    return [r.step for r in recs if sched.take(r)]


def test_schedule_holds_the_rate_in_simulated_time():
    _, recs = _records(40, 0.05)  # 20 steps per simulated second
    assert _taken(5.0, recs) == list(range(0, 40, 4))  # 5 Hz: every 4th step
    assert _taken(2.0, recs) == list(range(0, 40, 10))
    assert _taken(0.0, recs) == []
    _, slow = _records(10, 0.55)  # steps slower than the rate: one frame per step, no more
    assert _taken(5.0, slow) == list(range(10))


def test_schedule_waits_for_a_record_that_carries_a_frame():
    _, recs = _records(40, 0.05, every=3)  # the loop attached a frame to every 3rd record only
    taken = _taken(5.0, recs)
    # Frames sit at 3.0 + 0.15 j s. The slots of 0.2 s from t = 0 hold one frame each: the first
    # frame-bearing record of each slot (3.0, 3.3, 3.45, 3.6, 3.9, 4.05, 4.2, 4.5, 4.65, 4.8).
    assert taken == [0, 6, 9, 12, 18, 21, 24, 30, 33, 36]
    slots = [int(recs[k].sim_time * 5.0 + 1e-9) for k in taken]
    assert slots == list(range(15, 25))  # one frame per slot: 5 Hz held on average


def test_both_sinks_log_the_same_frames_at_the_rate_in_log_time(tmp_path, helpers):
    header, recs = _records(30, 0.05)
    cfg = LoggingConfig(image_rate_hz=5.0)
    mcap = helpers.write_run(McapSink, tmp_path / "r.mcap", header, recs, None, cfg=cfg)
    rrd = helpers.write_run(RerunSink, tmp_path / "r.rrd", header, recs, None, cfg=cfg)
    with open(mcap, "rb") as f:
        msgs = list(make_reader(f).iter_messages(topics=["/camera/image"]))
    log_times = np.array([m.log_time for _, _, m in msgs])
    assert np.all(np.diff(log_times) == 200_000_000)  # 5 Hz of log time exactly
    assert [m.sequence for _, _, m in msgs] == list(range(0, 30, 4))
    rr_steps = []
    for ch in RrdReader(rrd).stream():
        if ch.entity_path == "/camera/image" and not ch.is_static:
            rr_steps += ch.to_record_batch().column("step").to_pylist()
    assert sorted(rr_steps) == list(range(0, 30, 4))
    # Read back, only the logged frames carry an image; a replay's schedule takes them all.
    back = read_mcap(mcap).records
    assert [r.step for r in back if r.image is not None] == list(range(0, 30, 4))
    assert _taken(5.0, back) == list(range(0, 30, 4))


def test_log_times_start_at_the_documented_epoch(tmp_path, helpers):
    header, recs = _records(3, 0.5)
    path = helpers.write_run(McapSink, tmp_path / "e.mcap", header, recs, None)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        first = next(m for _, c, m in reader.iter_messages() if c.topic == "/rod/state")
    assert summary.statistics.message_start_time == codec.LOG_EPOCH_NS  # header, target scene
    assert first.log_time == codec.LOG_EPOCH_NS + 3_000_000_000
    assert meta["rodctl.run"]["log_time"].startswith("ns: 2000-01-01T00:00:00Z")
    assert json.loads(first.data)["sim_time"] == 3.0


@pytest.mark.parametrize("sim_time", [float("nan"), -1.0])
def test_time_of_a_non_finite_or_negative_sim_time_is_the_epoch(sim_time):
    assert codec.log_time_ns(sim_time) == codec.LOG_EPOCH_NS
