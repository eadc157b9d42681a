"""Config loading: shipped configs validate; every kind of bad input is a clear exit-2 error."""

from __future__ import annotations

import json

import jsonschema
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from paths import CONFIGS, REPO
from typer.testing import CliRunner

from rodctl.bench.compare import load_compare_config
from rodctl.cli import app
from rodctl.config import ConfigError, ExperimentConfig, dump_config, load_config, read_yaml
from rodctl.config.compare import CompareConfig

runner = CliRunner()


def test_configs_folder_is_not_empty():
    assert CONFIGS, "configs/ must ship at least the default config"
    assert REPO / "configs" / "default.yaml" in CONFIGS


def _is_compare(path) -> bool:
    return "methods" in read_yaml(path)


def _is_sweep(path) -> bool:
    return "parameters" in read_yaml(path)


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_every_shipped_config_validates(path):
    if _is_sweep(path):
        from rodctl.bench.sweep import load_sweep_config
        from rodctl.config.sweep import SweepConfig

        cfg = load_sweep_config(path)
        model = SweepConfig
    elif _is_compare(path):
        cfg = load_compare_config(path)
        model = CompareConfig
    else:
        cfg = load_config(path)
        model = ExperimentConfig
    # The resolved dump loads back to the same config (round trip through YAML).
    assert model.model_validate(yaml.safe_load(dump_config(cfg))) == cfg
    result = runner.invoke(app, ["config", "show", str(path)])
    assert result.exit_code == 0, result.output
    assert model.model_validate(yaml.safe_load(result.stdout)) == cfg


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_schema_validates_shipped_configs(path):
    kind = ["--sweep"] if _is_sweep(path) else ["--compare"] if _is_compare(path) else []
    args = ["config", "schema", *kind]
    result = runner.invoke(app, args)
    assert result.exit_code == 0
    schema = json.loads(result.stdout)
    jsonschema.validate(read_yaml(path), schema)


def test_schema_rejects_unknown_key():
    schema = ExperimentConfig.model_json_schema()
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"rod": {"lenght": 0.5}}, schema)


def test_overrides_apply_as_yaml_scalars():
    cfg = load_config(REPO / "configs/default.yaml", ["rod.length=0.6", "seed=7", "name=abc"])
    assert cfg.rod.length == 0.6 and cfg.seed == 7 and cfg.name == "abc"
    cfg = load_config(None, ["rod.clamp_pose=[0.1, 0.2, 0.3]"])
    assert cfg.rod.clamp_pose == (0.1, 0.2, 0.3)


def test_section_without_type_means_the_default_method():
    cfg = load_config(None, ["controller.type=mfac"])
    assert load_config(None).controller.type == cfg.controller.type


def _fail(args, tmp_path=None):
    result = runner.invoke(app, args)
    out = result.stdout + (result.stderr or "")
    assert result.exit_code == 2, out
    assert "Traceback" not in out
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return out


def test_missing_file(tmp_path):
    out = _fail(["config", "show", str(tmp_path / "nope.yaml")])
    assert "nope.yaml" in out and "no such file" in out


