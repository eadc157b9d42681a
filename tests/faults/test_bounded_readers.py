"""Bounded readers: a crafted run.mcap, a hostile YAML file or an absurd count is refused with one
message naming the file, the topic or the field, before anything large is inflated, expanded,
parsed or allocated (limits in docs/reliability.md, "Bounded readers and failure reporting")."""

from __future__ import annotations

import json
import tracemalloc
from pathlib import Path

import lz4.frame
import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Footer, Header
from mcap.writer import CompressionType, Writer
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config.loading import MAX_YAML_BYTES
from rodctl.errors import UserError
from rodctl.logs import codec
from rodctl.logs.mcap import MAGIC, McapSink, read_mcap
from rodctl.logs.synthetic import SyntheticRun

SCRIPTED = REPO / "configs/scripted.yaml"
SMOKE = REPO / "configs/compare-smoke.yaml"


def _run(*args: str):
    res = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    return res


# ----------------------------------------------------------------------------- MCAP bombs
def _bomb(path: Path, compression: str, declared: int | None) -> Path:
    """An MCAP holding one chunk that inflates to 16 MiB of zeros (a few kB on disk)."""
    zeros = b"\0" * (16 << 20)
    if compression == "zstd":
        data = zstandard.ZstdCompressor().compress(zeros)
    else:
        data = lz4.frame.compress(zeros, store_size=False)
    b = RecordBuilder()
    Header(profile="", library="rodctl").write(b)
    size = len(zeros) if declared is None else declared
    Chunk(message_start_time=0, message_end_time=0, uncompressed_crc=0, compression=compression,
          uncompressed_size=size, data=data).write(b)  # fmt: skip
    DataEnd(data_section_crc=0).write(b)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
    path.write_bytes(MAGIC + b.end() + MAGIC)
    return path


