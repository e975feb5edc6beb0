"""The compliance models (Top10NN, VGG-LSTM, Res-Tf), their backbones and the registry.

Build a model by name: ``create_model("res_tf", inputs="ImageFW")``; see docs/models.md.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

# InputStrategy (data.inputs) is torch-free and re-exported here for the models' users;
# the rest (torch, the networks) loads on first use of a name below (PEP 562), and that
# first use imports the model modules, which registers them.
from tactile_compliance.data.inputs import InputStrategy

#: Public name -> the module of this package that defines it.
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
#: Importing these modules registers the built-in models.
_MODEL_MODULES = ("res_tf", "scalar_mlp", "top10nn", "vgg_lstm")


def known_model_names() -> list[str]:
    """The model names ``create_model`` takes, sorted, without loading torch: the built-in
    models (each module of ``_MODEL_MODULES`` registers the model of its own name;
    tests/test_models.py checks it) and, once the registry is loaded, any model a program
    registered."""
    registry = sys.modules.get(f"{__name__}.registry")
    added = registry.list_models() if registry is not None else []
    return sorted({*_MODEL_MODULES, *added})


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    for model_module in _MODEL_MODULES:
        importlib.import_module(f"{__name__}.{model_module}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


__all__ = [
    "BACKBONE_WEIGHTS_URLS",
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
