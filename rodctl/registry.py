"""Open registries of every extension kind, and plug-in loading.

Why: a method is three stages (feature map, Jacobian estimator, controller) and every one of them
is chosen in a config by its `type`; so are a mid-run event (`run.events`), an output sink
(`logging.sinks`) and an executor (`--executor`). Each type registers itself *beside its
implementation*, together with its config model and a factory, so that adding a type touches
one module: the config unions, the JSON schema (`rodctl config schema`), `rodctl plugins` and
the method builder all read these registries. Packages outside rodctl add types the same way
from a module named by an entry point in the group `rodctl.plugins` (Gymnasium's `register` +
entry points and LeRobot's `register_third_party_plugins` are the models).

Usage, next to an implementation::

    class MyControllerConfig(StrictModel):
        type: Literal["mine"] = "mine"
        gain: float = 0.5

    @CONTROLLERS.register(MyControllerConfig)
    def _build(cfg: MyControllerConfig, ctx: BuildContext) -> Controller:
        return MyController(cfg.gain)

The six kinds and what their registered function is called with:

* feature, estimator, controller: `factory(cfg, ctx: BuildContext)` -> the stage object;
* event: `apply(event, sim, camera)` -> one log line (the event mutates the simulator and/or
  the camera; `rodctl.events`);
* sink: `factory(cfg, ctx: rodctl.logs.sinks.SinkContext)` -> a `rodctl.logs.base.Sink`;
* executor: `factory(cfg, ctx: rodctl.executors.base.ExecutorContext)` -> an `Executor`.

`Registry.build(cfg, *args)` looks the type up (refusing a tampered built-in) and calls it.
"""

from __future__ import annotations

import builtins
import hashlib
import importlib
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any, Concatenate, Generic, ParamSpec, Protocol, TypeVar

import numpy as np
from pydantic import BaseModel

from rodctl.errors import UserError

#: The entry-point group outside packages use to add stage types.
PLUGIN_GROUP = "rodctl.plugins"

#: Set to 1 (what `rodctl --allow-override` does) to let a plug-in replace a built-in type.
ALLOW_OVERRIDE_ENV = "RODCTL_ALLOW_OVERRIDE"

_PACKAGE_DIR = Path(__file__).resolve().parent

C = TypeVar("C", bound=BaseModel)
T = TypeVar("T")
#: What a factory takes after its config: a `BuildContext` for the stages, a `SinkContext` or an
#: `ExecutorContext` for sinks and executors, `(sim, camera)` for events.
P = ParamSpec("P")


class ExperimentSpec(Protocol):
    """The experiment a stage is built for (`rodctl.config.ExperimentConfig` is one), as far as
    the registry knows it: a protocol, so that the registry, which the config models import,
    does not import them back. A stage that needs more of it (the autoencoder checks its
    checkpoint against the whole config) takes the `ExperimentConfig` it is given."""

    @property
    def seed(self) -> int: ...

    @property
    def rod(self) -> BaseModel: ...

    @property
    def camera(self) -> BaseModel: ...

    @property
    def feature(self) -> BaseModel: ...


@dataclass(frozen=True)
class BuildContext:
    """What a factory may need besides its own config: facts of the set-up, not of a stage.

    Attributes:
        points: N, the number of centerline points the feature map is given.
        p: the feature dimension (estimators; 0 when building a feature map).
        q: gripper degrees of freedom (3: x, y, theta).
        home_pose: (3,) gripper pose at the start of the episode, world frame.
        max_step: (3,) per-axis speed limit of one control step [m, m, rad].
        camera: the calibrated camera model (`project`, `unproject`, `projection_jacobian`),
            for methods that use the calibration (e.g. the offline ASAP model).
        oracle: () -> (p, q) the simulator's true Jacobian of this method's feature at the
            current shape (only the labelled `oracle` reference uses it).
        experiment: the whole experiment config (e.g. an encoder checks the rod and camera).
    """

    points: int
    p: int = 0
    q: int = 3
    home_pose: np.ndarray | None = None
    max_step: np.ndarray | None = None
    camera: Any = None
    oracle: Any = None
    experiment: ExperimentSpec | None = None