@pytest.mark.parametrize(
    ("compression", "declared", "why"),
    [
        ("zstd", None, "refused without decompressing"),  # says what it inflates to
        ("zstd", 4000, "refused without decompressing"),  # lies: its frame says 16 MiB
        ("lz4", 4000, "inflates past the 4000 bytes"),  # lies, and lz4 frames need not say
    ],
    ids=["zstd-declared", "zstd-lying", "lz4-lying"],
)
def test_a_decompression_bomb_is_refused_before_it_inflates(tmp_path, compression, declared, why):
    bomb = _bomb(tmp_path / "run.mcap", compression, declared)
    tracemalloc.start()
    try:
        with pytest.raises(UserError, match=why) as err:
            read_mcap(bomb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "chunk 1" in str(err.value)
    assert peak < 4 << 20, f"{peak} bytes allocated to refuse a {bomb.stat().st_size}-byte file"
    res = _run("replay", bomb, "--no-figures")
    assert res.exit_code == 2 and why in res.output and str(bomb) in res.output


# --------------------------------------------------------------------------- deep JSON
def _synthetic_log(path: Path) -> Path:
    run = SyntheticRun(seed=1, image_every=100)
    sink = McapSink(path)
    sink.open(run.header)
    for r in run.records(3):
        sink.write(r)
    sink.close(None, "completed")
    return path


def _tampered(src: Path, dst: Path, topic: str, change) -> Path:
    """A copy of the log `src` whose first message on `topic` has its data replaced by
    `change(data)` (the rest, metadata included, copied unchanged)."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = list(reader.iter_messages(log_time_order=False))
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    with open(dst, "wb") as out:
        w = Writer(out, compression=CompressionType.NONE)
        w.start(profile="", library="rodctl")
        ids = {}
        for sid, s in summary.schemas.items():
            ids[sid] = w.register_schema(name=s.name, encoding=s.encoding, data=s.data)
        chans = {}
        for cid, c in summary.channels.items():
            chans[cid] = w.register_channel(
                topic=c.topic, message_encoding=c.message_encoding, schema_id=ids[c.schema_id]
            )
        for name, data in metadata:
            w.add_metadata(name, data)
        done = False
        for _, ch, m in messages:
            data = m.data
            if ch.topic == topic and not done:
                data, done = change(data), True
            w.add_message(channel_id=chans[ch.id], log_time=m.log_time,
                          publish_time=m.publish_time, sequence=m.sequence, data=data)  # fmt: skip
        w.finish()
    return dst


def _deep_config(data: bytes) -> bytes:
    header = json.loads(data)
    header["config_yaml"] = "a: " + "[" * 20_000 + "]" * 20_000 + "\n"
    return json.dumps(header).encode()


@pytest.mark.parametrize(
    ("topic", "change", "says"),
    [
        (codec.TOPIC_CONTROL, lambda d: b'{"step": 0, "u": ' + b"[" * 100_000 + b"]" * 100_000
         + b"}", "/control nested too deeply"),
        (codec.TOPIC_HEADER, lambda d: b"[" * 100_000 + b"]" * 100_000,
         "/run/header nested too deeply"),
        (codec.TOPIC_HEADER, _deep_config, "config embedded in /run/header is unusable"),
    ],
    ids=["control", "header", "embedded-config"],
)  # fmt: skip
def test_deeply_nested_json_in_a_log_is_refused_naming_the_topic(tmp_path, topic, change, says):
    good = _synthetic_log(tmp_path / "good.mcap")
    assert len(read_mcap(good).records) == 3  # the copy is faithful before it is damaged
    assert len(read_mcap(_tampered(good, tmp_path / "copy.mcap", "/none", bytes)).records) == 3
    bad = _tampered(good, tmp_path / "run.mcap", topic, change)
    res = _run("replay", bad, "--no-figures")
    assert res.exit_code == 2, res.output
    assert says in res.output and str(bad) in res.output


# ------------------------------------------------------------------------------ YAML
def _compare_with_targets(tmp_path: Path, text: str) -> Path:
    (tmp_path / "targets.yaml").write_text(text)
    cfg = tmp_path / "compare.yaml"
    cfg.write_text(
        SMOKE.read_text().replace("targets: {count: 2,", "targets: {file: targets.yaml,")
    )
    return cfg


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("targets: " + "[" * 600 + "]" * 600 + "\n", "nesting deeper than 32"),
        ("targets: [[0.4, 0.1, 0.5]]\ntargets: [[0.4, 0.1, 0.6]]\n", "duplicate key 'targets'"),
    ],
    ids=["deep", "duplicate-key"],
)
def test_a_targets_file_follows_the_rules_of_config_files(tmp_path, text, says):
    cfg = _compare_with_targets(tmp_path, text)
    res = _run("compare", cfg, "-q", "-o", tmp_path / "runs")
    assert res.exit_code == 2, res.output
    assert "targets.file" in res.output and says in res.output
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def _just_too_big(path: Path) -> Path:
    """A valid YAML list (`- 0`, one item a line) one byte over the size limit."""
    item = b"- 0\n"
    n = MAX_YAML_BYTES // len(item) + 1
    path.write_bytes(item * n)
    assert path.stat().st_size > MAX_YAML_BYTES
    return path


def test_a_yaml_over_the_size_limit_is_refused_before_parsing(tmp_path):
    big = _just_too_big(tmp_path / "big.yaml")
    tracemalloc.start()
    try:
        res = _run("config", "show", big)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert res.exit_code == 2 and "refused before parsing" in res.output and str(big) in res.output
    assert peak < 3 * MAX_YAML_BYTES, "read once, never parsed (a parse takes ~100x the text)"
    cfg = tmp_path / "compare.yaml"
    cfg.write_text(SMOKE.read_text().replace("targets: {count: 2,", "targets: {file: big.yaml,"))
    res = _run("compare", cfg, "-q", "-o", tmp_path / "runs")
    assert res.exit_code == 2 and "targets.file" in res.output and "refused before" in res.output


def test_a_400_byte_alias_bomb_is_refused_before_it_is_expanded(tmp_path):
    # Ten copies of the previous level, eight levels deep: 10**7 poses once expanded.
    names = "abcdefgh"
    levels = ["&a [0.4,0.1,0.5]"]
    for prev, name in zip(names, names[1:], strict=False):
        levels.append(f"&{name} [" + ",".join([f"*{prev}"] * 10) + "]")
    text = (
        "name: bomb\nfeature: {type: bezier}\ncontroller:\n  type: scripted\n  waypoints: "
        + "[" + ", ".join(levels) + "]\nrun: {target: {pose: [0.42, -0.08, -0.4]}}\n"
    )  # fmt: skip
    assert len(text) < 400
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(text)
    res = _run("simulate", bomb, "-q", "-o", tmp_path / "runs")
    assert res.exit_code == 2, res.output
    assert "aliases are expanded" in res.output and str(bomb) in res.output
    assert not (tmp_path / "runs").exists()


def test_an_empty_config_file_is_refused_with_a_hint(tmp_path):
    empty = tmp_path / "empty.yaml"
    for text in ("", "\n# only a comment\n"):
        empty.write_text(text)
        res = _run("simulate", empty, "-q", "-o", tmp_path / "runs")
        assert res.exit_code == 2 and "is empty" in res.output and "{}" in res.output
    assert not (tmp_path / "runs").exists()
    empty.write_text("{}\n")  # the defaults, on purpose
    assert _run("config", "show", empty).exit_code == 0


# ------------------------------------------------------------------- counts and seeds
@pytest.mark.parametrize(
    ("config", "override", "field"),
    [
        (SMOKE, "targets.count=1000000000", "targets.count"),
        (SMOKE, f"seed={2**70}", "seed"),
        (REPO / "configs/sweep-smoke.yaml", f"seed={2**70}", "seed"),
        (REPO / "configs/sweep-smoke.yaml", f"seeds=[0, {2**64}]", "seeds.1"),
        (SCRIPTED, f"seed={2**64}", "seed"),
    ],
    ids=["targets.count", "compare-seed", "sweep-seed", "sweep-seeds", "simulate-seed"],
)
def test_counts_and_seeds_are_bounded_alike_in_every_command(config, override, field):
    res = _run("config", "show", config, "--set", override)
    assert res.exit_code == 2, res.output
    assert f"  {field}: " in res.output and "less than or equal to" in res.output
