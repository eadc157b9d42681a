"""Every registered stage type is complete: a documented config model, a factory that builds an
object honouring its protocol, and a shipped config that the config-driven tests run with it
(the python-control meta-tests are the model: a type nobody runs is a type nobody checked)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from paths import CONFIGS, PLUGIN_CONFIGS, plugin_installed

from rodctl.config.base import StrictModel
from rodctl.registry import STAGES, BuildContext, load_plugins

load_plugins()
REGISTERED = [(kind, reg) for kind, registry in STAGES.items() for reg in registry]
IDS = [f"{kind}:{reg.type}" for kind, reg in REGISTERED]


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


@pytest.mark.parametrize(("kind", "reg"), REGISTERED, ids=IDS)
def test_config_model_is_strict_and_documented(kind, reg):
    model = reg.config
    assert issubclass(model, StrictModel), "unknown keys must be errors (StrictModel)"
    assert (model.__doc__ or "").strip(), f"{model.__name__} needs a docstring"
    for name, f in model.model_fields.items():
        if name != "type":
            assert f.description, f"{model.__name__}.{name} needs a description"


@pytest.mark.parametrize(("kind", "reg"), REGISTERED, ids=IDS)
def test_a_shipped_config_runs_the_type(kind, reg):
    """tests/test_shipped_configs.py and tests/test_compare.py run every config in configs/ (and
    the plug-in's): each registered type must appear in one of them."""
    assert (kind, reg.type) in _types_used_by_shipped_configs(), (
        f"no shipped config uses {kind} type {reg.type!r}"
    )


def _default(model):
    try:
        return model()
    except Exception:  # noqa: BLE001 - a model with required fields (e.g. scripted waypoints)
        return None


@pytest.mark.parametrize(("kind", "reg"), REGISTERED, ids=IDS)
def test_factory_builds_an_object_honouring_the_protocol(kind, reg):
    cfg = _default(reg.config)
    if cfg is None:
        pytest.skip(f"{reg.type} has required fields; its shipped config covers it")
    if kind == "feature" and reg.type == "autoencoder":
        from rodctl.config import ExperimentConfig

        ctx = BuildContext(points=100, experiment=ExperimentConfig())
    else:
        ctx = BuildContext(
            points=100,
            p=6,
            q=3,
            home_pose=np.array([0.4, 0.2, 0.0]),
            max_step=np.array([0.01, 0.01, 0.05]),
            oracle=lambda: np.ones((6, 3)),  # what the simulator would say (oracle estimator)
        )
    obj = reg.factory(cfg, ctx)
    rng = np.random.default_rng(0)
    if kind == "feature":
        t = np.linspace(0.0, 1.0, 100)
        c = np.column_stack([200 + 250 * t, 240 + 40 * np.sin(2 * t)])
        s = obj.encode(c)
        assert s.shape == (obj.dim,) and np.all(np.isfinite(s))
    elif kind == "estimator":
        J = rng.normal(0.0, 30.0, (6, 3))
        obj.reset(J)
        out = obj.update(J @ np.array([0.01, 0.0, 0.02]), np.array([0.01, 0.0, 0.02]))
        assert out.shape == (6, 3) and isinstance(obj.info(), dict)
    else:
        obj.reset()
        J = rng.normal(0.0, 30.0, (6, 3))
        u = obj.command(np.zeros(6), J @ np.array([0.002, -0.001, 0.004]), J, np.zeros(3))
        assert np.asarray(u).shape == (3,) and np.all(np.isfinite(u))