@dataclass(frozen=True)
class Registration(Generic[C]):
    """One registered type: its config model, its factory and where it comes from."""

    kind: str
    type: str
    # `builtins.type`: the field `type` above shadows the builtin in the class body.
    config: builtins.type[C]
    factory: Callable[..., Any]
    source: str
    summary: str = ""


@dataclass
class Registry(Generic[T]):
    """The types of one extension kind ("feature", "estimator", "controller", "event", "sink",
    "executor"), by `type` name. `default`: the type a section without `type` means (None: the
    kind has no default, e.g. events)."""

    kind: str
    default: str | None
    _entries: dict[str, Registration] = field(default_factory=dict)

    def register(
        self, config: type[C], *, replace: bool = False
    ) -> Callable[[Callable[Concatenate[C, P], T]], Callable[Concatenate[C, P], T]]:
        """Decorator registering `factory(cfg, ctx)` for the config model `config`.

        The type name is the default of the model's `type` field (a `Literal`).

        Raises:
            ValueError: the model has no `type` default, or the name is taken (unless
                `replace`).
        """
        name = _type_name(config)

        def decorator(factory: Callable[Concatenate[C, P], T]) -> Callable[Concatenate[C, P], T]:
            if name in self._entries and not replace:
                raise ValueError(
                    f"{self.kind} type {name!r} is already registered by "
                    f"{self._entries[name].source}"
                )
            # Once rodctl's own types are registered, registering one of their names again
            # replaces the paper's method (another factory, or the same factory with another
            # config model and so other defaults): only when the user says so.
            override = (self.kind, name) in _ORIGINAL
            if override and not override_allowed():
                raise OverrideRefused(
                    f"it replaces the built-in {self.kind} type {name!r}, which needs "
                    f"`rodctl --allow-override` ({ALLOW_OVERRIDE_ENV}=1)"
                )
            # The first paragraph, not the first line, which may stop mid-sentence.
            doc = " ".join((config.__doc__ or "").strip().split("\n\n")[0].split())
            self._entries[name] = Registration(
                kind=self.kind,
                type=name,
                config=config,
                factory=factory,
                source=_override_source(factory) if override else _source_of(factory),
                summary=doc,
            )
            if override:
                _record_override(self.kind, name, "registered with replace=True")
                _TRUSTED[(self.kind, name)] = _fingerprint(self._entries[name])
            _invalidate_models()
            return factory

        return decorator

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[Registration]:
        return iter(self._entries.values())

    def __len__(self) -> int:
        return len(self._entries)

    def names(self) -> list[str]:
        """Registered type names, in registration order (built-ins first)."""
        return list(self._entries)

    def get(self, name: str) -> Registration:
        """The registration of `name`.

        Raises:
            UserError: no such type; the message lists the registered ones.
        """
        try:
            return self._entries[name]
        except KeyError:
            raise UserError(
                f"{self.kind}.type: unknown type {name!r}; registered: {', '.join(self.names())}"
                " (`rodctl plugins` lists them with their sources)"
            ) from None

    def config_models(self) -> list[type[BaseModel]]:
        """Every registered config model (the members of the config union)."""
        return [e.config for e in self._entries.values()]

    def build(self, cfg: BaseModel, *args: Any) -> T:
        """The object `cfg` describes, made by its registered factory: `factory(cfg, *args)`
        (a stage's `ctx`; an event's `sim, camera`, which returns the event's log line).

        Raises:
            UserError: the registration of a built-in type was changed outside `register`
                (a plug-in patched the registry) and overrides are not allowed.
        """
        name = cfg.type  # type: ignore[attr-defined]
        _check_builtin(self, name, culprit=None)
        return self.get(name).factory(cfg, *args)

    def provenance(self, name: str) -> dict[str, Any]:
        """Which factory builds type `name`: `module:attr`, its file and its origin (built-in,
        or the plug-in that registered it), and whether it overrides a built-in type."""
        _check_builtin(self, name, culprit=None)
        reg = self.get(name)
        fn = reg.factory
        module = getattr(fn, "__module__", None) or "?"
        attr = getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None) or repr(fn)
        original = _ORIGINAL.get((self.kind, name))
        overridden = original is not None and not _same(_fingerprint(reg), original)
        return {
            "type": name,
            "factory": f"{module}:{attr}",
            "file": _code_file(fn),
            "origin": "built-in" if _is_builtin_code(fn) and not overridden else "plug-in",
            "source": reg.source,
            "overrides_builtin": overridden,
        }


