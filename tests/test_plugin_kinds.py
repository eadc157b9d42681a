"""The three kinds a plug-in adds besides stages, through the CLI with no edit inside rodctl: the
example package examples/plugin-kinds/ registers an event (`gripper_nudge`), a sink (`csv`) and
an executor (`thread`); a run applies the event, writes the sink's file (the same numbers as its
MCAP), and compare on the plug-in's executor gives the local executor's results."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config import ExperimentConfig
from rodctl.logs.mcap import read_mcap

needs_plugin = pytest.mark.skipif(
    importlib.util.find_spec("rodctl_example_kinds") is None,
    reason="example plug-in not installed (pip install -e examples/plugin-kinds)",
)
KINDS_DIR = REPO / "examples/plugin-kinds"
QUIET = ["--set", "logging.rerun=false", "--set", "logging.figures=false"]


def _invoke(*args: str):
    return CliRunner().invoke(app, list(args))


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8", newline="") as fh:
        return list(csv.DictReader(fh))


@needs_plugin
def test_plugins_lists_the_event_sink_and_executor_with_their_source():
    res = _invoke("plugins")
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    for kind, name in (("event", "gripper_nudge"), ("sink", "csv"), ("executor", "thread")):
        start = lines.index(f"{kind}:")
        line = next(ln for ln in lines[start:] if ln.strip().startswith(name + " "))
        assert "plug-in rodctl-example-kinds" in line, line


@needs_plugin
def test_simulate_applies_the_plugin_event_and_writes_the_plugin_sink(tmp_path):
    res = _invoke("simulate", str(KINDS_DIR / "nudge.yaml"), "-q", "-o", str(tmp_path), *QUIET)
    assert res.exit_code == 0, res.output
    run_dir = Path(res.output.strip().splitlines()[-1])
    summary = json.loads((run_dir / "summary.json").read_text())
    rows = _rows(run_dir / "steps.csv")
    assert [int(r["step"]) for r in rows] == list(range(summary["steps"] + 1))
    # The sink's numbers are the run's: those of run.mcap, step by step.
    logged = read_mcap(run_dir / "run.mcap", images=False).records
    assert len(logged) == len(rows)
    for row, rec in zip(rows, logged, strict=True):
        assert float(row["pixel_error"]) == rec.pixel_error and float(row["T1"]) == rec.T1
        g = [float(row[k]) for k in ("gripper_x", "gripper_y", "gripper_theta")]
        np.testing.assert_array_equal(g, rec.gripper)
    # The event fired before step 12's move: the gripper went by the step's command plus the
    # knock of 2 cm in y, and the step's events say so (and only that step's).
    (nudged,) = [r for r in rows if "gripper_nudge" in r["events"]]
    assert int(nudged["step"]) == 12
    before, now = rows[11], rows[12]
    for axis, knock in (("x", 0.0), ("y", 0.02), ("theta", 0.0)):
        moved = float(now[f"gripper_{axis}"]) - float(before[f"gripper_{axis}"])
        assert moved == pytest.approx(float(now[f"u_{axis}"]) + knock, abs=1e-9), axis
    assert summary["outcome"] == "converged"
    # The run says which plug-ins made it: the event's and the sink's factories, in meta.json
    # and in run.mcap's provenance record, beside the stages'.
    meta = json.loads((run_dir / "meta.json").read_text())
    from mcap.reader import make_reader  # noqa: PLC0415

    with (run_dir / "run.mcap").open("rb") as fh:
        records = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
    logged = {k: json.loads(v) for k, v in records["rodctl.provenance"].items()}
    for where in (meta, logged):
        (event,) = where["events"]
        assert event["type"] == "gripper_nudge" and event["origin"] == "plug-in"
        assert "rodctl-example-kinds" in event["source"]
        sinks = {s["type"]: s for s in where["sinks"]}
        assert set(sinks) == {"mcap", "csv"}  # rerun and figures are switched off
        assert sinks["csv"]["origin"] == "plug-in" and sinks["mcap"]["origin"] == "built-in"
    assert logged["events"] == meta["events"] and logged["sinks"] == meta["sinks"]


@needs_plugin
def test_compare_on_the_plugin_executor_gives_the_local_results(tmp_path):
    config = str(KINDS_DIR / "compare.yaml")
    results = {}
    for executor, workers in (("thread", "2"), ("local", "1")):
        out = tmp_path / executor
        res = _invoke("compare", config, "-q", "-o", str(out), "--executor", executor,
                      "--workers", workers)  # fmt: skip
        assert res.exit_code == 0, res.output
        folder = Path(res.output.strip().splitlines()[-1])
        results[executor] = _rows(folder / "results.csv")
        made_by = json.loads((folder / "meta.json").read_text())["executor"]
        assert made_by["type"] == executor
        assert made_by["origin"] == ("plug-in" if executor == "thread" else "built-in")
        for episode in sorted((folder / "episodes").glob("*/t*")):  # keep_logs: the csv sink
            assert any("gripper_nudge" in r["events"] for r in _rows(episode / "steps.csv"))
    thread, local = results["thread"], results["local"]
    assert len(thread) == 2 and {r["finished_before_event"] for r in thread} == {"False"}
    for a, b in zip(thread, local, strict=True):
        assert {k: v for k, v in a.items() if k != "wall_time_s"} == {
            k: v for k, v in b.items() if k != "wall_time_s"
        }


@needs_plugin
@pytest.mark.parametrize(
    ("sets", "said"),
    [
        (["run.events=[{type: gripper_nudge, at_step: 2, delta: [0.6, 0.0, 0.0]}]"],
         "run.events"),
        (["logging.sinks=[{type: csv, name: ../outside.csv}]"], "logging.sinks.0.name"),
        (["logging.sinks=[{type: no_such_sink}]"], "'no_such_sink'"),
        (["logging.sinks=[{type: mcap}]"], "logging.mcap: true"),
    ],
    ids=["nudge-out-of-range", "csv-name-escapes", "unknown-sink", "switched-sink-listed"],
)  # fmt: skip
def test_bad_plugin_settings_are_refused_with_exit_2(sets, said):
    args = [a for s in sets for a in ("--set", s)]
    res = _invoke("config", "show", str(KINDS_DIR / "nudge.yaml"), *args)
    assert res.exit_code == 2, res.output
    assert said in res.output and "Traceback" not in res.output


@needs_plugin
def test_the_event_check_sees_the_state_the_earlier_events_left():
    """The nudge's own `check` reads the held length an earlier grasp slip left: 0.3 m is
    shorter than the 0.5 m rod but not than the 0.25 m left after the slip."""
    nudge = {"type": "gripper_nudge", "at_step": 5, "delta": [0.0, 0.2, 0.0]}
    ExperimentConfig.model_validate({"run": {"events": [nudge]}})
    slip = {"type": "grasp_slip", "at_step": 3, "ds": 0.3}
    with pytest.raises(ValueError, match=r"run\.events\[1\]\.delta: .*held rod \(0\.2 m"):
        ExperimentConfig.model_validate({"run": {"events": [slip, nudge]}})


def test_an_unknown_executor_is_exit_2_naming_the_registered_ones(tmp_path):
    res = _invoke("compare", str(REPO / "configs/compare.yaml"), "-q", "-o",
                  str(tmp_path), "--executor", "no_such_executor")  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "'no_such_executor'" in res.output and "'local'" in res.output
