"""Frames are PNG-encoded, and Rerun batches sent, on background threads: the files must not
depend on how fast those threads are."""

from __future__ import annotations

import filecmp
import random
import subprocess
import time

import numpy as np
import pytest
from rerun.chunk import RrdReader

from rodctl.logs import codec
from rodctl.logs.mcap import McapSink, read_mcap
from rodctl.logs.rerun import RerunSink
from rodctl.logs.synthetic import SyntheticRun
from rodctl.replay import compare_records


@pytest.fixture
def slow_random_encoder(monkeypatch):
    """PNG encoding that takes 0-8 ms longer, at random: the worst case for ordering bugs."""
    real = codec.encode_png
    rng = random.Random(1234)

    def slow(image, level=1):
        time.sleep(rng.uniform(0.0, 0.008))
        return real(image, level)

    monkeypatch.setattr(codec, "encode_png", slow)
    codec.FRAMES.reset()
    yield
    codec.FRAMES.reset()


@pytest.mark.slow
def test_mcap_bytes_do_not_depend_on_encoding_speed(tmp_path, helpers, slow_random_encoder):
    run = SyntheticRun(seed=8, image_every=1)
    records = run.records(25)
    a = helpers.write_run(McapSink, tmp_path / "a.mcap", run.header, records, None)
    codec.FRAMES.reset()
    b = helpers.write_run(McapSink, tmp_path / "b.mcap", run.header, records, None)
    assert filecmp.cmp(a, b, shallow=False)
    back = read_mcap(a)
    assert compare_records(back.records, records, images=True) == []
    assert sum(r.image is not None for r in back.records) == 25  # 0.2 s steps: every frame


def test_rerun_recordings_compare_equal_whatever_the_timing(
    tmp_path, helpers, rerun_exe, slow_random_encoder
):
    run = SyntheticRun(seed=9, image_every=1)
    records = run.records(23)
    a = helpers.write_run(RerunSink, tmp_path / "a.rrd", run.header, records, None)
    codec.FRAMES.reset()
    b = helpers.write_run(RerunSink, tmp_path / "b.rrd", run.header, records, None)
    res = subprocess.run(
        [rerun_exe, "rrd", "compare", "--unordered", str(a), str(b)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]


def test_a_bad_frame_is_refused_when_written_not_later(tmp_path, synthetic):
    header, records = synthetic
    sink = McapSink(tmp_path / "bad.mcap")
    sink.open(header)
    bad = SyntheticRun(seed=3, image_every=0).records(1)[0]
    bad.image = records[0].image[:, :, :2].copy()  # two channels
    with pytest.raises(ValueError, match="frame must be"):
        sink.write(bad)
    sink.write(records[0])  # the sink is still usable: nothing of the bad step was queued
    sink.close(None, "completed")
    assert [r.step for r in read_mcap(tmp_path / "bad.mcap").records] == [0]


def test_an_encoding_error_surfaces_one_step_later_and_leaves_the_file_whole(tmp_path):
    run = SyntheticRun(seed=4, image_every=0)
    records = run.records(4)
    records[1].u = np.array(["not", "a", "number"])  # fails in the writer thread
    sink = McapSink(tmp_path / "e.mcap")
    sink.open(run.header)
    sink.write(records[0])
    sink.write(records[1])  # queued: the loop does not wait for encoding
    with pytest.raises(ValueError, match="could not convert"):
        sink.write(records[2])  # the first write after the failed step reports it
    sink.write(records[3])
    sink.close(None, "failed")
    back = read_mcap(tmp_path / "e.mcap")
    assert [r.step for r in back.records] == [0, 2, 3] and back.status == "failed"


def test_the_loop_may_reuse_a_record_s_arrays_after_writing_it(tmp_path, helpers):
    """The sinks' threads read a step after `write` returned: they must work on copies."""
    run = SyntheticRun(seed=6, image_every=0)
    records = run.records(12)
    want = helpers.write_run(McapSink, tmp_path / "want.mcap", run.header, records, None)
    mcap, rrd = McapSink(tmp_path / "got.mcap"), RerunSink(tmp_path / "got.rrd")
    for sink in (mcap, rrd):
        sink.open(run.header)
    for rec in records:
        for sink in (mcap, rrd):
            sink.write(rec)
        for name in ("centerline", "extracted", "projected_truth", "u", "s", "J"):
            getattr(rec, name)[...] = -1.0  # the loop scribbles over its buffers
        rec.estimator_info.clear()
    for sink in (mcap, rrd):
        sink.close(None, "completed")
    assert filecmp.cmp(want, tmp_path / "got.mcap", shallow=False)
    pristine = SyntheticRun(seed=6, image_every=0).records(12)
    got = {}
    for ch in RrdReader(tmp_path / "got.rrd").stream():
        if ch.entity_path == "/camera/centerline" and not ch.is_static:
            batch = ch.to_record_batch()
            steps = batch.column("step").to_pylist()
            strips = batch.column("LineStrips2D:strips").to_pylist()
            got.update({k: np.asarray(v[0]) for k, v in zip(steps, strips, strict=True)})
    assert sorted(got) == list(range(12))
    for r in pristine:
        assert np.allclose(got[r.step], r.extracted, atol=1e-4), r.step