def _type_name(config: type[BaseModel]) -> str:
    f = config.model_fields.get("type")
    if f is None or not isinstance(f.default, str):
        raise ValueError(f"{config.__name__} needs a field `type: Literal[...] = '<name>'`")
    return f.default


def _source_of(fn: Callable[..., Any]) -> str:
    module = getattr(fn, "__module__", "") or ""
    top = module.split(".")[0]
    if _is_builtin_code(fn):
        return "rodctl (built-in)"
    return f"plug-in {_LOADING or top} ({module})"


def _override_source(fn: Callable[..., Any]) -> str:
    """The `source` of a registration that replaced a built-in type."""
    module = getattr(fn, "__module__", "") or ""
    return f"plug-in {_LOADING or 'unknown (after the plug-ins were loaded)'} ({module})"


def _code_file(fn: Any) -> str | None:
    """The source file of a factory: its code object's, else its module's."""
    code = getattr(fn, "__code__", None)
    if code is not None:
        return str(code.co_filename)
    module = sys.modules.get(getattr(fn, "__module__", "") or "")
    return getattr(module, "__file__", None)


def _is_builtin_code(fn: Any) -> bool:
    """True when the factory's code lives in rodctl's own package folder (its module name is
    not enough: a plug-in can name its function's module anything)."""
    path = _code_file(fn)
    if not path:
        return False
    try:
        return Path(path).resolve().is_relative_to(_PACKAGE_DIR)
    except (OSError, ValueError):
        return False


def override_allowed() -> bool:
    """The user allowed plug-ins to replace built-in types (`--allow-override`)."""
    return os.environ.get(ALLOW_OVERRIDE_ENV, "").strip().lower() in {"1", "true", "yes", "on"}


class OverrideRefused(ValueError):
    """A plug-in tried to replace a built-in type without `--allow-override`."""


def _fingerprint(reg: Registration) -> tuple[Any, ...]:
    """What must stay identical for a registration to be the one `register` made."""
    fn = reg.factory
    return (reg, fn, reg.config, getattr(fn, "__code__", None), reg.source)


def _same(a: tuple[Any, ...], b: tuple[Any, ...]) -> bool:
    return all(x is y for x, y in zip(a, b, strict=True))


def _restore(registry: Registry, name: str, trusted: tuple[Any, ...]) -> None:
    """Put the trusted registration back, undoing in-place edits of it too."""
    reg, fn, config, code, source = trusted
    if code is not None and getattr(fn, "__code__", None) is not code:
        fn.__code__ = code
    for attr, value in (("factory", fn), ("config", config), ("source", source)):
        if getattr(reg, attr) is not value:
            object.__setattr__(reg, attr, value)  # a frozen dataclass edited the same way
    registry._entries[name] = reg
    _invalidate_models()


