"""The compliance models (Top10NN, VGG-LSTM, Res-Tf), their backbones and the registry.

Build a model by name: ``create_model("res_tf", inputs="ImageFW")``; see
``list_models()`` for the names and ``docs/models.md`` for the architectures. The
paper's per-model settings and search spaces are declared on the model classes and read
with ``paper_settings(name, inputs)`` / ``search_dimensions(name, inputs)``.
"""

from __future__ import annotations

from tactile_compliance.models.backbones import (
    BACKBONE_WEIGHTS_URLS,
    create_backbone,
    list_backbones,
)
from tactile_compliance.models.base import NUM_FRAMES, FusionModel, TactileModel
from tactile_compliance.models.inputs import InputStrategy
from tactile_compliance.models.registry import (
    create_model,
    get_model_class,
    list_models,
    model_hyperparameters,
    register_model,
)

# Importing the model modules registers them.
from tactile_compliance.models.res_tf import ResTf
from tactile_compliance.models.settings import (
    SearchDimension,
    paper_settings,
    search_dimensions,
)
from tactile_compliance.models.top10nn import Top10NN
from tactile_compliance.models.vgg_lstm import VggLstm

__all__ = [
    "BACKBONE_WEIGHTS_URLS",
    "NUM_FRAMES",
    "FusionModel",
    "InputStrategy",
    "ResTf",
    "SearchDimension",
    "TactileModel",
    "Top10NN",
    "VggLstm",
    "create_backbone",
    "create_model",
    "get_model_class",
    "list_backbones",
    "list_models",
    "model_hyperparameters",
    "paper_settings",
    "register_model",
    "search_dimensions",
]
