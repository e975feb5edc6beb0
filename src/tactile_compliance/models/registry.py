"""Model registry: ``register_model`` / ``create_model`` / ``list_models`` (timm style).
Adding a model: docs/models.md, "Adding a model".

A model registers where it is defined: the first lookup imports every module of this
package and every entry point of :data:`ENTRY_POINT_GROUP` (:func:`discover_models`), so
a new module in ``models/`` or an installed plugin needs no list to be named in.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect
import pkgutil
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

from torch import nn

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.models import ENTRY_POINT_GROUP
from tactile_compliance.suggest import did_you_mean

__all__ = [
    "ENTRY_POINT_GROUP",
    "backbone_models",
    "create_model",
    "discover_models",
    "get_model_class",
    "list_models",
    "model_display_names",
    "model_hyperparameters",
    "register_model",
    "takes_any_hparam",
]

_REGISTRY: dict[str, type[nn.Module]] = {}


_PACKAGE = __name__.rpartition(".")[0]
_discovered = False


def discover_models() -> None:
    """Import, once per process, every module of ``tactile_compliance.models`` (but those
    whose name starts with ``_``) and load every entry point of :data:`ENTRY_POINT_GROUP`;
    importing a module runs its ``@register_model`` decorators. Every lookup below calls
    it first, so a fresh process finds the model a checkpoint names.

    An entry point that fails to load is skipped with a one-line ``RuntimeWarning``
    naming it (a broken plugin must not stop the built-in models); a built-in module that
    fails to import raises.
    """
    global _discovered
    if _discovered:
        return
    # Set first: a model module that looks a model up while it is imported must not
    # start the discovery again.
    _discovered = True
    package = importlib.import_module(_PACKAGE)
    for module in pkgutil.iter_modules(package.__path__):
        if not module.name.startswith("_"):
            importlib.import_module(f"{_PACKAGE}.{module.name}")
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            entry.load()
        except Exception as err:  # any failure of a third-party import
            warnings.warn(
                f"model plugin {entry.name!r} ({entry.value}) failed to load and is "
                f"skipped: {type(err).__name__}: {err}",
                RuntimeWarning,
                stacklevel=2,
            )


ModelT = TypeVar("ModelT", bound=type[nn.Module])


def register_model(name: str) -> Callable[[ModelT], ModelT]:
    """Class decorator that makes a model available to :func:`create_model` as ``name``
    (and sets ``cls.model_name``, which checkpoints record). The class takes ``inputs``
    first and its hyperparameters as keyword arguments; a name taken is a ValueError."""
    key = name.strip().lower()
    if not key:
        raise ValueError("model name must not be empty")

    def decorator(cls: ModelT) -> ModelT:
        existing = _REGISTRY.get(key)
        # Re-registering the same class (module reload) is fine; shadowing another is not.
        if existing is not None and existing.__qualname__ != cls.__qualname__:
            raise ValueError(
                f"model name {key!r} is already registered by {existing.__module__}."
                f"{existing.__qualname__}"
            )
        cls.model_name = key  # type: ignore[attr-defined]
        _REGISTRY[key] = cls
        return cls

    return decorator


def list_models() -> list[str]:
    """Registered model names, sorted."""
    discover_models()
    return sorted(_REGISTRY)


def model_display_names() -> dict[str, str]:
    """Registered name -> display name, in display order, from each class's
    ``display_name`` and ``display_order``."""
    discover_models()
    # Classes that declare no order come after the declared ones (then by name).
    order = {name: int(getattr(cls, "display_order", 1_000_000)) for name, cls in _REGISTRY.items()}
    ranked = sorted(_REGISTRY, key=lambda name: (order[name], name))
    return {name: getattr(_REGISTRY[name], "display_name", "") or name for name in ranked}


def backbone_models() -> dict[str, str]:
    """Pretrainable backbone name -> the registered model that uses it, from each class's
    ``pretrain_backbones``."""
    return {
        backbone: name
        for name in list_models()
        for backbone in getattr(_REGISTRY[name], "pretrain_backbones", ())
    }


def get_model_class(name: str) -> type[nn.Module]:
    """The class registered as ``name`` (case-insensitive); ValueError lists the models."""
    discover_models()
    key = name.strip().lower() if isinstance(name, str) else name
    if key not in _REGISTRY:
        raise ValueError(
            f"unknown model {name!r}{did_you_mean(str(name), list_models())}; available "
            f"models: {', '.join(list_models()) or '(none)'}"
        )
    return _REGISTRY[key]


def model_hyperparameters(name: str) -> dict[str, Any]:
    """The constructor keyword arguments of model ``name`` (but ``inputs``) and their defaults."""
    signature = inspect.signature(get_model_class(name).__init__)
    return {
        p.name: p.default
        for p in signature.parameters.values()
        if p.name not in ("self", "inputs") and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    }


def takes_any_hparam(name: str) -> bool:
    """Whether model ``name``'s constructor takes ``**kwargs`` (any hyperparameter)."""
    parameters = inspect.signature(get_model_class(name).__init__).parameters.values()
    return any(p.kind is p.VAR_KEYWORD for p in parameters)


def create_model(name: str, inputs: InputStrategy | str = "ALL", **hparams: Any) -> nn.Module:
    """Build registered model ``name`` (case-insensitive) for input strategy ``inputs``;
    hyperparameters not given take the paper's defaults.

    Raises:
        ValueError: unknown model name, input strategy or hyperparameter (the message
            names it and lists the valid ones).
    """
    cls = get_model_class(name)
    strategy = InputStrategy.parse(inputs)
    if not takes_any_hparam(name):
        valid = model_hyperparameters(name)
        unknown = sorted(set(hparams) - set(valid))
        if unknown:
            raise ValueError(
                f"unknown hyperparameter(s) {', '.join(unknown)} for model {name!r}; "
                f"valid: {', '.join(sorted(valid))}"
            )
    return cls(strategy, **hparams)
