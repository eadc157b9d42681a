"""Hostile and absurd input: every case is refused up front with exit 2 and one message naming
the field or file, never a traceback and never a crash later in the run."""

from __future__ import annotations

import pytest
from paths import REPO
from typer.testing import CliRunner

from rodctl.cli import app
from rodctl.config import ExperimentConfig
from rodctl.config.compare import CompareConfig

DEFAULT = str(REPO / "configs/default.yaml")


def _run(*args: str):
    res = CliRunner().invoke(app, list(args))
    assert "Traceback" not in res.output
    return res


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("camera.width=100000000", "camera.width"),
        ("rod.dt=1.0e308", "rod.dt"),
        ("rod.iterations=10000000", "rod.iterations"),
        ("rod.control_period=1.0e300", "rod.control_period"),
        ("rod.max_settle_time=1.0e300", "rod.max_settle_time"),
        ("run.stall_window=1000000000", "run.stall_window"),
        ("estimator.p0=1.0e308", "estimator.p0"),
        ("camera.extract.step_px=1.0e308", "camera.extract.step_px"),
        ("rod.segments=1000000", "rod.segments"),
        ("run.max_steps=true", "max_steps"),
        ("rod.clamp_pose=[1.0e300, 0, 0]", "rod.clamp_pose.0"),
    ],
)
def test_absurd_values_are_refused_naming_the_field(override, field, tmp_path):
    res = _run("simulate", DEFAULT, "-o", str(tmp_path), "--set", override)
    assert res.exit_code == 2, res.output
    assert field in res.output
    assert not any(tmp_path.iterdir()), "nothing is created for a config that cannot run"


def test_a_window_of_1e26_is_refused():
    res = _run("config", "show", DEFAULT, "--set", "estimator.type=windowed_ls",
               "--set", "estimator.window=100000000000000000000000000")  # fmt: skip
    assert res.exit_code == 2 and "estimator.window" in res.output


def test_a_run_that_cannot_fit_in_memory_is_refused():
    big = ["--set", "camera.width=8192", "--set", "camera.height=8192"]
    res = _run("config", "show", DEFAULT, *big, "--set", "logging.flush_every_steps=100000")
    assert res.exit_code == 2 and "GiB" in res.output


@pytest.mark.slow
def test_deeply_nested_yaml_is_refused(tmp_path):
    deep = tmp_path / "deep.yaml"
    deep.write_text("a: " + "[" * 600 + "]" * 600 + "\n")
    for args in (["config", "show", str(deep)], ["simulate", str(deep), "-o", str(tmp_path)]):
        res = _run(*args)
        assert res.exit_code == 2 and "nesting deeper" in res.output
    res = _run("config", "show", DEFAULT, "--set", "run.max_steps=" + "[" * 600)
    assert res.exit_code == 2 and "--set" in res.output


def test_duplicate_keys_are_refused_with_their_lines(tmp_path):
    dup = tmp_path / "dup.yaml"
    dup.write_text("name: x\nrun: {max_steps: 10}\nseed: 1\nrun: {max_steps: 20}\n")
    res = _run("config", "show", str(dup))
    assert res.exit_code == 2
    assert "duplicate key 'run'" in res.output and "line 4" in res.output


def test_booleans_are_not_numbers_but_are_booleans():
    assert _run("config", "show", DEFAULT, "--set", "run.max_steps=true").exit_code == 2
    assert _run("config", "show", DEFAULT, "--set", "logging.mcap=false").exit_code == 0


def _unbounded(schema: dict) -> set[str]:
    defs = schema.get("$defs", {})
    out: set[str] = set()

    def walk(node: dict, path: str) -> None:
        if "$ref" in node:
            return walk(defs[node["$ref"].split("/")[-1]], path)
        for key in ("anyOf", "oneOf", "allOf"):
            for sub in node.get(key, []):
                walk(sub, path)
        kind = node.get("type")
        if kind in ("number", "integer") and "enum" not in node and "const" not in node:
            if "maximum" not in node and "exclusiveMaximum" not in node:  # an enum is bounded
                out.add(path)
        for name, sub in node.get("properties", {}).items():
            walk(sub, f"{path}.{name}" if path else name)
        if kind == "array":
            if isinstance(node.get("items"), dict):
                walk(node["items"], path + "[]")
            for i, sub in enumerate(node.get("prefixItems", [])):
                walk(sub, f"{path}[{i}]")

    walk(schema, "")
    return out


def test_every_number_in_the_experiment_schema_has_an_upper_bound():
    assert _unbounded(ExperimentConfig.model_json_schema()) == set()


def test_every_number_in_the_compare_base_has_an_upper_bound():
    unbounded = {p for p in _unbounded(CompareConfig.model_json_schema()) if p.startswith("base.")}
    assert unbounded == set()