def test_yaml_syntax_error(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("rod:\n  length: [0.5\nseed: 1\n")
    out = _fail(["config", "show", str(bad)])
    assert "bad.yaml" in out and "YAML syntax error" in out and "line" in out


def test_top_level_not_a_mapping(tmp_path):
    bad = tmp_path / "list.yaml"
    bad.write_text("- 1\n- 2\n")
    out = _fail(["config", "show", str(bad)])
    assert "list.yaml" in out and "mapping" in out


def test_unknown_key(tmp_path):
    bad = tmp_path / "typo.yaml"
    bad.write_text("rod:\n  lenght: 0.5\n")
    out = _fail(["config", "show", str(bad)])
    assert "typo.yaml" in out and "rod.lenght" in out and "unknown key" in out


def test_wrong_type(tmp_path):
    bad = tmp_path / "type.yaml"
    bad.write_text("seed: banana\n")
    out = _fail(["config", "show", str(bad)])
    assert "seed" in out and "integer" in out and "banana" in out


@pytest.mark.parametrize(
    ("override", "path"),
    [
        ("rod.length=-1", "rod.length"),
        ("rod.segments=1", "rod.segments"),
        ("camera.points=1", "camera.points"),
        ("rod.workspace.x_limits=[1, 0]", "rod.workspace"),
    ],
)
def test_out_of_range(override, path, repo):
    out = _fail(["config", "show", str(repo / "configs/default.yaml"), "--set", override])
    assert path in out and "default.yaml" in out


def test_unknown_method_type(repo):
    out = _fail(
        ["config", "show", str(repo / "configs/default.yaml"), "--set", "controller.type=x"]
    )
    assert "controller" in out and "'x'" in out


@pytest.mark.parametrize(
    "override", ["rod.length", "=3", "rod..length=1", "rod.length=[1", "seed.x=1"]
)
def test_malformed_set(override, repo):
    out = _fail(["config", "show", str(repo / "configs/default.yaml"), "--set", override])
    assert "--set" in out or "seed" in out


def test_an_index_into_a_list_the_file_does_not_set_says_to_set_the_list(repo):
    """Found by a new-user trial: `rod.max_step.0=0.02` with no rod.max_step in the file was
    'Input should be a valid tuple' (a mapping {"0": 0.02} had been made)."""
    out = _fail(
        ["config", "show", str(repo / "configs/default.yaml"), "--set", "rod.max_step.0=0.02"]
    )
    assert "the config does not set rod.max_step, so there is no list to index" in out
    assert load_config(None, ["rod.max_step=[0.02, 0.01, 0.05]"]).rod.max_step[0] == 0.02


def test_config_error_is_a_user_error():
    with pytest.raises(ConfigError):
        load_config(None, ["rod.length=0"])


# --- property-based: mutate valid configs, the CLI never prints a traceback -------------------


def _leaf_paths(node, prefix=()):
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _leaf_paths(v, (*prefix, k))
    elif isinstance(node, list):
        yield prefix
        for i, v in enumerate(node):
            yield from _leaf_paths(v, (*prefix, str(i)))
    else:
        yield prefix


_DEFAULT = load_config(None).model_dump(mode="json")
_PATHS = sorted({".".join(p) for p in _leaf_paths(_DEFAULT) if p})

_values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**6), max_value=10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.lists(st.floats(allow_nan=False, width=32), max_size=4),
    st.sampled_from(["[1, 2", "{a: 1}", "!!python/object:os.system", "'", "a: b: c"]),
)


@pytest.mark.slow
@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    path=st.one_of(st.sampled_from(_PATHS), st.text(min_size=0, max_size=10)),
    value=_values,
    raw=st.booleans(),
)
def test_mutated_configs_never_traceback(path, value, raw):
    text = value if (raw and isinstance(value, str)) else yaml.safe_dump(value).strip()
    text = text.removesuffix("\n...").strip()
    result = runner.invoke(
        app, ["config", "show", str(REPO / "configs/default.yaml"), "--set", f"{path}={text}"]
    )
    out = result.stdout + (result.stderr or "")
    assert result.exit_code in (0, 2), out
    assert "Traceback" not in out
    if result.exit_code == 2:
        assert result.stderr.startswith("error: "), out
    if result.exception is not None:
        assert isinstance(result.exception, SystemExit), repr(result.exception)


@pytest.mark.parametrize(
    ("override", "line"),
    [
        ("run.target.pose=[0.3,0.1]", "run.target.pose: expected a list of 3 or 6 values, got 2"),
        ("run.target.pose=[0,0,0,0]", "run.target.pose: expected a list of 3 or 6 values, got 4"),
        ("controller.weights=[0.5,0.5]", "controller.weights: expected a list of 7 values, got 2"),
        ("run.target.pose=[0,0,x]", "run.target.pose.2: Input should be a valid number"),
        ("rod.length=true", "rod.length: expected a number, not a boolean (got True)"),
        ("seed=true", "seed: expected a number, not a boolean (got True)"),
        ("controller.weights=[true,0,0,0,0,0,0]", "controller.weights: expected a number, not"),
        ("run.target.pose=3", "run.target.pose: Input should be a valid tuple (got 3)"),
        # list[Pose] | list[DualPose]: the member whose length fits speaks, not the other too.
        ("controller.waypoints=[[0.4,0.1,0.5],[0.3,0.1,x]]", "controller.waypoints.1.2: Input"),
        (
            "controller.waypoints=[[0.4,0.1,0.5],[0.3,0.1]]",
            "controller.waypoints.1: expected a list of 3 values, got 2",
        ),  # fmt: skip
        # YAML 1.1 reads 2e2 (no dot) as text: say what to write instead.
        (
            "run.max_steps=2e2",
            "run.max_steps: expected a whole number, got the text '2e2': write 200",
        ),
    ],
)
def test_an_invalid_value_is_named_once_by_its_dotted_key(override, line):
    """A list of the wrong length is one line (not one per absent item and per union branch);
    a boolean for a number names the field, not its section."""
    scripted = override.startswith("controller.waypoints")
    with pytest.raises(ConfigError) as err:
        load_config(REPO / ("configs/scripted.yaml" if scripted else "configs/default.yaml"),
                    [override])  # fmt: skip
    lines = str(err.value).splitlines()[1:]
    assert len(lines) == 1 and lines[0].strip().startswith(line), lines


