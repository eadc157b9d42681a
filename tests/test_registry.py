"""Every registered type of the six kinds (feature, estimator, controller, event, sink, executor)
is complete: a documented config model, a factory (or apply function) that builds an object
honouring its protocol (`rodctl.testing` runs each one), and a test that names it; each stage type
also runs in a shipped config (the python-control meta-tests are the model: a type nobody runs is
a type nobody checked). And the list of built-in modules cannot drift from the code."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import yaml
from paths import CONFIGS, PLUGIN_CONFIGS, REPO, plugin_installed

from rodctl import registry as registry_module
from rodctl.config.base import StrictModel
from rodctl.registry import KINDS, STAGES, load_plugins
from rodctl.testing import check_event, check_executor, check_sink, check_stage

load_plugins()
REGISTERED = [(kind, reg) for kind, registry in STAGES.items() for reg in registry]
IDS = [f"{kind}:{reg.type}" for kind, reg in REGISTERED]
EVERY = [(kind, reg) for kind, registry in KINDS.items() for reg in registry]
EVERY_IDS = [f"{kind}:{reg.type}" for kind, reg in EVERY]


def _ours(reg) -> bool:
    """A type rodctl's repository ships: a built-in or one of the examples/ plug-ins (its code
    file is inside the repository; an editable install of examples/ points there)."""
    path = registry_module._code_file(reg.factory)
    return path is not None and Path(path).resolve().is_relative_to(REPO.resolve())


#: The meta-tests of this repository's coverage (a shipped config runs it, a test names it) hold
#: rodctl's own types only: a user's plug-in installed into the same venv is covered by its own
#: package's tests, not by rodctl's configs. The checks of a type itself (a strict documented
#: config, `check_stage` & co.) still run on every registered type.
OURS = [(kind, reg) for kind, reg in REGISTERED if _ours(reg)]
OURS_IDS = [f"{kind}:{reg.type}" for kind, reg in OURS]
EVERY_OURS = [(kind, reg) for kind, reg in EVERY if _ours(reg)]
EVERY_OURS_IDS = [f"{kind}:{reg.type}" for kind, reg in EVERY_OURS]


def _of(kind: str) -> list:
    return [reg for reg in KINDS[kind]]


def _types_used_by_shipped_configs() -> set[tuple[str, str]]:
    used: set[tuple[str, str]] = set()
    paths = list(CONFIGS) + (list(PLUGIN_CONFIGS) if plugin_installed() else [])
    for path in paths:
        data = yaml.safe_load(path.read_text()) or {}
        sections = [data] + [m for m in (data.get("methods") or {}).values()]
        for section in sections:
            for kind, registry in STAGES.items():
                stage = section.get(kind)
                if isinstance(stage, dict):
                    used.add((kind, stage.get("type", registry.default)))
                elif stage is None and section is data and "methods" not in data:
                    used.add((kind, registry.default))
    return used


@pytest.mark.parametrize(("kind", "reg"), EVERY, ids=EVERY_IDS)
def test_config_model_is_strict_and_documented(kind, reg):
    model = reg.config
    assert issubclass(model, StrictModel), "unknown keys must be errors (StrictModel)"
    assert (model.__doc__ or "").strip(), f"{model.__name__} needs a docstring"
    for name, f in model.model_fields.items():
        if name != "type":
            assert f.description, f"{model.__name__}.{name} needs a description"


@pytest.mark.parametrize(("kind", "reg"), OURS, ids=OURS_IDS)
def test_a_shipped_config_runs_the_type(kind, reg):
    """tests/test_shipped_configs.py and tests/test_compare.py run every config in configs/ (and
    the plug-in's): each registered type must appear in one of them."""
    assert (kind, reg.type) in _types_used_by_shipped_configs(), (
        f"no shipped config uses {kind} type {reg.type!r}"
    )


#: Stage types whose config has required fields: what `check_stage` builds them from, and the
#: dimensions they need (the learned model's checkpoint gives an 8 x 3 Jacobian).
_REQUIRED = {
    "scripted": ({"type": "scripted", "waypoints": [[0.45, 0.1, 0.1]]}, {}),
    "learned": ({"type": "learned", "checkpoint": "rodctl/assets/learned-yu2023.npz"}, {"p": 8}),
}


@pytest.mark.parametrize(("kind", "reg"), REGISTERED, ids=IDS)
def test_check_stage_passes_on_every_stage_type(kind, reg, monkeypatch):
    """`rodctl.testing.check_stage`: built from its config, finite outputs of the protocol's
    shapes, deterministic (the plug-in's types included)."""
    monkeypatch.chdir(REPO)  # the learned model's checkpoint path is relative to the repo
    config, dims = _REQUIRED.get(reg.type, (reg.type, {}))
    report = check_stage(kind, config, **dims)
    assert report.type == reg.type and report.shapes


def test_check_stage_catches_a_stage_that_breaks_its_protocol():
    """It can fail: a controller returning a (2,) command, one returning NaN, and one that is
    not deterministic (it draws from a generator it does not seed) are each refused."""
    from typing import Literal

    import numpy as np

    from rodctl.registry import CONTROLLERS
    from rodctl.testing import StageCheckFailed

    class BrokenConfig(StrictModel):
        """A controller that breaks its protocol in the way `how` says."""

        type: Literal["broken_for_test"] = "broken_for_test"
        how: Literal["shape", "nan", "random"] = "shape"

    class Broken:
        def __init__(self, how):
            self.how, self.rng = how, np.random.default_rng()

        def reset(self):
            pass

        def command(self, s, s_target, J, r):
            if self.how == "shape":
                return np.zeros(2)
            if self.how == "nan":
                return np.full(3, np.nan)
            return self.rng.normal(size=3)

    CONTROLLERS.register(BrokenConfig)(lambda cfg, ctx: Broken(cfg.how))
    try:
        for how, said in [("shape", "shape"), ("nan", "not finite"), ("random", "determin")]:
            with pytest.raises(StageCheckFailed, match=said):
                check_stage("controller", {"type": "broken_for_test", "how": how})
    finally:
        del CONTROLLERS._entries["broken_for_test"]


def test_check_stage_catches_an_estimator_whose_info_needs_reset_first():
    """Found by a new-user trial: an estimator that sets its state in `reset` passed, and every
    run then failed at step 0 (the loop logs `info()` during probing, before `reset`)."""
    from typing import Literal

    import numpy as np

    from rodctl.registry import ESTIMATORS
    from rodctl.testing import StageCheckFailed

    class LateConfig(StrictModel):
        """An estimator whose state exists only after `reset`."""

        type: Literal["late_for_test"] = "late_for_test"

    class Late:
        def reset(self, J0):
            self.J = np.array(J0, dtype=float)

        def update(self, ds, dr):
            return self.J

        def info(self):
            return {"norm": float(np.abs(self.J).sum())}

    ESTIMATORS.register(LateConfig)(lambda cfg, ctx: Late())
    try:
        with pytest.raises(StageCheckFailed, match=r"info\(\) before reset\(\) raised"):
            check_stage("estimator", "late_for_test")
    finally:
        del ESTIMATORS._entries["late_for_test"]


@pytest.mark.parametrize("reg", _of("event"), ids=lambda r: r.type)
def test_every_event_type_validates_and_applies_its_example(reg):
    """Each event type gives an `example`; it is valid in a config (`run.events`, the union of
    the registered types) and its apply function changes a small rod and returns a log line."""
    from rodctl.config import ExperimentConfig

    assert reg.config.example is not None, f"{reg.config.__name__} needs an `example`"
    cfg = ExperimentConfig.model_validate(
        {"rod": {"segments": 20}, "run": {"max_steps": 5, "events": [reg.config.example]}}
    )
    (event,) = cfg.run.events
    assert type(event) is reg.config
    assert check_event(event)


def test_an_unknown_event_type_is_refused_naming_the_field(tmp_path):
    from rodctl.config import load_config
    from rodctl.errors import UserError

    path = tmp_path / "gust.yaml"
    path.write_text("run:\n  events:\n    - {type: no_such_event, at_step: 1}\n")
    with pytest.raises(UserError, match=r"run\.events\.0: .*'no_such_event'.*'stiffness'"):
        load_config(path)


#: Sinks and executors that need more than a folder or one in-process worker, and the test
#: that runs them instead.
_RUN_ELSEWHERE = {
    ("sink", "figures"): "tests/test_figure_process.py",  # a helper process drawing matplotlib
    ("sink", "live"): "tests/logs/test_live.py",  # a WebSocket server: it needs a client
    ("executor", "ray"): "tests/test_executors.py",  # starts a Ray (about 10 s)
}


@pytest.mark.parametrize("reg", _of("sink"), ids=lambda r: r.type)
def test_every_sink_type_writes_a_synthetic_run(reg, tmp_path):
    elsewhere = _RUN_ELSEWHERE.get(("sink", reg.type))
    if elsewhere:
        assert f"{reg.type}" in (REPO / elsewhere).read_text()
        pytest.skip(f"run by {elsewhere}")
    assert check_sink(reg.type, tmp_path)


@pytest.mark.parametrize("reg", _of("executor"), ids=lambda r: r.type)
def test_every_executor_type_maps_tasks(reg):
    elsewhere = _RUN_ELSEWHERE.get(("executor", reg.type))
    if elsewhere:
        assert f'"{reg.type}"' in (REPO / elsewhere).read_text()
        pytest.skip(f"run by {elsewhere}")
    check_executor(reg.type)


def _test_texts() -> str:
    """Every test module's text but this one's (and the example plug-in's tests)."""
    files = [p for p in (REPO / "tests").rglob("*.py") if p.name != "test_registry.py"]
    return "\n".join(p.read_text(encoding="utf-8") for p in files)


_TEXTS = _test_texts()


@pytest.mark.parametrize(("kind", "reg"), EVERY_OURS, ids=EVERY_OURS_IDS)
def test_every_type_is_named_by_a_test(kind, reg):
    """A type no test names is a type nobody checked (a new event type once passed 130 tests
    with nothing covering it): some test module must name it ("type" or type: type)."""
    name = re.escape(reg.type)
    pattern = rf"[\"']{name}[\"']|type[=:]\s*{name}\b|{kind}\.type={name}\b"
    assert re.search(pattern, _TEXTS), f"no test names the {kind} type {reg.type!r}"


_REGISTRIES = {"FEATURES", "ESTIMATORS", "CONTROLLERS", "EVENTS", "SINKS", "EXECUTORS"}


def _registering_modules() -> set[str]:
    """The modules of rodctl that register a type (`<REGISTRY>.register(...)` in their code)."""
    found = set()
    for path in (REPO / "rodctl").rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        if ".register(" not in text:
            continue
        tree = ast.parse(text)
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == "register"
                and isinstance(node.func.value, ast.Name)
                and node.func.value.id in _REGISTRIES
            ):
                rel = path.relative_to(REPO).with_suffix("")
                found.add(".".join(rel.parts).removesuffix(".__init__"))
    return found


