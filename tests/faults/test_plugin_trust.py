"""Plug-ins under attack (issue 29, Trust): a plug-in cannot silently replace a built-in type,
neither through its entry point nor by patching the registry; an allowed override is loud and
recorded; meta.json and run.mcap say which plug-ins were loaded and which factory built each
stage; a plug-in that exits or raises BaseException at import is named, exit 2.

The plug-ins are real installed distributions: a module and a `*.dist-info` with an
`entry_points.txt` on PYTHONPATH, found by importlib.metadata as pip's would be."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from paths import REPO

from rodctl.errors import UserError

QUICK = ["--set", "logging.rerun=false", "--set", "logging.figures=false",
         "--set", "run.max_steps=3"]  # fmt: skip

#: A factory that runs the built-in MFAC: what a hijacker would start from.
_EVIL = """
from rodctl.control.mfac import _build as _real

def evil(cfg, ctx):
    return _real(cfg, ctx)
"""

REPLACE = (
    _EVIL
    + """
from rodctl.control.mfac import MfacControllerConfig
from rodctl.registry import CONTROLLERS
CONTROLLERS.register(MfacControllerConfig, replace=True)(evil)
"""
)

PATCH = (
    _EVIL
    + """
import dataclasses
from rodctl.registry import CONTROLLERS
CONTROLLERS._entries["mfac"] = dataclasses.replace(CONTROLLERS.get("mfac"), factory=evil)
"""
)


def _install(tmp_path: Path, module: str, code: str) -> Path:
    """A distribution `rodfault-<module>` 0.1 whose entry point names `module`."""
    (tmp_path / f"{module}.py").write_text(textwrap.dedent(code))
    dist = tmp_path / f"rodfault_{module}-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: rodfault-{module}\nVersion: 0.1\n"
    )
    (dist / "entry_points.txt").write_text(f"[rodctl.plugins]\n{module} = {module}\n")
    return tmp_path / f"{module}.py"


def _rodctl(tmp_path: Path, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    path = os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))
    return subprocess.run(
        [sys.executable, "-m", "rodctl", *args],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": path, **(env or {})},
        cwd=tmp_path,
        timeout=180,
    )


def _line(text: str, type_name: str) -> str:
    return next(ln for ln in text.splitlines() if ln.strip().startswith(type_name + " "))


@pytest.mark.slow
@pytest.mark.parametrize("code", [REPLACE, PATCH], ids=["re-registered", "registry patched"])
def test_a_plugin_cannot_replace_a_builtin_type_unless_allowed(tmp_path, code):
    _install(tmp_path, "hijack", code)
    out = tmp_path / "runs"
    res = _rodctl(tmp_path, "simulate", str(REPO / "configs/default.yaml"), "-q", "-o", str(out),
                  *QUICK)  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert "hijack" in res.stderr and "'mfac'" in res.stderr and "--allow-override" in res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists() or not any(out.iterdir()), "nothing ran"
    listed = _rodctl(tmp_path, "plugins")
    assert listed.returncode == 2, listed.stderr
    assert "rodctl (built-in)" in _line(listed.stdout, "mfac")  # the truth: not replaced
    assert "failed plug-in hijack" in listed.stderr and "'mfac'" in listed.stderr


@pytest.mark.slow
def test_an_allowed_override_is_loud_and_recorded_in_meta_and_mcap(tmp_path):
    module = _install(tmp_path, "hijack", REPLACE)
    out = tmp_path / "runs"
    res = _rodctl(tmp_path, "--allow-override", "simulate", str(REPO / "configs/default.yaml"),
                  "-q", "-o", str(out), *QUICK)  # fmt: skip
    assert res.returncode in (0, 1), res.stderr  # 3 steps: the run's outcome does not matter
    assert "warning" in res.stderr and "'mfac'" in res.stderr and "rodfault-hijack" in res.stderr
    (run_dir,) = out.iterdir()
    meta = json.loads((run_dir / "meta.json").read_text())
    sha = hashlib.sha256(module.read_bytes()).hexdigest()
    mine = [p for p in meta["plugins"]["loaded"] if p["distribution"] == "rodfault-hijack"]
    assert mine == [
        {"entry_point": "hijack", "value": "hijack", "distribution": "rodfault-hijack",
         "version": "0.1", "module": "hijack", "file": str(module), "sha256": sha}
    ]  # fmt: skip
    (override,) = meta["plugins"]["overrides"]
    assert (override["kind"], override["type"], override["by"]) == (
        "controller", "mfac", "rodfault-hijack 0.1"
    )  # fmt: skip
    stages = meta["stages"]
    assert stages["controller"]["factory"] == "hijack:evil"
    assert stages["controller"]["origin"] == "plug-in" and stages["controller"]["overrides_builtin"]
    assert stages["feature"]["origin"] == "built-in"
    assert stages["estimator"]["factory"] == "rodctl.estimation.akf:_build"

    from mcap.reader import make_reader

    with (run_dir / "run.mcap").open("rb") as fh:
        records = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
    logged = {k: json.loads(v) for k, v in records["rodctl.provenance"].items()}
    assert logged["stages"] == stages
    assert logged["plugins"] == meta["plugins"]

    listed = _rodctl(tmp_path, "plugins", env={"RODCTL_ALLOW_OVERRIDE": "1"})
    assert listed.returncode == 0, listed.stderr
    line = _line(listed.stdout, "mfac")
    assert "plug-in rodfault-hijack 0.1" in line and "REPLACES the built-in" in line
    assert sha in listed.stdout


@pytest.mark.slow
@pytest.mark.parametrize(
    ("code", "said"),
    [
        ("import sys\nsys.exit(0)\n", "SystemExit"),
        ("raise KeyboardInterrupt\n", "KeyboardInterrupt"),
    ],
    ids=["sys.exit(0)", "KeyboardInterrupt"],
)
def test_a_plugin_that_exits_or_raises_baseexception_at_import_is_named(tmp_path, code, said):
    _install(tmp_path, "quitter", code)
    res = _rodctl(tmp_path, "config", "show", str(REPO / "configs/default.yaml"))
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert "quitter" in res.stderr and said in res.stderr
    assert "Traceback" not in res.stderr
    assert res.stdout == ""


# --- patched after loading: refused where the stage is built ----------------------------------


def _patch_variants():
    def swap_registration(reg, evil):
        import dataclasses

        from rodctl.registry import CONTROLLERS

        CONTROLLERS._entries["mfac"] = dataclasses.replace(reg, factory=evil)

    def mutate_frozen(reg, evil):
        object.__setattr__(reg, "factory", evil)

    def swap_code(reg, evil):
        reg.factory.__code__ = evil.__code__

    return [swap_registration, mutate_frozen, swap_code]


@pytest.mark.parametrize("patch", _patch_variants(), ids=lambda f: f.__name__)
def test_a_registry_patched_after_loading_is_refused_when_the_method_is_built(patch, monkeypatch):
    from rodctl import registry
    from rodctl.config import ExperimentConfig
    from rodctl.registry import CONTROLLERS, BuildContext, load_plugins

    load_plugins()
    reg = CONTROLLERS.get("mfac")
    saved = (dict(CONTROLLERS._entries), reg.factory, reg.factory.__code__)
    monkeypatch.delenv(registry.ALLOW_OVERRIDE_ENV, raising=False)

    def evil(cfg, ctx):  # the same signature as the built-in factory
        raise AssertionError("the hijacked factory ran")

    cfg = ExperimentConfig()
    ctx = BuildContext(points=30, p=6, q=3, home_pose=np.zeros(3), max_step=np.ones(3))
    try:
        patch(reg, evil)
        with pytest.raises(UserError, match=r"built-in controller type 'mfac' was replaced"):
            CONTROLLERS.build(cfg.controller, ctx)
        with pytest.raises(UserError, match="--allow-override"):
            CONTROLLERS.provenance("mfac")
    finally:
        object.__setattr__(reg, "factory", saved[1])
        reg.factory.__code__ = saved[2]
        CONTROLLERS._entries.clear()
        CONTROLLERS._entries.update(saved[0])
    assert CONTROLLERS.provenance("mfac")["origin"] == "built-in"


def test_the_builtin_factory_with_another_config_model_is_an_override_too(monkeypatch):
    """The same factory registered again with a config model of other defaults (other MFAC
    weights) changes the result as much as another factory: refused unless allowed."""
    from typing import Literal

    from rodctl import registry
    from rodctl.control.mfac import MfacControllerConfig, _build
    from rodctl.registry import CONTROLLERS, load_plugins

    load_plugins()
    monkeypatch.delenv(registry.ALLOW_OVERRIDE_ENV, raising=False)

    class OtherDefaults(MfacControllerConfig):
        """MFAC with other weights."""

        type: Literal["mfac"] = "mfac"

    before = CONTROLLERS.get("mfac")
    with pytest.raises(registry.OverrideRefused, match="built-in controller type 'mfac'"):
        CONTROLLERS.register(OtherDefaults, replace=True)(_build)
    assert CONTROLLERS.get("mfac") is before
    assert CONTROLLERS.provenance("mfac")["overrides_builtin"] is False


@pytest.mark.parametrize(
    ("kind", "name", "model"),
    [
        ("event", "stiffness", "rodctl.events:StiffnessChange"),
        ("sink", "mcap", "rodctl.logs.sinks:McapSinkConfig"),
        ("executor", "local", "rodctl.executors.local:LocalExecutorConfig"),
    ],
)
def test_a_builtin_event_sink_or_executor_is_guarded_like_a_stage(kind, name, model, monkeypatch):
    """The other three kinds have the stages' trust: re-registering a built-in is refused
    without --allow-override, and a registry patched afterwards is refused where it is used."""
    import dataclasses
    import importlib

    from rodctl import registry

    registry.load_plugins()
    monkeypatch.delenv(registry.ALLOW_OVERRIDE_ENV, raising=False)
    reg = registry.KINDS[kind]
    module, attr = model.split(":")
    config = getattr(importlib.import_module(module), attr)
    before = reg.get(name)
    with pytest.raises(registry.OverrideRefused, match=f"built-in {kind} type '{name}'"):
        reg.register(config, replace=True)(lambda *args: None)
    assert reg.get(name) is before
    cfg = config.model_validate(config.example) if kind == "event" else config()
    monkeypatch.setitem(reg._entries, name, dataclasses.replace(before, factory=lambda *a: None))
    with pytest.raises(UserError, match=f"built-in {kind} type '{name}' was replaced"):
        reg.build(cfg)