def _record_override(kind: str, name: str, how: str) -> None:
    """An allowed override: warned about on stderr (once, by the main process) and recorded
    for meta.json and the MCAP provenance."""
    reg = KINDS[kind]._entries.get(name)
    fn = reg.factory if reg is not None else None
    entry = {
        "kind": kind,
        "type": name,
        "by": _LOADING or "unknown (after the plug-ins were loaded)",
        "how": how,
        "factory": f"{getattr(fn, '__module__', '?')}:{getattr(fn, '__qualname__', '?')}",
        "file": _code_file(fn),
    }
    OVERRIDES.append(entry)
    if not _IN_WORKER:
        print(
            f"warning: the built-in {kind} type {name!r} is REPLACED by {entry['by']} "
            f"({entry['factory']}, {entry['file']}): allowed by --allow-override "
            f"({ALLOW_OVERRIDE_ENV}); results of this run are not the built-in method's",
            file=sys.stderr,
        )


def _tampered(registry: Registry, name: str) -> bool:
    trusted = _TRUSTED.get((registry.kind, name))
    if trusted is None:
        return False
    reg = registry._entries.get(name)
    return reg is None or not _same(_fingerprint(reg), trusted)


def _check_builtin(registry: Registry, name: str, culprit: str | None) -> str | None:
    """Refuse (or, when allowed, record) a built-in registration changed outside `register`.

    Returns the refusal message when `culprit` names the plug-in being loaded (the
    registration is then restored); raises `UserError` otherwise.
    """
    if not _tampered(registry, name):
        return None
    if override_allowed():
        reg = registry._entries.get(name)
        if reg is None:
            _restore(registry, name, _TRUSTED[(registry.kind, name)])
            return None
        honest = Registration(
            kind=reg.kind,
            type=reg.type,
            config=reg.config,
            factory=reg.factory,
            source=_override_source(reg.factory),
            summary=reg.summary,
        )
        registry._entries[name] = honest
        _record_override(registry.kind, name, "patched the registry")
        _TRUSTED[(registry.kind, name)] = _fingerprint(honest)
        return None
    reg = registry._entries.get(name)
    fn = reg.factory if reg is not None else None
    what = (
        f"the built-in {registry.kind} type {name!r} was replaced by patching the registry "
        f"(its factory is now {getattr(fn, '__module__', '?')}:{getattr(fn, '__qualname__', '?')}"
        f" from {_code_file(fn)})"
    )
    if culprit is not None:
        _restore(registry, name, _TRUSTED[(registry.kind, name)])
        return what
    raise UserError(
        f"{what}; refusing to run it. Uninstall the plug-in that did it, or allow it with "
        f"`rodctl --allow-override` ({ALLOW_OVERRIDE_ENV}=1)"
    )


FEATURES: Registry = Registry("feature", default="autoencoder")
ESTIMATORS: Registry = Registry("estimator", default="akf")
CONTROLLERS: Registry = Registry("controller", default="mfac")

EVENTS: Registry = Registry("event", default=None)
SINKS: Registry = Registry("sink", default=None)
EXECUTORS: Registry = Registry("executor", default="local")

#: The registries of a method's stages, by the config section they fill.
STAGES: dict[str, Registry] = {
    "feature": FEATURES,
    "estimator": ESTIMATORS,
    "controller": CONTROLLERS,
}

#: Every registry, by kind: the three stages, then mid-run events, output sinks, executors.
KINDS: dict[str, Registry] = {
    **STAGES,
    "event": EVENTS,
    "sink": SINKS,
    "executor": EXECUTORS,
}

#: Config models whose schema embeds the stage unions; rebuilt when a type is registered.
_DEPENDENT_MODELS: list[type[BaseModel]] = []
_LOADING: str | None = None  # the plug-in entry point being loaded (for `source`)
_IN_WORKER = False  # a worker process: the parent has already warned
#: (kind, type) of rodctl's own types: the fingerprint of each as rodctl registered it, and of
#: the registration allowed now (the same, or an override the user allowed).
_ORIGINAL: dict[tuple[str, str], tuple[Any, ...]] = {}
_TRUSTED: dict[tuple[str, str], tuple[Any, ...]] = {}
#: Plug-ins loaded by this process (`plugin_provenance`), and the overrides allowed.
LOADED: list[dict[str, Any]] = []
OVERRIDES: list[dict[str, Any]] = []
_BUILTINS_LOADED = False
_PLUGINS_LOADED = False
_QUIET = False  # registering built-ins: the models are built once, afterwards

