"""run.mcap read back with the standard `mcap` reader: the topic contract, units, timing, schemas.

The contract is the "The MCAP log" table of docs/outputs.md; field names are checked exactly.
"""

from __future__ import annotations

import base64
import filecmp
import json
import subprocess

import jsonschema
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from rodctl.logs import codec, schemas
from rodctl.logs.mcap import McapSink

CONTRACT = {
    "/rod/state": ["step", "sim_time", "gripper", "centerline"],
    "/camera/centerline": ["step", "extracted", "projected_truth"],
    "/control": ["step", "u", "s", "s_target", "T1", "J", "pixel_error"],
}


def _xy(points):
    """[{x, y}, ...] as an (M, 2) array."""
    return np.array([[p["x"], p["y"]] for p in points], dtype=np.float64).reshape(-1, 2)


def _messages(path):
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        msgs = [(s, c, m, json.loads(m.data)) for s, c, m in reader.iter_messages()]
        attachments = list(reader.iter_attachments())
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return summary, msgs, attachments, metadata


def test_contract_topics_fields_and_step_count(mcap_file, synthetic):
    header, records = synthetic
    _, msgs, _, _ = _messages(mcap_file)
    for topic, fields in CONTRACT.items():
        on_topic = [(c, m, d) for _, c, m, d in msgs if c.topic == topic]
        assert [d["step"] for _, _, d in on_topic] == [r.step for r in records], topic
        for _, _, d in on_topic:
            assert list(d)[: len(fields)] == fields, topic  # contract fields, in order, first
    by_step = {d["step"]: d for _, c, _, d in msgs if c.topic == "/control"}
    for r in records:
        d = by_step[r.step]
        p, q = r.J.shape
        assert (p, q) == (6, 3)
        assert len(d["J"]) == p * q
        assert np.array_equal(np.reshape(d["J"], (p, q)), r.J)  # row-major, exact floats
        assert d["u"] == r.u.tolist() and d["T1"] == r.T1
        assert d["pixel_error"] == r.pixel_error and d["s"] == r.s.tolist()
    rod = {d["step"]: d for _, c, _, d in msgs if c.topic == "/rod/state"}
    cam = {d["step"]: d for _, c, _, d in msgs if c.topic == "/camera/centerline"}
    for r in records:
        assert rod[r.step]["sim_time"] == r.sim_time
        assert np.array_equal(rod[r.step]["gripper"], r.gripper)
        assert np.array_equal(_xy(rod[r.step]["centerline"]), r.centerline)
        assert _xy(cam[r.step]["extracted"]).shape == (100, 2)
        assert np.array_equal(_xy(cam[r.step]["projected_truth"]), r.projected_truth)
        assert rod[r.step]["nonfinite"] == [] == cam[r.step]["nonfinite"]


def test_units_timing_and_sequence(mcap_file, synthetic):
    header, records = synthetic
    summary, msgs, _, _ = _messages(mcap_file)
    channels = {c.topic: c for c in summary.channels.values()}
    assert channels["/rod/state"].metadata["unit.sim_time"] == "s"
    assert channels["/rod/state"].metadata["unit.centerline"].startswith("m ")
    assert channels["/rod/state"].metadata["unit.gripper"].startswith("m, m, rad")
    assert channels["/camera/centerline"].metadata["unit.extracted"].startswith("px")
    assert channels["/control"].metadata["unit.pixel_error"] == "px"
    # Log time = 2000-01-01T00:00:00Z + simulated time, so viewers show a date, not 1970.
    epoch = 946_684_800 * 10**9
    assert codec.LOG_EPOCH_NS == epoch
    sim_ns = {r.step: epoch + round(r.sim_time * 1e9) for r in records}
    for _, c, m, d in msgs:
        if c.topic in CONTRACT:
            assert m.log_time == m.publish_time == sim_ns[d["step"]]
            assert m.sequence == d["step"]
    # Units are physical: the world centerline spans about the rod length (m), pixels fit in
    # the 640 x 480 frame.
    d = next(d for _, c, _, d in msgs if c.topic == "/rod/state")
    arc = np.linalg.norm(np.diff(_xy(d["centerline"]), axis=0), axis=1).sum()
    assert 0.3 < arc < 1.0
    px = _xy(next(d for _, c, _, d in msgs if c.topic == "/camera/centerline")["extracted"])
    assert px.min() >= 0 and px[:, 0].max() < 640 and px[:, 1].max() < 480
    # log_time = simulated time: nothing before the epoch, nothing later than the last step.
    assert summary.statistics.message_start_time == epoch
    assert summary.statistics.message_end_time == sim_ns[records[-1].step]
    assert summary.statistics.message_count == len(msgs)