def test_the_builtin_module_list_is_the_modules_that_register():
    """`registry._BUILTIN_MODULES` is imported to register rodctl's own types: a module that
    registers one but is not listed would be silently absent; one listed that registers none is
    a stale line. Both fail here."""
    listed = set(registry_module._BUILTIN_MODULES)
    found = _registering_modules()
    assert found - listed == set(), "register types but are not in _BUILTIN_MODULES"
    assert listed - found == set(), "listed in _BUILTIN_MODULES but register nothing"
    assert len(listed) == len(registry_module._BUILTIN_MODULES), "listed twice"


def test_a_controller_that_returns_none_is_named_not_called_diverged():
    """Found by a new-user trial: a plug-in controller returning None was reported as
    'diverged: the controller's command u = [nan] is not finite'."""
    from typing import Literal

    from rodctl.config import load_config
    from rodctl.env import ShapeServoEnv
    from rodctl.episode import EpisodeFailed, run_episode
    from rodctl.method import Method
    from rodctl.registry import CONTROLLERS

    class NoneConfig(StrictModel):
        """A controller that forgets to return its command."""

        type: Literal["none_for_test"] = "none_for_test"

    class Forgets:
        def reset(self):
            pass

        def command(self, s, s_target, J, r):
            return None

    CONTROLLERS.register(NoneConfig)(lambda cfg, ctx: Forgets())
    try:
        sets = ["feature.type=bezier", "controller.type=none_for_test", "rod.segments=20"]
        sets += ["rod.engine=quasistatic", "logging.mcap=false", "logging.rerun=false"]
        cfg = load_config(REPO / "configs/default.yaml", sets)
        with pytest.raises(EpisodeFailed) as err:
            run_episode(ShapeServoEnv(cfg), Method.from_config(cfg))
        said = "controller 'none_for_test': command(s, s*, J, r) returned None, not a (3,) command"
        assert err.value.result.error == f"ValueError: {said}"
    finally:
        del CONTROLLERS._entries["none_for_test"]
