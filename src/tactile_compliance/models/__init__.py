"""The compliance models (Top10NN, VGG-LSTM, Res-Tf), their backbones and the registry.

Build a model by name: ``create_model("res_tf", inputs="ImageFW")``; see docs/models.md.
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata
import pkgutil
import re
import sys
from pathlib import Path
from typing import Any

# InputStrategy (data.inputs) is torch-free and re-exported here for the models' users;
# the rest (torch, the networks) loads on first use of a name below (PEP 562). Models
# register where they are defined: the registry's first lookup imports every module of
# this package (registry.discover_models), so a new model is one module, named nowhere.
from tactile_compliance.data.inputs import InputStrategy

#: Public name -> the module of this package that defines it (the package's API; a new
#: model need not be added).
_LAZY = {
    "BACKBONE_WEIGHTS_URLS": "backbones",
    "create_backbone": "backbones",
    "list_backbones": "backbones",
    "backbone_models": "registry",
    "NUM_FRAMES": "base",
    "FusionModel": "base",
    "TactileModel": "base",
    "create_model": "registry",
    "get_model_class": "registry",
    "list_models": "registry",
    "model_display_names": "registry",
    "model_hyperparameters": "registry",
    "register_model": "registry",
    "ResTf": "res_tf",
    "ScalarMLP": "scalar_mlp",
    "SearchDimension": "settings",
    "paper_settings": "settings",
    "search_dimensions": "settings",
    "Top10NN": "top10nn",
    "VggLstm": "vgg_lstm",
}


#: A model's registration as its module writes it (read by ``known_model_names``).
_REGISTERED = re.compile(r"""@register_model\(\s*["']([A-Za-z0-9_.-]+)["']""")
#: Entry-point group through which another distribution adds models: each entry, named
#: after its model, names a module (or an object in one) whose import registers the model
#: with ``register_model``.
ENTRY_POINT_GROUP = "tactile_compliance.models"


@functools.cache  # every config validates its model name: read the sources once
def _declared_model_names() -> frozenset[str]:
    """The names the package's modules and the entry points declare (see below)."""
    names: set[str] = set()
    for module in pkgutil.iter_modules(__path__):
        path = Path(getattr(module.module_finder, "path", "")) / f"{module.name}.py"
        if not module.name.startswith("_") and path.is_file():
            names.update(_REGISTERED.findall(path.read_text(encoding="utf-8")))
    names.update(e.name for e in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP))
    return frozenset(names)


def known_model_names() -> list[str]:
    """The model names ``create_model`` takes, sorted, without loading torch.

    The names this package's modules register (``register_model`` decorators), read from
    their sources (not imported), the names of the ``tactile_compliance.models``
    entry points (an entry point is named after its model), and, once the registry is
    loaded, any model a program registered. The registry's own list after
    ``discover_models`` is the same set (tests/test_models.py checks it)."""
    names = set(_declared_model_names())
    registry = sys.modules.get(f"{__name__}.registry")
    if registry is not None:
        names.update(registry.list_models())
    return sorted(names)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


__all__ = [
    "BACKBONE_WEIGHTS_URLS",
    "ENTRY_POINT_GROUP",
    "NUM_FRAMES",
    "FusionModel",
    "InputStrategy",
    "ResTf",
    "ScalarMLP",
    "SearchDimension",
    "TactileModel",
    "Top10NN",
    "VggLstm",
    "backbone_models",
    "create_backbone",
    "create_model",
    "get_model_class",
    "known_model_names",
    "list_backbones",
    "list_models",
    "model_display_names",
    "model_hyperparameters",
    "paper_settings",
    "register_model",
    "search_dimensions",
]
