"""run.rrd read back with rerun.chunk.RrdReader and checked with the bundled `rerun` CLI."""

from __future__ import annotations

import subprocess

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from rodctl.logs.rerun import RerunSink
from rodctl.logs.synthetic import SyntheticRun

ENTITIES = {
    "/world/rod",
    "/world/target",
    "/world/gripper",
    "/world/clamp",
    "/camera/image",
    "/camera/centerline",
    "/camera/projected_truth",
    "/camera/target",
    "/control/T1",
    "/control/pixel_error",
    "/control/u/x",
    "/control/u/y",
    "/control/u/theta",
    "/log",
}


def _chunks(path):
    out: dict[str, list] = {}
    for ch in RrdReader(path).stream():
        out.setdefault(ch.entity_path, []).append(ch)
    return out


def _column(chunks, name):
    """(steps, values) of one component over the non-static chunks of an entity."""
    steps, values = [], []
    for ch in chunks:
        if ch.is_static:
            continue
        rb = ch.to_record_batch()
        steps += rb.column("step").to_pylist()
        values += rb.column(name).to_pylist()
    order = np.argsort(steps, kind="stable")
    return [steps[i] for i in order], [values[i] for i in order]


def test_rrd_verify_passes(rrd_file, rerun_exe):
    res = subprocess.run(
        [rerun_exe, "rrd", "verify", str(rrd_file)], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stdout + res.stderr


def test_recording_entities_timelines_and_blueprint(rrd_file, synthetic):
    header, records = synthetic
    reader = RrdReader(rrd_file)
    [rec] = reader.recordings()
    assert rec.recording_id == header.run_id and rec.application_id == "rodctl"
    assert len(reader.blueprints()) == 1
    chunks = _chunks(rrd_file)
    assert ENTITIES <= set(chunks)
    for entity in ("/world/rod", "/camera/centerline", "/control/T1", "/control/u/theta"):
        for ch in chunks[entity]:
            if not ch.is_static:
                # No wall-clock timeline: only the two simulation timelines.
                assert set(ch.timeline_names) == {"step", "sim_time"}, entity
    for entity in ("/world/target", "/world/clamp", "/camera/target"):
        assert all(ch.is_static for ch in chunks[entity]), entity


def test_logged_values(rrd_file, synthetic):
    header, records = synthetic
    chunks = _chunks(rrd_file)
    steps, t1 = _column(chunks["/control/T1"], "Scalars:scalars")
    assert steps == [r.step for r in records]
    assert [v[0] for v in t1] == [r.T1 for r in records]
    _, ux = _column(chunks["/control/u/theta"], "Scalars:scalars")
    assert [v[0] for v in ux] == [r.u[2] for r in records]
    # The world is y-up, Rerun's 2D views y-down: the rod is stored as (x, -y), float32.
    _, rod = _column(chunks["/world/rod"], "LineStrips2D:strips")
    last = np.asarray(rod[-1][0], dtype=np.float64)
    want = records[-1].centerline * [1.0, -1.0]
    assert last.shape == (51, 2) and np.allclose(last, want, atol=1e-6)
    _, px = _column(chunks["/camera/centerline"], "LineStrips2D:strips")
    assert np.allclose(np.asarray(px[3][0]), records[3].extracted, atol=1e-4)
    sim = []
    for ch in chunks["/control/T1"]:
        if not ch.is_static:
            col = ch.to_record_batch().column("sim_time")
            sim += col.cast(pa.int64()).to_pylist()
    assert sorted(sim) == [round(r.sim_time * 1e9) for r in records]
    img_steps, _ = _column(chunks["/camera/image"], "EncodedImage:blob")
    assert img_steps == [r.step for r in records if r.image is not None]


def test_two_recordings_of_the_same_records_compare_equal(tmp_path, synthetic, helpers, rerun_exe):
    header, records = synthetic
    a = helpers.write_run(RerunSink, tmp_path / "a.rrd", header, records[:12], None)
    b = helpers.write_run(RerunSink, tmp_path / "b.rrd", header, records[:12], None)
    other = SyntheticRun(seed=4, image_every=5)
    c = helpers.write_run(RerunSink, tmp_path / "c.rrd", header, other.records(12), None)

    def compare(x, y):
        return subprocess.run(
            [rerun_exe, "rrd", "compare", "--unordered", str(x), str(y)],
            capture_output=True,
            text=True,
            timeout=60,
        ).returncode

    assert compare(a, b) == 0
    assert compare(a, c) != 0


def test_close_is_idempotent_and_write_after_close_fails(tmp_path, synthetic):
    header, records = synthetic
    sink = RerunSink(tmp_path / "x.rrd")
    sink.close(None, "failed")  # never opened: nothing to do
    assert not (tmp_path / "x.rrd").exists()
    sink = RerunSink(tmp_path / "y.rrd")
    sink.open(header)
    sink.write(records[0])
    sink.close(None, "interrupted")
    sink.close(None, "interrupted")
    with pytest.raises(RuntimeError):
        sink.write(records[1])
    chunks = _chunks(tmp_path / "y.rrd")
    steps, _ = _column(chunks["/control/T1"], "Scalars:scalars")
    assert steps == [0]  # the buffered step was sent on close