@pytest.mark.slow
def test_schemas_foxglove_messages_and_images(mcap_file, synthetic):
    header, records = synthetic
    summary, msgs, _, _ = _messages(mcap_file)
    want = {
        "/rod/state": "rodctl.RodState",
        "/camera/centerline": "rodctl.CameraCenterline",
        "/control": "rodctl.Control",
        "/world/rod": "foxglove.SceneUpdate",
        "/world/target": "foxglove.SceneUpdate",
        "/world/gripper": "foxglove.SceneUpdate",
        "/camera/image": "foxglove.CompressedImage",
        "/log": "foxglove.Log",
    }
    for s, c, _, d in msgs:
        assert c.message_encoding == "json" and s.encoding == "jsonschema"
        if c.topic in want:
            assert s.name == want[c.topic]
        jsonschema.validate(d, json.loads(s.data))  # every message fits its registered schema
    scenes = [d for _, c, _, d in msgs if c.topic == "/world/rod"]
    assert len(scenes) == len(records)
    line = scenes[-1]["entities"][0]["lines"][0]
    pts = np.array([[p["x"], p["y"]] for p in line["points"]])
    assert np.array_equal(pts, records[-1].centerline) and line["type"] == 0
    target = [d for _, c, _, d in msgs if c.topic == "/world/target"]
    assert len(target) == 1
    images = [(m, d) for _, c, m, d in msgs if c.topic == "/camera/image"]
    with_frames = [r for r in records if r.image is not None]
    assert [m.sequence for m, _ in images] == [r.step for r in with_frames]
    for (m, d), r in zip(images, with_frames, strict=True):
        assert d["format"] == "png" and d["frame_id"] == "camera"
        assert np.array_equal(codec.decode_png(base64.b64decode(d["data"])), r.image)
        assert d["timestamp"] == codec.foxglove_time(m.log_time)
    logs = [d["message"] for _, c, _, d in msgs if c.topic == "/log"]
    assert any("phase probe" in t for t in logs) and any("occluded" in t for t in logs)
    assert "completed" in logs[-1]


def test_config_metadata_attachment_and_compression(mcap_file, synthetic):
    header, _ = synthetic
    summary, _, attachments, metadata = _messages(mcap_file)
    assert [a.name for a in attachments] == ["config.yaml"]
    assert attachments[0].data.decode() == header.config_yaml
    cfg = yaml.safe_load(header.config_yaml)
    assert json.loads(metadata["rodctl.config"]["rod.length"]) == cfg["rod"]["length"]
    assert json.loads(metadata["rodctl.config"]["seed"]) == cfg["seed"]
    # Nothing per-invocation (run id, wall clock) is logged: reruns are byte-identical.
    assert "run_id" not in metadata["rodctl.run"] and metadata["rodctl.run"]["method"]
    assert metadata["rodctl.end"] == {"status": "completed", "steps": "30"}
    assert {ci.compression for ci in summary.chunk_indexes} == {"zstd"}
    assert len(summary.chunk_indexes) >= 3  # chunks closed every flush_every_steps = 10 steps


def test_every_schema_constant_is_valid_json_schema():
    for schema in schemas.ALL.values():
        jsonschema.Draft7Validator.check_schema(schema)


def test_rerun_mcap_check_accepts_the_file(mcap_file, rerun_exe):
    res = subprocess.run(
        [rerun_exe, "mcap", "check", str(mcap_file)], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stdout + res.stderr


def test_same_records_give_identical_bytes(tmp_path, synthetic, helpers):
    header, records = synthetic
    summary = helpers.summary_of(records)
    a = helpers.write_run(McapSink, tmp_path / "a.mcap", header, records, summary)
    b = helpers.write_run(McapSink, tmp_path / "b.mcap", header, records, summary)
    assert filecmp.cmp(a, b, shallow=False)
    # …and the bytes do depend on the data (the comparison can fail).
    changed = list(records)
    changed[7] = codec.record_from_messages(
        codec.rod_state_message(records[7]),
        codec.camera_message(records[7]),
        {**codec.control_message(records[7]), "T1": np.nextafter(records[7].T1, 1.0)},
        None,
    )
    c = helpers.write_run(McapSink, tmp_path / "c.mcap", header, changed, summary)
    assert not filecmp.cmp(a, c, shallow=False)


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_other_compressions_read_back(tmp_path, synthetic, compression, helpers):
    from rodctl.config.logging import LoggingConfig
    from rodctl.logs.mcap import read_mcap

    header, records = synthetic
    cfg = LoggingConfig(mcap_compression=compression)
    path = helpers.write_run(McapSink, tmp_path / "r.mcap", header, records[:8], None, cfg=cfg)
    run = read_mcap(path)
    assert [r.step for r in run.records] == list(range(8))
    with open(path, "rb") as f:
        comp = {ci.compression for ci in make_reader(f).get_summary().chunk_indexes}
    assert comp == {"lz4" if compression == "lz4" else ""}