#: The modules that register the built-in types (imported on first use of a registry). The one
#: list of them: tests/test_registry.py checks that every module of rodctl that registers a
#: type is here, and that each one here registers one, so a built-in cannot be silently absent.
_BUILTIN_MODULES = (
    "rodctl.features.autoencoder_config",
    "rodctl.features.bezier",
    "rodctl.features.fourier",
    "rodctl.features.nodes",
    "rodctl.estimation.akf",
    "rodctl.estimation.broyden",
    "rodctl.estimation.windowed_ls",
    "rodctl.estimation.asap",
    "rodctl.estimation.oracle",
    "rodctl.estimation.learned",
    "rodctl.control.mfac",
    "rodctl.control.pinv",
    "rodctl.control.qp",
    "rodctl.control.scripted",
    "rodctl.control.convex",
    "rodctl.events",
    "rodctl.logs.sinks",
    "rodctl.executors.local",
    "rodctl.executors.ray",
)


def depends_on_stages(model: type[BaseModel]) -> type[BaseModel]:
    """Class decorator: rebuild `model`'s schema whenever the set of registered types changes
    (of any kind; a model embedding another dependent model is decorated after it, and so
    rebuilt after it)."""
    _DEPENDENT_MODELS.append(model)
    return model


def _invalidate_models() -> None:
    if _QUIET:
        return
    for model in _DEPENDENT_MODELS:
        if model.__pydantic_complete__:
            model.model_rebuild(force=True)


def load_builtins() -> None:
    """Import the modules that register rodctl's own types (idempotent)."""
    global _BUILTINS_LOADED, _QUIET
    if _BUILTINS_LOADED:
        return
    _BUILTINS_LOADED = True
    _QUIET = True
    try:
        for name in _BUILTIN_MODULES:
            importlib.import_module(name)
    finally:
        _QUIET = False
    for kind, registry in KINDS.items():
        for reg in registry:
            if _is_builtin_code(reg.factory):
                _ORIGINAL[(kind, reg.type)] = _TRUSTED[(kind, reg.type)] = _fingerprint(reg)
    _invalidate_models()


@dataclass(frozen=True)
class PluginError:
    """A plug-in that could not be loaded."""

    name: str
    value: str
    error: str


def load_plugins(*, strict: bool = True) -> list[PluginError]:
    """Import every entry point of the group `rodctl.plugins` (once per process).

    Every command calls this at start-up, and so do compare's worker processes. An entry point
    names a module (`pkg.module`) or a callable (`pkg.module:register`, called with no
    arguments) that registers types in the registries above.

    Args:
        strict: raise a `UserError` for the first plug-in that fails; otherwise return the
            failures (`rodctl plugins` lists them).

    Raises:
        UserError: (strict) a plug-in failed to import, naming it and why.
    """
    global _PLUGINS_LOADED, _LOADING
    load_builtins()
    if _PLUGINS_LOADED:
        return []
    _PLUGINS_LOADED = True
    failures: list[PluginError] = []
    for ep in sorted(metadata.entry_points(group=PLUGIN_GROUP), key=lambda e: e.name):
        dist = getattr(ep, "dist", None)
        _LOADING = f"{dist.name} {dist.version}" if dist is not None else ep.name
        try:
            obj = ep.load()
            if callable(obj) and not isinstance(obj, type(sys)):
                obj()
        except OverrideRefused as exc:
            failures.append(PluginError(ep.name, ep.value, str(exc)))
        except Exception as exc:  # noqa: BLE001 - a broken plug-in is reported, not a traceback
            failures.append(PluginError(ep.name, ep.value, f"{type(exc).__name__}: {exc}"))
        except BaseException as exc:  # noqa: BLE001 - sys.exit or Ctrl-C at import: named, exit 2
            what = "it called sys.exit" if isinstance(exc, SystemExit) else "it raised"
            failures.append(
                PluginError(ep.name, ep.value, f"{what} at import: {type(exc).__name__}({exc})")
            )
        else:
            LOADED.append(_loaded_record(ep, dist))
        finally:
            for kind, registry in KINDS.items():
                for name in sorted(t for k, t in _ORIGINAL if k == kind):
                    refused = _check_builtin(registry, name, culprit=_LOADING)
                    if refused:
                        failures.append(
                            PluginError(
                                ep.name,
                                ep.value,
                                f"{refused}, which needs `rodctl --allow-override` "
                                f"({ALLOW_OVERRIDE_ENV}=1)",
                            )
                        )
            _LOADING = None
    if failures and strict:
        f = failures[0]
        raise UserError(
            f"plug-in {f.name!r} ({f.value}, entry point group {PLUGIN_GROUP}) failed to load: "
            f"{f.error}. Fix or uninstall it (`pip uninstall` its package)"
        )
    return failures


