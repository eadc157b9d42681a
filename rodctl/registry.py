"""Open registries of the pluggable stages, and plug-in loading.

Why: a method is three stages (feature map, Jacobian estimator, controller) and every one of them
is chosen in a config by its `type`. Each type registers itself *beside its implementation*,
together with its config model and a factory, so that adding a type touches one module: the
config unions, the JSON schema (`rodctl config schema`), `rodctl plugins` and the method builder
all read these registries. Packages outside rodctl add types the same way from a module named
by an entry point in the group `rodctl.plugins` (Gymnasium's `register` + entry points and
LeRobot's `register_third_party_plugins` are the models).

Usage, next to an implementation::

    class MyControllerConfig(StrictModel):
        type: Literal["mine"] = "mine"
        gain: float = 0.5

    @CONTROLLERS.register(MyControllerConfig)
    def _build(cfg: MyControllerConfig, ctx: BuildContext) -> Controller:
        return MyController(cfg.gain)
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any, Generic, TypeVar

import numpy as np
from pydantic import BaseModel

from rodctl.errors import UserError

#: The entry-point group outside packages use to add stage types.
PLUGIN_GROUP = "rodctl.plugins"

C = TypeVar("C", bound=BaseModel)
T = TypeVar("T")


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
    experiment: Any = None


@dataclass(frozen=True)
class Registration(Generic[C]):
    """One registered type: its config model, its factory and where it comes from."""

    kind: str
    type: str
    config: type[C]
    factory: Callable[[C, BuildContext], Any]
    source: str
    summary: str = ""


@dataclass
class Registry(Generic[T]):
    """The types of one stage kind ("feature", "estimator", "controller"), by `type` name."""

    kind: str
    default: str
    _entries: dict[str, Registration] = field(default_factory=dict)

    def register(
        self, config: type[C], *, replace: bool = False
    ) -> Callable[[Callable[[C, BuildContext], T]], Callable[[C, BuildContext], T]]:
        """Decorator registering `factory(cfg, ctx)` for the config model `config`.

        The type name is the default of the model's `type` field (a `Literal`).

        Raises:
            ValueError: the model has no `type` default, or the name is taken (unless
                `replace`).
        """
        name = _type_name(config)

        def decorator(factory: Callable[[C, BuildContext], T]) -> Callable[[C, BuildContext], T]:
            if name in self._entries and not replace:
                raise ValueError(
                    f"{self.kind} type {name!r} is already registered by "
                    f"{self._entries[name].source}"
                )
            doc = (config.__doc__ or "").strip().splitlines()
            self._entries[name] = Registration(
                kind=self.kind,
                type=name,
                config=config,
                factory=factory,
                source=_source_of(factory),
                summary=doc[0] if doc else "",
            )
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

    def build(self, cfg: BaseModel, ctx: BuildContext) -> T:
        """The object `cfg` describes, made by its registered factory."""
        return self.get(cfg.type).factory(cfg, ctx)  # type: ignore[attr-defined]


def _type_name(config: type[BaseModel]) -> str:
    f = config.model_fields.get("type")
    if f is None or not isinstance(f.default, str):
        raise ValueError(f"{config.__name__} needs a field `type: Literal[...] = '<name>'`")
    return f.default


def _source_of(fn: Callable[..., Any]) -> str:
    module = getattr(fn, "__module__", "") or ""
    top = module.split(".")[0]
    if top == "rodctl":
        return "rodctl (built-in)"
    return f"plug-in {_LOADING or top} ({module})"


FEATURES: Registry = Registry("feature", default="autoencoder")
ESTIMATORS: Registry = Registry("estimator", default="akf")
CONTROLLERS: Registry = Registry("controller", default="mfac")

#: The registries by the config section they fill.
STAGES: dict[str, Registry] = {
    "feature": FEATURES,
    "estimator": ESTIMATORS,
    "controller": CONTROLLERS,
}

#: Config models whose schema embeds the stage unions; rebuilt when a type is registered.
_DEPENDENT_MODELS: list[type[BaseModel]] = []
_LOADING: str | None = None  # the plug-in entry point being loaded (for `source`)
_BUILTINS_LOADED = False
_PLUGINS_LOADED = False
_QUIET = False  # registering built-ins: the models are built once, afterwards

#: The modules that register the built-in types (imported on first use of a registry).
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
)


def depends_on_stages(model: type[BaseModel]) -> type[BaseModel]:
    """Class decorator: rebuild `model`'s schema whenever the set of stage types changes."""
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
        except Exception as exc:  # noqa: BLE001 - a broken plug-in is reported, not a traceback
            failures.append(PluginError(ep.name, ep.value, f"{type(exc).__name__}: {exc}"))
        finally:
            _LOADING = None
    if failures and strict:
        f = failures[0]
        raise UserError(
            f"plug-in {f.name!r} ({f.value}, entry point group {PLUGIN_GROUP}) failed to load: "
            f"{f.error}. Fix or uninstall it (`pip uninstall` its package)"
        )
    return failures