@pytest.mark.parametrize(
    ("text", "was"), [("010", "8"), ("12:30", "750"), ("1:0", "60"), ("1:30.5", "90.5")]
)
def test_yaml_1_1_octal_and_base_60_numbers_are_refused(tmp_path, text, was):
    """YAML 1.1 reads them as numbers other than the ones written; refused in --set and files."""
    with pytest.raises(ConfigError, match=rf"'{text}' .* is {was} in YAML 1\.1"):
        load_config(REPO / "configs/default.yaml", [f"run.max_steps={text}"])
    path = tmp_path / "c.yaml"
    path.write_text(f"run:\n  max_steps: {text}\n")
    with pytest.raises(ConfigError, match=r"line 2, column 14\) is .* in YAML 1\.1 \(a"):
        load_config(path)
    assert load_config(REPO / "configs/default.yaml", ["run.max_steps=1_000"]).run.max_steps == 1000


@pytest.mark.parametrize("value", ["interrupted", "error", "converge"])
def test_run_expect_takes_only_an_outcome_a_config_can_reach(value):
    """`run.expect` is one of the episode's outcomes, but not an interruption or an error."""
    with pytest.raises(ConfigError, match=r"run\.expect: .*'lost_tracking' or 'completed'"):
        load_config(REPO / "configs/default.yaml", [f"run.expect={value}"])
    cfg = load_config(REPO / "configs/default.yaml", ["run.expect=completed"])
    assert cfg.run.expect == "completed"
    assert "expect: completed" in dump_config(cfg)  # the outcome's value, as it was written


def _shipped_dumps():
    """What `dump_config` writes of every shipped config under configs/ (the experiment, compare
    and sweep configs as read and validated, experiments also `clean`; the suites (and each
    scenario) and the tuning files as read)."""
    from rodctl.bench.sweep import load_sweep_config

    for path in sorted((REPO / "configs").rglob("*.yaml")):
        data = read_yaml(path)
        if path.parent.name == "tuning":
            yield path, data
        elif "parameters" in data or "methods" in data:
            yield path, data
            load = load_sweep_config if "parameters" in data else load_compare_config
            yield path, load(path).model_dump(mode="json")
        elif "scenarios" in data:
            yield path, data
            for name, scenario in data["scenarios"].items():
                yield path, {name: scenario, "base": data.get("base")}
        else:
            cfg = load_config(path)
            yield path, cfg.model_dump(mode="json")
            yield path, yaml.safe_load(dump_config(cfg, clean=True))


@pytest.mark.skipif(not hasattr(yaml, "CSafeDumper"), reason="PyYAML built without libyaml")
def test_libyaml_dumper_writes_the_python_emitters_bytes():
    """`dump_config` uses libyaml's CSafeDumper (issue 24): the same text as PyYAML's own
    SafeDumper for every shipped config, so run directories and checkpoints keep their bytes."""
    seen = 0
    for path, data in _shipped_dumps():
        opts = dict(sort_keys=False, default_flow_style=None)
        c_text = yaml.dump(data, Dumper=yaml.CSafeDumper, **opts)
        assert c_text == yaml.dump(data, Dumper=yaml.SafeDumper, **opts), path
        seen += 1
    assert seen > 30
    cfg = load_config(REPO / "configs/default.yaml")
    opts = dict(sort_keys=False, default_flow_style=None)
    assert dump_config(cfg) == yaml.dump(
        cfg.model_dump(mode="json"), Dumper=yaml.SafeDumper, **opts
    )