def _loaded_record(ep: Any, dist: Any) -> dict[str, Any]:
    """What meta.json and the MCAP header say of one loaded plug-in."""
    module = ep.value.split(":")[0].strip()
    path = getattr(sys.modules.get(module), "__file__", None)
    digest = None
    if path:
        try:
            digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
        except OSError:
            digest = None
    return {
        "entry_point": ep.name,
        "value": ep.value,
        "distribution": dist.name if dist is not None else None,
        "version": dist.version if dist is not None else None,
        "module": module,
        "file": path,
        "sha256": digest,
    }


def plugin_provenance() -> dict[str, Any]:
    """The plug-ins this process loaded and the built-in types they were allowed to replace."""
    return {"loaded": [dict(p) for p in LOADED], "overrides": [dict(o) for o in OVERRIDES]}


def stage_provenance(cfg: Any) -> dict[str, Any]:
    """Which registered factory builds each stage of `cfg` (a config with `feature`,
    `estimator` and `controller` sections; a compare config: one entry per method)."""
    load_plugins()

    def one(section: Any) -> dict[str, Any]:
        return {
            kind: STAGES[kind].provenance(getattr(section, kind).type)
            for kind in STAGES
            if getattr(section, kind, None) is not None
        }

    methods = getattr(cfg, "methods", None)
    if isinstance(methods, dict):
        return {name: one(m) for name, m in methods.items()}
    if getattr(cfg, "feature", None) is None and getattr(cfg, "base", None) is not None:
        return {"base": one(cfg.base)}  # a sweep of its base's stages
    return one(cfg)


def component_provenance(cfg: Any, executor: str | None = None) -> dict[str, Any]:
    """Which registered factory builds each mid-run event (`run.events`) and each sink (the
    MCAP and Rerun switches, the figures, `logging.sinks`) of `cfg` (an experiment config, or a
    compare or sweep config: its `base`'s), and the executor `executor` (`--executor`), plug-ins
    included: with `stage_provenance`, every registered type a run was made with."""
    load_plugins()
    exp = cfg if getattr(cfg, "logging", None) is not None else getattr(cfg, "base", None)
    out: dict[str, Any] = {}
    if exp is not None and getattr(exp, "run", None) is not None:
        log = exp.logging  # the sinks in `rodctl.logs.sinks.selected_sinks` order, by name
        switched = [("figures", log.figures), ("mcap", log.mcap), ("rerun", log.rerun)]
        sinks = [name for name, on in switched if on] + [s.type for s in log.sinks]
        out["events"] = [EVENTS.provenance(e.type) for e in exp.run.events]
        out["sinks"] = [SINKS.provenance(name) for name in sinks]
    if executor is not None:
        out["executor"] = EXECUTORS.provenance(executor)
    return out
